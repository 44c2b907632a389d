#include "grasp/grasp_queue.h"

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <numeric>
#include <optional>
#include <random>
#include <set>
#include <thread>
#include <vector>

namespace bp {
namespace {

PlanResult MakePlan(int n, int first_instance = 0) {
  PlanResult r;
  r.outcome = n > 0 ? PlanResult::Outcome::kGrasps : PlanResult::Outcome::kNoObjects;
  for (int i = 0; i < n; ++i) {
    Grasp g;
    g.instance_id = first_instance + i;
    g.class_id = i % 3;
    r.grasps.push_back(g);
  }
  r.detections = n;
  return r;
}

// PopFirst accepting whatever it offers; each remaining count it offered
// is appended to `offered`.
GraspQueue::Popped PopFirstAccepting(GraspQueue& q, std::vector<int>& offered) {
  return q.PopFirst([&](const Grasp&, int remaining) {
    offered.push_back(remaining);
    return true;
  });
}

// The instance ids of `grasps`, in their order.
std::vector<int> InstanceIds(const std::vector<Grasp>& grasps) {
  std::vector<int> ids;
  for (const Grasp& g : grasps) ids.push_back(g.instance_id);
  return ids;
}

TEST(GraspQueue, ReportsNoOutcomeBeforeAnyPlan) {
  GraspQueue q;
  const auto p = q.Pop();
  EXPECT_FALSE(p.grasp.has_value());
  EXPECT_EQ(p.remaining, 0);
  EXPECT_FALSE(p.outcome.has_value());
}

TEST(GraspQueue, RemainingCountsIncludeThePoppedGraspThenZero) {
  GraspQueue q;
  q.Replace(MakePlan(3));
  std::vector<int> remaining, instances;
  for (int i = 0; i < 4; ++i) {
    const auto p = q.Pop();
    remaining.push_back(p.remaining);
    instances.push_back(p.grasp ? p.grasp->instance_id : -1);
    EXPECT_EQ(p.outcome, PlanResult::Outcome::kGrasps);
  }
  EXPECT_EQ(remaining, (std::vector<int>{3, 2, 1, 0}));
  EXPECT_EQ(instances, (std::vector<int>{0, 1, 2, -1}));
}

TEST(GraspQueue, ReplaceDiscardsTheOldGraspsAndKeepsTheNewOutcome) {
  GraspQueue q;
  q.Replace(MakePlan(5));
  (void)q.Pop();
  PlanResult none;
  none.outcome = PlanResult::Outcome::kNoCollisionFree;
  none.detections = 2;
  q.Replace(none);
  const auto p = q.Pop();
  EXPECT_FALSE(p.grasp);
  EXPECT_EQ(p.outcome, PlanResult::Outcome::kNoCollisionFree);
  ASSERT_TRUE(q.LastPlan());
  EXPECT_EQ(q.LastPlan()->detections, 2);
  q.Reset();
  EXPECT_FALSE(q.Pop().outcome.has_value());
}

TEST(GraspQueue, PopFirstLeavesRefusedGraspsQueuedInOrder) {
  GraspQueue q;
  q.Replace(MakePlan(4));  // instances 0..3, classes 0, 1, 2, 0
  // Class 1 cannot be sent (e.g. does not fit the robot's registers).
  auto not_class_1 = [](const Grasp& g, int) { return g.class_id != 1; };
  std::vector<int> remaining_seen;
  GraspQueue::Popped p = q.PopFirst([&](const Grasp& g, int remaining) {
    remaining_seen.push_back(remaining);
    return g.class_id != 1;
  });
  ASSERT_TRUE(p.grasp);
  EXPECT_EQ(p.grasp->instance_id, 0);
  EXPECT_EQ(p.remaining, 4);
  EXPECT_EQ(p.refused, 0);
  EXPECT_EQ(remaining_seen, (std::vector<int>{4}));
  p = q.PopFirst(not_class_1);  // skips instance 1
  ASSERT_TRUE(p.grasp);
  EXPECT_EQ(p.grasp->instance_id, 2);
  EXPECT_EQ(p.remaining, 3);
  EXPECT_EQ(p.refused, 1);
  p = q.PopFirst(not_class_1);
  EXPECT_EQ(p.grasp->instance_id, 3);
  p = q.PopFirst(not_class_1);  // only the refused one is left: nothing popped
  EXPECT_FALSE(p.grasp);
  EXPECT_EQ(p.refused, 1);
  EXPECT_EQ(p.outcome, PlanResult::Outcome::kGrasps);
  EXPECT_EQ(q.size(), 1);
  // Another robot (another range) still gets it.
  p = q.Pop();
  ASSERT_TRUE(p.grasp);
  EXPECT_EQ(p.grasp->instance_id, 1);
  EXPECT_EQ(p.remaining, 1);
}

TEST(GraspQueue, HandingOutAPartWithdrawsTheGraspsItMakesStaleAndCountsThemOut) {
  GraspQueue q;
  PlanResult plan = MakePlan(5);
  plan.grasps[1].stale_after = {0};     // touches part 0
  plan.grasps[3].stale_after = {0, 2};  // touches parts 0 and 2
  plan.grasps[4].stale_after = {3};     // only part 3, which is never handed out
  q.Replace(plan);
  GraspQueue::Popped first = q.Pop();
  ASSERT_TRUE(first.grasp);
  EXPECT_EQ(first.grasp->instance_id, 0);
  EXPECT_EQ(first.remaining, 3);  // 0, 2, 4
  ASSERT_EQ(first.withdrawn.size(), 2u);
  EXPECT_EQ(first.withdrawn[0].instance_id, 1);
  EXPECT_EQ(first.withdrawn[1].instance_id, 3);
  EXPECT_EQ(q.size(), 2);
  std::vector<int> instances, remaining;
  for (int i = 0; i < 3; ++i) {
    const GraspQueue::Popped p = q.Pop();
    instances.push_back(p.grasp ? p.grasp->instance_id : -1);
    remaining.push_back(p.remaining);
    EXPECT_TRUE(p.withdrawn.empty());
  }
  EXPECT_EQ(instances, (std::vector<int>{2, 4, -1}));
  EXPECT_EQ(remaining, (std::vector<int>{2, 1, 0}));
  ASSERT_TRUE(q.LastPlan());
  EXPECT_EQ(q.LastPlan()->withdrawn, 2);
  EXPECT_EQ(q.LastPlan()->total_grasps, 5);
}

// Scene 10230 (docs/tuning.md): picking bracket 5 let bracket 15, which
// touched it, and the tee 16 on bracket 15 drop; 15's grasp was withdrawn,
// the tee's was served. Staleness passes through a withdrawn part that
// touches a moving one, not through one withdrawn for its approach alone.
TEST(GraspQueue, StalenessPassesThroughAWithdrawnPartThatTouchesAMovedOne) {
  GraspQueue q;
  PlanResult plan = MakePlan(6, 5);  // parts 5..10
  plan.grasps[1].stale_after = {5, 7};  // part 6: touches 5 (and 7)
  plan.grasps[1].touching = {5, 7};
  plan.grasps[2].stale_after = {6};  // part 7: touches 6
  plan.grasps[2].touching = {6};
  plan.grasps[3].stale_after = {5};  // part 8: its approach passes close to 5
  plan.grasps[4].stale_after = {8};  // part 9: touches 8, which does not move
  plan.grasps[4].touching = {8};
  plan.grasps[5].stale_after = {7};  // part 10: its approach passes close to 7
  q.Replace(plan);
  std::vector<int> offered;
  GraspQueue::Popped first = PopFirstAccepting(q, offered);
  ASSERT_TRUE(first.grasp);
  EXPECT_EQ(first.grasp->instance_id, 5);
  EXPECT_EQ(InstanceIds(first.withdrawn), (std::vector<int>{6, 7, 8, 10}));
  EXPECT_EQ(first.withdrawn_positions, (std::vector<int>{1, 2, 3, 5}));
  EXPECT_EQ(offered, (std::vector<int>{2}));  // 5 and 9
  EXPECT_EQ(first.remaining, 2);
  const GraspQueue::Popped next = q.Pop();
  ASSERT_TRUE(next.grasp);
  EXPECT_EQ(next.grasp->instance_id, 9);
  EXPECT_EQ(next.remaining, 1);
  ASSERT_TRUE(q.LastPlan());
  EXPECT_EQ(q.LastPlan()->withdrawn, 4);
  // 9 was the last grasp.
  EXPECT_EQ(q.size(), 0);
}

// Scene 10606 (docs/tuning.md): the tee's grasp was withdrawn by an earlier
// pick; a later pick of a part it touched let it drop onto the spot of a
// grasp queued beside it. A part withdrawn earlier is still in the bin.
TEST(GraspQueue, APartWithdrawnEarlierStillPassesStalenessOn) {
  GraspQueue q;
  PlanResult plan = MakePlan(4);        // parts 0..3
  plan.grasps[1].stale_after = {0, 2};  // part 1: its approach passes close to 0; it touches 2
  plan.grasps[1].touching = {2};
  plan.grasps[2].stale_after = {1};     // part 2: touches 1
  plan.grasps[2].touching = {1};
  plan.grasps[3].stale_after = {1};     // part 3: its approach passes close to 1
  q.Replace(plan);
  GraspQueue::Popped p = q.Pop();  // 0: withdraws 1 (which does not move)
  ASSERT_TRUE(p.grasp);
  ASSERT_EQ(p.withdrawn.size(), 1u);
  EXPECT_EQ(p.withdrawn[0].instance_id, 1);
  EXPECT_EQ(p.remaining, 3);
  p = q.Pop();  // 2: part 1, still in the bin, touches it and may move onto 3's path
  ASSERT_TRUE(p.grasp);
  EXPECT_EQ(p.grasp->instance_id, 2);
  ASSERT_EQ(p.withdrawn.size(), 1u);
  EXPECT_EQ(p.withdrawn[0].instance_id, 3);
  EXPECT_EQ(p.remaining, 1);
  EXPECT_EQ(q.size(), 0);
}

// Scene 15630 (docs/tuning.md): picking L-bracket 14 let L-bracket 18,
// which touched it, drop 11.3 mm under the tool of tee 16's queued grasp;
// 18 had no grasp in the queue (its grasp was screened out), so nothing
// passed the staleness on. A part without a queued grasp
// (PlanResult::ungrasped_touching) is still in the bin: it may move, and
// moves the parts touching it, whether or not they have grasps queued.
TEST(GraspQueue, StalenessPassesThroughAPartWithoutAQueuedGrasp) {
  GraspQueue q;
  PlanResult plan = MakePlan(7);  // parts 0..6 queued; 7..10 have no grasp
  // Part 7 touches 0 (the part picked), 5 and 8; 8 touches 7; 9 and 10
  // touch each other and nothing that moves.
  plan.ungrasped_touching = {{7, {0, 5, 8}}, {8, {7}}, {9, {10}}, {10, {9}}};
  plan.grasps[1].stale_after = {7};     // part 1: its tool passes close to 7
  plan.grasps[2].stale_after = {9};     // part 2: its tool passes close to 9
  plan.grasps[3].stale_after = {8};     // part 3: its tool passes close to 8 (on 7)
  plan.grasps[5].stale_after = {7};     // part 5: touches 7
  plan.grasps[5].touching = {7};
  plan.grasps[6].stale_after = {5};     // part 6: its tool passes close to 5 (on 7)
  q.Replace(plan);
  std::vector<int> offered;
  GraspQueue::Popped p = PopFirstAccepting(q, offered);
  ASSERT_TRUE(p.grasp);
  EXPECT_EQ(p.grasp->instance_id, 0);
  EXPECT_EQ(InstanceIds(p.withdrawn), (std::vector<int>{1, 3, 5, 6}));
  EXPECT_EQ(offered, (std::vector<int>{3}));  // 0, 2 and 4
  EXPECT_EQ(p.remaining, 3);
  EXPECT_EQ(q.contents().queued, (std::vector<int>{2, 4}));
  // Part 2's tool passes 9, which touches no part that moved.
  p = q.Pop();
  ASSERT_TRUE(p.grasp);
  EXPECT_EQ(p.grasp->instance_id, 2);
  EXPECT_TRUE(p.withdrawn.empty());
  // A later plan lists its own parts without grasps: none of these.
  PlanResult next = MakePlan(2, 20);
  next.grasps[1].stale_after = {7};
  q.Replace(next);
  p = q.Pop();
  ASSERT_TRUE(p.grasp);
  EXPECT_TRUE(p.withdrawn.empty());
  EXPECT_EQ(p.remaining, 2);
}

// The answer path encodes the remaining count before the grasp leaves
// (PopFirst): it is the count after the withdrawal, as with Pop.
TEST(GraspQueue, PopFirstOffersTheCountAfterTheWithdrawalAndWithdrawsLikePop) {
  GraspQueue q;
  PlanResult plan = MakePlan(5);
  plan.grasps[1].stale_after = {0};
  plan.grasps[3].stale_after = {0, 2};
  q.Replace(plan);
  std::vector<int> offered;
  GraspQueue::Popped p = PopFirstAccepting(q, offered);
  ASSERT_TRUE(p.grasp);
  EXPECT_EQ(p.grasp->instance_id, 0);
  EXPECT_EQ(offered, (std::vector<int>{3}));
  EXPECT_EQ(p.remaining, 3);
  EXPECT_EQ(p.withdrawn.size(), 2u);
  EXPECT_EQ(q.size(), 2);  // 2 and 4
  EXPECT_EQ(q.Pop().grasp->instance_id, 2);
}

TEST(GraspQueue, AGraspWithoutAnInstanceWithdrawsNothing) {
  GraspQueue q;
  PlanResult plan = MakePlan(2);
  plan.grasps[0].instance_id = -1;
  plan.grasps[1].stale_after = {-1};
  q.Replace(plan);
  EXPECT_EQ(q.Pop().remaining, 2);
  EXPECT_EQ(q.Pop().remaining, 1);
}

TEST(GraspQueue, HandsEachGraspOnceUnderConcurrentPops) {
  constexpr int kGrasps = 20000;
  constexpr int kThreads = 8;
  GraspQueue q;
  q.Replace(MakePlan(kGrasps));
  std::vector<std::vector<int>> got(kThreads);
  std::vector<std::vector<int>> remaining(kThreads);
  std::atomic<bool> go{false};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      while (!go.load()) std::this_thread::yield();
      for (;;) {
        const auto p = q.Pop();
        if (!p.grasp) break;
        got[t].push_back(p.grasp->instance_id);
        remaining[t].push_back(p.remaining);
      }
    });
  }
  go = true;
  for (auto& th : threads) th.join();
  std::vector<int> all, all_remaining;
  for (int t = 0; t < kThreads; ++t) {
    all.insert(all.end(), got[t].begin(), got[t].end());
    all_remaining.insert(all_remaining.end(), remaining[t].begin(), remaining[t].end());
  }
  ASSERT_EQ(all.size(), static_cast<size_t>(kGrasps));
  std::sort(all.begin(), all.end());
  std::sort(all_remaining.begin(), all_remaining.end());
  for (int i = 0; i < kGrasps; ++i) {
    EXPECT_EQ(all[i], i);                 // every grasp exactly once
    EXPECT_EQ(all_remaining[i], i + 1);   // every remaining count exactly once
  }
}

