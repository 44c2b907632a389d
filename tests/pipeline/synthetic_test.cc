#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>

#include "pipeline/internal/depth_noise.h"
#include "pipeline/synthetic_source.h"
#include "pipeline/synthetic_variety.h"
#include "tests/test_meshes.h"

namespace bp {
namespace {

Cell TestCell(int num_parts, uint64_t seed, bool noise) {
  Cell cell;
  cell.name = "test";
  cell.camera.X_BC =
      MakePose(Eigen::AngleAxisd(M_PI, Vec3::UnitX()).toRotationMatrix(), Vec3(0.7, 0.0, 0.9));
  CameraConfig c;
  c.id = 1;
  c.name = "qvga";
  c.intrinsics.width = 320;
  c.intrinsics.height = 240;
  c.intrinsics.fx = c.intrinsics.fy = 400;
  c.intrinsics.cx = 159.5;
  c.intrinsics.cy = 119.5;
  c.min_depth = 0.3;
  c.max_depth = 2.0;
  c.noise.enabled = noise;
  cell.camera.configs.push_back(c);
  cell.camera.default_config = 1;
  cell.bin.inner_size = Vec3(0.3, 0.2, 0.15);
  cell.bin.wall_thickness = 0.01;
  cell.bin.X_BW = MakePose(Mat3::Identity(), Vec3(0.7, 0.0, 0.0));
  cell.source.num_parts = num_parts;
  cell.source.seed = seed;
  return cell;
}

std::vector<PileClass> Classes() {
  std::vector<PileClass> c(2);
  c[0] = {0, "block", std::make_shared<TriangleMesh>(testing::BoxMesh({0.06f, 0.04f, 0.02f}))};
  c[1] = {1, "puck", std::make_shared<TriangleMesh>(testing::CylinderMesh(0.02f, 0.03f))};
  return c;
}

TriangleMesh BinMesh(const Cell& cell) {
  return testing::OpenBinMesh(cell.bin.inner_size.cast<float>(),
                              static_cast<float>(cell.bin.wall_thickness));
}

std::unique_ptr<SyntheticSource> MakeSource(const Cell& cell) {
  auto s = SyntheticSource::Create(cell, Classes(), BinMesh(cell));
  EXPECT_TRUE(s.ok()) << s.status().ToString();
  return s.ok() ? std::move(*s) : nullptr;
}

Frame CaptureOk(SyntheticSource& source, CaptureRequest request = {}) {
  auto f = source.Capture(request);
  EXPECT_TRUE(f.ok()) << f.status().ToString();
  return f.ok() ? std::move(*f) : Frame{};
}

template <typename T>
bool SameBytes(const Image<T>& a, const Image<T>& b) {
  return a.width == b.width && a.height == b.height &&
         std::memcmp(a.data.data(), b.data.data(), a.data.size() * sizeof(T)) == 0;
}

// Distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5).
double PointTriangleDistance(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return (p - a).norm();
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return (p - b).norm();
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return (p - (a + d1 / (d1 - d3) * ab)).norm();
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return (p - c).norm();
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return (p - (a + d2 / (d2 - d6) * ac)).norm();
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    return (p - (b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b))).norm();
  }
  const double denom = 1.0 / (va + vb + vc);
  return (p - (a + ab * (vb * denom) + ac * (vc * denom))).norm();
}

double MeshDistance(const TriangleMesh& m, const Vec3& p_O) {
  double best = 1e9;
  for (const auto& t : m.triangles) {
    best = std::min(best, PointTriangleDistance(p_O, m.vertices[t[0]].cast<double>(),
                                                m.vertices[t[1]].cast<double>(),
                                                m.vertices[t[2]].cast<double>()));
  }
  return best;
}

