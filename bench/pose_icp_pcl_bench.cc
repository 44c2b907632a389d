// Refinement alone: binpick's point-to-plane ICP (internal/point_to_plane_icp.h,
// precomputed closest-point field) against PCL 1.13's
// IterativeClosestPointWithNormals, both started from the ground-truth pose
// perturbed by 3 mm / 3 degrees (seeded), on the same synthetic segments
// (default cell, 640 x 480, parts >= 50% visible).
//
//   ./build/bin/bp_bench --benchmark_filter='IcpCompare'
//
// Kept in its own file: PCL's registration headers are the heaviest include
// in the project.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdio>
#include <ctime>
#include <random>

#include <pcl/features/normal_3d.h>
#include <pcl/point_types.h>
#include <pcl/registration/icp.h>
#include <pcl/search/kdtree.h>

#include "core/mesh_gen.h"
#include "pipeline/internal/closest_point_field.h"
#include "pipeline/internal/model_sampling.h"
#include "pipeline/internal/point_to_plane_icp.h"
#include "pipeline/pose_estimator.h"
#include "pipeline/synthetic_source.h"

namespace bp {
namespace {

double CpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

struct Case {
  int cls;
  Pose X_true, X_start;
  Vec3 camera_B;
  std::vector<Eigen::Vector3f> points_B;
};

void BM_IcpCompare(benchmark::State& state) {
  auto cell = LoadDefaultCell();
  if (!cell.ok()) return state.SkipWithError("no cell");
  std::vector<internal::OrientedPoints> dense, coarse;
  std::vector<internal::ClosestPointField> fields(cell->parts.size());
  for (size_t k = 0; k < cell->parts.size(); ++k) {
    auto mesh = LoadMesh(cell->parts[k].mesh);
    if (!mesh.ok()) return state.SkipWithError("no mesh");
    dense.push_back(internal::SampleSurface(*mesh, 0.0008, 1));
    coarse.push_back(internal::VoxelDownsample(dense.back(), 0.002, 45.0));
    fields[k].Build(dense.back().points, 0.001f, 0.006f);
  }
  std::vector<Case> cases;
  std::mt19937_64 rng{5};
  std::normal_distribution<double> g(0.0, 1.0);
  for (int f = 0; f < 3; ++f) {
    Cell c = *cell;
    c.source.seed = 1 + f;
    auto source = MakeSyntheticSource(c);
    if (!source.ok()) return state.SkipWithError("no source");
    auto fr = (*source)->Capture(CaptureRequest{});
    if (!fr.ok()) return state.SkipWithError("capture failed");
    for (const PartTruth& t : fr->truth->parts) {
      if (t.visible_fraction < 0.5) continue;
      Case cs;
      for (size_t k = 0; k < cell->parts.size(); ++k) {
        if (cell->parts[k].class_id == t.class_id) cs.cls = static_cast<int>(k);
      }
      cs.X_true = t.X_BO;
      const Vec3 axis = Vec3(g(rng), g(rng), g(rng)).normalized();
      const Vec3 shift = 0.003 * Vec3(g(rng), g(rng), g(rng)).normalized();
      cs.X_start = MakePose(Mat3(Eigen::AngleAxisd(3.0 * M_PI / 180.0, axis)) * t.X_BO.linear(),
                            t.X_BO.translation() + shift);
      cs.camera_B = fr->X_BC.translation();
      for (int v = 0; v < fr->depth.height; ++v) {
        for (int u = 0; u < fr->depth.width; ++u) {
          const float z = fr->depth.at(u, v);
          if (fr->truth->labels.at(u, v) != t.instance_id || !std::isfinite(z)) continue;
          cs.points_B.push_back((fr->X_BC * Deproject(fr->intrinsics, u, v, z).cast<double>()).cast<float>());
        }
      }
      cases.push_back(std::move(cs));
    }
  }
  for (auto _ : state) {
    std::vector<double> own_t, own_r, own_ms, pcl_t, pcl_r, pcl_ms, pcl_normals_ms;
    for (const Case& cs : cases) {
      const Symmetry& sym = cell->parts[cs.cls].symmetry;
      // binpick: all segment points, pure point-to-plane (no silhouette term).
      double t0 = CpuMs();
      internal::IcpModel model{dense[cs.cls].points, dense[cs.cls].normals, &fields[cs.cls], {}};
      internal::IcpOptions o;
      o.iterations = 30;
      o.initial_distance = 0.006f;
      o.final_distance = 0.002f;
      const auto own = internal::RefinePointToPlane(model, cs.points_B, cs.X_start, cs.camera_B, o);
      own_ms.push_back(CpuMs() - t0);
      own_t.push_back(1000 * SymmetricTranslationError(own.X_BO, cs.X_true, sym));
      own_r.push_back(SymmetricRotationError(own.X_BO, cs.X_true, sym) * 180 / M_PI);

      // PCL: model samples (2 mm, every side: PCL has no visibility) onto the
      // segment with normals from NormalEstimation (k = 10).
      t0 = CpuMs();
      pcl::PointCloud<pcl::PointXYZ>::Ptr xyz(new pcl::PointCloud<pcl::PointXYZ>);
      for (const auto& p : cs.points_B) xyz->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
      pcl::NormalEstimation<pcl::PointXYZ, pcl::Normal> ne;
      pcl::PointCloud<pcl::Normal> normals;
      ne.setInputCloud(xyz);
      ne.setSearchMethod(pcl::search::KdTree<pcl::PointXYZ>::Ptr(new pcl::search::KdTree<pcl::PointXYZ>));
      ne.setKSearch(10);
      ne.setViewPoint(cs.camera_B.x(), cs.camera_B.y(), cs.camera_B.z());
      ne.compute(normals);
      pcl::PointCloud<pcl::PointNormal>::Ptr target(new pcl::PointCloud<pcl::PointNormal>);
      for (size_t i = 0; i < xyz->size(); ++i) {
        pcl::PointNormal pn;
        pn.x = (*xyz)[i].x, pn.y = (*xyz)[i].y, pn.z = (*xyz)[i].z;
        pn.normal_x = normals[i].normal_x, pn.normal_y = normals[i].normal_y, pn.normal_z = normals[i].normal_z;
        if (std::isfinite(pn.normal_x)) target->push_back(pn);
      }
      pcl_normals_ms.push_back(CpuMs() - t0);
      t0 = CpuMs();
      pcl::PointCloud<pcl::PointNormal>::Ptr src(new pcl::PointCloud<pcl::PointNormal>);
      const Eigen::Matrix3f R = cs.X_start.linear().cast<float>();
      const Eigen::Vector3f tr = cs.X_start.translation().cast<float>();
      for (size_t i = 0; i < coarse[cs.cls].size(); ++i) {
        const Eigen::Vector3f p = R * coarse[cs.cls].points[i] + tr;
        const Eigen::Vector3f n = R * coarse[cs.cls].normals[i];
        if (n.dot(cs.camera_B.cast<float>() - p) <= 0) continue;  // give PCL the camera-facing half
        pcl::PointNormal pn;
        pn.x = p.x(), pn.y = p.y(), pn.z = p.z();
        pn.normal_x = n.x(), pn.normal_y = n.y(), pn.normal_z = n.z();
        src->push_back(pn);
      }
      pcl::IterativeClosestPointWithNormals<pcl::PointNormal, pcl::PointNormal> icp;
      icp.setInputSource(src);
      icp.setInputTarget(target);
      icp.setMaxCorrespondenceDistance(0.006);
      icp.setMaximumIterations(30);
      icp.setTransformationEpsilon(1e-10);
      pcl::PointCloud<pcl::PointNormal> aligned;
      icp.align(aligned);
      pcl_ms.push_back(CpuMs() - t0);
      Pose delta = Pose::Identity();
      delta.matrix() = icp.getFinalTransformation().cast<double>();
      const Pose X_pcl = delta * cs.X_start;
      pcl_t.push_back(1000 * SymmetricTranslationError(X_pcl, cs.X_true, sym));
      pcl_r.push_back(SymmetricRotationError(X_pcl, cs.X_true, sym) * 180 / M_PI);
    }
    std::printf("\nICP from truth + 3 mm / 3 deg on %zu segments (thread CPU ms; medians)\n", cases.size());
    std::printf("%-40s %8s %8s %8s\n", "", "t_mm", "r_deg", "ms");
    std::printf("%-40s %8.3f %8.3f %8.2f\n", "binpick point-to-plane (field lookup)", Median(own_t), Median(own_r),
                Median(own_ms));
    std::printf("%-40s %8.3f %8.3f %8.2f  (+%.2f ms normals)\n", "PCL IterativeClosestPointWithNormals",
                Median(pcl_t), Median(pcl_r), Median(pcl_ms), Median(pcl_normals_ms));
    std::fflush(stdout);
  }
  state.counters["segments"] = static_cast<double>(cases.size());
}
BENCHMARK(BM_IcpCompare)->Iterations(1)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace bp
