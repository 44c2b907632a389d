// PpfModel on the shipped L-bracket: Match finds the part's pose; the peaks
// one Match records (PpfMatchOptions::record) give a later, wider Match of the
// same points the poses it would have found voting again, and are read only
// when they were recorded for the same points and reference selection; Build
// refuses more points than its 16-bit entries index.
#include "pipeline/internal/ppf_matcher.h"

#include <future>

#include <gtest/gtest.h>

#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/mesh_gen.h"
#include "pipeline/internal/model_sampling.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {
namespace {

struct PpfScene {
  PpfModel model;
  float diameter = 0;
  Pose X_BO = Pose::Identity();
  std::vector<Eigen::Vector3f> points, normals;  // the part at X_BO, facing the camera
};

PpfScene MakeScene() {
  PpfScene s;
  const OrientedPoints m = SampleSurface(MakeLBracket(), 0.004, 1);
  const float diameter = static_cast<float>(PointSetDiameter(m.points));
  s.diameter = diameter;
  PpfParams params;
  params.distance_step = 0.05f * diameter;
  params.max_bucket_entries = 50;
  EXPECT_TRUE(s.model.Build(m.points, m.normals, params, diameter).ok());
  Pose& X_BO = s.X_BO;
  X_BO.linear() = (Eigen::AngleAxisd(0.7, Vec3::UnitZ()) * Eigen::AngleAxisd(0.5, Vec3(1, 0, 1).normalized()))
                      .toRotationMatrix();
  X_BO.translation() = Vec3(0.6, -0.05, 0.04);
  const Vec3 camera(0.65, 0.0, 1.0);
  for (size_t i = 0; i < m.size(); ++i) {
    const Vec3 p = X_BO * m.points[i].cast<double>();
    const Vec3 n = X_BO.linear() * m.normals[i].cast<double>();
    if (n.dot(camera - p) <= 0) continue;
    s.points.push_back(p.cast<float>());
    s.normals.push_back(n.cast<float>());
  }
  return s;
}

PpfMatchOptions Options(int peaks_per_reference, int peaks_examined, int max_poses) {
  PpfMatchOptions o;
  o.reference_stride = 3;
  o.max_reference_points = 20;
  o.max_partners = 100;
  o.cluster_translation = 0.01;
  o.cluster_rotation = 0.4;
  o.max_poses = max_poses;
  o.peaks_per_reference = peaks_per_reference;
  o.peaks_examined = peaks_examined;
  o.accept = [](const Pose&) { return true; };
  return o;
}

void ExpectSamePoses(const std::vector<CoarsePose>& a, const std::vector<CoarsePose>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].votes, b[i].votes) << i;
    EXPECT_TRUE(a[i].X_BO.isApprox(b[i].X_BO, 1e-12)) << i;
  }
}

// The table's alpha_m is fixed point (16 bits) and both angles are taken
// into [0, 2 pi) before their difference: the part's own pose wins the vote.
TEST(PpfMatcher, TheMostVotedPoseIsThePartsPose) {
  const PpfScene s = MakeScene();
  ASSERT_GT(s.points.size(), 100u);
  const Symmetry none;
  const std::vector<CoarsePose> poses = s.model.Match(s.points, s.normals, {}, Options(1, 1, 4), none);
  ASSERT_FALSE(poses.empty());
  // Within a distance step and an alpha bin (12 deg) of the truth.
  EXPECT_LT((poses.front().X_BO.translation() - s.X_BO.translation()).norm(), 0.05 * s.diameter);
  EXPECT_LT(SymmetricRotationError(poses.front().X_BO, s.X_BO, none), 12.0 * M_PI / 180.0);
  // Noiseless samples of the model itself: nearly every pair votes for it
  // (798 votes against 28 for the next pose; 520 against 78 when the
  // table's negative angles were not taken into [0, 2 pi)).
  ASSERT_GE(poses.size(), 2u);
  EXPECT_GT(poses[0].votes, 10 * poses[1].votes);
}

