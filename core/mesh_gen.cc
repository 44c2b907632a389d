#include "core/mesh_gen.h"

#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <unordered_map>
#include <vector>

namespace bp {
namespace {

using V2 = Eigen::Vector2d;
using V3 = Eigen::Vector3d;

// Vertices closer than this are one vertex; a vertex closer than this to an
// edge splits it. Far below any feature size and far above double rounding.
constexpr double kWeldTolerance = 1e-7;  // m
// Twice the area below which a triangle is dropped as degenerate.
constexpr double kMinTwiceArea = 1e-14;  // m^2

void Require(bool ok, const char* what) {
  if (!ok) {
    std::fprintf(stderr, "mesh_gen: invalid parameters: %s\n", what);
    std::abort();
  }
}

double Angle(int k, int n) { return 2.0 * std::numbers::pi * k / n; }

// Collects faces generated independently (a triangle soup), each triangle
// turned to face a given outward direction, then stitches them into one
// indexed mesh: welds coincident vertices and splits edges that have another
// face's vertex in their interior (T-junctions), so that neighbouring faces
// share every edge and the result is watertight.
class Builder {
 public:
  void Tri(const V3& a, const V3& b, const V3& c, const V3& outward) {
    const V3 n = (b - a).cross(c - a);
    if (n.norm() < kMinTwiceArea) return;
    const bool keep = n.dot(outward) >= 0;
    soup_.push_back(a);
    soup_.push_back(keep ? b : c);
    soup_.push_back(keep ? c : b);
  }
  // a, b, c, d in cyclic order around a planar (or nearly planar) quad.
  void Quad(const V3& a, const V3& b, const V3& c, const V3& d, const V3& outward) {
    Tri(a, b, c, outward);
    Tri(a, c, d, outward);
  }

  TriangleMesh Finish() const;