// For every 4th labelled pixel with valid depth: distance of the deprojected
// point to the labelled part's surface at its true pose. Returns the errors
// divided by `scale(z)`.
std::vector<double> SurfaceErrors(const SyntheticSource& source, const Frame& f,
                                  double (*scale)(double)) {
  std::vector<double> errors;
  const auto classes = Classes();
  const TriangleMesh bin_mesh = BinMesh(TestCell(0, 0, false));
  for (int v = 0; v < f.depth.height; v += 4) {
    for (int u = 0; u < f.depth.width; u += 4) {
      const float z = f.depth.at(u, v);
      const uint16_t label = f.truth->labels.at(u, v);
      if (!std::isfinite(z) || label == 0) continue;
      const Vec3 p_B = f.X_BC * Deproject(f.intrinsics, u, v, z).cast<double>();
      double d;
      if (label == GroundTruth::kBinLabel) {
        d = MeshDistance(bin_mesh, source.X_BW().inverse() * p_B);
      } else {
        auto it = std::find_if(f.truth->parts.begin(), f.truth->parts.end(),
                               [&](const PartTruth& t) { return t.instance_id == label; });
        if (it == f.truth->parts.end()) {
          ADD_FAILURE() << "label " << label << " has no truth";
          continue;
        }
        d = MeshDistance(*classes[it->class_id].mesh, it->X_BO.inverse() * p_B);
      }
      errors.push_back(d / scale(z));
    }
  }
  return errors;
}

TEST(SyntheticSource, SameSeedGivesIdenticalFramesAndAnotherSeedDoesNot) {
  auto a = MakeSource(TestCell(8, 3, true));
  auto b = MakeSource(TestCell(8, 3, true));
  auto c = MakeSource(TestCell(8, 4, true));
  ASSERT_TRUE(a && b && c);
  const Frame fa = CaptureOk(*a), fb = CaptureOk(*b), fc = CaptureOk(*c);
  EXPECT_TRUE(SameBytes(fa.depth, fb.depth));
  EXPECT_TRUE(SameBytes(fa.intensity, fb.intensity));
  EXPECT_TRUE(SameBytes(fa.truth->labels, fb.truth->labels));
  EXPECT_FALSE(SameBytes(fa.depth, fc.depth));
  EXPECT_FALSE(SameBytes(fa.truth->labels, fc.truth->labels));
  EXPECT_EQ(fa.source, "synthetic seed=3 capture=0");
  // The next capture of one pile draws new noise but shows the same scene.
  const Frame fa2 = CaptureOk(*a);
  EXPECT_FALSE(SameBytes(fa.depth, fa2.depth));
  EXPECT_TRUE(SameBytes(fa.truth->labels, fa2.truth->labels));
}

// Frames equal byte for byte: depth (NaNs included), intensity, labels and
// every part's truth.
void ExpectSameFrame(const Frame& a, const Frame& b) {
  EXPECT_TRUE(SameBytes(a.depth, b.depth));
  EXPECT_TRUE(SameBytes(a.intensity, b.intensity));
  ASSERT_TRUE(a.truth && b.truth);
  EXPECT_TRUE(SameBytes(a.truth->labels, b.truth->labels));
  ASSERT_EQ(a.truth->parts.size(), b.truth->parts.size());
  for (size_t i = 0; i < a.truth->parts.size(); ++i) {
    const PartTruth &p = a.truth->parts[i], &q = b.truth->parts[i];
    EXPECT_EQ(p.instance_id, q.instance_id);
    EXPECT_EQ(p.visible_pixels, q.visible_pixels);
    EXPECT_EQ(p.unoccluded_pixels, q.unoccluded_pixels);
    EXPECT_EQ(p.visible_fraction, q.visible_fraction);
    EXPECT_TRUE(p.X_BO.matrix() == q.X_BO.matrix());
  }
  EXPECT_EQ(a.source, b.source);
}

// The renders kept between captures (the whole scene while nothing was
// picked, each part's solo count while it did not move) give the frames a
// source rendering everything anew gives, through picks that resettle parts.
TEST(SyntheticSource, CachedRendersGiveTheFramesOfFreshOnes) {
  Cell cell = TestCell(14, 11, true);
  cell.source.simulate_picks = true;
  auto cached = MakeSource(cell);
  auto fresh = MakeSource(cell);
  ASSERT_TRUE(cached && fresh);
  auto capture_both = [&]() {
    fresh->ForgetRenders();
    Frame f = CaptureOk(*fresh);
    ExpectSameFrame(CaptureOk(*cached), f);
    return f;
  };
  capture_both();
  const Frame again = capture_both();  // nothing picked: no render at all in `cached`
  // The top part (nothing above moves), then the least visible one (parts
  // above it resettle), each followed by two captures.
  const auto by_visible = [](const PartTruth& a, const PartTruth& b) { return a.visible_pixels < b.visible_pixels; };
  const int top = std::max_element(again.truth->parts.begin(), again.truth->parts.end(), by_visible)->instance_id;
  cached->NotifyPicked(top);
  fresh->NotifyPicked(top);
  capture_both();
  const Frame after = capture_both();
  std::vector<PartTruth> seen;
  for (const PartTruth& t : after.truth->parts) {
    if (t.visible_pixels > 0) seen.push_back(t);
  }
  ASSERT_FALSE(seen.empty());
  const int low = std::min_element(seen.begin(), seen.end(), by_visible)->instance_id;
  const auto before = cached->pile().parts();
  cached->NotifyPicked(low);
  fresh->NotifyPicked(low);
  int moved = 0;
  for (const PilePart& p : cached->pile().parts()) {
    for (const PilePart& q : before) moved += p.instance_id == q.instance_id && !(p.X_WO.matrix() == q.X_WO.matrix());
  }
  capture_both();
  capture_both();
  EXPECT_GT(moved, 0) << "the pick under others resettled nothing: the test does not cover moved parts";
}

