#include "pipeline/synthetic_pile.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <utility>

namespace bp {

namespace {

// Uniform random rotation (Shoemake), from three uniform reals.
Mat3 RandomRotation(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> U(0.0, 1.0);
  const double u1 = U(rng), u2 = U(rng), u3 = U(rng);
  const double a = std::sqrt(1 - u1), b = std::sqrt(u1);
  const Quat q(a * std::sin(2 * M_PI * u2), a * std::cos(2 * M_PI * u2),
               b * std::sin(2 * M_PI * u3), b * std::cos(2 * M_PI * u3));
  return q.normalized().toRotationMatrix();
}

Pose Lowered(const Pose& X, double dz) {
  Pose out = X;
  out.translation().z() -= dz;
  return out;
}

bool OverlapXY(const Eigen::AlignedBox3d& a, const Eigen::AlignedBox3d& b) {
  return a.min().x() <= b.max().x() && b.min().x() <= a.max().x() && a.min().y() <= b.max().y() &&
         b.min().y() <= a.max().y();
}

}  // namespace

SyntheticPile::SyntheticPile(SyntheticPile&&) noexcept = default;
SyntheticPile& SyntheticPile::operator=(SyntheticPile&&) noexcept = default;
SyntheticPile::~SyntheticPile() = default;

const PilePart* SyntheticPile::Find(int instance_id) const {
  for (const auto& p : parts_) {
    if (p.instance_id == instance_id) return &p;
  }
  return nullptr;
}

bool SyntheticPile::InsideInterior(const Eigen::AlignedBox3d& box) const {
  const double hx = bin_.inner_size.x() / 2, hy = bin_.inner_size.y() / 2;
  return box.min().x() >= -hx && box.max().x() <= hx && box.min().y() >= -hy &&
         box.max().y() <= hy && box.min().z() >= 0.0;
}

std::optional<Pose> SyntheticPile::Drop(size_t class_index, const Pose& X_WO_start,
                                        int self_id) const {
  const CollisionGeometry& g = *geometries_[class_index];
  const int ignore[] = {self_id};
  auto collides = [&](const Pose& X) { return scene_.Collides(g, X, ignore); };
  if (collides(X_WO_start)) return std::nullopt;

  // Free fall through empty space: nothing can be hit before the part's
  // bounding box reaches the top of a box below it (or the floor, z = 0).
  Pose X_free = X_WO_start;
  const Eigen::AlignedBox3d box = g.WorldBounds(X_free);
  if (InsideInterior(box)) {
    double floor_z = 0.0;
    bool can_jump = true;
    for (size_t i = 0; i < parts_.size(); ++i) {
      if (parts_[i].instance_id == self_id) continue;
      const Eigen::AlignedBox3d& other = bounds_W_[i];
      if (!OverlapXY(box, other)) continue;
      if (other.max().z() >= box.min().z()) {
        can_jump = false;
        break;
      }
      floor_z = std::max(floor_z, other.max().z());
    }
    const double gap = box.min().z() - floor_z - options_.tolerance;
    if (can_jump && gap > 0) X_free = Lowered(X_free, gap);
  }

  // Coarse steps down to the first contact, then bisection.
  const double lowest = -bin_.wall_thickness - 1.0;  // safety stop: fell through the floor
  Pose X_hit = X_free;
  bool hit = false;
  while (X_free.translation().z() > lowest) {
    const Pose next = Lowered(X_free, options_.coarse_step);
    if (collides(next)) {
      X_hit = next;
      hit = true;
      break;
    }
    X_free = next;
  }
  if (!hit) return std::nullopt;
  double z_free = X_free.translation().z(), z_hit = X_hit.translation().z();
  while (z_free - z_hit > options_.tolerance) {
    const double mid = 0.5 * (z_free + z_hit);
    Pose X_mid = X_free;
    X_mid.translation().z() = mid;
    if (collides(X_mid)) {
      z_hit = mid;
    } else {
      z_free = mid;
    }
  }
  X_free.translation().z() = z_free;
  return X_free;
}

Pose SyntheticPile::Settle(size_t class_index, const Pose& X_WO, int self_id) const {
  const CollisionGeometry& g = *geometries_[class_index];
  const Vec3 c_O = g.local_bounds().center();  // centre of mass proxy, part frame
  Pose best = X_WO;
  double best_z = (best * c_O).z();
  static const double kAnglesDeg[] = {12.0, 4.0};
  static const Vec3 kAxes[] = {Vec3::UnitX(), Vec3::UnitY(), -Vec3::UnitX(), -Vec3::UnitY()};
  for (int iter = 0; iter < options_.settle_iterations; ++iter) {
    bool improved = false;
    const Pose base = best;
    const Vec3 c_W = base * c_O;
    for (double angle_deg : kAnglesDeg) {
      for (const Vec3& axis : kAxes) {
        // Tilt about the horizontal axis through the centre, lift a little, drop.
        const Mat3 R = Eigen::AngleAxisd(angle_deg * M_PI / 180.0, axis).toRotationMatrix();
        Pose X = base;
        X.linear() = R * base.linear();
        X.translation() =
            c_W + R * (base.translation() - c_W) + Vec3(0, 0, 4 * options_.coarse_step);
        if (!InsideInterior(g.WorldBounds(X))) continue;
        const auto rest = Drop(class_index, X, self_id);
        if (!rest) continue;
        const double z = (*rest * c_O).z();
        if (z < best_z - options_.tolerance) {
          best = *rest;
          best_z = z;
          improved = true;
        }
      }
    }
    if (!improved) break;
  }
  return best;
}

Result<SyntheticPile> SyntheticPile::Generate(const BinSpec& bin, const TriangleMesh& bin_mesh,
                                              std::vector<PileClass> classes,
                                              const PileOptions& options) {
  if (classes.empty()) return Status::InvalidArgument("pile: no part classes");
  if (options.coarse_step <= 0 || options.tolerance <= 0) {
    return Status::InvalidArgument("pile: coarse_step and tolerance must be positive");
  }
  SyntheticPile pile;
  pile.bin_ = bin;
  pile.options_ = options;
  for (const auto& c : classes) {
    if (!c.mesh)
      return Status::InvalidArgument("pile: class " + std::to_string(c.class_id) + " has no mesh");
    auto g = CollisionGeometry::FromMesh(*c.mesh);
    if (!g.ok())
      return Status::InvalidArgument("pile: class " + c.name + ": " + g.status().message());
    pile.geometries_.push_back(*g);
  }
  pile.classes_ = std::move(classes);
  auto bin_g = CollisionGeometry::FromMesh(bin_mesh);
  if (!bin_g.ok()) return Status::InvalidArgument("pile: bin mesh: " + bin_g.status().message());
  pile.bin_geometry_ = *bin_g;
  if (Status s = pile.scene_.Add(kBinId, pile.bin_geometry_, Pose::Identity()); !s.ok()) return s;

  const double max_rest =
      options.max_rest_height > 0 ? options.max_rest_height : bin.inner_size.z();
  const double hx = bin.inner_size.x() / 2, hy = bin.inner_size.y() / 2;
  std::mt19937_64 rng(options.seed);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  int next_id = 1;
  for (int n = 0; n < options.num_parts; ++n) {
    const size_t ci = std::uniform_int_distribution<size_t>(0, pile.classes_.size() - 1)(rng);
    const CollisionGeometry& g = *pile.geometries_[ci];
    bool placed = false;
    for (int attempt = 0; attempt < options.attempts_per_part && !placed; ++attempt) {
      const Mat3 R = RandomRotation(rng);
      const double ux = U(rng), uy = U(rng);
      const Eigen::AlignedBox3d rb = g.WorldBounds(MakePose(R, Vec3::Zero()));
      const double margin = 1e-4;
      const double x_lo = -hx - rb.min().x() + margin, x_hi = hx - rb.max().x() - margin;
      const double y_lo = -hy - rb.min().y() + margin, y_hi = hy - rb.max().y() - margin;
      if (x_lo > x_hi || y_lo > y_hi) continue;  // does not fit this way round
      double top = 0.0;
      for (const auto& b : pile.bounds_W_) top = std::max(top, b.max().z());
      const Vec3 t(x_lo + ux * (x_hi - x_lo), y_lo + uy * (y_hi - y_lo),
                   top + 0.005 - rb.min().z());
      const auto rest = pile.Drop(ci, MakePose(R, t), -1);
      if (!rest) continue;
      const Pose X_WO = pile.Settle(ci, *rest, -1);
      if ((X_WO * g.local_bounds().center()).z() > max_rest) continue;
      PilePart part;
      part.instance_id = next_id++;
      part.class_id = pile.classes_[ci].class_id;
      part.class_index = ci;
      part.X_WO = X_WO;
      if (Status s = pile.scene_.Add(part.instance_id, pile.geometries_[ci], X_WO); !s.ok())
        return s;
      pile.parts_.push_back(part);
      pile.bounds_W_.push_back(g.WorldBounds(X_WO));
      placed = true;
    }
    if (!placed) ++pile.skipped_;
  }
  return pile;
}

Status SyntheticPile::RemovePart(int instance_id) {
  auto it = std::find_if(parts_.begin(), parts_.end(),
                         [&](const PilePart& p) { return p.instance_id == instance_id; });
  if (it == parts_.end()) return Status::NotFound("pile: no part " + std::to_string(instance_id));
  const size_t index = static_cast<size_t>(it - parts_.begin());
  if (Status s = scene_.Remove(instance_id); !s.ok()) return s;
  parts_.erase(it);
  bounds_W_.erase(bounds_W_.begin() + static_cast<std::ptrdiff_t>(index));

  // Every part is dropped again, lowest first (ties by index: deterministic),
  // in passes until a pass moves none: the parts above the removed one, and
  // those a part that dropped held (one resting on it, or leaning on it with
  // its bottom below the dropped part's). A part counts as moved when it
  // falls more than `tolerance`, the bisection's resolution: a resting part
  // dropped again may come out up to that lower, and stays. Each move lowers
  // a part by more than `tolerance`, so the passes end.
  bool moved = true;
  while (moved) {
    moved = false;
    std::vector<std::pair<double, size_t>> order;
    for (size_t i = 0; i < parts_.size(); ++i) order.emplace_back(bounds_W_[i].min().z(), i);
    std::sort(order.begin(), order.end());
    for (const auto& [bottom, i] : order) {
      PilePart& p = parts_[i];
      const auto rest = Drop(p.class_index, p.X_WO, p.instance_id);
      if (!rest) continue;  // wedged: stays where it is
      if (rest->translation().z() >= p.X_WO.translation().z() - options_.tolerance) continue;
      p.X_WO = *rest;
      bounds_W_[i] = geometries_[p.class_index]->WorldBounds(p.X_WO);
      if (Status s = scene_.SetPose(p.instance_id, p.X_WO); !s.ok()) return s;
      moved = true;
    }
  }
  return Status::Ok();
}

}  // namespace bp
