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
  // An empty path keeps grasps in memory only.
  explicit TeachStore(std::string path = {});
  // Loads the file if it exists (a missing file is an empty store).
  // @returns Corruption naming the file for unreadable YAML or bad entries.
  Status Load();
  // Stores `grasp` (named taught_<n> when its name is empty) and persists.
  // @returns Internal naming the file when it cannot be written; the grasp
  // stays in memory either way.
  Status Add(TaughtGrasp grasp);
  std::vector<TaughtGrasp> All() const;
  const std::string& path() const { return path_; }

 private:
  Status WriteLocked() const;  // REQUIRES: mutex_ held
  const std::string path_;
  mutable std::mutex mutex_;
  std::vector<TaughtGrasp> grasps_;  // GUARDED_BY(mutex_)
};

}  // namespace bp
