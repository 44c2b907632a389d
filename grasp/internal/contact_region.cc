#include "grasp/internal/contact_region.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "pipeline/frame.h"

namespace bp::internal {
namespace {

// Distance along the ray to the nearest triangle of `mesh` within (0, t_max],
// and whether that triangle faces the ray's origin; nullopt when none.
// Moller-Trumbore, double precision.
struct Hit {
  double t = 0.0;
  bool front = false;
};
std::optional<Hit> CastRay(const TriangleMesh& mesh, const Vec3& origin, const Vec3& dir, double t_max) {
  std::optional<Hit> best;
  for (const Eigen::Vector3i& tri : mesh.triangles) {
    const Vec3 a = mesh.vertices[tri[0]].cast<double>();
    const Vec3 e1 = mesh.vertices[tri[1]].cast<double>() - a;
    const Vec3 e2 = mesh.vertices[tri[2]].cast<double>() - a;
    const Vec3 p = dir.cross(e2);
    const double det = e1.dot(p);
    if (std::abs(det) < 1e-14) continue;  // parallel to the triangle
    const double inv = 1.0 / det;
    const Vec3 s = origin - a;
    const double u = s.dot(p) * inv;
    if (u < 0.0 || u > 1.0) continue;
    const Vec3 q = s.cross(e1);
    const double v = dir.dot(q) * inv;
    if (v < 0.0 || u + v > 1.0) continue;
    const double t = e2.dot(q) * inv;
    if (t <= 0.0 || t > t_max || (best && t >= best->t)) continue;
    // Counter-clockwise seen from outside: the normal e1 x e2 points out.
    best = Hit{t, e1.cross(e2).dot(dir) < 0.0};
  }
  return best;
}

// Samples of one contact: rays from origins_T along dir_T (tool frame),
// first front-facing part surface within reach, returned in G.
std::vector<Eigen::Vector3f> CastContact(const TriangleMesh& part_O, const Pose& X_OG,
                                         const std::vector<Vec3>& origins_G, const Vec3& dir_G, double reach) {
  std::vector<Eigen::Vector3f> samples;
  const Vec3 dir_O = X_OG.linear() * dir_G;
  const Pose X_GO = X_OG.inverse();
  for (const Vec3& o_G : origins_G) {
    const std::optional<Hit> hit = CastRay(part_O, X_OG * o_G, dir_O, reach);
    if (!hit || !hit->front) continue;
    samples.push_back((X_GO * (X_OG * o_G + hit->t * dir_O)).cast<float>());
  }
  return samples;
}

}  // namespace

Result<ContactShape> MakeContactShape(const GripperSpec& gripper, const TriangleMesh& gripper_T) {
  const SeenContactRule& rule = gripper.seen_contact;
  ContactShape shape;
  shape.kind = gripper.kind;
  if (gripper.kind == GripperSpec::Kind::kSuction) {
    shape.radius = rule.radius;
    if (shape.radius <= 0.0) {
      constexpr float kContactPlane = 0.001f;  // m: vertices this close to z = 0 form the cup's lip
      for (const Eigen::Vector3f& v : gripper_T.vertices) {
        if (std::abs(v.z()) <= kContactPlane) shape.radius = std::max(shape.radius, static_cast<double>(v.head<2>().norm()));
      }
      if (shape.radius <= 0.0) {
        return Status::InvalidArgument("gripper '" + gripper.name +
                                       "': no mesh vertex at the contact plane z = 0 to size the suction footprint; "
                                       "set grippers[].seen_contact.radius");
      }
    }
    return shape;
  }
  float z_tip = -std::numeric_limits<float>::infinity();
  for (const Eigen::Vector3f& v : gripper_T.vertices) z_tip = std::max(z_tip, v.z());
  shape.half_opening = gripper.opening / 2;
  shape.pad_width = rule.pad_width;
  shape.pad_z_max = z_tip;
  shape.pad_z_min = z_tip - rule.pad_depth;
  return shape;
}

ContactRegion SampleContactRegion(const ContactShape& shape, const TriangleMesh& part_O, const Pose& X_OG) {
  ContactRegion region;
  if (shape.kind == GripperSpec::Kind::kSuction) {
    // A square grid of pitch radius / 3 clipped to the disk (29 rays).
    const double r = shape.radius, pitch = r / 3, reach = std::max(r, 0.005);
    std::vector<Vec3> origins;
    for (int i = -3; i <= 3; ++i) {
      for (int j = -3; j <= 3; ++j) {
        if (i * i + j * j <= 9) origins.emplace_back(i * pitch, j * pitch, -reach);
      }
    }
    region.contacts.push_back(CastContact(part_O, X_OG, origins, Vec3::UnitZ(), 2 * reach));
    return region;
  }
  // Each pad: 5 rays across (y) by 6 along z, cast toward the tool's axis.
  constexpr int kAcross = 5, kAlong = 6;
  for (const double side : {1.0, -1.0}) {
    std::vector<Vec3> origins;
    for (int i = 0; i < kAcross; ++i) {
      const double y = shape.pad_width * (static_cast<double>(i) / (kAcross - 1) - 0.5);
      for (int k = 0; k < kAlong; ++k) {
        const double z = shape.pad_z_min + (shape.pad_z_max - shape.pad_z_min) * k / (kAlong - 1);
        origins.emplace_back(side * shape.half_opening, y, z);
      }
    }
    region.contacts.push_back(CastContact(part_O, X_OG, origins, Vec3(-side, 0, 0), shape.half_opening));
  }
  return region;
}

SeenSurface::SeenSurface(const DepthImage& depth, const Intrinsics& K, const Pose& X_BC, double max_distance)
    : max_distance_(max_distance), depth_(&depth), K_(K) {
  const Pose X_CB = X_BC.inverse();
  R_CB_ = X_CB.linear().cast<float>();
  t_CB_ = X_CB.translation().cast<float>();
}

SeenSurface::SeenSurface(std::span<const Eigen::Vector3f> points_B, double max_distance)
    : max_distance_(max_distance) {
  points_.Build(points_B, static_cast<float>(max_distance));
}

bool SeenSurface::Seen(const Eigen::Vector3f& p_B) const {
  const float d = static_cast<float>(max_distance_);
  if (depth_ == nullptr) return points_.size() > 0 && points_.AnyWithin(p_B, d);
  const Eigen::Vector3f p_C = R_CB_ * p_B + t_CB_;
  if (!(p_C.z() > 0.0f)) return false;
  const double u = K_.fx * p_C.x() / p_C.z() + K_.cx, v = K_.fy * p_C.y() / p_C.z() + K_.cy;
  if (!std::isfinite(u) || !std::isfinite(v)) return false;
  const long u0 = std::lround(u), v0 = std::lround(v);
  const float d2 = d * d;
  for (long vv = v0 - 1; vv <= v0 + 1; ++vv) {
    if (vv < 0 || vv >= depth_->height) continue;
    for (long uu = u0 - 1; uu <= u0 + 1; ++uu) {
      if (uu < 0 || uu >= depth_->width) continue;
      const float z = depth_->at(static_cast<int>(uu), static_cast<int>(vv));
      if (!std::isfinite(z)) continue;
      const Eigen::Vector3f m_C = Deproject(K_, static_cast<float>(uu), static_cast<float>(vv), z);
      if ((m_C - p_C).squaredNorm() <= d2) return true;
    }
  }
  return false;
}

double SeenFraction(std::span<const Eigen::Vector3f> samples_G, const Pose& X_BG, const SeenSurface& seen) {
  if (samples_G.empty()) return 0.0;
  const Eigen::Isometry3f X = X_BG.cast<float>();
  int n = 0;
  for (const Eigen::Vector3f& p_G : samples_G) n += seen.Seen(X * p_G) ? 1 : 0;
  return static_cast<double>(n) / static_cast<double>(samples_G.size());
}

}  // namespace bp::internal