TEST(GraspQueue, EachGraspIsHandedOutOrWithdrawnExactlyOnceUnderConcurrentPops) {
  // Each pop scans the queue (a plan queues tens of grasps): 2000 keep it quick.
  constexpr int kGrasps = 2000;
  const spdlog::level::level_enum level = spdlog::get_level();
  spdlog::set_level(spdlog::level::warn);  // a withdrawal logs a line
  struct Restore {
    spdlog::level::level_enum level;
    ~Restore() { spdlog::set_level(level); }
  } restore{level};
  constexpr int kThreads = 8;
  GraspQueue q;
  PlanResult plan = MakePlan(kGrasps);
  std::mt19937 rng{42};
  std::uniform_int_distribution<int> pick(0, kGrasps - 1);
  for (Grasp& g : plan.grasps) {
    for (int k = 0; k < 2; ++k) g.stale_after.push_back(pick(rng));
  }
  q.Replace(plan);
  std::vector<std::vector<int>> handed(kThreads), withdrawn(kThreads);
  std::atomic<bool> go{false};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      while (!go.load()) std::this_thread::yield();
      for (;;) {
        const auto p = q.Pop();
        if (!p.grasp) break;
        handed[t].push_back(p.grasp->instance_id);
        for (const Grasp& w : p.withdrawn) withdrawn[t].push_back(w.instance_id);
      }
    });
  }
  go = true;
  for (auto& th : threads) th.join();
  std::vector<int> all, out;
  for (int t = 0; t < kThreads; ++t) {
    all.insert(all.end(), handed[t].begin(), handed[t].end());
    out.insert(out.end(), withdrawn[t].begin(), withdrawn[t].end());
  }
  EXPECT_GT(out.size(), 0u);
  const size_t handed_count = all.size();
  all.insert(all.end(), out.begin(), out.end());
  std::sort(all.begin(), all.end());
  ASSERT_EQ(all.size(), static_cast<size_t>(kGrasps));
  for (int i = 0; i < kGrasps; ++i) EXPECT_EQ(all[i], i);
  EXPECT_EQ(q.LastPlan()->withdrawn, static_cast<int>(out.size()));
  EXPECT_EQ(handed_count + out.size(), static_cast<size_t>(kGrasps));
}

