// Private to bp_grasp: the part surface a grasp touches (its contact region)
// and whether a frame's depth shows it (SeenContactRule, core/cell.h; issue
// 37 item 2).
//
// A contact region is sampled once per cell grasp by casting rays from the
// gripper's contacts onto the part mesh: the suction cup's footprint disk
// straight along the approach (tool +z), each parallel-jaw finger pad along
// its closing direction. The samples are kept in the grasp's tool frame G, so
// the symmetric copies of a grasp share them (the part looks the same from
// every copy). At plan time a sample X_BG * p_G is "seen" when the frame
// measured a point within max_distance of it.
//
// Frames (STYLE.md): B base, C camera, O part, G the grasp's tool frame
// (tool centre point, +z into the part). Metres.
#pragma once

#include <memory>
#include <optional>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/image.h"
#include "core/mesh.h"
#include "core/pose.h"
#include "core/status.h"
#include "pipeline/internal/point_hash.h"

namespace bp::internal {

// Where a gripper touches a part, in its tool frame T (= G at a grasp).
struct ContactShape {
  GripperSpec::Kind kind = GripperSpec::Kind::kSuction;
  double radius = 0.0;        // suction: footprint disk radius at z = 0
  double half_opening = 0.0;  // parallel jaw: the finger pads' inner faces at x = +-half_opening
  double pad_width = 0.0;     // parallel jaw: pad extent along y, centred
  double pad_z_min = 0.0;     // parallel jaw: pad extent along z
  double pad_z_max = 0.0;
};

// The gripper's contact shape from its spec and mesh (in T): the suction
// footprint radius is seen_contact.radius, or (0) the largest distance from
// the z axis of the mesh's vertices within 1 mm of z = 0; a jaw's pads reach
// pad_depth up from the mesh's largest z (the finger tips). @returns
// InvalidArgument naming the gripper when a suction mesh has no vertex at
// its contact plane.
Result<ContactShape> MakeContactShape(const GripperSpec& gripper, const TriangleMesh& gripper_T);

// Samples of the part surface under each contact of a grasp, in G (m): one
// contact for suction, two for a jaw (+x finger, then -x finger). A sample
// is the first front-facing part surface a contact ray meets within reach
// (suction: from radius or 5 mm above the tool plane to as far below it;
// jaw: from the pad to the tool's z axis); rays that meet none leave no
// sample (a footprint overhanging the part's edge or a hole).
struct ContactRegion {
  std::vector<std::vector<Eigen::Vector3f>> contacts;
};

// Ray casts for the grasp X_OG on `part_O` (every triangle; Build time and
// taught grasps only).
ContactRegion SampleContactRegion(const ContactShape& shape, const TriangleMesh& part_O, const Pose& X_OG);

// What this frame measured, for the seen test. Organized frames are tested
// on the depth image (a sample is projected into it; the measured points of
// the 3x3 pixels around it are compared): no per-frame build, and a surface
// hidden behind another part or facing away shows a measured point that is
// not the sample's. Unorganized frames are tested on the ROI points through a
// hash grid (built on construction).
class SeenSurface {
 public:
  // `depth` (metres along the camera's z, NaN = none) with its intrinsics,
  // camera X_BC. The image must outlive this object.
  SeenSurface(const DepthImage& depth, const Intrinsics& K, const Pose& X_BC, double max_distance);
  // Points in B (the frame's ROI points), copied into a hash grid.
  SeenSurface(std::span<const Eigen::Vector3f> points_B, double max_distance);

  // True when the frame measured a point within max_distance of p_B.
  bool Seen(const Eigen::Vector3f& p_B) const;
  double max_distance() const { return max_distance_; }

 private:
  double max_distance_ = 0.0;
  // Organized.
  const DepthImage* depth_ = nullptr;
  Intrinsics K_;
  Eigen::Matrix3f R_CB_ = Eigen::Matrix3f::Identity();
  Eigen::Vector3f t_CB_ = Eigen::Vector3f::Zero();
  // Unorganized.
  PointHash points_;
};

// Share of `samples_G` (a contact's samples) that `seen` shows at the grasp
// X_BG; 0 for no samples.
double SeenFraction(std::span<const Eigen::Vector3f> samples_G, const Pose& X_BG, const SeenSurface& seen);

}  // namespace bp::internal
