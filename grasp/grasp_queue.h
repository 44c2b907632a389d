// One task's queue of grasps, refilled by each detection.
//
// A stale queue is never served: when Pop hands out a grasp on part P, the
// queued grasps whose Grasp::stale_after names P (parts that touched P, or
// whose approach passes close to it) leave the queue with it, and the
// remaining count says so (docs/protocols.md, "Stale grasps"). Staleness
// passes through a part that may move: a withdrawn grasp whose part touches
// P (Grasp::touching) makes the grasps naming ITS part stale too, and so on;
// so does a part the plan queued no grasp for that touches P
// (PlanResult::ungrasped_touching), or one whose grasp left the queue
// earlier (withdrawn or screened out): all are still in the bin.
//
// A screen (SetScreen) may take grasps out too: the failed-pick feedback
// (grasp/failed_picks.h) withholds grasps on spots a robot failed to pick.
//
// The first pose early (docs/protocols.md "The first pose early"):
// PublishHead queues a plan's first grasp alone while the planner checks the
// rest; that plan's Replace (same capture) then merges the full queue in.
// While it fills, the remaining count answered is an upper bound that never
// rises (the parts with candidates); a head already handed out leaves the
// full queue as if popped from it (with the grasps it makes stale), so
// nothing is handed out twice; a head the screen would not serve is never
// published, and one the screen stops serving is withdrawn at once.
//
// Thread-safety: every member but SetScreen is safe to call concurrently; each grasp of a
// Replace() is handed out by at most one Pop() (exactly one unless withdrawn).
// Replace and Pop are atomic with respect to each other: a Pop sees either
// the old or the new queue.
#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <utility>
#include <vector>

#include "grasp/grasp.h"
#include "grasp/planner.h"

namespace bp {

class GraspQueue {
 public:
  struct Popped {
    std::optional<Grasp> grasp;  // empty when the queue is exhausted or was never filled
    // Grasps left INCLUDING this one (the DaoAI payload_1), after the
    // withdrawal: N for the first of N, 1 for the last, 0 when `grasp` is empty.
    int remaining = 0;
    // Queued grasps withdrawn with this one (stale: Grasp::stale_after).
    std::vector<Grasp> withdrawn;
    // Where `grasp` and each of `withdrawn` were in the queue when taken
    // (indices before the take; Restore puts them back there).
    int position = 0;
    std::vector<int> withdrawn_positions;
    // Outcome of the plan that filled the queue; empty when no plan has
    // completed since construction or the last Reset().
    std::optional<PlanResult::Outcome> outcome;
    uint64_t generation = 0;  // increments with every Replace / Reset
    // PopFirst: grasps the predicate refused, left queued in their order.
    int refused = 0;
    // The queue held a plan's head alone (PublishHead): `remaining` is the
    // upper bound the plan gave, not a count.
    bool filling = false;
  };

  // The instance ids of the grasps still queued (in hand-out order) and of
  // those withdrawn as stale since the last Replace / Reset (for the status
  // page: a grasp in neither was handed out).
  struct Contents {
    std::vector<int> queued;
    std::vector<int> withdrawn;
  };

  // A summary of the last plan without its grasps.
  struct Summary {
    PlanResult::Outcome outcome = PlanResult::Outcome::kNoObjects;
    int total_grasps = 0;
    int64_t roi_points = 0;
    int64_t largest_region_points = 0;
    int detections = 0;
    int withdrawn = 0;  // grasps withdrawn as stale since the plan was queued
    int screened = 0;   // grasps the screen took out (failed-pick feedback) since then
    std::optional<FillLevel> fill;  // the plan's fill level (PlanResult::fill)
  };

  // Takes grasps out of the queue, under its lock, and returns them
  // (FailedPicks::Screen: failed-pick feedback). Called after every Replace
  // and Restore, and by Rescreen. It must not call back into the queue.
  using Screen = std::function<std::vector<Grasp>(std::deque<Grasp>&)>;
  // Whether the screen serves a grasp whatever else is queued
  // (FailedPicks::Judge kServe): a head published early must be, since the
  // screen of the full queue may withhold what it keeps in a queue of one.
  using Serves = std::function<bool(const Grasp&)>;
  // Set once, before the queue is used (not synchronized with the other members).
  void SetScreen(Screen screen, Serves serves = nullptr) {
    screen_ = std::move(screen);
    serves_ = std::move(serves);
  }
  // Runs the screen on the queued grasps now (after a failure report).
  // A queue the screen empties reports kNoCollisionFree from then on.
  // @returns the grasps it took out.
  int Rescreen();

