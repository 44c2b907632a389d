#include "grasp/grasp_queue.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <string>
#include <utility>

namespace bp {

bool GraspQueue::Replace(PlanResult result, uint64_t capture_seq) {
  Summary s;
  s.outcome = result.outcome;
  s.total_grasps = static_cast<int>(result.grasps.size());
  s.roi_points = result.roi_points;
  s.largest_region_points = result.largest_region_points;
  s.detections = result.detections;
  std::deque<Grasp> grasps(std::make_move_iterator(result.grasps.begin()),
                           std::make_move_iterator(result.grasps.end()));
  const bool stale_listed =
      std::any_of(grasps.begin(), grasps.end(), [](const Grasp& g) { return !g.stale_after.empty(); });
  std::lock_guard lock(mutex_);
  if (capture_seq != 0 && capture_seq < capture_seq_) return false;
  if (capture_seq != 0) capture_seq_ = capture_seq;
  grasps_.swap(grasps);
  stale_listed_ = stale_listed;
  withdrawn_ids_.clear();
  summary_ = s;
  ++generation_;
  return true;
}

bool GraspQueue::Restore(Grasp grasp, uint64_t generation) {
  std::lock_guard lock(mutex_);
  if (generation != generation_) return false;
  grasps_.push_front(std::move(grasp));
  return true;
}

void GraspQueue::Reset() {
  std::deque<Grasp> old;
  std::lock_guard lock(mutex_);
  grasps_.swap(old);
  withdrawn_ids_.clear();
  summary_.reset();
  ++generation_;
}

namespace {

// True when `g` is made stale by handing out part `picked` (Grasp::stale_after).
bool StaleAfter(const Grasp& g, int picked) {
  return picked >= 0 && std::find(g.stale_after.begin(), g.stale_after.end(), picked) != g.stale_after.end();
}

void LogWithdrawal(const GraspQueue::Popped& p) {
  if (p.withdrawn.empty()) return;
  std::string ids;
  for (const Grasp& g : p.withdrawn) ids += (ids.empty() ? "" : ", ") + std::to_string(g.instance_id);
  spdlog::info("grasp queue: handing out part {} withdraws the stale grasps on parts {}; {} left", p.grasp->instance_id,
               ids, p.remaining - 1);
}

}  // namespace

int GraspQueue::StaleCount(int picked) const {
  if (picked < 0 || !stale_listed_) return 0;
  return static_cast<int>(
      std::count_if(grasps_.begin(), grasps_.end(), [picked](const Grasp& g) { return StaleAfter(g, picked); }));
}

void GraspQueue::TakeAt(std::deque<Grasp>::iterator it, Popped& p) {
  p.grasp = std::move(*it);
  grasps_.erase(it);
  const int picked = p.grasp->instance_id;
  if (StaleCount(picked) > 0) {
    std::deque<Grasp> kept;
    for (Grasp& g : grasps_) {
      if (StaleAfter(g, picked)) {
        withdrawn_ids_.push_back(g.instance_id);
        p.withdrawn.push_back(std::move(g));
      } else {
        kept.push_back(std::move(g));
      }
    }
    grasps_.swap(kept);
    if (summary_) summary_->withdrawn += static_cast<int>(p.withdrawn.size());
  }
  p.remaining = 1 + static_cast<int>(grasps_.size());
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
      if (!sendable(*it, size - StaleCount(it->instance_id))) {
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