// Render readback and noise run in parallel row bands: one thread and four
// give the same bytes.
TEST(SyntheticSource, ParallelBandsGiveTheFramesOfOneThread) {
  for (bool noise : {true, false}) {
    auto serial = MakeSource(TestCell(12, 13, noise));
    auto parallel = MakeSource(TestCell(12, 13, noise));
    ASSERT_TRUE(serial && parallel);
    Frame one, four;
    tbb::task_arena(1).execute([&] { one = CaptureOk(*serial); });
    tbb::task_arena(4).execute([&] { four = CaptureOk(*parallel); });
    ExpectSameFrame(one, four);
  }
}

TEST(SyntheticSource, NoiselessDepthLiesOnTheLabelledPartsSurface) {
  auto source = MakeSource(TestCell(10, 5, false));
  ASSERT_TRUE(source);
  const Frame f = CaptureOk(*source);
  ASSERT_TRUE(f.truth.has_value());
  ASSERT_TRUE(f.organized());
  const auto errors = SurfaceErrors(*source, f, [](double) { return 1.0; });
  ASSERT_GT(errors.size(), 1000u);
  const double worst = *std::max_element(errors.begin(), errors.end());
  EXPECT_LT(worst, 0.0005);
  // Every part is in the truth with its class and a pose in B.
  EXPECT_EQ(f.truth->parts.size(), source->pile().parts().size());
}

TEST(SyntheticSource, NoisyDepthStaysWithinFourSigmaOfTheSurface) {
  auto source = MakeSource(TestCell(10, 5, true));
  ASSERT_TRUE(source);
  const Frame f = CaptureOk(*source);
  const NoiseModel noise;
  static const double base = noise.axial_sigma_base, quad = noise.axial_sigma_quadratic;
  const auto errors = SurfaceErrors(*source, f, [](double z) { return base + quad * z * z; });
  ASSERT_GT(errors.size(), 1000u);
  const auto outside =
      std::count_if(errors.begin(), errors.end(), [](double e) { return e > 4.0; });
  EXPECT_LE(outside, static_cast<long>(errors.size() / 500));
  // ... and is actually noisy.
  const auto above_half_sigma =
      std::count_if(errors.begin(), errors.end(), [](double e) { return e > 0.5; });
  EXPECT_GT(above_half_sigma, static_cast<long>(errors.size() / 4));
}

TEST(SyntheticSource, LoneUnoccludedPartIsFullyVisible) {
  auto source = MakeSource(TestCell(1, 2, false));
  ASSERT_TRUE(source);
  const Frame f = CaptureOk(*source);
  ASSERT_EQ(f.truth->parts.size(), 1u);
  const PartTruth& t = f.truth->parts[0];
  EXPECT_GT(t.visible_pixels, 50);
  EXPECT_EQ(t.visible_pixels, t.unoccluded_pixels);
  EXPECT_DOUBLE_EQ(t.visible_fraction, 1.0);
}