TEST(GraspQueue, PopsConcurrentWithReplaceSeeOnePlanEach) {
  // Plan i holds 1 + i % 10 grasps with instance ids 1000 * i + k. A popped
  // grasp's remaining count must match its position in its own plan, never a
  // mix of two plans.
  GraspQueue q;
  std::atomic<bool> stop{false};
  std::atomic<int> popped{0}, bad{0};
  std::thread popper([&] {
    while (!stop) {
      const auto p = q.Pop();
      if (!p.grasp) continue;
      ++popped;
      const int plan = p.grasp->instance_id / 1000, k = p.grasp->instance_id % 1000;
      if (p.remaining != (1 + plan % 10) - k) ++bad;
    }
  });
  for (int i = 0; i < 2000; ++i) {
    q.Replace(MakePlan(1 + i % 10, 1000 * i));
    std::this_thread::yield();
  }
  // The popper may not have been scheduled during the loop (2 busy cores): let
  // it take at least the last plan's grasps before stopping it.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (popped.load() == 0 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  stop = true;
  popper.join();
  EXPECT_EQ(bad.load(), 0);
  EXPECT_GT(popped.load(), 0);
}

}  // namespace
}  // namespace bp

namespace bp {
namespace {

// Issue 39: of two detections of one task, the one of the later capture
// fills the queue, whichever finishes last.
TEST(GraspQueue, APlanOfAnOlderCaptureNeverReplacesANewerOne) {
  GraspQueue q;
  EXPECT_TRUE(q.Replace(MakePlan(2, /*first_instance=*/200), /*capture_seq=*/2));
  EXPECT_FALSE(q.Replace(MakePlan(5, /*first_instance=*/100), /*capture_seq=*/1));
  EXPECT_EQ(q.size(), 2);
  EXPECT_EQ(q.Pop().grasp->instance_id, 200);
  int discarded = -1;
  EXPECT_TRUE(q.Replace(MakePlan(3, /*first_instance=*/300), /*capture_seq=*/3, &discarded));
  EXPECT_EQ(discarded, 1);  // the plan of capture 2 had one grasp left
  EXPECT_EQ(q.Pop().grasp->instance_id, 300);
}

// A grasp put back goes to the front with its remaining count, unless a
// later plan replaced the one it came from.
TEST(GraspQueue, ARestoredGraspIsHandedOutNextUnlessTheQueueWasReplaced) {
  GraspQueue q;
  q.Replace(MakePlan(3));
  GraspQueue::Popped first = q.Pop();
  ASSERT_TRUE(first.grasp);
  EXPECT_TRUE(q.Restore(first));
  const GraspQueue::Popped again = q.Pop();
  EXPECT_EQ(again.grasp->instance_id, first.grasp->instance_id);
  EXPECT_EQ(again.remaining, 3);
  q.Replace(MakePlan(4, /*first_instance=*/10));
  EXPECT_FALSE(q.Restore(again));
  EXPECT_EQ(q.size(), 4);
  EXPECT_EQ(q.Pop().grasp->instance_id, 10);
}

// A grasp whose answer was not written comes back with the grasps its
// hand-out withdrew as stale (it never happened), each where it was, and is
// no longer counted withdrawn; a grasp taken past refused ones (PopFirst)
// goes back behind them.
TEST(GraspQueue, ARestoredGraspBringsBackTheGraspsWithdrawnWithItInTheirPlaces) {
  GraspQueue q;
  PlanResult plan = MakePlan(5);
  plan.grasps[2].stale_after = {1};
  plan.grasps[4].stale_after = {1};
  q.Replace(plan);
  // Grasp 0 does not fit this link: 1 is taken, 2 and 4 withdrawn.
  GraspQueue::Popped p = q.PopFirst([](const Grasp& g, int) { return g.instance_id != 0; });
  ASSERT_TRUE(p.grasp);
  EXPECT_EQ(p.grasp->instance_id, 1);
  EXPECT_EQ(p.remaining, 3);  // 0, 1, 3
  ASSERT_EQ(p.withdrawn.size(), 2u);
  EXPECT_EQ(q.contents().withdrawn, (std::vector<int>{2, 4}));
  EXPECT_TRUE(q.Restore(p));
  EXPECT_EQ(q.contents().queued, (std::vector<int>{0, 1, 2, 3, 4}));
  EXPECT_TRUE(q.contents().withdrawn.empty());
  EXPECT_EQ(q.LastPlan()->withdrawn, 0);
  // Handed out for good this time: the same withdrawal, counted once.
  const GraspQueue::Popped again = q.PopFirst([](const Grasp& g, int) { return g.instance_id != 0; });
  EXPECT_EQ(again.grasp->instance_id, 1);
  EXPECT_EQ(q.contents().queued, (std::vector<int>{0, 3}));
  EXPECT_EQ(q.LastPlan()->withdrawn, 2);
}


// ---- the first pose early (PublishHead, then the plan's Replace merges) ----

// Plan of parts 0..n-1 in order; part 1 touches 0, part 3 touches 0 and 2.
PlanResult MakeStalePlan(int n) {
  PlanResult plan = MakePlan(n);
  if (n > 1) plan.grasps[1].stale_after = {0};
  if (n > 3) plan.grasps[3].stale_after = {0, 2};
  return plan;
}

TEST(GraspQueueHead, AHeadTakenWhileFillingLeavesTheMergedQueueWithTheGraspsItMakesStale) {
  GraspQueue q;
  q.Replace(MakePlan(2, 100), 1);  // the previous capture's plan
  int discarded = -1;
  ASSERT_TRUE(q.PublishHead(MakeStalePlan(5).grasps[0], 5, 2, &discarded));
  EXPECT_EQ(discarded, 2);
  const auto head = q.Pop();
  ASSERT_TRUE(head.grasp);
  EXPECT_EQ(head.grasp->instance_id, 0);
  EXPECT_TRUE(head.filling);
  EXPECT_EQ(head.remaining, 5);  // the bound, not a count
  const auto empty = q.Pop();    // nothing queued until the plan completes
  EXPECT_FALSE(empty.grasp);
  EXPECT_TRUE(q.Replace(MakeStalePlan(5), 2, &discarded));
  EXPECT_EQ(discarded, 0);
  std::vector<int> handed{0}, remaining{head.remaining};
  for (auto p = q.Pop(); p.grasp; p = q.Pop()) {
    EXPECT_FALSE(p.filling);
    handed.push_back(p.grasp->instance_id);
    remaining.push_back(p.remaining);
  }
  EXPECT_EQ(handed, (std::vector<int>{0, 2, 4}));  // 1 and 3 were stale once 0 was out
  EXPECT_EQ(remaining, (std::vector<int>{5, 2, 1}));
  EXPECT_EQ(q.contents().withdrawn, (std::vector<int>{1, 3}));
  EXPECT_EQ(q.LastPlan()->withdrawn, 2);
}

TEST(GraspQueueHead, AHeadStillQueuedAtTheMergeIsTheFirstOfTheFullQueue) {
  GraspQueue q;
  ASSERT_TRUE(q.PublishHead(MakePlan(4).grasps[0], 6, 1));
  EXPECT_EQ(q.size(), 1);
  ASSERT_TRUE(q.Replace(MakePlan(4), 1));
  std::vector<int> handed, remaining;
  for (auto p = q.Pop(); p.grasp; p = q.Pop()) {
    handed.push_back(p.grasp->instance_id);
    remaining.push_back(p.remaining);
  }
  EXPECT_EQ(handed, (std::vector<int>{0, 1, 2, 3}));
  EXPECT_EQ(remaining, (std::vector<int>{4, 3, 2, 1}));
}

TEST(GraspQueueHead, AHeadWhoseAnswerWasNotWrittenComesBackWithWhatTheMergeWithdrew) {
  for (const bool merged_first : {false, true}) {
    SCOPED_TRACE(merged_first ? "restored after the merge" : "restored while filling");
    GraspQueue q;
    ASSERT_TRUE(q.PublishHead(MakeStalePlan(5).grasps[0], 5, 1));
    GraspQueue::Popped head = q.Pop();
    ASSERT_TRUE(head.grasp);
    if (merged_first) {
      ASSERT_TRUE(q.Replace(MakeStalePlan(5), 1));
    }
    ASSERT_TRUE(q.Restore(head));
    if (!merged_first) {
      const auto again = q.Pop();  // the same head, with the same bound
      ASSERT_TRUE(again.grasp);
      EXPECT_EQ(again.grasp->instance_id, 0);
      EXPECT_EQ(again.remaining, 5);
      ASSERT_TRUE(q.Restore(again));
      ASSERT_TRUE(q.Replace(MakeStalePlan(5), 1));
    }
    EXPECT_EQ(q.contents().queued, (std::vector<int>{0, 1, 2, 3, 4}));
    EXPECT_TRUE(q.contents().withdrawn.empty());
    EXPECT_EQ(q.LastPlan()->withdrawn, 0);
  }
}

TEST(GraspQueueHead, AHeadOfAnOlderOrTheSameCaptureIsNotPublished) {
  GraspQueue q;
  ASSERT_TRUE(q.Replace(MakePlan(3), 5));
  EXPECT_FALSE(q.PublishHead(MakePlan(1, 50).grasps[0], 1, 4));
  EXPECT_FALSE(q.PublishHead(MakePlan(1, 50).grasps[0], 1, 5));
  EXPECT_EQ(q.contents().queued, (std::vector<int>{0, 1, 2}));
  // A later capture's plan replaces a head still filling (no merge).
  ASSERT_TRUE(q.PublishHead(MakePlan(1, 50).grasps[0], 3, 6));
  const auto head = q.Pop();
  ASSERT_TRUE(q.Replace(MakePlan(2, 70), 7));
  EXPECT_FALSE(q.Restore(head));
  EXPECT_EQ(q.contents().queued, (std::vector<int>{70, 71}));
}

// The screen withholds grasps on `failed` parts while another grasp is
// served (FailedPicks' rule), and serves() says which it serves alone.
struct FailedSet {
  std::set<int> failed;
  void Install(GraspQueue& q) {
    q.SetScreen(
        [this](std::deque<Grasp>& grasps) {
          std::vector<Grasp> removed;
          const bool any_served = std::any_of(grasps.begin(), grasps.end(),
                                              [this](const Grasp& g) { return !failed.count(g.instance_id); });
          if (!any_served) return removed;
          std::deque<Grasp> kept;
          for (Grasp& g : grasps) {
            if (failed.count(g.instance_id)) {
              removed.push_back(std::move(g));
            } else {
              kept.push_back(std::move(g));
            }
          }
          grasps.swap(kept);
          return removed;
        },
        [this](const Grasp& g) { return !failed.count(g.instance_id); });
  }
};

TEST(GraspQueueHead, AHeadTheFullQueuesScreenWouldWithholdIsNeverServedEarly) {
  FailedSet screen;
  GraspQueue q;
  screen.Install(q);
  screen.failed = {0};
  // Alone, the screen would keep it (nothing else served): not published.
  EXPECT_FALSE(q.PublishHead(MakePlan(3).grasps[0], 3, 1));
  screen.failed.clear();
  ASSERT_TRUE(q.PublishHead(MakePlan(3).grasps[0], 3, 2));
  // A failure reported on it while it fills withdraws it at once.
  screen.failed = {0};
  EXPECT_EQ(q.Rescreen(), 1);
  EXPECT_FALSE(q.Pop().grasp);
  ASSERT_TRUE(q.Replace(MakePlan(3), 2));
  EXPECT_EQ(q.contents().queued, (std::vector<int>{1, 2}));  // the full queue's screen agrees
}

// Random plans and stale lists; a head popped or not before the merge,
// restored or not: every grasp of the plan is handed out or withdrawn
// exactly once, and the remaining counts the robot reads never rise.
TEST(GraspQueueHead, NothingIsHandedOutTwiceOrLostAndRemainingNeverRisesAcrossTheMerge) {
  std::mt19937 rng(40);
  for (int trial = 0; trial < 300; ++trial) {
    SCOPED_TRACE("trial " + std::to_string(trial));
    const int n = 1 + static_cast<int>(rng() % 8);
    PlanResult plan = MakePlan(n);
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n; ++j) {
        if (i != j && rng() % 4 == 0) plan.grasps[i].stale_after.push_back(j);
      }
    }
    const int bound = n + static_cast<int>(rng() % 3);
    GraspQueue q;
    ASSERT_TRUE(q.PublishHead(plan.grasps[0], bound, 1));
    std::vector<int> handed, remaining;
    std::optional<GraspQueue::Popped> out;
    if (rng() % 4 != 0) {
      out = q.Pop();
      ASSERT_TRUE(out->grasp);
      if (rng() % 3 == 0) {
        ASSERT_TRUE(q.Restore(*out));  // written: no
        out.reset();
      }
    }
    ASSERT_TRUE(q.Replace(plan, 1));
    if (out && rng() % 3 == 0) {
      ASSERT_TRUE(q.Restore(*out));  // its write failed after the merge
      out.reset();
    }
    if (out) {
      handed.push_back(out->grasp->instance_id);
      remaining.push_back(out->remaining);
    }
    for (auto p = q.Pop(); p.grasp; p = q.Pop()) {
      handed.push_back(p.grasp->instance_id);
      remaining.push_back(p.remaining);
    }
    std::vector<int> all = handed;
    const std::vector<int> withdrawn = q.contents().withdrawn;
    all.insert(all.end(), withdrawn.begin(), withdrawn.end());
    std::sort(all.begin(), all.end());
    std::vector<int> expected(n);
    std::iota(expected.begin(), expected.end(), 0);
    EXPECT_EQ(all, expected);
    EXPECT_TRUE(std::is_sorted(remaining.rbegin(), remaining.rend()));
    for (int r : remaining) EXPECT_LE(r, bound);
    ASSERT_FALSE(handed.empty());
    EXPECT_EQ(handed.front(), 0);
  }
}

