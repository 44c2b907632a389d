// Taught grasps (RC_SEND_POSE), persisted in a small YAML file:
//
//   # binpick taught grasps (X_OG: tool centre point in the part frame)
//   grasps:
//     - {class_id: 0, name: taught_1, gripper: suction,
//        pose: {xyz: [x, y, z], quat_wxyz: [w, x, y, z]}}
//
// Every Add rewrites the file atomically (temp file, fsync, rename), so a
// crash leaves either the old or the new file, never a torn one.
// Thread-safety: all members may be called concurrently.
#pragma once

#include <mutex>
#include <string>
#include <vector>

#include "core/status.h"
#include "grasp/grasp_planning.h"

namespace bp {

class TeachStore {
 public:
  // Taught grasps kept per part class and gripper (issue 39: each one adds
  // candidates to every plan, and a robot looping RC 30 must not grow the
  // file and the plans without bound).
  static constexpr size_t kDefaultMaxPerClass = 32;

  // An empty path keeps grasps in memory only.
  explicit TeachStore(std::string path = {}, size_t max_per_class = kDefaultMaxPerClass);
  // Loads the file if it exists (a missing file is an empty store).
  // @returns Corruption naming the file for unreadable YAML or bad entries.
  Status Load();
  // Stores `grasp` (named taught_<n> when its name is empty) and persists.
  // @returns OutOfRange (not stored) when its class and gripper already have
  // max_per_class grasps; Internal naming the file when it cannot be
  // written (the grasp stays in memory).
  Status Add(TaughtGrasp grasp);
  std::vector<TaughtGrasp> All() const;
  const std::string& path() const { return path_; }

 private:
  Status WriteLocked() const;  // REQUIRES: mutex_ held
  const std::string path_;
  const size_t max_per_class_;
  mutable std::mutex mutex_;
  std::vector<TaughtGrasp> grasps_;  // GUARDED_BY(mutex_)
};

}  // namespace bp
