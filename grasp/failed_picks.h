// Failed-pick feedback (issue 41 part 3; docs/protocols.md "Failed-pick
// feedback"): a robot reports that the last grasp it was given failed, and
// binpick stops sending it to that spot for a while.
//
// A failed spot is where the part was, in the bin frame W (X_WB * the part's
// origin in base; W the bin its grasp's capture measured, Grasp::X_BW, else
// the nominal bin), with its class, so it survives re-captures: a later
// capture's detection of the same part lands on the same spot. One task's
// rule (FailedPickRule, cell tasks[].failed_picks):
//   - a report on a part within `radius` of a remembered spot of the same
//     class counts one more failure there; else it opens a spot;
//   - a spot is remembered for `captures` captures of the task after its
//     last failure (OnCapture ages it), then released;
//   - a grasp whose part lies within `radius` of a remembered spot (the
//     part itself, or a near neighbour that the failed attempt may have
//     moved) is withheld: it leaves the queue while any other grasp is left;
//     when only withheld grasps are left they stay (the robot would
//     otherwise stop on a part it may still pick: a slip is often chance);
//   - a grasp on a spot with `max_failures` failures (same class) is
//     refused: it leaves the queue even when nothing else is left, and a
//     queue emptied that way answers NO_COLLISION_FREE_POSE;
//   - a collision (the robot stopped on contact) takes its spot to
//     `max_failures` at once: the robot is never sent into the same contact
//     again while the spot is remembered (a vacuum or slip failure is often
//     chance, a contact is the plan's, and another try would repeat it);
//     and a spot with a collision is remembered while its part is there:
//     each capture that detects a part of its class within `radius` of it
//     (Seen) counts as its last failure, so it is released `captures`
//     captures after the last capture that showed it, once the part is gone
//     or moved away (what the tool met is still there while the part is:
//     docs/tuning.md, "Hidden space behind detected parts");
//   - a failed last resort (Grasp::last_resort: a grasp on an ambiguous
//     detection that lands only if the pose it was planned on is true) also
//     refutes that pose: while the spot is remembered, plans put the
//     detection there on its other poses (Refuted, ApplyRefutedPoses), and
//     a grasp so planned (Grasp::reposed) is served, not withheld.
//
// Thread-safety: every member is safe to call concurrently (one mutex).
// Screen() is called under a GraspQueue's lock (GraspQueue::SetScreen), so
// FailedPicks never calls into a queue.
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <mutex>
#include <span>
#include <string>
#include <string_view>
#include <tuple>
#include <utility>
#include <vector>

#include "core/cell.h"
#include "core/pose.h"
#include "grasp/grasp.h"
#include "grasp/planner.h"
#include "pipeline/perception.h"

namespace bp {

// Why the pick failed, as the robot says (the request's payload_2).
enum class PickFailure : int32_t {
  kUnspecified = 0,
  kNoVacuum = 1,  // the vacuum never built up
  kSlipped = 2,   // the part was held, then lost
  kCollision = 3,  // the robot stopped on contact (a protective stop, a force limit)
};
std::string_view ToString(PickFailure reason);
// 0, 1, 2, 3 -> the reason; anything else -> false.
bool PickFailureFromWire(int32_t value, PickFailure* out);

class FailedPicks {
 public:
  // Spots are kept in the bin frame of each grasp (Grasp::X_BW, where bin
  // detection measured the bin), else in `X_BW` (the cell's nominal bin pose).
  FailedPicks(FailedPickRule rule, Pose X_BW);

  // What a report did.
  struct Recorded {
    int failures = 0;      // failures on the spot, this one included
    bool refused = false;  // the spot reached max_failures: its grasps are refused
  };
  // The robot reports that `grasp` failed.
  Recorded Report(const Grasp& grasp, PickFailure reason);
  // A capture of the task happened: every spot ages by one capture; spots
  // `captures` captures past their last failure are released.
  void OnCapture();
  // The parts a capture of the task detected (their classes and poses in
  // B; the bin of that capture at X_BW, nullopt: the nominal one): a spot
  // with a collision and a part of its class within `radius` is still
  // there, aged back to 0. Called after OnCapture, before the capture's
  // plan is screened.
  void Seen(std::span<const DetectedPart> parts, const std::optional<Pose>& X_BW);

  enum class Verdict { kServe, kWithheld, kRefused };
  Verdict Judge(const Grasp& grasp) const;
  // Applies the rule above to grasps in queue order (order kept).
  // @returns the grasps removed.
  std::vector<Grasp> Screen(std::deque<Grasp>& grasps) const;
  std::vector<Grasp> Screen(std::vector<Grasp>& grasps) const;

  // Failures reported since start, per part class and grasp name (the
  // cell's grasp name; a symmetry variant's suffix "@k" / "~v" kept off).
  struct Count {
    int class_id = 0;
    std::string grasp;
    PickFailure reason = PickFailure::kUnspecified;
    uint64_t failures = 0;
  };
  std::vector<Count> Counts() const;
  // A spot remembered now.
  struct Spot {
    Vec3 p_W = Vec3::Zero();  // part origin in the bin frame, m
    int class_id = 0;
    int failures = 0;
    int age = 0;  // captures since its last failure, or since a capture showed its part (collided)
    bool collided = false;  // a failure there was a collision (Seen keeps it)
    std::vector<Pose> refuted_X_WO = {};  // poses failed last resorts were planned on
  };
  std::vector<Spot> Spots() const;
  // The poses the remembered spots' failed last resorts refuted (for
  // PlanRequest::refuted).
  std::vector<RefutedPose> Refuted() const;
  const FailedPickRule& rule() const { return rule_; }

 private:
  Vec3 InBin(const Grasp& grasp) const;
  Verdict JudgeLocked(const Grasp& grasp) const;  // mutex_ held
  template <typename Seq>
  std::vector<Grasp> ScreenImpl(Seq& grasps) const;

  const FailedPickRule rule_;
  const Pose X_WB_;
  mutable std::mutex mutex_;
  std::vector<Spot> spots_;  // GUARDED_BY(mutex_)
  // (class, grasp name, reason) -> failures.  GUARDED_BY(mutex_)
  std::map<std::tuple<int, std::string, int32_t>, uint64_t> counts_;
};

// The cell's grasp name of a queued grasp: "run_top@3~v" -> "run_top".
std::string BaseGraspName(const std::string& name);

// A detection's pose matches a refuted one within the strict pose
// tolerance (5 mm, 5 deg, symmetry-aware): a new capture of an unmoved part
// finds it there again, and an ambiguous detection's poses differ by more.
inline constexpr double kRefutedMatchPosition = 0.005;  // m
inline constexpr double kRefutedMatchDeg = 5.0;
// Puts each ambiguous detection (Detection::alternatives_X_BO) with some
// pose, best or alternative, at a refuted pose of its class (X_BW: the
// bin of this capture) on its other poses: the best of those left becomes
// X_BO, the rest its alternatives. A detection all of whose poses are
// refuted is left as it is. @returns per detection whether it was changed.
std::vector<bool> ApplyRefutedPoses(std::span<const RefutedPose> refuted, const Cell& cell, const Pose& X_BW,
                                    std::vector<Detection>& detections);

}  // namespace bp