// Robots popping while the planner publishes the head and merges the rest.
TEST(GraspQueueHead, ConcurrentPopsAcrossPublishAndMergeHandEachGraspOutOnce) {
  for (int round = 0; round < 50; ++round) {
    GraspQueue q;
    const PlanResult plan = MakeStalePlan(12);
    std::atomic<bool> go{false};
    std::mutex mutex;
    std::vector<int> handed;
    std::vector<std::thread> robots;
    for (int r = 0; r < 3; ++r) {
      robots.emplace_back([&] {
        while (!go) std::this_thread::yield();
        for (int k = 0; k < 40; ++k) {
          const auto p = q.Pop();
          if (p.grasp) {
            std::lock_guard lock(mutex);
            handed.push_back(p.grasp->instance_id);
          }
        }
      });
    }
    go = true;
    ASSERT_TRUE(q.PublishHead(plan.grasps[0], 12, 1));
    std::this_thread::yield();
    ASSERT_TRUE(q.Replace(plan, 1));
    for (auto& t : robots) t.join();
    for (auto p = q.Pop(); p.grasp; p = q.Pop()) handed.push_back(p.grasp->instance_id);
    std::vector<int> all = handed;
    const std::vector<int> withdrawn = q.contents().withdrawn;
    all.insert(all.end(), withdrawn.begin(), withdrawn.end());
    std::sort(all.begin(), all.end());
    std::vector<int> expected(12);
    std::iota(expected.begin(), expected.end(), 0);
    ASSERT_EQ(all, expected) << "round " << round;
  }
}