TEST(SyntheticSource, PartsUnderOthersArePartlyVisible) {
  auto source = MakeSource(TestCell(25, 5, false));
  ASSERT_TRUE(source);
  const Frame f = CaptureOk(*source);
  int partly = 0;
  for (const auto& t : f.truth->parts) {
    EXPECT_GE(t.visible_fraction, 0.0);
    EXPECT_LE(t.visible_fraction, 1.0);
    EXPECT_LE(t.visible_pixels, t.unoccluded_pixels);
    partly += (t.visible_fraction < 0.95) ? 1 : 0;
  }
  EXPECT_GT(partly, 0);
  // Parts that support another one are, seen from above, mostly partly hidden by it.
  int supporters = 0, hidden_supporters = 0;
  const auto& pile = source->pile();
  for (const auto& p : pile.parts()) {
    Pose lower = p.X_WO;
    lower.translation().z() -= 0.0005;
    const int self[] = {p.instance_id};
    for (int support :
         pile.scene().CollidingIds(*pile.class_geometry(p.class_index), lower, self)) {
      if (support == SyntheticPile::kBinId) continue;
      const auto& t = *std::find_if(f.truth->parts.begin(), f.truth->parts.end(),
                                    [&](const PartTruth& x) { return x.instance_id == support; });
      ++supporters;
      hidden_supporters += t.visible_fraction < 1.0 ? 1 : 0;
    }
  }
  ASSERT_GT(supporters, 0);
  EXPECT_GE(hidden_supporters * 4, supporters * 3) << hidden_supporters << " of " << supporters;
}

TEST(SyntheticSource, PickedPartLeavesTheNextFrameAndTheTruth) {
  Cell cell = TestCell(10, 5, false);
  cell.source.simulate_picks = true;
  auto source = MakeSource(cell);
  ASSERT_TRUE(source);
  const Frame f0 = CaptureOk(*source);
  const auto best = std::max_element(
      f0.truth->parts.begin(), f0.truth->parts.end(),
      [](const PartTruth& a, const PartTruth& b) { return a.visible_pixels < b.visible_pixels; });
  const int picked = best->instance_id;
  ASSERT_GT(best->visible_pixels, 0);
  source->NotifyPicked(picked);
  const Frame f1 = CaptureOk(*source);
  EXPECT_EQ(f1.truth->parts.size(), f0.truth->parts.size() - 1);
  for (const auto& t : f1.truth->parts) EXPECT_NE(t.instance_id, picked);
  EXPECT_EQ(std::count(f1.truth->labels.data.begin(), f1.truth->labels.data.end(), picked), 0);
  for (const auto& p : source->pile().parts())
    EXPECT_FALSE(source->pile().scene().ObjectCollides(p.instance_id));

  // Without simulate_picks the pile stays as it is.
  auto keep = MakeSource(TestCell(10, 5, false));
  ASSERT_TRUE(keep);
  keep->NotifyPicked(picked);
  EXPECT_EQ(keep->pile().parts().size(), f0.truth->parts.size());
}

TEST(SyntheticSource, RejectsUnknownConfigAndEyeInHandWithoutFlangePose) {
  Cell cell = TestCell(2, 1, false);
  auto source = MakeSource(cell);
  ASSERT_TRUE(source);
  CaptureRequest bad;
  bad.config_id = 7;
  EXPECT_EQ(source->Capture(bad).status().code(), Status::Code::kNotFound);

  cell.camera.eye_in_hand = true;
  cell.camera.X_FC = Pose::Identity();
  auto hand = MakeSource(cell);
  ASSERT_TRUE(hand);
  EXPECT_EQ(hand->Capture({}).status().code(), Status::Code::kInvalidArgument);
  CaptureRequest r;
  r.X_BF = cell.camera.X_BC;  // flange where the fixed camera was: same view
  const Frame f = CaptureOk(*hand, r);
  const Frame g = CaptureOk(*source);
  EXPECT_TRUE(f.X_BC.isApprox(g.X_BC));
  EXPECT_TRUE(SameBytes(f.truth->labels, g.truth->labels));
}

TEST(SyntheticSource, ProjectorShadowInvalidatesPixelsBesideRaisedParts) {
  Cell cell = TestCell(6, 9, true);
  NoiseModel& n = cell.camera.configs[0].noise;
  n.axial_sigma_base = n.axial_sigma_quadratic = 0;
  n.random_dropout = 0;
  n.grazing_start_deg = n.grazing_full_deg = 90;
  auto shadowed = MakeSource(cell);
  n.projector_shadow = false;
  auto lit = MakeSource(cell);
  ASSERT_TRUE(shadowed && lit);
  const Frame a = CaptureOk(*shadowed), b = CaptureOk(*lit);
  const size_t valid_a = a.ValidPointCount(), valid_b = b.ValidPointCount();
  EXPECT_LT(valid_a + 100, valid_b);
  // Without shadow and noise the depth is the clean render.
  for (size_t i = 0; i < b.depth.data.size(); ++i) {
    EXPECT_EQ(std::isfinite(b.depth.data[i]), b.truth->labels.data[i] != 0);
  }
}

