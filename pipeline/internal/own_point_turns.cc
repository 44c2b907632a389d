#include "pipeline/internal/own_point_turns.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <spdlog/spdlog.h>

namespace bp::internal {

namespace {

// A ROI point within this of another detection's surface is that
// detection's (Acceptance's explained distance).
constexpr float kForeignDistance = 0.0025f;
// The part's reach: its surface samples' farthest distance from their
// centroid, plus this (metres).
constexpr float kReachMargin = 0.005f;
// The turns looked at (ChooseTurn's step): in pile 1013 of the tuning range
// a tee 24 deg off about its run explains 8% more at its true turn, a peak
// about 8 deg wide (the branch's end moves 3.5 mm in 4 deg) that the fine
// pass's 30 deg grid and a 10 deg one step over.
constexpr double kTurnStepDeg = 5.0;
float ReachOf(const ClassModel& m) {
  const Eigen::Vector3f c = m.centroid_O();
  float r2 = 0.f;
  for (const Eigen::Vector3f& p : m.surface_points_O()) r2 = std::max(r2, (p - c).squaredNorm());
  return std::sqrt(r2) + kReachMargin;
}

const ClassModel* ModelOf(std::span<const ClassModel* const> models, int class_id) {
  for (const ClassModel* m : models) {
    if (m->class_id() == class_id) return m;
  }
  return nullptr;
}

// The pixels (v * width + u) of the ROI points within `reach` of centre_B,
// from a window about the centre's pixel large enough to hold them.
std::vector<size_t> PixelsNear(const Frame& frame, std::span<const Eigen::Vector3f> roi_points_B,
                                std::span<const int32_t> point_of_pixel, const Eigen::Vector3f& centre_B,
                                float reach) {
  std::vector<size_t> out;
  const Pose X_CB = frame.X_BC.inverse();
  const Eigen::Vector3f c_C = (X_CB * centre_B.cast<double>()).cast<float>();
  const float nearest = c_C.z() - reach;
  if (!(nearest > 1e-3f)) return out;
  const Intrinsics& K = frame.intrinsics;
  const int half = static_cast<int>(std::ceil(reach * std::max(K.fx, K.fy) / nearest)) + 1;
  const int uc = static_cast<int>(std::lround(K.fx * c_C.x() / c_C.z() + K.cx));
  const int vc = static_cast<int>(std::lround(K.fy * c_C.y() / c_C.z() + K.cy));
  const int w = frame.depth.width, h = frame.depth.height;
  const float r2 = reach * reach;
  for (int v = std::max(0, vc - half); v <= std::min(h - 1, vc + half); ++v) {
    for (int u = std::max(0, uc - half); u <= std::min(w - 1, uc + half); ++u) {
      const size_t pix = static_cast<size_t>(v) * w + u;
      const int32_t i = point_of_pixel[pix];
      if (i >= 0 && (roi_points_B[static_cast<size_t>(i)] - centre_B).squaredNorm() <= r2) out.push_back(pix);
    }
  }
  return out;
}

}  // namespace

int RedecideTurns(std::span<const ClassModel* const> models, const Frame& frame,
                  std::span<const Eigen::Vector3f> roi_points_B, std::span<const int32_t> point_of_pixel,
                  const std::optional<Eigen::Vector4d>& floor_plane_B, double min_gain,
                  double min_foreign_fraction, std::vector<Detection>* detections) {
  if (!frame.organized() || point_of_pixel.size() != frame.depth.data.size() || !frame.intrinsics.valid()) return 0;
  std::vector<const ClassModel*> model_of(detections->size(), nullptr);
  std::vector<float> reach(detections->size(), 0.f);
  bool any = false;
  for (size_t d = 0; d < detections->size(); ++d) {
    model_of[d] = ModelOf(models, (*detections)[d].class_id);
    if (model_of[d] == nullptr) continue;
    reach[d] = ReachOf(*model_of[d]);
    any = any || model_of[d]->has_turn_axes();
  }
  if (!any) return 0;
  const auto centre = [&](size_t d) -> Eigen::Vector3f {
    return ((*detections)[d].X_BO * model_of[d]->centroid_O().cast<double>()).cast<float>();
  };
  // The frame with the neighbours' pixels blanked, restored after each part.
  Frame masked;
  masked.depth = frame.depth;
  masked.intrinsics = frame.intrinsics;
  masked.X_BC = frame.X_BC;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  int changed = 0;
  for (size_t d = 0; d < detections->size(); ++d) {
    if (model_of[d] == nullptr || !model_of[d]->has_turn_axes()) continue;
    Detection& det = (*detections)[d];
    const Eigen::Vector3f c = centre(d);
    const std::vector<size_t> near = PixelsNear(frame, roi_points_B, point_of_pixel, c, reach[d]);
    std::vector<Eigen::Vector3f> pts(near.size());
    for (size_t k = 0; k < near.size(); ++k) pts[k] = roi_points_B[static_cast<size_t>(point_of_pixel[near[k]])];
    std::vector<uint8_t> foreign(near.size(), 0);
    for (size_t k = 0; k < detections->size(); ++k) {
      if (k == d || model_of[k] == nullptr || (centre(k) - c).norm() > reach[d] + reach[k]) continue;
      model_of[k]->MarkOnSurface((*detections)[k].X_BO, pts, kForeignDistance, &foreign);
    }
    std::vector<Eigen::Vector3f> own;
    std::vector<size_t> blanked;
    for (size_t k = 0; k < near.size(); ++k) {
      if (!foreign[k]) {
        own.push_back(pts[k]);
        continue;
      }
      masked.depth.data[near[k]] = nan;
      blanked.push_back(near[k]);
    }
    if (!det.pose_ambiguous() &&
        static_cast<double>(blanked.size()) < min_foreign_fraction * static_cast<double>(near.size())) {
      for (size_t pix : blanked) masked.depth.data[pix] = frame.depth.data[pix];
      continue;
    }
    SegmentView view;
    view.points_B = own;
    view.frame = &masked;
    view.floor_plane_B = floor_plane_B;
    const TurnChoice choice = model_of[d]->ChooseTurn(view, det.X_BO, det.alternatives_X_BO, kTurnStepDeg);
    for (size_t pix : blanked) masked.depth.data[pix] = frame.depth.data[pix];
    if (choice.given_net <= 0 || !(choice.net > (1.0 + min_gain) * choice.given_net)) continue;
    spdlog::debug("perception: class {} at ({:.1f}, {:.1f}, {:.1f}) mm turned on its own points: net {} -> {} "
                  "({} own points, {} a neighbour's)",
                  det.class_id, 1e3 * c.x(), 1e3 * c.y(), 1e3 * c.z(), choice.given_net, choice.net, own.size(),
                  blanked.size());
    const Pose old = det.X_BO;
    det.X_BO = choice.X_BO;
    // An alternative the new pose lies within the tolerance of is the new
    // pose; the old pose is an alternative only when it is another pose (a
    // turn of a few degrees refines the pose, it does not make it ambiguous).
    const ClassModel& model = *model_of[d];
    std::erase_if(det.alternatives_X_BO, [&](const Pose& X) { return !model.DistinctPoses(X, choice.X_BO); });
    if (model.DistinctPoses(old, choice.X_BO)) det.alternatives_X_BO.insert(det.alternatives_X_BO.begin(), old);
    const size_t max_alternatives =
        static_cast<size_t>(std::max(1, model_of[d]->estimator_options().max_alternatives));
    if (det.alternatives_X_BO.size() > max_alternatives) det.alternatives_X_BO.resize(max_alternatives);
    std::vector<Eigen::Vector3f> support(det.support.size());
    for (size_t k = 0; k < det.support.size(); ++k) support[k] = roi_points_B[static_cast<size_t>(det.support[k])];
    std::vector<uint8_t> on(support.size(), 0);
    model_of[d]->MarkOnSurface(det.X_BO, support, kForeignDistance, &on);
    std::vector<int32_t> kept;
    for (size_t k = 0; k < det.support.size(); ++k) {
      if (on[k]) kept.push_back(det.support[k]);
    }
    det.support = std::move(kept);
    ++changed;
  }
  return changed;
}

}  // namespace bp::internal