// The head as the planner publishes it (PlanGrasps's PrimaryGrasp): no
// stale lists; the full plan's grasp of that part carries them.
Grasp Bare(Grasp g) {
  g.stale_after.clear();
  g.touching.clear();
  return g;
}

// Parts 0..4: 0 and 1 touch, 1 and 2 touch (2 may move when 1 does).
PlanResult MakeTouchingPlan() {
  PlanResult plan = MakePlan(5);
  plan.grasps[0].stale_after = {1};
  plan.grasps[0].touching = {1};
  plan.grasps[1].stale_after = {0, 2};
  plan.grasps[1].touching = {0, 2};
  plan.grasps[2].stale_after = {1};
  plan.grasps[2].touching = {1};
  return plan;
}

TEST(GraspQueueHead, AHeadTakenEarlyMakesStaleThroughTouchingPartsAtTheMerge) {
  GraspQueue q;
  ASSERT_TRUE(q.PublishHead(Bare(MakeTouchingPlan().grasps[0]), 5, 1));
  const auto head = q.Pop();
  ASSERT_TRUE(head.grasp);
  ASSERT_TRUE(q.Replace(MakeTouchingPlan(), 1));
  // 1 touched the head (withdrawn, it may move), so 2, which touches 1, too.
  EXPECT_EQ(q.contents().queued, (std::vector<int>{3, 4}));
  EXPECT_EQ(q.contents().withdrawn, (std::vector<int>{1, 2}));
  const auto next = q.Pop();
  ASSERT_TRUE(next.grasp);
  EXPECT_EQ(next.remaining, 2);
  EXPECT_LT(next.remaining, head.remaining);
}