// One pass over a reference point's touched cells resets them, collects the
// peaks and, without peaks wanted (one peak, no accept, no record), finds
// the lowest cell with the most votes among those the floor lets through:
// both paths give the same poses, and every recorded reference's best cell
// is its first peak.
TEST(PpfMatcher, TheOnePeakPathAndThePeakListAgree) {
  const PpfScene s = MakeScene();
  const Symmetry none;
  PpfMatchOptions fast = Options(1, 1, 12);
  fast.accept = nullptr;
  PpfVotes votes;
  PpfMatchOptions listed = Options(1, 1, 12);
  listed.record = &votes;
  const std::vector<CoarsePose> a = s.model.Match(s.points, s.normals, {}, fast, none);
  ASSERT_GE(a.size(), 2u);
  ExpectSamePoses(s.model.Match(s.points, s.normals, {}, listed, none), a);
  ASSERT_GT(votes.references.size(), 10u);
  for (const PpfVotes::Reference& r : votes.references) {
    ASSERT_FALSE(r.peaks.empty());
    EXPECT_EQ(r.peaks.front().first, r.best);
    EXPECT_EQ(r.peaks.front().second, r.best_bin);
    for (size_t i = 1; i < r.peaks.size(); ++i) {
      EXPECT_TRUE(r.peaks[i - 1].first > r.peaks[i].first ||
                  (r.peaks[i - 1].first == r.peaks[i].first && r.peaks[i - 1].second < r.peaks[i].second));
    }
  }
  // The accumulator is back to zero after each reference point: one
  // reference point's best cell holds about one vote per partner (at most
  // 100 partners; without the reset, the votes of all earlier reference
  // points too).
  for (const PpfVotes::Reference& r : votes.references) EXPECT_LE(r.best, 2 * listed.max_partners);
}

// Each thread keeps its vote accumulator from call to call, all zero in
// between: a call after calls on a larger model (which grew it), after a
// call that recorded peaks and after one that an exception from `accept`
// ended, finds exactly the poses the first call found.
TEST(PpfMatcher, NoVotesCarryOverFromOneCallToTheNext) {
  const PpfScene s = MakeScene();
  const Symmetry none;
  const PpfMatchOptions options = Options(2, 4, 12);
  const std::vector<CoarsePose> first = s.model.Match(s.points, s.normals, {}, options, none);
  ASSERT_GE(first.size(), 2u);

  const OrientedPoints dense = SampleSurface(MakeLBracket(), 0.0025, 2);
  PpfModel larger;
  PpfParams params;
  params.distance_step = 0.05f * s.diameter;
  params.max_bucket_entries = 50;
  ASSERT_TRUE(larger.Build(dense.points, dense.normals, params, s.diameter).ok());
  PpfVotes votes;
  PpfMatchOptions recorded = options;
  recorded.record = &votes;
  EXPECT_FALSE(larger.Match(s.points, s.normals, {}, recorded, none).empty());
  ExpectSamePoses(s.model.Match(s.points, s.normals, {}, options, none), first);

  PpfMatchOptions throwing = options;
  throwing.accept = [](const Pose&) -> bool { throw std::runtime_error("accept failed"); };
  EXPECT_THROW(s.model.Match(s.points, s.normals, {}, throwing, none), std::runtime_error);
  ExpectSamePoses(s.model.Match(s.points, s.normals, {}, options, none), first);
}

// A Match called from another's `accept` on the same thread (the vote
// accumulator is per thread) gets an accumulator of its own: the inner and
// the outer Match each find what they find alone, and so does the next one.
TEST(PpfMatcher, AMatchCalledFromAcceptFindsWhatItFindsAlone) {
  const PpfScene s = MakeScene();
  const Symmetry none;
  const PpfMatchOptions options = Options(2, 4, 12);
  const std::vector<CoarsePose> alone = s.model.Match(s.points, s.normals, {}, options, none);
  ASSERT_GE(alone.size(), 2u);
  std::vector<std::vector<CoarsePose>> inner;
  PpfMatchOptions nesting = options;
  nesting.accept = [&](const Pose&) {
    if (inner.size() < 3) inner.push_back(s.model.Match(s.points, s.normals, {}, options, none));
    return true;
  };
  ExpectSamePoses(s.model.Match(s.points, s.normals, {}, nesting, none), alone);
  ASSERT_EQ(inner.size(), 3u);
  for (const std::vector<CoarsePose>& poses : inner) ExpectSamePoses(poses, alone);
  ExpectSamePoses(s.model.Match(s.points, s.normals, {}, options, none), alone);
}

