#include "pipeline/truth_perception.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <unordered_map>
#include <utility>

#include "pipeline/synthetic_source.h"

namespace bp {

namespace {

struct KeyHash {
  size_t operator()(const Eigen::Vector3i& k) const {
    return (static_cast<size_t>(k.x()) * 73856093u) ^ (static_cast<size_t>(k.y()) * 19349663u) ^
           (static_cast<size_t>(k.z()) * 83492791u);
  }
};
struct KeyEq {
  bool operator()(const Eigen::Vector3i& a, const Eigen::Vector3i& b) const { return a == b; }
};

int Find(std::vector<int>& parent, int i) {
  while (parent[i] != i) {
    parent[i] = parent[parent[i]];
    i = parent[i];
  }
  return i;
}

}  // namespace

int64_t LargestRegionPoints(std::span<const Eigen::Vector3f> points, double cell) {
  std::unordered_map<Eigen::Vector3i, int, KeyHash, KeyEq> voxels;
  std::vector<int64_t> count;
  std::vector<Eigen::Vector3i> keys;
  voxels.reserve(points.size());
  for (const auto& p : points) {
    if (!p.allFinite()) continue;
    const Eigen::Vector3i k = (p.cast<double>() / cell).array().floor().cast<int>().matrix();
    auto [it, inserted] = voxels.try_emplace(k, static_cast<int>(count.size()));
    if (inserted) {
      count.push_back(0);
      keys.push_back(k);
    }
    ++count[it->second];
  }
  std::vector<int> parent(count.size());
  std::iota(parent.begin(), parent.end(), 0);
  for (size_t i = 0; i < keys.size(); ++i) {
    for (int dz = -1; dz <= 1; ++dz) {
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          auto it = voxels.find(keys[i] + Eigen::Vector3i(dx, dy, dz));
          if (it == voxels.end()) continue;
          const int a = Find(parent, static_cast<int>(i)), b = Find(parent, it->second);
          if (a != b) parent[a] = b;
        }
      }
    }
  }
  std::vector<int64_t> region(count.size(), 0);
  int64_t best = 0;
  for (size_t i = 0; i < count.size(); ++i) {
    const int r = Find(parent, static_cast<int>(i));
    region[r] += count[i];
    best = std::max(best, region[r]);
  }
  return best;
}

bool InRoi(const Cell& cell, const Pose& X_BW, const Eigen::Vector3f& p_B) {
  const Vec3 p_W = X_BW.inverse() * p_B.cast<double>();
  const double hx = cell.bin.inner_size.x() / 2 - cell.roi.wall_margin;
  const double hy = cell.bin.inner_size.y() / 2 - cell.roi.wall_margin;
  return std::abs(p_W.x()) <= hx && std::abs(p_W.y()) <= hy && p_W.z() >= cell.roi.floor_margin &&
         p_W.z() <= cell.roi.height;
}

TruthPerception::TruthPerception(Cell cell, TruthPerceptionOptions options)
    : cell_(std::move(cell)), options_(options) {}

Result<PerceptionResult> TruthPerception::Run(const Frame& frame, const std::vector<int>& classes,
                                              PerceptionEffort /*effort*/,
                                              const std::optional<PerceptionRegion>& region) const {
  const auto t0 = std::chrono::steady_clock::now();
  const Pose X_RB = region ? region->X_BR.inverse() : Pose::Identity();
  PerceptionResult out;
  // The oracle knows where the bin truly stands when the frame's truth does.
  if (!region && frame.truth && frame.truth->X_BW) {
    out.bin = BinDetection{};
    out.bin->found = true;
    out.bin->X_BW = *frame.truth->X_BW;
  }
  const Pose X_BW = BinPoseOf(out, cell_.bin);
  const auto in_roi = [&](const Eigen::Vector3f& p_B) {
    return region ? region->box_R.contains(X_RB * p_B.cast<double>()) : InRoi(cell_, X_BW, p_B);
  };
  std::vector<uint16_t> label_of_point;
  const Eigen::Isometry3f X_BC = frame.X_BC.cast<float>();
  const bool labelled = frame.truth && frame.organized() && frame.truth->labels.width == frame.depth.width &&
                        frame.truth->labels.height == frame.depth.height;
  if (frame.organized()) {
    for (int v = 0; v < frame.depth.height; ++v) {
      for (int u = 0; u < frame.depth.width; ++u) {
        const float z = frame.depth.at(u, v);
        if (!std::isfinite(z) || z <= 0.f) continue;
        const Eigen::Vector3f p_B = X_BC * Deproject(frame.intrinsics, static_cast<float>(u), static_cast<float>(v), z);
        if (!in_roi(p_B)) continue;
        const uint16_t label = labelled ? frame.truth->labels.at(u, v) : 0;
        // The region's known geometry (PerceptionRegion::clear_mesh_R, the
        // gripper) is dropped; the labels say which pixels are the tool's.
        if (region && region->clear_mesh_R && label == SyntheticSource::kToolLabel) continue;
        out.roi_points_B.push_back(p_B);
        label_of_point.push_back(label);
      }
    }
  } else {
    for (const auto& p_C : frame.points_C) {
      if (!p_C.allFinite()) continue;
      const Eigen::Vector3f p_B = X_BC * p_C;
      if (in_roi(p_B)) out.roi_points_B.push_back(p_B);
    }
    label_of_point.assign(out.roi_points_B.size(), 0);
  }
  out.roi_point_count = static_cast<int64_t>(out.roi_points_B.size());
  out.largest_region_points = LargestRegionPoints(out.roi_points_B, options_.region_cell);
  out.segment_of_point.assign(out.roi_points_B.size(), -1);
  if (frame.truth && labelled) {
    std::unordered_map<int, std::vector<int32_t>> support;
    for (size_t i = 0; i < label_of_point.size(); ++i) {
      const uint16_t l = label_of_point[i];
      if (l != 0 && l != GroundTruth::kBinLabel) support[l].push_back(static_cast<int32_t>(i));
    }
    for (const PartTruth& t : frame.truth->parts) {
      if (!classes.empty() && std::find(classes.begin(), classes.end(), t.class_id) == classes.end()) continue;
      auto it = support.find(t.instance_id);
      if (it == support.end()) continue;
      if (t.visible_fraction < options_.min_visible_fraction ||
          static_cast<int>(it->second.size()) < options_.min_support_points) {
        continue;
      }
      Detection d;
      d.class_id = t.class_id;
      d.X_BO = t.X_BO;
      d.score = t.visible_fraction;
      d.visible_fraction = t.visible_fraction;
      d.support = std::move(it->second);
      for (int32_t i : d.support) out.segment_of_point[i] = static_cast<int32_t>(out.detections.size());
      out.detections.push_back(std::move(d));
    }
  }
  if (out.detections.empty()) out.reason = frame.truth ? "no part visible enough (truth oracle)" : "frame has no ground truth";
  out.timings.push_back({"truth_oracle", std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count()});
  return out;
}

}  // namespace bp
