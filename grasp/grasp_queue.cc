#include "grasp/grasp_queue.h"

#include <utility>

namespace bp {

void GraspQueue::Replace(PlanResult result) {
  Summary s;
  s.outcome = result.outcome;
  s.total_grasps = static_cast<int>(result.grasps.size());
  s.roi_points = result.roi_points;
  s.largest_region_points = result.largest_region_points;
  s.detections = result.detections;
  std::deque<Grasp> grasps(std::make_move_iterator(result.grasps.begin()),
                           std::make_move_iterator(result.grasps.end()));
  std::lock_guard lock(mutex_);
  grasps_.swap(grasps);
  summary_ = s;
  ++generation_;
}

void GraspQueue::Reset() {
  std::deque<Grasp> old;
  std::lock_guard lock(mutex_);
  grasps_.swap(old);
  summary_.reset();
  ++generation_;
}

GraspQueue::Popped GraspQueue::Pop() {
  std::lock_guard lock(mutex_);
  Popped p;
  p.generation = generation_;
  if (summary_) p.outcome = summary_->outcome;
  if (grasps_.empty()) return p;
  p.remaining = static_cast<int>(grasps_.size());
  p.grasp = std::move(grasps_.front());
  grasps_.pop_front();
  return p;
}

GraspQueue::Popped GraspQueue::PopFirst(const std::function<bool(const Grasp&, int)>& sendable) {
  std::lock_guard lock(mutex_);
  Popped p;
  p.generation = generation_;
  if (summary_) p.outcome = summary_->outcome;
  const int remaining = static_cast<int>(grasps_.size());
  for (auto it = grasps_.begin(); it != grasps_.end(); ++it) {
    if (!sendable(*it, remaining)) {
      ++p.refused;
      continue;
    }
    p.remaining = remaining;
    p.grasp = std::move(*it);
    grasps_.erase(it);
    return p;
  }
  return p;
}

int GraspQueue::size() const {
  std::lock_guard lock(mutex_);
  return static_cast<int>(grasps_.size());
}

std::optional<GraspQueue::Summary> GraspQueue::LastPlan() const {
  std::lock_guard lock(mutex_);
  return summary_;
}

}  // namespace bp
