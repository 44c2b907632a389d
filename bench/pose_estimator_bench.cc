// Pose estimation on synthetic default-cell frames (20 parts, default noise,
// 640 x 480), with ground-truth ("oracle") segments: the pixels each part
// covers in the label image, since the segmentation stage is not written yet.
//
//   ./build/bin/bp_bench --benchmark_filter='Pose|OpenCv'
//
// BM_PoseAccuracy / BM_OpenCvPpfAccuracy run once over all segments of
// kFrames frames and print a table (recall over parts >= 50% visible, wrong
// detections, median / p95 errors, thread CPU time per segment). See
// docs/perception.md.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <map>
#include <memory>

#include <opencv2/core.hpp>
#include <opencv2/surface_matching.hpp>
#include <opencv2/surface_matching/ppf_helpers.hpp>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "core/mesh_gen.h"
#include "pipeline/internal/model_sampling.h"
#include "pipeline/pose_estimator.h"
#include "pipeline/synthetic_source.h"

namespace bp {
namespace {

constexpr int kFrames = 4;
constexpr double kDeg = M_PI / 180.0;

// Thread CPU time, ms: the machine is shared, wall time includes waiting.
double CpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

struct Segment {
  int frame = 0;
  int class_index = 0;
  Pose X_BO;
  double visible_fraction = 0;
  std::vector<Eigen::Vector3f> points_B;
};

struct Data {
  Cell cell;
  std::vector<TriangleMesh> meshes;  // by class index (cell.parts order)
  std::vector<std::unique_ptr<PoseEstimator>> estimators;
  std::vector<double> build_ms;
  std::vector<Frame> frames;
  std::vector<Segment> segments;
  Eigen::Vector4d floor_B;
};

[[noreturn]] void Die(const std::string& what) {
  std::fprintf(stderr, "pose bench setup: %s\n", what.c_str());
  std::abort();
}

const Data& GetData() {
  static const Data data = [] {
    Data d;
    auto cell = LoadDefaultCell();
    if (!cell.ok()) Die(cell.status().ToString());
    d.cell = *cell;
    for (const PartSpec& part : d.cell.parts) {
      auto mesh = LoadMesh(part.mesh);
      if (!mesh.ok()) Die(mesh.status().ToString());
      d.meshes.push_back(*mesh);
      const auto t0 = std::chrono::steady_clock::now();
      auto est = PoseEstimator::Build(*mesh, part.symmetry);
      d.build_ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      if (!est.ok()) Die(est.status().ToString());
      d.estimators.push_back(std::move(est).value());
    }
    const Vec3 n = d.cell.bin.X_BW.linear() * Vec3::UnitZ();
    d.floor_B << n, -n.dot(d.cell.bin.X_BW.translation());
    for (int f = 0; f < kFrames; ++f) {
      Cell c = d.cell;
      c.source.seed = 1 + f;
      c.source.num_parts = 20;
      auto source = MakeSyntheticSource(c);
      if (!source.ok()) Die(source.status().ToString());
      auto frame = (*source)->Capture(CaptureRequest{});
      if (!frame.ok() || !frame->truth) Die("capture failed");
      d.frames.push_back(std::move(*frame));
    }
    for (int f = 0; f < kFrames; ++f) {
      const Frame& fr = d.frames[f];
      for (const PartTruth& t : fr.truth->parts) {
        Segment s;
        s.frame = f;
        s.X_BO = t.X_BO;
        s.visible_fraction = t.visible_fraction;
        for (size_t k = 0; k < d.cell.parts.size(); ++k) {
          if (d.cell.parts[k].class_id == t.class_id) s.class_index = static_cast<int>(k);
        }
        for (int v = 0; v < fr.depth.height; ++v) {
          for (int u = 0; u < fr.depth.width; ++u) {
            const float z = fr.depth.at(u, v);
            if (fr.truth->labels.at(u, v) != t.instance_id || !std::isfinite(z) || z <= 0) continue;
            s.points_B.push_back((fr.X_BC * Deproject(fr.intrinsics, u, v, z).cast<double>()).cast<float>());
          }
        }
        if (s.points_B.size() >= 50) d.segments.push_back(std::move(s));
      }
    }
    return d;
  }();
  return data;
}

SceneView ViewOf(const Data& d, const Segment& s) {
  SceneView v;
  v.points_B = s.points_B;
  v.X_BC = d.frames[s.frame].X_BC;
  v.depth = &d.frames[s.frame].depth;
  v.intrinsics = d.frames[s.frame].intrinsics;
  v.support_plane_B = d.floor_B;
  return v;
}

std::vector<const Segment*> SegmentsOf(const Data& d, int class_index, double min_visible) {
  std::vector<const Segment*> out;
  for (const Segment& s : d.segments) {
    if (s.class_index == class_index && s.visible_fraction >= min_visible) out.push_back(&s);
  }
  return out;
}

void BM_PoseModelBuild(benchmark::State& state) {
  const Data& d = GetData();
  const int k = static_cast<int>(state.range(0));
  for (auto _ : state) {
    auto est = PoseEstimator::Build(d.meshes[k], d.cell.parts[k].symmetry);
    benchmark::DoNotOptimize(est.ok());
  }
  state.SetLabel(d.cell.parts[k].name);
}
BENCHMARK(BM_PoseModelBuild)->DenseRange(0, 2)->Unit(benchmark::kMillisecond)->Iterations(2);

// One segment of a part >= 50% visible (cycling through all of them).
void BM_PoseEstimate(benchmark::State& state) {
  const Data& d = GetData();
  const int k = static_cast<int>(state.range(0));
  const auto segs = SegmentsOf(d, k, 0.5);
  if (segs.empty()) return state.SkipWithError("no segment");
  size_t i = 0, points = 0;
  PoseTimings sum;
  for (auto _ : state) {
    const Segment& s = *segs[i++ % segs.size()];
    auto r = d.estimators[k]->Estimate(ViewOf(d, s));
    points += s.points_B.size();
    sum.prepare_ms += r->timings.prepare_ms;
    sum.coarse_ms += r->timings.coarse_ms;
    sum.refine_ms += r->timings.refine_ms;
    sum.verify_ms += r->timings.verify_ms;
  }
  const double n = static_cast<double>(state.iterations());
  state.counters["points"] = points / n;
  state.counters["prepare_ms"] = sum.prepare_ms / n;
  state.counters["coarse_ms"] = sum.coarse_ms / n;
  state.counters["refine_ms"] = sum.refine_ms / n;
  state.counters["verify_ms"] = sum.verify_ms / n;
  state.SetLabel(d.cell.parts[k].name);
}
BENCHMARK(BM_PoseEstimate)->DenseRange(0, 2)->Unit(benchmark::kMillisecond);

// All segments of one frame (~20 parts) on a 2-thread TBB arena, parallel over
// segments. arg 0: each segment against its own class; arg 1: against every
// class (what an unlabelled segmentation needs), keeping the best score.
void BM_PoseFrame2Threads(benchmark::State& state) {
  const Data& d = GetData();
  const bool all_classes = state.range(0) == 1;
  std::vector<const Segment*> segs;
  for (const Segment& s : d.segments) {
    if (s.frame == 0) segs.push_back(&s);
  }
  tbb::task_arena arena(2);
  for (auto _ : state) {
    arena.execute([&] {
      tbb::parallel_for(size_t{0}, segs.size(), [&](size_t i) {
        const Segment& s = *segs[i];
        if (!all_classes) {
          benchmark::DoNotOptimize(d.estimators[s.class_index]->Estimate(ViewOf(d, s)).ok());
          return;
        }
        for (const auto& e : d.estimators) benchmark::DoNotOptimize(e->Estimate(ViewOf(d, s)).ok());
      });
    });
  }
  state.counters["segments"] = static_cast<double>(segs.size());
  state.SetLabel(all_classes ? "every class per segment" : "own class per segment");
}
BENCHMARK(BM_PoseFrame2Threads)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();

// ---------------------------------------------------------------- OpenCV PPF

cv::Mat ToMat(const std::vector<Eigen::Vector3f>& p, const std::vector<Eigen::Vector3f>* n) {
  cv::Mat m(static_cast<int>(p.size()), n ? 6 : 3, CV_32F);
  for (int i = 0; i < m.rows; ++i) {
    for (int j = 0; j < 3; ++j) m.at<float>(i, j) = p[i][j];
    if (n) {
      for (int j = 0; j < 3; ++j) m.at<float>(i, 3 + j) = (*n)[i][j];
    }
  }
  return m;
}

struct OpenCvModel {
  std::unique_ptr<cv::ppf_match_3d::PPF3DDetector> detector;
  cv::Mat model_pc;
  double train_ms = 0;
};

const std::vector<OpenCvModel>& OpenCvModels() {
  static const std::vector<OpenCvModel> models = [] {
    const Data& d = GetData();
    std::vector<OpenCvModel> v;
    for (const TriangleMesh& mesh : d.meshes) {
      const auto dense = internal::SampleSurface(mesh, 0.0008, 1);
      const auto pts = internal::VoxelDownsample(dense, 0.002, 45.0);
      OpenCvModel m;
      m.model_pc = ToMat(pts.points, &pts.normals);
      m.detector = std::make_unique<cv::ppf_match_3d::PPF3DDetector>(0.05, 0.05);
      const auto t0 = std::chrono::steady_clock::now();
      m.detector->trainModel(m.model_pc);
      m.train_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      v.push_back(std::move(m));
    }
    return v;
  }();
  return models;
}

// OpenCV's pipeline: scene normals (computeNormalsPC3d, 8 neighbours, flipped
// to the camera), PPF3DDetector::match (scene sampling 1/5, distance 0.05),
// optionally its ICP on the top results. Returns the best pose.
Pose OpenCvMatch(const OpenCvModel& m, const Segment& s, const Vec3& camera_B, bool icp) {
  cv::Mat pc = ToMat(s.points_B, nullptr), pcn;
  cv::ppf_match_3d::computeNormalsPC3d(pc, pcn, 8, true,
                                       cv::Vec3f(static_cast<float>(camera_B.x()), static_cast<float>(camera_B.y()),
                                                 static_cast<float>(camera_B.z())));
  std::vector<cv::ppf_match_3d::Pose3DPtr> results;
  m.detector->match(pcn, results, 1.0 / 5.0, 0.05);
  if (results.empty()) return Pose::Identity();
  if (icp) {
    if (results.size() > 3) results.resize(3);
    cv::ppf_match_3d::ICP refine(50, 0.005f, 2.5f, 6);
    refine.registerModelToScene(m.model_pc, pcn, results);
    std::sort(results.begin(), results.end(), [](const auto& a, const auto& b) { return a->residual < b->residual; });
  }
  Pose X = Pose::Identity();
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) X.matrix()(r, c) = results[0]->pose(r, c);
  }
  return X;
}

