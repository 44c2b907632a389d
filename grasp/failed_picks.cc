#include "grasp/failed_picks.h"

#include <algorithm>
#include <cmath>
#include <tuple>

#include "pipeline/evaluation.h"

namespace bp {

std::string_view ToString(PickFailure reason) {
  switch (reason) {
    case PickFailure::kUnspecified:
      return "unspecified";
    case PickFailure::kNoVacuum:
      return "no_vacuum";
    case PickFailure::kSlipped:
      return "slipped";
    case PickFailure::kCollision:
      return "collision";
  }
  return "unspecified";
}

bool PickFailureFromWire(int32_t value, PickFailure* out) {
  if (value < 0 || value > 3) return false;
  *out = static_cast<PickFailure>(value);
  return true;
}

std::string BaseGraspName(const std::string& name) {
  const size_t end = name.find_first_of("@~");
  return end == std::string::npos ? name : name.substr(0, end);
}

FailedPicks::FailedPicks(FailedPickRule rule, Pose X_BW) : rule_(rule), X_WB_(X_BW.inverse()) {}

Vec3 FailedPicks::InBin(const Grasp& grasp) const {
  const Vec3& p_B = grasp.X_BO.translation();
  return grasp.X_BW ? Vec3(grasp.X_BW->inverse() * p_B) : Vec3(X_WB_ * p_B);
}

FailedPicks::Recorded FailedPicks::Report(const Grasp& grasp, PickFailure reason) {
  const Vec3 p_W = InBin(grasp);
  std::lock_guard lock(mutex_);
  ++counts_[{grasp.class_id, BaseGraspName(grasp.name), static_cast<int32_t>(reason)}];
  Spot* same = nullptr;
  for (Spot& s : spots_) {
    if (s.class_id != grasp.class_id || (s.p_W - p_W).norm() > rule_.radius) continue;
    if (same == nullptr || (s.p_W - p_W).norm() < (same->p_W - p_W).norm()) same = &s;
  }
  if (same == nullptr) {
    spots_.push_back(Spot{p_W, grasp.class_id, 0, 0});
    same = &spots_.back();
  }
  ++same->failures;
  if (reason == PickFailure::kCollision) {
    same->failures = std::max(same->failures, rule_.max_failures);
    same->collided = true;
  }
  same->age = 0;
  same->p_W = p_W;  // where the part was last tried (a slip may have moved it)
  if (grasp.last_resort) {
    // It lands only if the pose it was planned on is true: that pose is refuted.
    const Pose X_WB = grasp.X_BW ? grasp.X_BW->inverse() : X_WB_;
    same->refuted_X_WO.push_back(X_WB * grasp.X_BO);
  }
  return Recorded{same->failures, same->failures >= rule_.max_failures};
}

void FailedPicks::OnCapture() {
  std::lock_guard lock(mutex_);
  for (Spot& s : spots_) ++s.age;
  spots_.erase(std::remove_if(spots_.begin(), spots_.end(), [&](const Spot& s) { return s.age > rule_.captures; }),
               spots_.end());
}

void FailedPicks::Seen(std::span<const DetectedPart> parts, const std::optional<Pose>& X_BW) {
  const Pose X_WB = X_BW ? X_BW->inverse() : X_WB_;
  std::lock_guard lock(mutex_);
  for (Spot& s : spots_) {
    if (!s.collided) continue;
    const bool there = std::any_of(parts.begin(), parts.end(), [&](const DetectedPart& p) {
      return p.class_id == s.class_id && (X_WB * p.X_BO.translation() - s.p_W).norm() <= rule_.radius;
    });
    if (there) s.age = 0;
  }
}

FailedPicks::Verdict FailedPicks::Judge(const Grasp& grasp) const {
  std::lock_guard lock(mutex_);
  return JudgeLocked(grasp);
}

FailedPicks::Verdict FailedPicks::JudgeLocked(const Grasp& grasp) const {
  const Vec3 p_W = InBin(grasp);
  Verdict v = Verdict::kServe;
  for (const Spot& s : spots_) {
    if ((s.p_W - p_W).norm() > rule_.radius) continue;
    if (s.class_id == grasp.class_id && s.failures >= rule_.max_failures) return Verdict::kRefused;
    // A grasp planned on the poses a failed last resort left is a new try there.
    if (grasp.reposed && s.class_id == grasp.class_id && !s.refuted_X_WO.empty()) continue;
    v = Verdict::kWithheld;
  }
  return v;
}

template <typename Seq>
std::vector<Grasp> FailedPicks::ScreenImpl(Seq& grasps) const {
  std::vector<Grasp> removed;
  std::vector<Verdict> verdicts;
  verdicts.reserve(grasps.size());
  bool any_served = false;
  {
    std::lock_guard lock(mutex_);
    if (spots_.empty()) return removed;
    for (const Grasp& g : grasps) {
      verdicts.push_back(JudgeLocked(g));
      any_served = any_served || verdicts.back() == Verdict::kServe;
    }
  }
  Seq kept;
  for (size_t i = 0; i < grasps.size(); ++i) {
    const bool keep = verdicts[i] == Verdict::kServe || (verdicts[i] == Verdict::kWithheld && !any_served);
    if (keep) {
      kept.push_back(std::move(grasps[i]));
    } else {
      removed.push_back(std::move(grasps[i]));
    }
  }
  grasps = std::move(kept);
  return removed;
}

std::vector<Grasp> FailedPicks::Screen(std::deque<Grasp>& grasps) const { return ScreenImpl(grasps); }
std::vector<Grasp> FailedPicks::Screen(std::vector<Grasp>& grasps) const { return ScreenImpl(grasps); }

std::vector<FailedPicks::Count> FailedPicks::Counts() const {
  std::lock_guard lock(mutex_);
  std::vector<Count> out;
  for (const auto& [key, n] : counts_) {
    out.push_back(Count{std::get<0>(key), std::get<1>(key), static_cast<PickFailure>(std::get<2>(key)), n});
  }
  return out;
}

std::vector<FailedPicks::Spot> FailedPicks::Spots() const {
  std::lock_guard lock(mutex_);
  return spots_;
}

std::vector<RefutedPose> FailedPicks::Refuted() const {
  std::lock_guard lock(mutex_);
  std::vector<RefutedPose> out;
  for (const Spot& s : spots_) {
    for (const Pose& X_WO : s.refuted_X_WO) out.push_back(RefutedPose{s.class_id, X_WO});
  }
  return out;
}

std::vector<bool> ApplyRefutedPoses(std::span<const RefutedPose> refuted, const Cell& cell, const Pose& X_BW,
                                    std::vector<Detection>& detections) {
  std::vector<bool> changed(detections.size(), false);
  if (refuted.empty()) return changed;
  const double max_angle = kRefutedMatchDeg * M_PI / 180.0;
  for (size_t i = 0; i < detections.size(); ++i) {
    Detection& d = detections[i];
    const PartSpec* part = cell.FindPart(d.class_id);
    if (!d.pose_ambiguous() || part == nullptr) continue;
    const auto is_refuted = [&](const Pose& X_BO) {
      for (const RefutedPose& r : refuted) {
        if (r.class_id != d.class_id) continue;
        const Pose X_BO_r = X_BW * r.X_WO;
        if (SymmetryAwareTranslationError(X_BO, X_BO_r, part->symmetry) <= kRefutedMatchPosition &&
            SymmetryAwareRotationError(X_BO, X_BO_r, part->symmetry) <= max_angle) {
          return true;
        }
      }
      return false;
    };
    // The detection's poses, best first (X_BO, then its alternatives in order).
    std::vector<Pose> live;
    if (!is_refuted(d.X_BO)) live.push_back(d.X_BO);
    for (const Pose& alt : d.alternatives_X_BO) {
      if (!is_refuted(alt)) live.push_back(alt);
    }
    if (live.empty() || live.size() == d.alternatives_X_BO.size() + 1) continue;
    d.X_BO = live.front();
    d.alternatives_X_BO.assign(live.begin() + 1, live.end());
    changed[i] = true;
  }
  return changed;
}

}  // namespace bp