TEST(DepthNoise, GrazingSurfacesDropOutAndRangeIsEnforced) {
  Intrinsics K;
  K.width = 200;
  K.height = 200;
  K.fx = K.fy = 300;
  K.cx = 99.5;
  K.cy = 99.5;
  // Rows 0-99: plane facing the camera at 1 m. Rows 100-199: plane through
  // (0, 0, 1) with normal (sin t, 0, cos t), t = 75 deg, so the angle to the
  // viewing ray of column u is t - atan(xn) (xn = (u - cx) / fx).
  const double t = 75.0 * M_PI / 180.0;
  DepthImage depth(200, 200);
  for (int v = 0; v < 200; ++v) {
    for (int u = 0; u < 200; ++u) {
      const double xn = (u - K.cx) / K.fx;
      const double denom = 1.0 + std::tan(t) * xn;
      depth.at(u, v) = v < 100 ? 1.0f : denom > 0.02 ? static_cast<float>(1.0 / denom) : NAN;
    }
  }
  depth.at(5, 5) = 0.1f;  // nearer than min_depth
  NoiseModel model;
  model.projector_shadow = false;
  internal::NoiseInputs in;
  in.K = &K;
  in.min_depth = 0.3;
  in.max_depth = 100.0;
  DepthImage noisy = depth;
  internal::ApplyDepthNoise(model, in, 42, noisy);
  EXPECT_TRUE(std::isnan(noisy.at(5, 5)));

  int facing = 0, facing_valid = 0;
  double sum2 = 0;
  int steep = 0, steep_valid = 0, mild = 0, mild_valid = 0, mid = 0, mid_valid = 0;
  for (int v = 1; v < 199; ++v) {
    if (v >= 98 && v <= 101) continue;
    for (int u = 1; u < 199; ++u) {
      if (!std::isfinite(depth.at(u, v)) || !std::isfinite(depth.at(u - 1, v))) continue;
      const bool valid = std::isfinite(noisy.at(u, v));
      if (v < 100) {
        ++facing;
        if (valid) {
          ++facing_valid;
          sum2 += std::pow(noisy.at(u, v) - 1.0, 2);
        }
        continue;
      }
      const double angle_deg = (t - std::atan((u - K.cx) / K.fx)) * 180.0 / M_PI;
      if (angle_deg > 85.5) {
        ++steep;
        steep_valid += valid;
      } else if (angle_deg < 71.5) {
        ++mild;
        mild_valid += valid;
      } else if (angle_deg > 77.5 && angle_deg < 79.5) {
        ++mid;
        mid_valid += valid;
      }
    }
  }
  ASSERT_GT(steep, 100);
  ASSERT_GT(mild, 100);
  ASSERT_GT(mid, 100);
  EXPECT_EQ(steep_valid, 0);
  EXPECT_GT(mild_valid, 0.99 * mild);
  EXPECT_GT(mid_valid, 0.3 * mid);
  EXPECT_LT(mid_valid, 0.7 * mid);
  EXPECT_GT(facing_valid, 0.99 * facing);
  EXPECT_LT(facing_valid, facing);  // random dropout
  const double sigma = std::sqrt(sum2 / facing_valid);
  EXPECT_NEAR(sigma, model.axial_sigma_base + model.axial_sigma_quadratic, 0.00004);
  // Reproducible with the seed, different with another.
  DepthImage again = depth, other = depth;
  internal::ApplyDepthNoise(model, in, 42, again);
  internal::ApplyDepthNoise(model, in, 43, other);
  EXPECT_TRUE(SameBytes(noisy, again));
  EXPECT_FALSE(SameBytes(noisy, other));
}

// The noise's own draws are libstdc++'s uniform and normal distributions bit
// for bit (frames rendered before and after it are the same bytes), in the
// mixes the noise makes: uniforms between normals, a normal's saved second
// value read after uniforms.
TEST(DepthNoise, DrawsAreTheStandardDistributionsBitForBit) {
  for (uint64_t seed : {1ull, 42ull, 0x9E3779B97F4A7C15ull}) {
    internal::NoiseDraws draws(seed);
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> U(0.0, 1.0);
    std::normal_distribution<double> N(0.0, 1.0);
    for (int i = 0; i < 200000; ++i) {
      const double a = i % 3 == 0 ? draws.Normal() : draws.Uniform();
      const double b = i % 3 == 0 ? N(rng) : U(rng);
      ASSERT_EQ(std::memcmp(&a, &b, sizeof a), 0) << "seed " << seed << ", draw " << i << ": " << a << " vs " << b;
    }
  }
}