void BM_OpenCvPpfMatch(benchmark::State& state) {
  const Data& d = GetData();
  const auto& models = OpenCvModels();
  const int k = static_cast<int>(state.range(0));
  const bool icp = state.range(1) == 1;
  const auto segs = SegmentsOf(d, k, 0.5);
  if (segs.empty()) return state.SkipWithError("no segment");
  size_t i = 0;
  for (auto _ : state) {
    const Segment& s = *segs[i++ % segs.size()];
    benchmark::DoNotOptimize(OpenCvMatch(models[k], s, d.frames[s.frame].X_BC.translation(), icp));
  }
  state.counters["train_ms"] = models[k].train_ms;
  state.SetLabel(d.cell.parts[k].name + (icp ? " +ICP" : ""));
}
BENCHMARK(BM_OpenCvPpfMatch)->ArgsProduct({{0, 1, 2}, {0, 1}})->Unit(benchmark::kMillisecond);

// ---------------------------------------------------------------- accuracy

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * (v.size() - 1) + 0.5))];
}

struct Tally {
  int segments = 0, eligible = 0, found_eligible = 0, detections = 0, wrong = 0;
  std::vector<double> t_mm, r_deg, ms;
};

// Correct: ADD-S below 10% of the diameter. Errors are over correct detections.
void Report(const char* method, const std::map<int, Tally>& tallies, const Data& d) {
  std::printf("\n%s on %d frames (oracle segments; recall over parts >= 50%% visible)\n", method, kFrames);
  std::printf("%-16s %5s %9s %8s %7s %9s %9s %9s %9s %8s %8s\n", "class", "segs", "recall", "dets", "wrong",
              "med_t_mm", "p95_t_mm", "med_r_deg", "p95_r_deg", "med_ms", "p95_ms");
  Tally all;
  for (const auto& [k, t] : tallies) {
    std::printf("%-16s %5d %4d/%-4d %8d %7d %9.3f %9.3f %9.3f %9.3f %8.2f %8.2f\n", d.cell.parts[k].name.c_str(),
                t.segments, t.found_eligible, t.eligible, t.detections, t.wrong, Percentile(t.t_mm, 0.5),
                Percentile(t.t_mm, 0.95), Percentile(t.r_deg, 0.5), Percentile(t.r_deg, 0.95), Percentile(t.ms, 0.5),
                Percentile(t.ms, 0.95));
    all.segments += t.segments, all.eligible += t.eligible, all.found_eligible += t.found_eligible;
    all.detections += t.detections, all.wrong += t.wrong;
    all.t_mm.insert(all.t_mm.end(), t.t_mm.begin(), t.t_mm.end());
    all.r_deg.insert(all.r_deg.end(), t.r_deg.begin(), t.r_deg.end());
    all.ms.insert(all.ms.end(), t.ms.begin(), t.ms.end());
  }
  std::printf("%-16s %5d %4d/%-4d %8d %7d %9.3f %9.3f %9.3f %9.3f %8.2f %8.2f\n", "all", all.segments,
              all.found_eligible, all.eligible, all.detections, all.wrong, Percentile(all.t_mm, 0.5),
              Percentile(all.t_mm, 0.95), Percentile(all.r_deg, 0.5), Percentile(all.r_deg, 0.95),
              Percentile(all.ms, 0.5), Percentile(all.ms, 0.95));
  std::fflush(stdout);
}