// Matches on four threads at once, each with its own accumulator, find
// what one thread finds.
TEST(PpfMatcher, ConcurrentMatchesFindWhatOneThreadFinds) {
  const PpfScene s = MakeScene();
  const Symmetry none;
  const PpfMatchOptions options = Options(2, 4, 12);
  const std::vector<CoarsePose> serial = s.model.Match(s.points, s.normals, {}, options, none);
  std::vector<std::future<std::vector<std::vector<CoarsePose>>>> runs;
  for (int t = 0; t < 4; ++t) {
    runs.push_back(std::async(std::launch::async, [&] {
      std::vector<std::vector<CoarsePose>> out;
      for (int k = 0; k < 5; ++k) out.push_back(s.model.Match(s.points, s.normals, {}, options, none));
      return out;
    }));
  }
  for (auto& run : runs) {
    for (const std::vector<CoarsePose>& poses : run.get()) ExpectSamePoses(poses, serial);
  }
}

TEST(PpfMatcher, BuildRejectsMoreModelPointsThanTheTableCanIndex) {
  const std::vector<Eigen::Vector3f> points(PpfModel::kMaxModelPoints + 1, Eigen::Vector3f::Zero()),
      normals(points.size(), Eigen::Vector3f::UnitZ());
  PpfModel model;
  const Status s = model.Build(points, normals, PpfParams{}, 0.1f);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("at most 65536 points"), std::string::npos) << s.message();
  EXPECT_FALSE(model.Build(points, std::span<const Eigen::Vector3f>(normals).first(10), PpfParams{}, 0.1f).ok());
}

TEST(PpfMatcher, RecordedPeaksGiveAWiderSearchTheSamePoses) {
  const PpfScene s = MakeScene();
  ASSERT_GT(s.points.size(), 100u);
  const Symmetry none;
  // The first search (as a wave's): 1 peak of 8, recording 16.
  PpfVotes votes;
  PpfMatchOptions narrow = Options(1, 8, 12);
  const std::vector<CoarsePose> plain = s.model.Match(s.points, s.normals, {}, narrow, none);
  narrow.record = &votes;
  narrow.record_peaks = 16;
  ExpectSamePoses(s.model.Match(s.points, s.normals, {}, narrow, none), plain);
  ASSERT_FALSE(votes.references.empty());
  EXPECT_EQ(votes.points, s.points.size());
  for (const PpfVotes::Reference& r : votes.references) EXPECT_LE(r.peaks.size(), 16u);

  // The wider search (as the second look's): 2 peaks of 16.
  PpfMatchOptions wide = Options(2, 16, 36);
  const std::vector<CoarsePose> fresh = s.model.Match(s.points, s.normals, {}, wide, none);
  ASSERT_FALSE(fresh.empty());
  wide.replay = &votes;
  ExpectSamePoses(s.model.Match(s.points, s.normals, {}, wide, none), fresh);

  // The recorded peaks are read, not voted again: with none recorded, no pose.
  PpfVotes emptied = votes;
  emptied.references.clear();
  wide.replay = &emptied;
  EXPECT_TRUE(s.model.Match(s.points, s.normals, {}, wide, none).empty());

  // Recorded for other points, another reference selection or fewer peaks
  // than examined: ignored, the Match votes.
  PpfVotes other = emptied;
  other.points = s.points.size() - 1;
  wide.replay = &other;
  ExpectSamePoses(s.model.Match(s.points, s.normals, {}, wide, none), fresh);
  other = emptied;
  other.max_reference_points = 30;
  ExpectSamePoses(s.model.Match(s.points, s.normals, {}, wide, none), fresh);
  other = emptied;
  other.recorded_peaks = 8;
  ExpectSamePoses(s.model.Match(s.points, s.normals, {}, wide, none), fresh);
}

}  // namespace
}  // namespace bp::internal
