// RefinePointToPlane on the shipped L-bracket's dense samples: it converges
// to the true pose from a small offset, and the gate schedule
// (IcpOptions::shrink_iterations) decides the first iteration that may stop.
#include "pipeline/internal/point_to_plane_icp.h"

#include <gtest/gtest.h>

#include <vector>

#include <Eigen/Geometry>

#include "core/mesh_gen.h"
#include "pipeline/internal/closest_point_field.h"
#include "pipeline/internal/model_sampling.h"

namespace bp::internal {
namespace {

struct IcpScene {
  OrientedPoints dense;
  ClosestPointField field;
  Pose X_BO = Pose::Identity();
  Vec3 camera_B = Vec3::Zero();
  std::vector<Eigen::Vector3f> scene_B;  // every 3rd sample facing the camera, at X_BO
  IcpModel model() const { return IcpModel{dense.points, dense.normals, &field, {}}; }
};

IcpScene MakeScene() {
  IcpScene s;
  s.dense = SampleSurface(MakeLBracket(), 0.0008, 1);
  s.field.Build(s.dense.points, 0.001f, 0.006f);
  s.X_BO.linear() = (Eigen::AngleAxisd(0.4, Vec3::UnitZ()) * Eigen::AngleAxisd(0.3, Vec3(1, 1, 0).normalized()))
                        .toRotationMatrix();
  s.X_BO.translation() = Vec3(0.6, -0.05, 0.04);
  s.camera_B = Vec3(0.65, 0.0, 1.0);
  for (size_t i = 0; i < s.dense.size(); i += 3) {
    const Vec3 p = s.X_BO * s.dense.points[i].cast<double>();
    const Vec3 n = s.X_BO.linear() * s.dense.normals[i].cast<double>();
    if (n.dot(s.camera_B - p) > 0) s.scene_B.push_back(p.cast<float>());
  }
  return s;
}

double AngleDeg(const Pose& a, const Pose& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle() * 180.0 / M_PI;
}

TEST(PointToPlaneIcp, ConvergesToTheTruePoseFromASmallOffset) {
  const IcpScene s = MakeScene();
  ASSERT_GT(s.scene_B.size(), 500u);
  Pose start = s.X_BO;
  start.linear() = Eigen::AngleAxisd(2.0 * M_PI / 180.0, Vec3(0.3, -0.5, 0.8).normalized()) * start.linear();
  start.translation() += Vec3(0.0012, -0.0008, 0.0005);
  for (const int shrink : {0, 1, 3}) {
    IcpOptions o;
    o.iterations = 30;
    o.shrink_iterations = shrink;
    o.convergence = 5e-5f;
    const IcpResult r = RefinePointToPlane(s.model(), s.scene_B, start, s.camera_B, o);
    ASSERT_TRUE(r.ok) << "shrink " << shrink;
    EXPECT_LT((r.X_BO.translation() - s.X_BO.translation()).norm(), 1e-4) << "shrink " << shrink;
    EXPECT_LT(AngleDeg(r.X_BO, s.X_BO), 0.1) << "shrink " << shrink;
    EXPECT_LT(r.rms, 1e-4) << "shrink " << shrink;
  }
}

TEST(PointToPlaneIcp, TheGateScheduleSetsTheFirstIterationThatMayStop) {
  // At the true pose every update is (nearly) zero, so the loop stops at the
  // first iteration at the final gate: iteration shrink_iterations + 1, with
  // min(iterations / 3, 6) for 0 and at most `iterations`.
  const IcpScene s = MakeScene();
  const auto iterations = [&](int iters, int shrink) {
    IcpOptions o;
    o.iterations = iters;
    o.shrink_iterations = shrink;
    const IcpResult r = RefinePointToPlane(s.model(), s.scene_B, s.X_BO, s.camera_B, o);
    EXPECT_TRUE(r.ok);
    return r.iterations;
  };
  EXPECT_EQ(iterations(30, 0), 7);
  EXPECT_EQ(iterations(7, 0), 3);
  EXPECT_EQ(iterations(30, 3), 4);
  EXPECT_EQ(iterations(30, 1), 2);
  EXPECT_EQ(iterations(10, 40), 10);
}

}  // namespace
}  // namespace bp::internal
