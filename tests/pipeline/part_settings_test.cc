// The settings that scale with the part and the camera
// (pipeline/internal/part_settings.h): the formulas' bounds, the mesh unit
// check's messages, and the shipped cell keeping the option defaults.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "core/cell.h"
#include "pipeline/internal/class_model.h"
#include "pipeline/internal/part_settings.h"
#include "pipeline/perception.h"
#include "pipeline/pose_estimator.h"

namespace bp {
namespace {

using internal::CameraFigures;
using internal::ClassFigures;
using internal::PartGeometry;

PartGeometry Geometry(double diameter) {
  PartGeometry g;
  g.diameter = diameter;
  return g;
}

// The reference camera: the defaults' noise and view spacing.
constexpr CameraFigures kReferenceCamera{0.0004, 0.0013};

TEST(PartSettings, TheShippedCellKeepsTheOptionDefaults) {
  const Cell cell = LoadDefaultCell().value();
  const PerceptionOptions defaults;
  const CameraFigures camera = internal::CameraFiguresOf(cell, defaults);
  std::vector<ClassFigures> classes;
  const PoseEstimatorOptions reference;
  for (const PartSpec& part : cell.parts) {
    auto model = internal::BuildClassModel(part, camera);
    ASSERT_TRUE(model.ok()) << model.status().ToString();
    const PoseEstimatorOptions& o = (*model)->estimator_options();
    SCOPED_TRACE(part.name);
    EXPECT_EQ(o.ppf_relative_sampling, reference.ppf_relative_sampling);
    EXPECT_EQ(o.icp_model_spacing, reference.icp_model_spacing);
    EXPECT_EQ(o.verify_model_spacing, reference.verify_model_spacing);
    EXPECT_EQ(o.support_distance, reference.support_distance);
    EXPECT_EQ(o.free_space_distance, reference.free_space_distance);
    EXPECT_EQ(o.icp_final_distance, reference.icp_final_distance);
    EXPECT_EQ(o.min_score, reference.min_score);
    EXPECT_EQ((*model)->inside_depth(), 0.001f);
    classes.push_back({(*model)->diameter(), (*model)->lowest_upward_face(), 0});
  }
  PerceptionOptions scaled = defaults;
  EXPECT_EQ(internal::ScaleToClasses(classes, camera, &scaled), "");
  EXPECT_EQ(scaled.min_segment_points, defaults.min_segment_points);
  EXPECT_EQ(scaled.floor_band, defaults.floor_band);
  EXPECT_EQ(scaled.view_waves, defaults.view_waves);
  EXPECT_EQ(scaled.second_look_min_points, defaults.second_look_min_points);
  // The count is at the camera's view spacing (the coarser config's).
  EXPECT_EQ(scaled.min_segment_spacing, camera.view_spacing);
}

// A frame's segment minimum covers the same surface area as
// min_segment_points at min_segment_spacing: fewer grid points on a coarser
// grid, never more on a finer one, at least 30 (or the options' own count).
TEST(PartSettings, AFrameSegmentMinimumKeepsTheSurfaceArea) {
  EXPECT_EQ(internal::FrameMinSegmentPoints(150, 0.002, 0.002), 150);
  EXPECT_EQ(internal::FrameMinSegmentPoints(150, 0.002, 0.0012), 150);
  EXPECT_EQ(internal::FrameMinSegmentPoints(150, 0.002, 0.0025), 96);  // 150 x 0.64
  EXPECT_EQ(internal::FrameMinSegmentPoints(150, 0.002, 0.004), 38);   // 37.5, rounded
  EXPECT_EQ(internal::FrameMinSegmentPoints(150, 0.002, 0.008), 30);
  EXPECT_EQ(internal::FrameMinSegmentPoints(20, 0.002, 0.008), 20);
  EXPECT_EQ(internal::FrameMinSegmentPoints(150, 0.0, 0.004), 150);  // off
  PerceptionOptions given;
  given.min_segment_spacing = 0.0;
  internal::ScaleToClasses({{0.06, 0.005, 0}}, kReferenceCamera, &given);
  EXPECT_EQ(given.min_segment_spacing, 0.0);
}

TEST(PartSettings, EstimatorSpacingsFollowThePartsDiameter) {
  const PoseEstimatorOptions reference;
  for (const double d : {0.004, 0.012, 0.05, 0.25, 1.5}) {
    SCOPED_TRACE(d);
    const PoseEstimatorOptions o = internal::ScaledEstimatorOptions(Geometry(d), kReferenceCamera, {});
    // The PPF step never goes below the views' sample spacing (nor above a
    // fifth of the part).
    EXPECT_GE(o.ppf_relative_sampling * d, std::min(kReferenceCamera.view_spacing, 0.2 * d) * (1 - 1e-9));
    EXPECT_LE(o.ppf_relative_sampling, 0.2);
    EXPECT_GE(o.icp_model_spacing, d / 300 * (1 - 1e-9));
    EXPECT_GE(o.icp_model_spacing, reference.icp_model_spacing);
    // Verification samples: at most D / 15 and the reference apart, never
    // finer than the dense samples they are drawn from.
    EXPECT_LE(o.verify_model_spacing, std::max(o.icp_model_spacing, std::min(reference.verify_model_spacing, d / 15)));
    EXPECT_GE(o.verify_model_spacing, o.icp_model_spacing);
  }
}

TEST(PartSettings, ANoisyCameraWidensTheDistancesAndTheOverridesWin) {
  const PoseEstimatorOptions reference;
  const CameraFigures noisy{0.002, 0.0013};
  const PoseEstimatorOptions o = internal::ScaledEstimatorOptions(Geometry(0.08), noisy, {});
  EXPECT_NEAR(o.support_distance, 3.4 * noisy.sigma_floor, 1e-12);
  EXPECT_NEAR(o.free_space_distance, 6.8 * noisy.sigma_floor, 1e-12);
  EXPECT_NEAR(o.icp_final_distance, 4.5 * noisy.sigma_floor, 1e-12);
  // A quiet camera keeps the reference values.
  const PoseEstimatorOptions quiet = internal::ScaledEstimatorOptions(Geometry(0.08), kReferenceCamera, {});
  EXPECT_EQ(quiet.support_distance, reference.support_distance);
  EXPECT_EQ(quiet.free_space_distance, reference.free_space_distance);
  EXPECT_EQ(quiet.icp_final_distance, reference.icp_final_distance);
  PartPerception overrides;
  overrides.support_distance = 0.001;
  overrides.ppf_step = 0.004;
  overrides.min_score = 0.5;
  const PoseEstimatorOptions over = internal::ScaledEstimatorOptions(Geometry(0.08), noisy, overrides);
  EXPECT_EQ(over.support_distance, 0.001);
  EXPECT_NEAR(over.ppf_relative_sampling * 0.08, 0.004, 1e-12);
  EXPECT_EQ(over.min_score, 0.5);
}

TEST(PartSettings, SmallAndFlatPartsShrinkTheSegmentsAndTheFloorBand) {
  const PerceptionOptions defaults;
  PerceptionOptions o = defaults;
  // A 12 mm part whose lowest upward face lying flat is 3 mm high.
  const std::string changed = internal::ScaleToClasses({{0.08, 0.01, 0}, {0.012, 0.003, 0}}, kReferenceCamera, &o);
  EXPECT_FALSE(changed.empty());
  EXPECT_GE(o.min_segment_points, 30);
  EXPECT_LT(o.min_segment_points, defaults.min_segment_points);
  EXPECT_LT(o.floor_band, 0.003);
  EXPECT_GE(o.floor_band, 3 * kReferenceCamera.sigma_floor);
  ASSERT_FALSE(o.view_waves.empty());
  for (size_t i = 0; i < o.view_waves.size(); ++i) {
    EXPECT_GE(o.view_waves[i], o.min_segment_points);
    if (i > 0) {
      EXPECT_LT(o.view_waves[i], o.view_waves[i - 1]);
    }
  }
  EXPECT_GE(o.second_look_min_points, o.min_segment_points);
  // A part's min_view_points override sets the segment size.
  PerceptionOptions p = defaults;
  internal::ScaleToClasses({{0.012, 0.003, 200}}, kReferenceCamera, &p);
  EXPECT_EQ(p.min_segment_points, 200);
  // Large parts never grow the segments or the band past the defaults.
  PerceptionOptions q = defaults;
  EXPECT_EQ(internal::ScaleToClasses({{0.5, 0.05, 0}}, kReferenceCamera, &q), "");
  EXPECT_EQ(q.min_segment_points, defaults.min_segment_points);
  EXPECT_EQ(q.floor_band, defaults.floor_band);
}

TEST(PartSettings, AMeshOutsideThePlausibleSizesIsRefusedNamingTheLikelyUnit) {
  EXPECT_TRUE(internal::CheckMeshScale(Geometry(0.07), "", "part.ply").ok());
  EXPECT_TRUE(internal::CheckMeshScale(Geometry(0.07), "metres", "part.ply").ok());
  const Status mm = internal::CheckMeshScale(Geometry(70.0), "", "part.ply");
  ASSERT_FALSE(mm.ok());
  EXPECT_NE(mm.message().find("millimetres"), std::string::npos) << mm.message();
  EXPECT_NE(mm.message().find("0.001"), std::string::npos) << mm.message();
  EXPECT_NE(mm.message().find("part.ply"), std::string::npos) << mm.message();
  const Status inches = internal::CheckMeshScale(Geometry(0.07), "inches", "part.stl");
  ASSERT_FALSE(inches.ok());
  EXPECT_NE(inches.message().find("inches"), std::string::npos) << inches.message();
  const Status tiny = internal::CheckMeshScale(Geometry(0.00007), "", "part.ply");
  ASSERT_FALSE(tiny.ok());
  EXPECT_NE(tiny.message().find("twice"), std::string::npos) << tiny.message();
}

}  // namespace
}  // namespace bp