 private:
  std::vector<V3> soup_;
};

struct CellKey {
  int64_t x, y, z;
  bool operator==(const CellKey&) const = default;
};
struct CellKeyHash {
  size_t operator()(const CellKey& k) const {
    return static_cast<size_t>(k.x * 73856093) ^ static_cast<size_t>(k.y * 19349663) ^
           static_cast<size_t>(k.z * 83492791);
  }
};

TriangleMesh Builder::Finish() const {
  // 1. Weld: hash grid with cell = tolerance, look at the 27 neighbours.
  std::vector<V3> verts;
  std::unordered_map<CellKey, std::vector<int>, CellKeyHash> grid;
  auto key_of = [](const V3& p) {
    return CellKey{static_cast<int64_t>(std::floor(p.x() / kWeldTolerance)),
                   static_cast<int64_t>(std::floor(p.y() / kWeldTolerance)),
                   static_cast<int64_t>(std::floor(p.z() / kWeldTolerance))};
  };
  std::vector<int> soup_index(soup_.size());
  for (size_t i = 0; i < soup_.size(); ++i) {
    const V3& p = soup_[i];
    const CellKey k = key_of(p);
    int found = -1;
    for (int dx = -1; dx <= 1 && found < 0; ++dx) {
      for (int dy = -1; dy <= 1 && found < 0; ++dy) {
        for (int dz = -1; dz <= 1 && found < 0; ++dz) {
          auto it = grid.find(CellKey{k.x + dx, k.y + dy, k.z + dz});
          if (it == grid.end()) continue;
          for (int idx : it->second) {
            if ((verts[idx] - p).norm() <= kWeldTolerance) {
              found = idx;
              break;
            }
          }
        }
      }
    }
    if (found < 0) {
      found = static_cast<int>(verts.size());
      verts.push_back(p);
      grid[k].push_back(found);
    }
    soup_index[i] = found;
  }

  std::vector<Eigen::Vector3i> work;
  for (size_t i = 0; i < soup_.size(); i += 3) {
    const Eigen::Vector3i t(soup_index[i], soup_index[i + 1], soup_index[i + 2]);
    if (t[0] != t[1] && t[1] != t[2] && t[0] != t[2]) work.push_back(t);
  }

  // 2. Split T-junctions. Vertices sorted by x give a cheap range query.
  std::vector<int> by_x(verts.size());
  for (size_t i = 0; i < by_x.size(); ++i) by_x[i] = static_cast<int>(i);
  std::sort(by_x.begin(), by_x.end(), [&](int a, int b) { return verts[a].x() < verts[b].x(); });
  auto on_edge = [&](int a, int b, int c, std::vector<std::pair<double, int>>* hits) {
    hits->clear();
    const V3& A = verts[a];
    const V3 d = verts[b] - A;
    const double len2 = d.squaredNorm();
    const double lo = std::min(A.x(), verts[b].x()) - kWeldTolerance;
    const double hi = std::max(A.x(), verts[b].x()) + kWeldTolerance;
    auto it = std::lower_bound(by_x.begin(), by_x.end(), lo, [&](int i, double x) { return verts[i].x() < x; });
    for (; it != by_x.end() && verts[*it].x() <= hi; ++it) {
      const int v = *it;
      if (v == a || v == b || v == c) continue;
      const double s = (verts[v] - A).dot(d) / len2;
      if (s <= 0.0 || s >= 1.0) continue;
      if ((A + s * d - verts[v]).norm() < kWeldTolerance) hits->emplace_back(s, v);
    }
    std::sort(hits->begin(), hits->end());
  };
  std::vector<Eigen::Vector3i> done;
  std::vector<std::pair<double, int>> hits;
  while (!work.empty()) {
    const Eigen::Vector3i t = work.back();
    work.pop_back();
    bool split = false;
    for (int e = 0; e < 3 && !split; ++e) {
      const int a = t[e], b = t[(e + 1) % 3], c = t[(e + 2) % 3];
      on_edge(a, b, c, &hits);
      if (hits.empty()) continue;
      int prev = a;
      for (const auto& h : hits) {
        work.emplace_back(prev, h.second, c);
        prev = h.second;
      }
      work.emplace_back(prev, b, c);
      split = true;
    }
    if (!split) done.push_back(t);
  }

  // 3. Compact (drop unused vertices) and convert to float.
  TriangleMesh mesh;
  std::vector<int> remap(verts.size(), -1);
  for (const auto& t : done) {
    Eigen::Vector3i u;
    for (int k = 0; k < 3; ++k) {
      int& r = remap[t[k]];
      if (r < 0) {
        r = static_cast<int>(mesh.vertices.size());
        // Round-off on axis planes (cos(pi/2) * r ~ 1e-18) is snapped to 0.
        const V3 v = verts[t[k]].unaryExpr([](double c) { return std::abs(c) < 1e-12 ? 0.0 : c; });
        mesh.vertices.push_back(v.cast<float>());
      }
      u[k] = r;
    }
    mesh.triangles.push_back(u);
  }
  return mesh;
}

// Solid of revolution about z of a closed (r, z) profile polygon. Profile
// points on the axis (r = 0) become poles.
void Revolve(Builder* B, const std::vector<V2>& profile, int n) {
  double twice_area = 0;
  for (size_t i = 0; i < profile.size(); ++i) {
    const V2& p = profile[i];
    const V2& q = profile[(i + 1) % profile.size()];
    twice_area += p.x() * q.y() - q.x() * p.y();
  }
  const double orient = twice_area > 0 ? 1.0 : -1.0;  // CCW profile: outward normal is (dz, -dr)
  auto at = [](const V2& rz, double th) { return V3(rz.x() * std::cos(th), rz.x() * std::sin(th), rz.y()); };
  for (size_t i = 0; i < profile.size(); ++i) {
    const V2& p = profile[i];
    const V2& q = profile[(i + 1) % profile.size()];
    const V2 d = q - p;
    const V2 nrz = orient * V2(d.y(), -d.x());
    for (int j = 0; j < n; ++j) {
      const double t0 = Angle(j, n), t1 = Angle(j + 1, n), tm = 0.5 * (t0 + t1);
      const V3 outward(nrz.x() * std::cos(tm), nrz.x() * std::sin(tm), nrz.y());
      B->Quad(at(p, t0), at(q, t0), at(q, t1), at(p, t1), outward);
    }
  }
}

struct Hole {
  V2 centre;
  double radius;
};

// Maps face coordinates (a, b) on the plane {coordinate `axis` = w} to 3D:
// a along axis+1, b along axis+2 (cyclic), so that the 2D angles of hole
// points agree with HoleWall's.
V3 OnPlane(int axis, double w, const V2& ab) {
  V3 p;
  p[axis] = w;
  p[(axis + 1) % 3] = ab.x();
  p[(axis + 2) % 3] = ab.y();
  return p;
}

// Rectangle [lo, hi] on the plane {axis = w}, facing sign * e_axis, with round
// through holes. Each hole sits in a square tile of half size tile_half meshed
// as a ring between the circle and the square (same angles on both), the rest
// of the rectangle is split into grid cells along the tile edges.
void HoledRect(Builder* B, int axis, double w, double sign, const V2& lo, const V2& hi,
               const std::vector<Hole>& holes, double tile_half, int n) {
  V3 outward = V3::Zero();
  outward[axis] = sign;
  std::vector<double> us{lo.x(), hi.x()}, vs{lo.y(), hi.y()};
  for (const Hole& h : holes) {
    Require(h.radius < tile_half, "hole larger than its tile");
    Require(h.centre.x() - tile_half > lo.x() && h.centre.x() + tile_half < hi.x() &&
                h.centre.y() - tile_half > lo.y() && h.centre.y() + tile_half < hi.y(),
            "hole too close to a plate edge");
    us.push_back(h.centre.x() - tile_half);
    us.push_back(h.centre.x() + tile_half);
    vs.push_back(h.centre.y() - tile_half);
    vs.push_back(h.centre.y() + tile_half);
  }
  std::sort(us.begin(), us.end());
  std::sort(vs.begin(), vs.end());
  us.erase(std::unique(us.begin(), us.end()), us.end());
  vs.erase(std::unique(vs.begin(), vs.end()), vs.end());
  auto P = [&](double a, double b) { return OnPlane(axis, w, V2(a, b)); };
  for (size_t i = 0; i + 1 < us.size(); ++i) {
    for (size_t j = 0; j + 1 < vs.size(); ++j) {
      const V2 c0(us[i], vs[j]), c1(us[i + 1], vs[j + 1]);
      const Hole* tile = nullptr;
      for (const Hole& h : holes) {
        if ((h.centre - V2::Constant(tile_half) - c0).norm() < 1e-12 &&
            (h.centre + V2::Constant(tile_half) - c1).norm() < 1e-12) {
          tile = &h;
        }
      }
      if (tile == nullptr) {
        for (const Hole& h : holes) {
          const bool overlaps = h.centre.x() + tile_half > c0.x() && h.centre.x() - tile_half < c1.x() &&
                                h.centre.y() + tile_half > c0.y() && h.centre.y() - tile_half < c1.y();
          Require(!overlaps, "hole tiles overlap");
        }
        B->Quad(P(c0.x(), c0.y()), P(c1.x(), c0.y()), P(c1.x(), c1.y()), P(c0.x(), c1.y()), outward);
        continue;
      }
      for (int k = 0; k < n; ++k) {
        auto ring = [&](int kk, bool square) {
          const double th = Angle(kk, n);
          V2 d(std::cos(th), std::sin(th));
          if (square) d /= std::max(std::abs(d.x()), std::abs(d.y()));
          const V2 q = tile->centre + (square ? tile_half : tile->radius) * d;
          return P(q.x(), q.y());
        };
        B->Quad(ring(k, true), ring(k + 1, true), ring(k + 1, false), ring(k, false), outward);
      }
    }
  }
}

// Cylindrical wall of a through hole from the plane {axis = w0} to {axis = w1},
// facing the hole's axis (out of the material).
void HoleWall(Builder* B, int axis, double w0, double w1, const Hole& h, int n) {
  for (int k = 0; k < n; ++k) {
    const double t0 = Angle(k, n), t1 = Angle(k + 1, n), tm = 0.5 * (t0 + t1);
    auto P = [&](double w, double th) {
      return OnPlane(axis, w, h.centre + h.radius * V2(std::cos(th), std::sin(th)));
    };
    const V3 outward = -(OnPlane(axis, 0, V2(std::cos(tm), std::sin(tm))));
    B->Quad(P(w0, t0), P(w0, t1), P(w1, t1), P(w1, t0), outward);
  }
}

// Axis-aligned closed box.
void Box(Builder* B, const V3& lo, const V3& hi) {
  for (int axis = 0; axis < 3; ++axis) {
    const int a = (axis + 1) % 3, b = (axis + 2) % 3;
    for (int side = 0; side < 2; ++side) {
      const double w = side ? hi[axis] : lo[axis];
      auto P = [&](double u, double v) { return OnPlane(axis, w, V2(u, v)); };
      V3 outward = V3::Zero();
      outward[axis] = side ? 1.0 : -1.0;
      B->Quad(P(lo[a], lo[b]), P(hi[a], lo[b]), P(hi[a], hi[b]), P(lo[a], hi[b]), outward);
    }
  }
}

}  // namespace

TriangleMesh MakeFlangedBushing(const FlangedBushingParams& p) {
  Require(p.segments > 0 && p.segments % 8 == 0, "segments must be a positive multiple of 8");
  Require(p.bore_diameter > 0 && p.bore_diameter < p.hub_diameter && p.hub_diameter < p.flange_diameter,
          "need 0 < bore < hub < flange diameter");
  Require(p.flange_thickness > 0 && p.flange_thickness < p.height, "need 0 < flange thickness < height");
  const double rb = p.bore_diameter / 2, rh = p.hub_diameter / 2, rf = p.flange_diameter / 2;
  Builder B;
  Revolve(&B,
          {V2(rb, 0), V2(rf, 0), V2(rf, p.flange_thickness), V2(rh, p.flange_thickness), V2(rh, p.height),
           V2(rb, p.height)},
          p.segments);
  return B.Finish();
}

TriangleMesh MakeLBracket(const LBracketParams& p) {
  Require(p.segments > 0 && p.segments % 8 == 0, "segments must be a positive multiple of 8");
  Require(p.thickness > 0 && p.thickness < p.base_length && p.thickness < p.height && p.width > 0,
          "bad plate sizes");
  const double L = p.base_length, W2 = p.width / 2, t = p.thickness, H = p.height;
  const double r = p.hole_diameter / 2, tile = 1.5 * r;
  const int n = p.segments;
  const std::vector<Hole> base{{p.base_hole_a, r}, {p.base_hole_b, r}};
  const std::vector<Hole> upright{{p.upright_hole, r}};
  Builder B;
  // z faces: (a, b) = (x, y).
  HoledRect(&B, 2, 0.0, -1, V2(0, -W2), V2(L, W2), base, tile, n);  // bottom
  HoledRect(&B, 2, t, +1, V2(t, -W2), V2(L, W2), base, tile, n);    // base top
  HoledRect(&B, 2, H, +1, V2(0, -W2), V2(t, W2), {}, tile, n);      // upright top
  // x faces: (a, b) = (y, z).
  HoledRect(&B, 0, 0.0, -1, V2(-W2, 0), V2(W2, H), upright, tile, n);  // upright outer
  HoledRect(&B, 0, t, +1, V2(-W2, t), V2(W2, H), upright, tile, n);    // upright inner
  HoledRect(&B, 0, L, +1, V2(-W2, 0), V2(W2, t), {}, tile, n);         // base end
  // y faces (the L profile): (a, b) = (z, x).
  for (const double sign : {-1.0, 1.0}) {
    HoledRect(&B, 1, sign * W2, sign, V2(0, 0), V2(H, t), {}, tile, n);
    HoledRect(&B, 1, sign * W2, sign, V2(0, t), V2(t, L), {}, tile, n);
  }
  for (const Hole& h : base) HoleWall(&B, 2, 0.0, t, h, n);
  for (const Hole& h : upright) HoleWall(&B, 0, 0.0, t, h, n);
  return B.Finish();
}

// The run's walls (radius rho) are (x, rho sin(a), rho cos(a)); the branch's
// (rho cos(f), rho sin(f), z). For equal radii the two cylinders meet on the
// planes z = +-x, so the saddle over the run is x = +-rho cos(a) at angle a
// (a in [-pi/2, pi/2]) and the branch wall starts at z = rho |cos(f)|. Using
// the same angle samples on both makes their saddle vertices coincide: the run
// wall keeps the two trapezoids outside the saddle on its upper half, the
// branch wall starts on the saddle. Done for the outer wall and for the bore.
TriangleMesh MakePipeTee(const PipeTeeParams& p) {
  const int n = p.segments;
  Require(n > 0 && n % 8 == 0, "segments must be a positive multiple of 8");
  const double R = p.outer_diameter / 2, r = p.inner_diameter / 2, L2 = p.run_length / 2, H = p.branch_height;
  Require(0 < r && r < R && R < L2 && R < H, "need 0 < inner < outer radius < run half length, branch height");
  auto snap = [](double v) { return std::abs(v) < 1e-12 ? 0.0 : v; };
  auto run = [](double x, double a, double rho) { return V3(x, rho * std::sin(a), rho * std::cos(a)); };
  auto branch = [](double f, double z, double rho) { return V3(rho * std::cos(f), rho * std::sin(f), z); };
  Builder B;
  for (const auto& [rho, sign] : {std::pair{R, 1.0}, std::pair{r, -1.0}}) {
    for (int k = -n / 2; k < n / 2; ++k) {
      const double a0 = Angle(k, n), a1 = Angle(k + 1, n), am = 0.5 * (a0 + a1);
      const V3 outward = sign * V3(0, std::sin(am), std::cos(am));
      if (k >= -n / 4 && k + 1 <= n / 4) {  // upper half: cut along the saddle
        const double s0 = snap(rho * std::cos(a0)), s1 = snap(rho * std::cos(a1));
        B.Quad(run(-L2, a0, rho), run(-s0, a0, rho), run(-s1, a1, rho), run(-L2, a1, rho), outward);
        B.Quad(run(s0, a0, rho), run(L2, a0, rho), run(L2, a1, rho), run(s1, a1, rho), outward);
      } else {
        B.Quad(run(-L2, a0, rho), run(L2, a0, rho), run(L2, a1, rho), run(-L2, a1, rho), outward);
      }
    }
    for (int j = 0; j < n; ++j) {
      const double f0 = Angle(j, n), f1 = Angle(j + 1, n), fm = 0.5 * (f0 + f1);
      const double z0 = snap(rho * std::abs(std::cos(f0))), z1 = snap(rho * std::abs(std::cos(f1)));
      B.Quad(branch(f0, z0, rho), branch(f1, z1, rho), branch(f1, H, rho), branch(f0, H, rho),
             sign * V3(std::cos(fm), std::sin(fm), 0));
    }
  }
  for (int k = 0; k < n; ++k) {
    const double a0 = Angle(k, n), a1 = Angle(k + 1, n);
    for (const double x : {-L2, L2}) {
      B.Quad(run(x, a0, R), run(x, a1, R), run(x, a1, r), run(x, a0, r), V3(x > 0 ? 1 : -1, 0, 0));
    }
    B.Quad(branch(a0, H, R), branch(a1, H, R), branch(a1, H, r), branch(a0, H, r), V3::UnitZ());
  }
  return B.Finish();
}

TriangleMesh MakeBinMesh(const BinSpec& bin) {
  const double X = bin.inner_size.x() / 2, Y = bin.inner_size.y() / 2, Z = bin.inner_size.z();
  const double t = bin.wall_thickness;
  Require(X > 0 && Y > 0 && Z > 0 && t > 0, "bin sizes must be positive");
  const double Xo = X + t, Yo = Y + t;
  // Corners counter-clockwise seen from +z.
  const V2 outer[4] = {V2(-Xo, -Yo), V2(Xo, -Yo), V2(Xo, Yo), V2(-Xo, Yo)};
  const V2 inner[4] = {V2(-X, -Y), V2(X, -Y), V2(X, Y), V2(-X, Y)};
  auto at = [](const V2& xy, double z) { return V3(xy.x(), xy.y(), z); };
  Builder B;
  B.Quad(at(outer[0], -t), at(outer[1], -t), at(outer[2], -t), at(outer[3], -t), -V3::UnitZ());
  B.Quad(at(inner[0], 0), at(inner[1], 0), at(inner[2], 0), at(inner[3], 0), V3::UnitZ());
  for (int i = 0; i < 4; ++i) {
    const int j = (i + 1) % 4;
    const V2 mid_o = 0.5 * (outer[i] + outer[j]), mid_i = 0.5 * (inner[i] + inner[j]);
    const V3 away(mid_o.x(), mid_o.y(), 0);  // from the centre through this side
    B.Quad(at(outer[i], -t), at(outer[j], -t), at(outer[j], Z), at(outer[i], Z), away);
    B.Quad(at(inner[i], 0), at(inner[j], 0), at(inner[j], Z), at(inner[i], Z), -V3(mid_i.x(), mid_i.y(), 0));
    B.Quad(at(outer[i], Z), at(outer[j], Z), at(inner[j], Z), at(inner[i], Z), V3::UnitZ());
  }
  return B.Finish();
}

TriangleMesh MakePlaceNest(const PlaceNestParams& p) {
  const V2 half = p.plate_size / 2;
  Require((p.plate_size.array() > 0).all() && p.plate_thickness > 0 && p.pyramid_height > 0, "bad place nest sizes");
  Require((p.base_min.array() > -half.array()).all() && (p.base_max.array() < half.array()).all() &&
              (p.base_min.array() < p.top_min.array()).all() && (p.top_min.array() < p.top_max.array()).all() &&
              (p.top_max.array() < p.base_max.array()).all(),
          "the pyramid's top must lie inside its base, and its base inside the plate");
  const double z0 = 0, z1 = p.plate_thickness, z2 = p.plate_thickness + p.pyramid_height;
  // Corners counter-clockwise seen from +z.
  auto rect = [](const V2& lo, const V2& hi, double z) {
    return std::array<V3, 4>{V3(lo.x(), lo.y(), z), V3(hi.x(), lo.y(), z), V3(hi.x(), hi.y(), z), V3(lo.x(), hi.y(), z)};
  };
  const auto bottom = rect(-half, half, z0), plate_top = rect(-half, half, z1);
  const auto base = rect(p.base_min, p.base_max, z1), top = rect(p.top_min, p.top_max, z2);
  Builder B;
  B.Quad(bottom[0], bottom[1], bottom[2], bottom[3], -V3::UnitZ());
  B.Quad(top[0], top[1], top[2], top[3], V3::UnitZ());
  for (int i = 0; i < 4; ++i) {
    const int j = (i + 1) % 4;
    const V3 mid = (bottom[i] + bottom[j]) / 2;
    const V3 side(mid.x(), mid.y(), 0);  // outward from the plate's centre
    B.Quad(bottom[i], bottom[j], plate_top[j], plate_top[i], side);
    B.Quad(plate_top[i], plate_top[j], base[j], base[i], V3::UnitZ());  // the plate's top around the pyramid
    const V3 edge = base[j] - base[i];
    const V3 slope_out = edge.cross(top[i] - base[i]);  // faces away from the pyramid's inside
    const V3 centre(((p.base_min + p.base_max) / 2).x(), ((p.base_min + p.base_max) / 2).y(), z1);
    B.Quad(base[i], base[j], top[j], top[i], slope_out.dot(base[i] - centre) >= 0 ? slope_out : V3(-slope_out));
  }
  return B.Finish();
}

TriangleMesh MakeSuctionGripper(const SuctionGripperParams& p) {
  Require(p.segments > 0 && p.segments % 8 == 0, "segments must be a positive multiple of 8");
  Require(p.cup_diameter > 0 && p.rod_diameter > 0 && p.cup_height > 0 && p.flange_offset > p.cup_height,
          "bad suction gripper sizes");
  const double rc = p.cup_diameter / 2, rr = p.rod_diameter / 2;
  Builder B;
  Revolve(&B,
          {V2(0, 0), V2(rc, 0), V2(rc, -p.cup_height), V2(rr, -p.cup_height), V2(rr, -p.flange_offset),
           V2(0, -p.flange_offset)},
          p.segments);
  return B.Finish();
}

TriangleMesh MakeParallelJawGripper(const ParallelJawParams& p) {
  const double palm_bottom = -p.flange_offset + p.palm_size.z();
  Require((p.palm_size.array() > 0).all() && palm_bottom < p.finger_tip_z, "bad palm size");
  Require(p.opening / 2 + p.finger_section.x() <= p.palm_size.x() / 2, "fingers stick out of the palm");
  Builder B;
  Box(&B, V3(-p.palm_size.x() / 2, -p.palm_size.y() / 2, -p.flange_offset),
      V3(p.palm_size.x() / 2, p.palm_size.y() / 2, palm_bottom));
  const double fy = p.finger_section.y() / 2, top = palm_bottom - p.finger_overlap;
  const double in = p.opening / 2, out = in + p.finger_section.x();
  Box(&B, V3(in, -fy, top), V3(out, fy, p.finger_tip_z));
  Box(&B, V3(-out, -fy, top), V3(-in, fy, p.finger_tip_z));
  return B.Finish();
}

}  // namespace bp