  // Discards what is left and queues result.grasps in order (with
  // result.ungrasped_touching, the parts that pass staleness on without a
  // grasp of their own), unless the queue already holds the plan of a
  // later capture: `capture_seq` numbers the task's captures (increasing;
  // 0: unnumbered, always replaces), so a detection that finishes late
  // never overwrites a newer scene.
  // @returns whether the queue was replaced; `*discarded` (optional): the
  // grasps of the replaced plan never handed out.
  bool Replace(PlanResult result, uint64_t capture_seq = 0, int* discarded = nullptr);
  // Queues `head` alone, the first grasp of the plan of capture
  // `capture_seq` still being completed (GraspPlanner::PlanWithHead), with
  // `max_queue` (>= 1) the bound on that plan's queue length answered as
  // the remaining count while it fills, and `next` (PlanHead::next) the
  // grasp that plan holds after the head's hand-out. Not published (false,
  // nothing changed) when the queue holds the plan of this capture or a
  // later one, or the screen would not serve the head, or `next` (the full
  // queue might then hold nothing after the head, where the bound said
  // more). The plan's Replace with the same capture_seq completes it (see
  // above). `*discarded` as Replace.
  bool PublishHead(Grasp head, int max_queue, uint64_t capture_seq = 0, int* discarded = nullptr,
                   const Grasp* next = nullptr);
  // Puts a grasp taken by Pop() / PopFirst() whose answer was not written
  // back where it was, as if never popped, with the grasps withdrawn with it
  // (the hand-out that made them stale did not happen), when the queue still
  // holds the plan they came from (p.generation). @returns false (and drops
  // them) when a later plan replaced that one, whose grasps describe the
  // scene as it is now.
  bool Restore(Popped p);
  // Discards everything; Pop reports no outcome until the next Replace.
  void Reset();
  // Hands out the first grasp and withdraws the queued grasps it makes stale.
  Popped Pop();
  // Pops the first grasp, in queue order, that `sendable` accepts; it is
  // given each grasp with the remaining count it would be answered with (the
  // queue's size, including the grasp, less the grasps it would withdraw as
  // stale). The accepted grasp withdraws the grasps it makes stale, as Pop.
  // The grasps it refuses stay queued, in order, and are counted in Popped::refused; `grasp` is empty when none
  // is accepted. `sendable` runs under the queue's lock: it must not call
  // back into the queue. Used to encode and range-check an answer before its
  // grasp leaves the queue (docs/protocols.md, "Nothing lost in 16 bits").
  Popped PopFirst(const std::function<bool(const Grasp&, int remaining)>& sendable);
  int size() const;
  Contents contents() const;
  std::optional<Summary> LastPlan() const;

 private:
  mutable std::mutex mutex_;
  std::deque<Grasp> grasps_;        // GUARDED_BY(mutex_)
  std::optional<Summary> summary_;  // GUARDED_BY(mutex_)
  uint64_t generation_ = 0;         // GUARDED_BY(mutex_)
  uint64_t capture_seq_ = 0;        // GUARDED_BY(mutex_): of the plan queued
  bool stale_listed_ = false;       // GUARDED_BY(mutex_): some queued grasp has stale_after
  std::vector<int> withdrawn_ids_;  // GUARDED_BY(mutex_): since the last Replace / Reset
  // GUARDED_BY(mutex_): the parts in the bin without a queued grasp, each
  // with the parts touching it: those the plan queued no grasp for
  // (PlanResult::ungrasped_touching) and those whose grasps left the queue
  // without being handed out (withdrawn or screened; their Grasp::touching)
  // since the last Replace / Reset. They pass staleness on.
  std::map<int, std::vector<int>> gone_touching_;
  Screen screen_;                   // set before use, then read-only
  Serves serves_;                   // set before use, then read-only
  // The head published early (all GUARDED_BY(mutex_)): filling_ until its
  // plan's Replace merges; head_id_ its part; head_taken_ while it is out
  // (popped, not restored); head_withdrawn_ the grasps the merge withdrew
  // as stale because the head was out (restored with it), with their
  // positions in the full queue, head_position_ the head's there and
  // head_merged_ its grasp as the full plan queued it (with stale_after and
  // touching, which the head published alone does not carry).
  bool filling_ = false;
  int filling_bound_ = 0;
  int head_id_ = -1;
  bool head_taken_ = false;
  std::vector<std::pair<int, Grasp>> head_withdrawn_;
  int head_position_ = 0;
  std::optional<Grasp> head_merged_;

  // The merge of a plan whose head was handed out while it filled, once
  // the full queue is in grasps_ and screened (as a Replace before that
  // hand-out would have): the head's grasp leaves it as TakeAt hands a
  // grasp out (the transitive stale rule included), its grasp and the
  // grasps it makes stale kept for a Restore (head_merged_,
  // head_withdrawn_). Needs mutex_.
  void TakeMergedHead();
  // Runs screen_ on grasps_. Needs mutex_. @returns the grasps it took out.
  int ApplyScreen();

  // Per queued grasp, whether handing out part `picked` makes it stale:
  // it names a part that may move (stale_after), where the parts that may
  // move are `picked` and, transitively, the parts of stale grasps that
  // touch one that may move (Grasp::touching), and so do the parts without
  // a queued grasp (gone_touching_: none planned, or withdrawn or screened
  // out earlier). Needs mutex_.
  std::vector<bool> StaleSet(int picked) const;
  // How many grasps StaleSet marks. Needs mutex_.
  int StaleCount(int picked) const;
  // Hands out *it into p, withdraws the grasps it makes stale, sets
  // p.remaining (after the withdrawal, including p.grasp). Needs mutex_.
  void TakeAt(std::deque<Grasp>::iterator it, Popped& p);
  // The withdrawal of TakeAt: the queued grasps handing out part `picked`
  // makes stale leave into p.withdrawn (positions as if p.grasp were still
  // at p.position). Needs mutex_.
  void WithdrawStale(int picked, Popped& p);
};

}  // namespace bp