// The head's hand-out, merged, passes staleness on through the parts its
// plan queued no grasp for, as a Pop from the full queue does.
TEST(GraspQueueHead, AHeadTakenEarlyMakesStaleThroughPartsWithoutAGraspAtTheMerge) {
  PlanResult plan = MakePlan(4);  // parts 0..3; 5 has no grasp
  plan.ungrasped_touching = {{5, {0}}};
  plan.grasps[2].stale_after = {5};  // part 2: its tool passes close to 5
  GraspQueue q;
  ASSERT_TRUE(q.PublishHead(Bare(plan.grasps[0]), 4, 1));
  const auto head = q.Pop();
  ASSERT_TRUE(head.grasp);
  ASSERT_TRUE(q.Replace(plan, 1));
  EXPECT_EQ(q.contents().queued, (std::vector<int>{1, 3}));
  EXPECT_EQ(q.contents().withdrawn, (std::vector<int>{2}));
  // Not handed out after all: 2 comes back.
  ASSERT_TRUE(q.Restore(head));
  EXPECT_EQ(q.contents().queued, (std::vector<int>{0, 1, 2, 3}));
}

TEST(GraspQueueHead, AHeadRestoredAfterTheMergeIsWithdrawnWhenATouchingPartIsHandedOut) {
  GraspQueue q;
  ASSERT_TRUE(q.PublishHead(Bare(MakeTouchingPlan().grasps[0]), 5, 1));
  const auto head = q.Pop();
  ASSERT_TRUE(q.Replace(MakeTouchingPlan(), 1));
  ASSERT_TRUE(q.Restore(head));  // its answer was not written
  EXPECT_EQ(q.contents().queued, (std::vector<int>{0, 1, 2, 3, 4}));
  // A robot whose link cannot carry the head's answer takes part 1: the
  // head (restored as the full plan queued it, stale lists included) and
  // part 2 touch it, so both leave.
  const auto p = q.PopFirst([](const Grasp& g, int) { return g.instance_id != 0; });
  ASSERT_TRUE(p.grasp);
  EXPECT_EQ(p.grasp->instance_id, 1);
  EXPECT_EQ(q.contents().queued, (std::vector<int>{3, 4}));
  EXPECT_EQ(q.contents().withdrawn, (std::vector<int>{0, 2}));
}

