#include "pipeline/internal/acceptance.h"

#include <algorithm>
#include <optional>

#include <tbb/parallel_for.h>

#include "pipeline/internal/view_preparation.h"

namespace bp::internal {

namespace {

// Two detections are one physical part when their centres (of the part's
// surface, not its origin: an L-bracket's origin is its corner) are closer
// than this fraction of the larger diameter, or when more than
// kMaxSharedSupport of the later one's support is already claimed ...
constexpr double kNmsRelativeDistance = 0.3;
constexpr double kMaxSharedSupport = 0.5;
// ... and the accepted detections that hold at least this fraction of the
// later one's support are the ones it conflicts with.
constexpr double kSharedOwner = 0.1;
// Parts of a pile never interpenetrate: a candidate conflicts when more than
// kMaxInsideFraction of its surface samples lie inside an accepted
// detection's material (deeper than its ClassModel::inside_depth), or the
// other way round.
constexpr double kMaxInsideFraction = 0.03;
// A view point is explained by a detection within this of its surface.
constexpr float kExplainedDistance = 0.0025f;
// A detection's support lies on one plane when this share of its points is
// within kOnePlaneDistance of their least-squares plane (metres: the
// estimator's 1.5 mm support distance; a 5 mm plate's edges lie beyond it).
constexpr double kOnePlaneShare = 0.95;
constexpr double kOnePlaneDistance = 0.0015;

}  // namespace

std::vector<Eigen::Vector3f> SurfaceAt(const ClassModel& model, const Pose& X_BO) {
  const std::span<const Eigen::Vector3f> s = model.surface_points_O();
  std::vector<Eigen::Vector3f> out(s.size());
  const Eigen::Matrix3f R = X_BO.linear().cast<float>();
  const Eigen::Vector3f t = X_BO.translation().cast<float>();
  for (size_t i = 0; i < s.size(); ++i) out[i] = R * s[i] + t;
  return out;
}

Acceptance::Acceptance(size_t roi_points, std::span<const ClassModel* const> models, double near_centre_min_shared,
                       std::span<const Eigen::Vector3f> roi_points_B)
    : models_(models), claims_(roi_points, 0), mark_(roi_points, 0), near_centre_min_shared_(near_centre_min_shared),
      roi_points_B_(roi_points_B) {}

const ClassModel* Acceptance::ModelOf(int class_id) const {
  for (const ClassModel* m : models_) {
    if (m->class_id() == class_id) return m;
  }
  return nullptr;
}

std::vector<size_t> Acceptance::Interpenetrated(const Candidate& c) const {
  std::vector<size_t> hit;
  const ClassModel* cm = ModelOf(c.class_id);
  if (cm == nullptr) return hit;
  std::vector<size_t> near;  // the live detections whose part may touch c's
  for (size_t k = 0; k < detections_.size(); ++k) {
    const Accepted& a = accepted_[k];
    if (a.dropped || (a.centre_B - c.centre_B).norm() > 0.5 * (c.diameter + a.diameter)) continue;
    if (ModelOf(detections_[k].class_id) != nullptr) near.push_back(k);
  }
  if (near.empty()) return hit;
  const std::vector<Eigen::Vector3f> mine = SurfaceAt(*cm, c.h.X_BO);
  const double limit_mine = kMaxInsideFraction * static_cast<double>(mine.size());
  // The acceptance runs alone between the waves: the neighbours' tests (a
  // few, each a few hundred closest-point lookups) on every thread.
  std::vector<uint8_t> inside(near.size(), 0);
  tbb::parallel_for(size_t{0}, near.size(), [&](size_t j) {
    const size_t k = near[j];
    const Accepted& a = accepted_[k];
    const ClassModel* km = ModelOf(detections_[k].class_id);
    const double limit_theirs = kMaxInsideFraction * static_cast<double>(a.surface_B.size());
    inside[j] =
        static_cast<double>(km->CountInside(detections_[k].X_BO, mine, km->inside_depth())) > limit_mine ||
        static_cast<double>(cm->CountInside(c.h.X_BO, a.surface_B, cm->inside_depth())) > limit_theirs;
  });
  for (size_t j = 0; j < near.size(); ++j) {
    if (inside[j]) hit.push_back(near[j]);
  }
  return hit;
}

bool Acceptance::SamePart(size_t k, const Candidate& c) const {
  const ClassModel* km = ModelOf(detections_[k].class_id);
  if (!(near_centre_min_shared_ > 0.0) || roi_points_B_.empty() || c.support_roi.empty() || km == nullptr) return true;
  std::vector<Eigen::Vector3f> support;
  support.reserve(c.support_roi.size());
  for (int32_t i : c.support_roi) support.push_back(roi_points_B_[static_cast<size_t>(i)]);
  std::vector<uint8_t> on(support.size(), 0);
  km->MarkOnSurface(detections_[k].X_BO, support, kExplainedDistance, &on);
  const auto n_on = static_cast<double>(std::count(on.begin(), on.end(), uint8_t{1}));
  return n_on >= near_centre_min_shared_ * static_cast<double>(support.size());
}

std::optional<std::vector<size_t>> Acceptance::Conflicts(const Candidate& c) {
  std::vector<size_t> conflicts;
  const auto conflict = [&conflicts](size_t k) {
    if (std::find(conflicts.begin(), conflicts.end(), k) == conflicts.end()) conflicts.push_back(k);
  };
  for (size_t k = 0; k < accepted_.size(); ++k) {
    const Accepted& a = accepted_[k];
    if (!a.dropped && (a.centre_B - c.centre_B).norm() < kNmsRelativeDistance * std::max(c.diameter, a.diameter) &&
        SamePart(k, c)) {
      conflicts.push_back(k);
    }
  }
  if (!c.support_roi.empty()) {
    size_t shared = 0;
    for (int32_t i : c.support_roi) shared += claims_[static_cast<size_t>(i)] > 0 ? 1 : 0;
    if (static_cast<double>(shared) > kMaxSharedSupport * static_cast<double>(c.support_roi.size())) {
      for (int32_t i : c.support_roi) mark_[static_cast<size_t>(i)] = 1;
      bool attributed = false;
      for (size_t k = 0; k < detections_.size(); ++k) {
        if (accepted_[k].dropped) continue;
        size_t overlap = 0;
        for (int32_t i : detections_[k].support) overlap += mark_[static_cast<size_t>(i)];
        if (static_cast<double>(overlap) >= kSharedOwner * static_cast<double>(c.support_roi.size())) {
          attributed = true;
          conflict(k);
        }
      }
      for (int32_t i : c.support_roi) mark_[static_cast<size_t>(i)] = 0;
      // Claimed, but by no one live detection in a large enough share: the
      // candidate explains nothing new.
      if (!attributed) return std::nullopt;
    }
  }
  for (size_t k : Interpenetrated(c)) conflict(k);
  return conflicts;
}

void Acceptance::Accept(std::vector<Candidate> candidates) {
  std::stable_sort(candidates.begin(), candidates.end(),
                   [](const Candidate& a, const Candidate& b) { return a.h.score > b.h.score; });
  for (Candidate& c : candidates) {
    const std::optional<std::vector<size_t>> found = Conflicts(c);
    if (!found) continue;
    const std::vector<size_t>& conflicts = *found;
    // Greedy by score: c loses to any conflicting detection that scores as
    // well, else replaces them all.
    if (std::any_of(conflicts.begin(), conflicts.end(), [&](size_t k) { return detections_[k].score >= c.h.score; })) {
      continue;
    }
    Add(std::move(c), conflicts);
  }
}

void Acceptance::Add(Candidate c, const std::vector<size_t>& conflicts) {
  for (size_t k : conflicts) {
    accepted_[k].dropped = true;
    for (int32_t i : detections_[k].support) --claims_[static_cast<size_t>(i)];
  }
  for (int32_t i : c.support_roi) ++claims_[static_cast<size_t>(i)];
  const ClassModel* m = ModelOf(c.class_id);
  accepted_.push_back({c.diameter, c.centre_B, m ? SurfaceAt(*m, c.h.X_BO) : std::vector<Eigen::Vector3f>{}});
  Detection d;
  d.class_id = c.class_id;
  d.X_BO = c.h.X_BO;
  d.score = c.h.score;
  d.visible_fraction = c.h.visible_fraction;
  d.rms_residual = c.h.rms_residual;
  d.support = std::move(c.support_roi);
  d.alternatives_X_BO = std::move(c.h.alternatives);
  detections_.push_back(std::move(d));
}

std::vector<size_t> Acceptance::Live() const {
  std::vector<size_t> live;
  for (size_t k = 0; k < detections_.size(); ++k) {
    if (!accepted_[k].dropped) live.push_back(k);
  }
  return live;
}

bool Acceptance::Supersede(size_t k, Candidate c) {
  if (k >= detections_.size() || accepted_[k].dropped) return false;
  std::vector<size_t> conflicts = Conflicts(c).value_or(std::vector<size_t>{k});
  if (std::any_of(conflicts.begin(), conflicts.end(), [k](size_t j) { return j != k; })) return false;
  Add(std::move(c), {k});
  return true;
}

double Acceptance::ExplainedFraction(const Segments& segments, const ViewIndices& view, double min_score) const {
  if (view.empty()) return 0.0;
  std::vector<Eigen::Vector3f> points;
  points.reserve(view.size());
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (int32_t k : view) {
    points.push_back(segments.points[static_cast<size_t>(k)]);
    centre += points.back().cast<double>();
  }
  centre /= static_cast<double>(points.size());
  double radius = 0.0;
  for (const Eigen::Vector3f& p : points) radius = std::max(radius, (p.cast<double>() - centre).norm());
  std::vector<uint8_t> on(points.size(), 0);
  for (size_t d = 0; d < detections_.size(); ++d) {
    const Accepted& a = accepted_[d];
    if (a.dropped || detections_[d].score < min_score) continue;
    // The part lies within a diameter of its surface centroid.
    if ((a.centre_B - centre).norm() > radius + a.diameter) continue;
    if (const ClassModel* m = ModelOf(detections_[d].class_id)) {
      m->MarkOnSurface(detections_[d].X_BO, points, kExplainedDistance, &on);
    }
  }
  return static_cast<double>(std::count(on.begin(), on.end(), uint8_t{1})) / static_cast<double>(on.size());
}

std::vector<uint8_t> Acceptance::UnexplainedSamples(const Segments& segments) const {
  const size_t n = segments.points.size();
  std::vector<uint8_t> on(n, 0);
  std::vector<size_t> unclaimed;  // in sample order: the only ones the detections' surfaces are tested on
  for (size_t k = 0; k < n; ++k) {
    on[k] = claims_[static_cast<size_t>(segments.roi_index[k])] > 0 ? 1 : 0;
    if (!on[k]) unclaimed.push_back(k);
  }
  // Per live detection, the unclaimed samples within its diameter of its
  // surface centroid (the part lies there).
  std::vector<size_t> live;
  for (size_t d = 0; d < detections_.size(); ++d) {
    if (!accepted_[d].dropped && ModelOf(detections_[d].class_id) != nullptr) live.push_back(d);
  }
  std::vector<std::vector<uint8_t>> marks(live.size());
  std::vector<std::vector<size_t>> near(live.size());
  tbb::parallel_for(size_t{0}, live.size(), [&](size_t j) {
    const Accepted& a = accepted_[live[j]];
    const Eigen::Vector3f centre = a.centre_B.cast<float>();
    const float r2 = static_cast<float>(a.diameter * a.diameter);
    std::vector<Eigen::Vector3f> points;
    for (size_t k : unclaimed) {
      if ((segments.points[k] - centre).squaredNorm() > r2) continue;
      near[j].push_back(k);
      points.push_back(segments.points[k]);
    }
    marks[j].assign(points.size(), 0);
    ModelOf(detections_[live[j]].class_id)->MarkOnSurface(detections_[live[j]].X_BO, points, kExplainedDistance,
                                                          &marks[j]);
  });
  for (size_t j = 0; j < live.size(); ++j) {
    for (size_t i = 0; i < near[j].size(); ++i) on[near[j][i]] |= marks[j][i];
  }
  for (uint8_t& u : on) u = u ? 0 : 1;
  return on;
}

std::vector<Detection> Acceptance::TakeDetections() {
  std::vector<Detection> live;
  for (size_t k = 0; k < detections_.size(); ++k) {
    if (!accepted_[k].dropped) live.push_back(std::move(detections_[k]));
  }
  detections_.clear();
  accepted_.clear();
  return live;
}

int WithholdAmbiguous(double min_visible, std::vector<Detection>* detections) {
  return static_cast<int>(std::erase_if(*detections, [&](const Detection& d) {
    return d.pose_ambiguous() && d.visible_fraction < min_visible;
  }));
}

double ShareOnOnePlane(std::span<const Eigen::Vector3f> points, double distance) {
  Eigen::Vector3d mean, normal;
  double rms = 0.0;
  if (!FitPlane(points, {}, &mean, &normal, &rms)) return 1.0;
  size_t on = 0;
  for (const Eigen::Vector3f& p : points) on += std::abs(normal.dot(p.cast<double>() - mean)) <= distance ? 1 : 0;
  return static_cast<double>(on) / static_cast<double>(points.size());
}

int WithholdOnePlane(double min_visible, std::span<const Eigen::Vector3f> roi_points_B,
                     std::vector<Detection>* detections) {
  return static_cast<int>(std::erase_if(*detections, [&](const Detection& d) {
    if (!(d.visible_fraction < min_visible) || d.support.empty()) return false;
    std::vector<Eigen::Vector3f> support;
    support.reserve(d.support.size());
    for (int32_t i : d.support) support.push_back(roi_points_B[static_cast<size_t>(i)]);
    return ShareOnOnePlane(support, kOnePlaneDistance) >= kOnePlaneShare;
  }));
}

}  // namespace bp::internal
