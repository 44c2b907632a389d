#include "grasp/grasp_queue.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstddef>
#include <string>
#include <utility>

#include "core/fault_points.h"

namespace bp {
namespace {

void LogWithdrawal(const GraspQueue::Popped& p) {
  if (p.withdrawn.empty()) return;
  std::string ids;
  for (const Grasp& g : p.withdrawn) ids += (ids.empty() ? "" : ", ") + std::to_string(g.instance_id);
  spdlog::info("grasp queue: handing out part {} withdraws the stale grasps on parts {}; {} left", p.grasp->instance_id,
               ids, p.remaining - 1);
}

}  // namespace

bool GraspQueue::Replace(PlanResult result, uint64_t capture_seq, int* discarded) {
  if (discarded) *discarded = 0;
  Summary s;
  s.outcome = result.outcome;
  s.total_grasps = static_cast<int>(result.grasps.size());
  s.roi_points = result.roi_points;
  s.largest_region_points = result.largest_region_points;
  s.fill = result.fill;
  s.detections = result.detections;
  std::deque<Grasp> grasps(std::make_move_iterator(result.grasps.begin()),
                           std::make_move_iterator(result.grasps.end()));
  const bool stale_listed =
      std::any_of(grasps.begin(), grasps.end(), [](const Grasp& g) { return !g.stale_after.empty(); });
  fault::Hit("grasp_queue.replace");  // tests: the refill's copy fails (no memory); nothing changed
  std::lock_guard lock(mutex_);
  if (capture_seq != 0 && capture_seq < capture_seq_) return false;
  // The plan whose head was published: the rest merges in behind it.
  const bool merge = filling_ && capture_seq == capture_seq_;
  if (capture_seq != 0) capture_seq_ = capture_seq;
  if (discarded && !merge) *discarded = static_cast<int>(grasps_.size());
  grasps_.swap(grasps);
  stale_listed_ = stale_listed;
  withdrawn_ids_.clear();
  // The parts without a queued grasp are in the bin from the start.
  gone_touching_ = std::move(result.ungrasped_touching);
  summary_ = s;
  // Merged: the same plan, so a Restore of the head finds it.
  if (!merge) ++generation_;
  const bool head_out = merge && head_taken_;
  filling_ = false;
  if (!merge) head_taken_ = false;
  ApplyScreen();
  if (head_out) TakeMergedHead();
  return true;
}

void GraspQueue::TakeMergedHead() {
  head_withdrawn_.clear();
  head_merged_.reset();
  head_position_ = 0;
  const auto head =
      std::find_if(grasps_.begin(), grasps_.end(), [this](const Grasp& g) { return g.instance_id == head_id_; });
  // As Pop would have taken it from the full queue, the transitive stale
  // rule included (filling_ is false here: no bound counted down).
  Popped p;
  if (head != grasps_.end()) {
    TakeAt(head, p);
    head_merged_ = std::move(p.grasp);
  } else if (std::find(withdrawn_ids_.begin(), withdrawn_ids_.end(), head_id_) != withdrawn_ids_.end()) {
    // Screened out by a failure reported on its spot since it was handed
    // out: that hand-out still makes its neighbours stale (and the part,
    // gone, passes nothing on as one left in the bin).
    gone_touching_.erase(head_id_);
    WithdrawStale(head_id_, p);
  } else if (!grasps_.empty()) {
    // A failed plan queues nothing; anything else breaks FindEarlyHead's invariant.
    spdlog::error("grasp queue: the plan completed without part {}, whose grasp was handed out early", head_id_);
  }
  head_position_ = p.position;
  for (size_t i = 0; i < p.withdrawn.size() && i < p.withdrawn_positions.size(); ++i) {
    head_withdrawn_.emplace_back(p.withdrawn_positions[i], std::move(p.withdrawn[i]));
  }
  if (!head_withdrawn_.empty()) {
    spdlog::info("grasp queue: the head handed out early (part {}) withdraws {} stale grasps from its plan", head_id_,
                 head_withdrawn_.size());
  }
}

bool GraspQueue::PublishHead(Grasp head, int max_queue, uint64_t capture_seq, int* discarded, const Grasp* next) {
  if (discarded) *discarded = 0;
  std::deque<Grasp> grasps;
  grasps.push_back(std::move(head));
  std::lock_guard lock(mutex_);
  if (capture_seq != 0 && capture_seq <= capture_seq_) return false;
  if (serves_ && (!serves_(grasps.front()) || (max_queue > 1 && next != nullptr && !serves_(*next)))) return false;
  if (capture_seq != 0) capture_seq_ = capture_seq;
  if (discarded) *discarded = static_cast<int>(grasps_.size());
  head_id_ = grasps.front().instance_id;
  grasps_.swap(grasps);
  stale_listed_ = false;  // the head's neighbours come with the full queue
  withdrawn_ids_.clear();
  gone_touching_.clear();
  Summary s;
  s.outcome = PlanResult::Outcome::kGrasps;
  s.total_grasps = 1;
  summary_ = s;
  ++generation_;
  filling_ = true;
  filling_bound_ = std::max(1, max_queue);
  head_taken_ = false;
  head_withdrawn_.clear();
  head_merged_.reset();
  head_position_ = 0;
  return true;
}

int GraspQueue::ApplyScreen() {
  if (!screen_ || grasps_.empty()) return 0;
  std::vector<Grasp> removed = screen_(grasps_);
  // A head alone stays where the full queue's screen would withhold it:
  // while it fills, a head the screen no longer serves is withdrawn.
  if (filling_ && serves_ && !grasps_.empty() && !serves_(grasps_.front())) {
    removed.push_back(std::move(grasps_.front()));
    grasps_.pop_front();
  }
  if (removed.empty()) return 0;
  for (const Grasp& g : removed) {
    withdrawn_ids_.push_back(g.instance_id);
    gone_touching_[g.instance_id] = g.touching;
  }
  if (summary_) {
    summary_->screened += static_cast<int>(removed.size());
    // Only refused grasps leave a queue empty (withheld ones stay when
    // nothing else is left): no collision-free grasp the robot may try.
    if (grasps_.empty() && summary_->outcome == PlanResult::Outcome::kGrasps) {
      summary_->outcome = PlanResult::Outcome::kNoCollisionFree;
    }
  }
  return static_cast<int>(removed.size());
}

int GraspQueue::Rescreen() {
  std::lock_guard lock(mutex_);
  return ApplyScreen();
}

bool GraspQueue::Restore(Popped p) {
  if (!p.grasp) return false;
  std::lock_guard lock(mutex_);
  if (p.generation != generation_) return false;
  if (p.grasp->instance_id == head_id_ && head_taken_) {
    head_taken_ = false;
    if (filling_) {
      ++filling_bound_;  // the robot never got it
    } else {
      // Taken before its plan merged: back where the full queue had it, as
      // the full plan queued it (the head alone carries no stale lists),
      // with the grasps the merge withdrew because it was out.
      p.position = head_position_;
      if (head_merged_) p.grasp = std::move(head_merged_);
      head_merged_.reset();
      for (auto& [position, grasp] : head_withdrawn_) {
        p.withdrawn_positions.push_back(position);
        p.withdrawn.push_back(std::move(grasp));
      }
      head_withdrawn_.clear();
    }
  }
  // Back where each was, in the order they were queued: inserting in
  // ascending original index rebuilds that order around the grasps still
  // queued (clamped when fewer are queued now).
  std::vector<std::pair<int, Grasp>> back;
  back.emplace_back(p.position, std::move(*p.grasp));
  for (size_t i = 0; i < p.withdrawn.size() && i < p.withdrawn_positions.size(); ++i) {
    back.emplace_back(p.withdrawn_positions[i], std::move(p.withdrawn[i]));
    // No longer withdrawn: the hand-out that made it stale did not happen.
    const auto id = std::find(withdrawn_ids_.begin(), withdrawn_ids_.end(), back.back().second.instance_id);
    if (id != withdrawn_ids_.end()) withdrawn_ids_.erase(id);
    gone_touching_.erase(back.back().second.instance_id);
    if (summary_ && summary_->withdrawn > 0) --summary_->withdrawn;
  }
  std::sort(back.begin(), back.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  for (auto& [position, grasp] : back) {
    const size_t at = std::min(static_cast<size_t>(std::max(position, 0)), grasps_.size());
    grasps_.insert(grasps_.begin() + static_cast<std::ptrdiff_t>(at), std::move(grasp));
  }
  ApplyScreen();
  return true;
}

void GraspQueue::Reset() {
  std::deque<Grasp> old;
  std::lock_guard lock(mutex_);
  grasps_.swap(old);
  withdrawn_ids_.clear();
  gone_touching_.clear();
  summary_.reset();
  ++generation_;
  filling_ = false;
  head_taken_ = false;
  head_withdrawn_.clear();
  head_merged_.reset();
}

std::vector<bool> GraspQueue::StaleSet(int picked) const {
  std::vector<bool> stale(grasps_.size(), false);
  if (picked < 0 || !stale_listed_) return stale;
  std::vector<int> moving = {picked};  // parts that may move
  const auto moves = [&moving](int id) { return std::find(moving.begin(), moving.end(), id) != moving.end(); };
  const auto names_moving = [&moves](const std::vector<int>& ids) { return std::any_of(ids.begin(), ids.end(), moves); };
  // Each pass adds the grasps naming a moving part; a part touching one
  // joins the moving ones and the passes go on (each part joins once).
  for (bool grew = true; grew;) {
    grew = false;
    for (const auto& [id, touching] : gone_touching_) {
      if (moves(id) || !names_moving(touching)) continue;
      moving.push_back(id);
      grew = true;
    }
    for (size_t i = 0; i < grasps_.size(); ++i) {
      // The picked grasp itself (still queued when PopFirst counts) is not withdrawn.
      const Grasp& g = grasps_[i];
      if (g.instance_id == picked) continue;
      stale[i] = stale[i] || names_moving(g.stale_after);
      if (stale[i] && !moves(g.instance_id) && names_moving(g.touching)) {
        moving.push_back(g.instance_id);
        grew = true;
      }
    }
  }
  return stale;
}

int GraspQueue::StaleCount(int picked) const {
  const std::vector<bool> stale = StaleSet(picked);
  return static_cast<int>(std::count(stale.begin(), stale.end(), true));
}

void GraspQueue::TakeAt(std::deque<Grasp>::iterator it, Popped& p) {
  p.position = static_cast<int>(it - grasps_.begin());
  p.grasp = std::move(*it);
  grasps_.erase(it);
  WithdrawStale(p.grasp->instance_id, p);
  p.remaining = 1 + static_cast<int>(grasps_.size());
  if (filling_) {
    // The head: what the plan may still queue, counted down (never rises).
    p.filling = true;
    p.remaining = filling_bound_--;
    if (p.grasp->instance_id == head_id_) head_taken_ = true;
  }
}

void GraspQueue::WithdrawStale(int picked, Popped& p) {
  const std::vector<bool> stale = StaleSet(picked);
  if (std::find(stale.begin(), stale.end(), true) == stale.end()) return;
  std::deque<Grasp> kept;
  int index = 0;  // in the queue after the erase
  for (Grasp& g : grasps_) {
    if (stale[static_cast<size_t>(index)]) {
      withdrawn_ids_.push_back(g.instance_id);
      gone_touching_[g.instance_id] = g.touching;
      p.withdrawn_positions.push_back(index < p.position ? index : index + 1);
      p.withdrawn.push_back(std::move(g));
    } else {
      kept.push_back(std::move(g));
    }
    ++index;
  }
  grasps_.swap(kept);
  if (summary_) summary_->withdrawn += static_cast<int>(p.withdrawn.size());
}

GraspQueue::Popped GraspQueue::Pop() {
  Popped p;
  {
    std::lock_guard lock(mutex_);
    p.generation = generation_;
    if (summary_) p.outcome = summary_->outcome;
    if (grasps_.empty()) return p;
    TakeAt(grasps_.begin(), p);
  }
  LogWithdrawal(p);
  return p;
}

GraspQueue::Popped GraspQueue::PopFirst(const std::function<bool(const Grasp&, int)>& sendable) {
  Popped p;
  {
    std::lock_guard lock(mutex_);
    p.generation = generation_;
    if (summary_) p.outcome = summary_->outcome;
    const int size = static_cast<int>(grasps_.size());
    for (auto it = grasps_.begin(); it != grasps_.end(); ++it) {
      // The count it would be answered with: after the grasps it makes stale leave.
      if (!sendable(*it, filling_ ? filling_bound_ : size - StaleCount(it->instance_id))) {
        ++p.refused;
        continue;
      }
      TakeAt(it, p);
      break;
    }
  }
  if (p.grasp) LogWithdrawal(p);
  return p;
}

int GraspQueue::size() const {
  std::lock_guard lock(mutex_);
  return static_cast<int>(grasps_.size());
}

GraspQueue::Contents GraspQueue::contents() const {
  Contents c;
  std::lock_guard lock(mutex_);
  for (const Grasp& g : grasps_) c.queued.push_back(g.instance_id);
  c.withdrawn = withdrawn_ids_;
  return c;
}

std::optional<GraspQueue::Summary> GraspQueue::LastPlan() const {
  std::lock_guard lock(mutex_);
  return summary_;
}

}  // namespace bp
