#include "pipeline/internal/enclosing_parts.h"

#include <algorithm>

#include <spdlog/spdlog.h>

namespace bp::internal {

namespace {

// A class this many times another's diameter may hold a part of its shape
// (the pipe tee, 107 mm, a flanged bushing's hub, 62 mm: the hub's 18 mm
// radius in the arm's 20 mm).
constexpr double kEnclosingRatio = 1.3;
// A sample within this of a detection's surface is the detection's
// (Acceptance's explained distance).
constexpr float kExplainedDistance = 0.0025f;
// The larger part replaces the detection when it covers this share of the
// samples on the detection's surface ...
constexpr double kCoveredShare = 0.8;
// ... and explains this many times as many of the view's samples.
constexpr double kMoreExplained = 1.5;

int ModelIndexOf(std::span<const ClassModel* const> models, int class_id) {
  for (size_t m = 0; m < models.size(); ++m) {
    if (models[m]->class_id() == class_id) return static_cast<int>(m);
  }
  return -1;
}

size_t Count(const std::vector<uint8_t>& flags) { return static_cast<size_t>(std::count(flags.begin(), flags.end(), uint8_t{1})); }

}  // namespace

std::vector<EnclosingView> EnclosingViews(const Segments& segments, const Acceptance& acceptance,
                                          std::span<const ClassModel* const> models, int min_unexplained) {
  std::vector<EnclosingView> out;
  std::vector<uint8_t> left;  // Acceptance::UnexplainedSamples, once a detection may be enclosed
  std::vector<int32_t> unexplained_samples;  // those of `left`, in sample order
  for (size_t k : acceptance.Live()) {
    const Detection& d = acceptance.detection(k);
    const int mi = ModelIndexOf(models, d.class_id);
    if (mi < 0) continue;
    const ClassModel& small = *models[static_cast<size_t>(mi)];
    std::vector<int32_t> support(d.support.begin(), d.support.end());
    std::sort(support.begin(), support.end());
    const Eigen::Vector3f centre = (d.X_BO * small.centroid_O().cast<double>()).cast<float>();
    for (size_t m = 0; m < models.size(); ++m) {
      if (models[m]->diameter() < kEnclosingRatio * small.diameter()) continue;
      if (left.empty()) {
        left = acceptance.UnexplainedSamples(segments);
        for (size_t s = 0; s < left.size(); ++s) {
          if (left[s]) unexplained_samples.push_back(static_cast<int32_t>(s));
        }
      }
      const float r = static_cast<float>(0.5 * models[m]->diameter() + 0.25 * small.diameter());
      // The unexplained samples within r counted first, from their own list
      // (few of the frame's once the passes are done): most detections
      // have too few of them near for a view.
      int unexplained = 0;
      for (int32_t s : unexplained_samples) {
        unexplained += (segments.points[static_cast<size_t>(s)] - centre).squaredNorm() > r * r ? 0 : 1;
      }
      if (unexplained < min_unexplained) continue;
      std::vector<int32_t> near;
      std::vector<Eigen::Vector3f> points;
      for (size_t s = 0; s < segments.points.size(); ++s) {
        if ((segments.points[s] - centre).squaredNorm() > r * r) continue;
        near.push_back(static_cast<int32_t>(s));
        points.push_back(segments.points[s]);
      }
      std::vector<uint8_t> on(points.size(), 0);
      small.MarkOnSurface(d.X_BO, points, kExplainedDistance, &on);
      // The larger part can explain no more than the view: kMoreExplained
      // times the detection's samples need that many unexplained ones more.
      const auto mine = static_cast<double>(Count(on));
      if (static_cast<double>(unexplained) < (kMoreExplained - 1.0) * mine) continue;
      EnclosingView ev;
      ev.detection = k;
      ev.model = static_cast<int>(m);
      for (size_t j = 0; j < near.size(); ++j) {
        const auto s = static_cast<size_t>(near[j]);
        const bool mine = on[j] || std::binary_search(support.begin(), support.end(), segments.roi_index[s]);
        if (!mine && !left[s]) continue;  // another detection's
        ev.view.push_back(near[j]);
        ev.on_detection.push_back(mine ? 1 : 0);
      }
      spdlog::debug("perception: class {} matched over detection {} (class {}): {} samples, {} unexplained",
                    models[m]->class_id(), k, d.class_id, ev.view.size(), unexplained);
      out.push_back(std::move(ev));
    }
  }
  return out;
}

int ReplaceEnclosed(const std::vector<EnclosingView>& views, const Segments& segments,
                    std::span<const ClassModel* const> models, ViewMatcher& matcher, Acceptance& acceptance) {
  if (views.empty()) return 0;
  ViewSet set;
  std::vector<int> model_of_view;
  for (const EnclosingView& ev : views) {
    set.views.push_back(ev.view);
    model_of_view.push_back(ev.model);
  }
  set.first_region = set.views.size();
  MatchOutcome matched = matcher.MatchClass(set, model_of_view);
  // Per detection, the candidate explaining most of its views' samples
  // among those that pass the rule.
  std::vector<size_t> best_of(views.size(), SIZE_MAX);  // per view: a candidate index
  std::vector<size_t> explained(views.size(), 0);
  for (size_t c = 0; c < matched.candidates.size(); ++c) {
    const Candidate& cand = matched.candidates[c];
    const auto v = static_cast<size_t>(cand.view);
    const EnclosingView& ev = views[v];
    std::vector<Eigen::Vector3f> points;
    points.reserve(ev.view.size());
    for (int32_t s : ev.view) points.push_back(segments.points[static_cast<size_t>(s)]);
    std::vector<uint8_t> on(points.size(), 0);
    models[static_cast<size_t>(ev.model)]->MarkOnSurface(cand.h.X_BO, points, kExplainedDistance, &on);
    size_t covered = 0;
    for (size_t j = 0; j < on.size(); ++j) covered += on[j] & ev.on_detection[j];
    const size_t total = Count(on), mine = Count(ev.on_detection);
    spdlog::debug("perception: class {} tried over detection {} (class {}): covers {} of its {} samples, "
                  "explains {} of {} (score {:.2f})",
                  cand.class_id, ev.detection, acceptance.detection(ev.detection).class_id, covered, mine, total,
                  points.size(), cand.h.score);
    if (static_cast<double>(covered) < kCoveredShare * static_cast<double>(mine) ||
        static_cast<double>(total) < kMoreExplained * static_cast<double>(mine) || total <= explained[v]) {
      continue;
    }
    best_of[v] = c;
    explained[v] = total;
  }
  int replaced = 0;
  for (size_t v = 0; v < views.size(); ++v) {
    if (best_of[v] == SIZE_MAX) continue;
    // The detection's other views (other larger classes) that explain more win.
    bool beaten = false;
    for (size_t u = 0; u < views.size(); ++u) {
      beaten |= u != v && views[u].detection == views[v].detection && best_of[u] != SIZE_MAX &&
                (explained[u] > explained[v] || (explained[u] == explained[v] && u < v));
    }
    if (beaten) continue;
    const Candidate& cand = matched.candidates[best_of[v]];
    const int small_class = acceptance.detection(views[v].detection).class_id;
    const Eigen::Vector3d at = cand.centre_B;
    if (acceptance.Supersede(views[v].detection, std::move(matched.candidates[best_of[v]]))) {
      spdlog::debug("perception: class {} at ({:.1f}, {:.1f}, {:.1f}) mm replaces a class {} detection it encloses",
                    models[static_cast<size_t>(views[v].model)]->class_id(), 1e3 * at.x(), 1e3 * at.y(), 1e3 * at.z(),
                    small_class);
      ++replaced;
    }
  }
  return replaced;
}

}  // namespace bp::internal