void Score(Tally& t, const Data& d, const Segment& s, bool detected, const Pose& X) {
  ++t.segments;
  const bool eligible = s.visible_fraction >= 0.5;
  t.eligible += eligible;
  if (!detected) return;
  ++t.detections;
  const PoseEstimator& e = *d.estimators[s.class_index];
  const Symmetry& sym = d.cell.parts[s.class_index].symmetry;
  const bool correct = AddS(e.surface_points_O(), X, s.X_BO) < 0.1 * e.diameter();
  if (!correct) {
    ++t.wrong;
    return;
  }
  t.found_eligible += eligible;
  t.t_mm.push_back(1000 * SymmetricTranslationError(X, s.X_BO, sym));
  t.r_deg.push_back(SymmetricRotationError(X, s.X_BO, sym) / kDeg);
}

void BM_PoseAccuracy(benchmark::State& state) {
  const Data& d = GetData();
  for (auto _ : state) {
    std::map<int, Tally> tallies;
    for (const Segment& s : d.segments) {
      const double t0 = CpuMs();
      auto r = d.estimators[s.class_index]->Estimate(ViewOf(d, s));
      const double ms = CpuMs() - t0;
      Tally& t = tallies[s.class_index];
      t.ms.push_back(ms);
      const bool det = r.ok() && !r->hypotheses.empty();
      Score(t, d, s, det, det ? r->hypotheses[0].X_BO : Pose::Identity());
    }
    Report("binpick PoseEstimator", tallies, d);
  }
}
BENCHMARK(BM_PoseAccuracy)->Iterations(1)->Unit(benchmark::kMillisecond);

// OpenCV always returns a pose; it counts as a detection on every segment.
void BM_OpenCvPpfAccuracy(benchmark::State& state) {
  const Data& d = GetData();
  const auto& models = OpenCvModels();
  const bool icp = state.range(0) == 1;
  for (auto _ : state) {
    std::map<int, Tally> tallies;
    for (const Segment& s : d.segments) {
      if (s.points_B.size() < 100) {  // too small for its normal estimation: a miss
        Score(tallies[s.class_index], d, s, false, Pose::Identity());
        continue;
      }
      const double t0 = CpuMs();
      const Pose X = OpenCvMatch(models[s.class_index], s, d.frames[s.frame].X_BC.translation(), icp);
      const double ms = CpuMs() - t0;
      Tally& t = tallies[s.class_index];
      t.ms.push_back(ms);
      Score(t, d, s, true, X);
    }
    Report(icp ? "OpenCV PPF3DDetector + ICP" : "OpenCV PPF3DDetector", tallies, d);
  }
}
BENCHMARK(BM_OpenCvPpfAccuracy)->Arg(0)->Arg(1)->Iterations(1)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace bp