// ---- Variety (docs/synthetic.md, "Variety") -----------------------------

TEST(SyntheticVariety, DrawsAreDeterministicPerSeedAndWithinTheirRanges) {
  const VarietySpec spec;
  int styles[3] = {0, 0, 0};
  for (uint64_t seed = 1; seed <= 200; ++seed) {
    const SceneVariety a = DrawSceneVariety(spec, seed), b = DrawSceneVariety(spec, seed);
    EXPECT_EQ(a.Describe(), b.Describe());
    EXPECT_NE(a.Describe(), DrawSceneVariety(spec, seed + 1).Describe());
    EXPECT_GE(a.tilt_deg, 0.0);
    EXPECT_LE(a.tilt_deg, spec.max_tilt_deg);
    EXPECT_LE(std::abs(a.roll_deg), spec.max_roll_deg);
    EXPECT_GE(a.resolution_scale, spec.resolution_scale[0]);
    EXPECT_LE(a.resolution_scale, spec.resolution_scale[1]);
    EXPECT_GE(a.axial_noise_scale, spec.axial_noise_scale[0]);
    EXPECT_LE(a.axial_noise_scale, spec.axial_noise_scale[1]);
    EXPECT_LE(a.mixed_pixels, spec.mixed_pixels[1]);
    EXPECT_LE(a.speckle, spec.speckle[1]);
    EXPECT_LE(std::abs(a.principal_dx), spec.principal_offset);
    ++styles[static_cast<int>(a.drop_style)];
  }
  EXPECT_EQ(styles[static_cast<int>(DropStyle::kDefault)], 0);
  EXPECT_GT(styles[static_cast<int>(DropStyle::kSettled)], 60);
  EXPECT_GT(styles[static_cast<int>(DropStyle::kJumbled)], 60);
}

Cell VarietyCell(int num_parts, uint64_t seed, bool noise) {
  Cell cell = TestCell(num_parts, seed, noise);
  cell.source.variety = VarietySpec{};
  return cell;
}

TEST(SyntheticSource, VarietyScenesAreDeterministicPerSeed) {
  auto a = MakeSource(VarietyCell(8, 3, true));
  auto b = MakeSource(VarietyCell(8, 3, true));
  auto c = MakeSource(VarietyCell(8, 4, true));
  ASSERT_TRUE(a && b && c);
  const Frame fa = CaptureOk(*a), fb = CaptureOk(*b), fc = CaptureOk(*c);
  EXPECT_TRUE(SameBytes(fa.depth, fb.depth));
  EXPECT_TRUE(SameBytes(fa.truth->labels, fb.truth->labels));
  EXPECT_TRUE(fa.X_BC.isApprox(fb.X_BC, 0.0));
  EXPECT_EQ(fa.intrinsics.width, fb.intrinsics.width);
  EXPECT_EQ(fa.intrinsics.fx, fb.intrinsics.fx);
  EXPECT_EQ(fa.source, fb.source);
  ASSERT_EQ(fa.truth->parts.size(), fb.truth->parts.size());
  for (size_t i = 0; i < fa.truth->parts.size(); ++i) {
    EXPECT_TRUE(fa.truth->parts[i].X_BO.isApprox(fb.truth->parts[i].X_BO, 0.0));
  }
  EXPECT_FALSE(fa.X_BC.isApprox(fc.X_BC, 1e-6));
  EXPECT_NE(fa.intrinsics.fx, fc.intrinsics.fx);
  EXPECT_NE(fa.source.find("variety: tilt"), std::string::npos) << fa.source;
  // Without variety the same seed renders the nominal camera.
  auto plain = MakeSource(TestCell(8, 3, true));
  ASSERT_TRUE(plain);
  EXPECT_TRUE(CaptureOk(*plain).X_BC.isApprox(TestCell(8, 3, true).camera.X_BC, 0.0));
}

