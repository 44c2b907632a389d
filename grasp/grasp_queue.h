// One task's queue of grasps, refilled by each detection.
//
// Thread-safety: every member is safe to call concurrently; each grasp of a
// Replace() is handed out by exactly one Pop(). Replace and Pop are atomic
// with respect to each other: a Pop sees either the old or the new queue.
#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <optional>

#include "grasp/grasp.h"
#include "grasp/planner.h"

namespace bp {

class GraspQueue {
 public:
  struct Popped {
    std::optional<Grasp> grasp;  // empty when the queue is exhausted or was never filled
    // Grasps left INCLUDING this one (the DaoAI payload_1): N for the first of
    // N, 1 for the last, 0 when `grasp` is empty.
    int remaining = 0;
    // Outcome of the plan that filled the queue; empty when no plan has
    // completed since construction or the last Reset().
    std::optional<PlanResult::Outcome> outcome;
    uint64_t generation = 0;  // increments with every Replace / Reset
    // PopFirst: grasps the predicate refused, left queued in their order.
    int refused = 0;
  };

  // A summary of the last plan without its grasps.
  struct Summary {
    PlanResult::Outcome outcome = PlanResult::Outcome::kNoObjects;
    int total_grasps = 0;
    int64_t roi_points = 0;
    int64_t largest_region_points = 0;
    int detections = 0;
  };

  // Discards what is left and queues result.grasps in order.
  void Replace(PlanResult result);
  // Discards everything; Pop reports no outcome until the next Replace.
  void Reset();
  Popped Pop();
  // Pops the first grasp, in queue order, that `sendable` accepts; it is
  // given each grasp with the remaining count it would be answered with (the
  // queue's size, including the grasp). The grasps it refuses stay queued,
  // in order, and are counted in Popped::refused; `grasp` is empty when none
  // is accepted. `sendable` runs under the queue's lock: it must not call
  // back into the queue. Used to encode and range-check an answer before its
  // grasp leaves the queue (docs/protocols.md, "Nothing lost in 16 bits").
  Popped PopFirst(const std::function<bool(const Grasp&, int remaining)>& sendable);
  int size() const;
  std::optional<Summary> LastPlan() const;

 private:
  mutable std::mutex mutex_;
  std::deque<Grasp> grasps_;        // GUARDED_BY(mutex_)
  std::optional<Summary> summary_;  // GUARDED_BY(mutex_)
  uint64_t generation_ = 0;         // GUARDED_BY(mutex_)
};

}  // namespace bp