// Random plans with random stale lists and touching pairs (symmetric, each
// also a stale pair), the head published bare: a head taken early and the
// plan merged hand out exactly what the plan queued at once hands out, and
// withdraw the same grasps.
TEST(GraspQueueHead, AHeadTakenEarlyHandsOutWhatThePlanQueuedAtOnceDoes) {
  std::mt19937 rng(3);
  for (int trial = 0; trial < 300; ++trial) {
    SCOPED_TRACE("trial " + std::to_string(trial));
    const int n = 1 + static_cast<int>(rng() % 9);
    PlanResult plan = MakePlan(n);
    std::vector<std::set<int>> stale(n), touching(n);
    for (int i = 0; i < n; ++i) {
      for (int j = i + 1; j < n; ++j) {
        if (rng() % 4 == 0) {  // touching: stale both ways
          touching[i].insert(j);
          touching[j].insert(i);
          stale[i].insert(j);
          stale[j].insert(i);
        } else if (rng() % 5 == 0) {  // one's approach passes the other
          const bool i_passes_j = rng() % 2 == 0;
          stale[i_passes_j ? i : j].insert(i_passes_j ? j : i);
        }
      }
    }
    for (int i = 0; i < n; ++i) {
      plan.grasps[i].stale_after.assign(stale[i].begin(), stale[i].end());
      plan.grasps[i].touching.assign(touching[i].begin(), touching[i].end());
    }
    GraspQueue direct;
    ASSERT_TRUE(direct.Replace(plan, 1));
    std::vector<int> want;
    for (auto p = direct.Pop(); p.grasp; p = direct.Pop()) want.push_back(p.grasp->instance_id);
    GraspQueue early;
    ASSERT_TRUE(early.PublishHead(Bare(plan.grasps[0]), n, 1));
    const auto head = early.Pop();
    ASSERT_TRUE(head.grasp);
    std::vector<int> got = {head.grasp->instance_id};
    ASSERT_TRUE(early.Replace(plan, 1));
    int last = head.remaining;
    for (auto p = early.Pop(); p.grasp; p = early.Pop()) {
      got.push_back(p.grasp->instance_id);
      EXPECT_LT(p.remaining, last);
      last = p.remaining;
    }
    EXPECT_EQ(got, want);
    std::vector<int> withdrawn_direct = direct.contents().withdrawn, withdrawn_early = early.contents().withdrawn;
    std::sort(withdrawn_direct.begin(), withdrawn_direct.end());
    std::sort(withdrawn_early.begin(), withdrawn_early.end());
    EXPECT_EQ(withdrawn_early, withdrawn_direct);
    EXPECT_EQ(early.LastPlan()->withdrawn, direct.LastPlan()->withdrawn);
  }
}

}  // namespace
}  // namespace bp