// The tilted, rolled camera still sees the whole bin, and the frame's X_BC
// and intrinsics are the ones it was rendered with: noiseless depth lies on
// the labelled parts' true surfaces.
TEST(SyntheticSource, AVariedCameraKeepsTheBinInViewAndTheTruthConsistent) {
  for (uint64_t seed : {2u, 7u, 11u}) {
    auto source = MakeSource(VarietyCell(8, seed, false));
    ASSERT_TRUE(source);
    const Frame f = CaptureOk(*source);
    ASSERT_TRUE(f.truth.has_value());
    const SceneVariety& v = *source->variety();
    const Pose nominal = TestCell(8, seed, false).camera.X_BC;
    const double tilt = std::acos(std::clamp(nominal.linear().col(2).dot(f.X_BC.linear().col(2)), -1.0, 1.0));
    EXPECT_NEAR(tilt * 180 / M_PI, v.tilt_deg, 1e-6) << v.Describe();
    EXPECT_EQ(f.intrinsics.width, source->camera().configs[0].intrinsics.width);
    EXPECT_EQ(f.intrinsics.width, static_cast<int>(std::lround(320 * v.resolution_scale)));
    // The inner box's corners project into the image.
    const Pose X_CB = f.X_BC.inverse();
    const Cell cell = TestCell(8, seed, false);
    for (double sx : {-0.5, 0.5}) {
      for (double sy : {-0.5, 0.5}) {
        for (double z : {0.0, cell.bin.inner_size.z()}) {
          const Vec3 p = X_CB * (cell.bin.X_BW * Vec3(sx * cell.bin.inner_size.x(), sy * cell.bin.inner_size.y(), z));
          const double u = f.intrinsics.fx * p.x() / p.z() + f.intrinsics.cx;
          const double w = f.intrinsics.fy * p.y() / p.z() + f.intrinsics.cy;
          EXPECT_GT(u, 0.0);
          EXPECT_LT(u, f.intrinsics.width - 1.0);
          EXPECT_GT(w, 0.0);
          EXPECT_LT(w, f.intrinsics.height - 1.0);
        }
      }
    }
    const auto errors = SurfaceErrors(*source, f, [](double) { return 1.0; });
    ASSERT_GT(errors.size(), 500u);
    EXPECT_LT(*std::max_element(errors.begin(), errors.end()), 0.0005) << v.Describe();
  }
}

// Mixed pixels take depths between the two sides of a depth edge; speckle
// moves a fraction of the pixels by many sigma; both off leaves neither.
TEST(DepthNoise, MixedPixelsFillDepthEdgesAndSpeckleMovesAFraction) {
  Intrinsics K;
  K.width = K.height = 200;
  K.fx = K.fy = 300;
  K.cx = K.cy = 99.5;
  DepthImage depth(200, 200);
  for (int v = 0; v < 200; ++v) {
    for (int u = 0; u < 200; ++u) depth.at(u, v) = u < 100 ? 0.9f : 1.0f;  // a 10 cm step at column 100
  }
  internal::NoiseInputs in;
  in.K = &K;
  in.min_depth = 0.3;
  in.max_depth = 10.0;
  NoiseModel model;
  model.projector_shadow = false;
  model.random_dropout = 0.0;
  const auto between = [](const DepthImage& d) {
    int n = 0;
    for (int v = 0; v < 200; ++v) {
      for (int u = 0; u < 200; ++u) n += d.at(u, v) > 0.91f && d.at(u, v) < 0.99f ? 1 : 0;
    }
    return n;
  };
  DepthImage plain = depth;
  internal::ApplyDepthNoise(model, in, 42, plain);
  EXPECT_EQ(between(plain), 0);
  model.mixed_pixels = 1.0;
  DepthImage mixed = depth;
  internal::ApplyDepthNoise(model, in, 42, mixed);
  // Columns 99 and 100 (400 edge pixels) take a depth between the sides.
  EXPECT_GT(between(mixed), 250);  // 80% of them expected: 0.91-0.99 of the 0.9-1.0 step
  EXPECT_LE(between(mixed), 400);
  model.mixed_pixels = 0.0;
  model.speckle = 0.05;
  model.speckle_sigma = 0.01;
  DepthImage speckled = depth;
  internal::ApplyDepthNoise(model, in, 42, speckled);
  int far = 0;
  for (int v = 0; v < 200; ++v) {
    for (int u = 0; u < 200; ++u) far += std::abs(speckled.at(u, v) - depth.at(u, v)) > 0.003f ? 1 : 0;
  }
  // 5% speckled, of which |N(0, 10 mm)| > 3 mm for 76%: about 1530 of 40000.
  EXPECT_GT(far, 1200);
  EXPECT_LT(far, 1900);
}

}  // namespace
}  // namespace bp
