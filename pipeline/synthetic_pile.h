// A pile of rigid parts dropped one by one into an open bin, with FCL contact
// checks: no interpenetration, parts rest on the floor, the walls or each other.
// All poses are in the bin frame W (origin at the centre of the inner floor
// surface, z up). See docs/synthetic.md for the drop algorithm.
//
// Deterministic: the same inputs and seed give the same pile, bit for bit
// (std::mt19937_64, ordered containers only). Not thread-safe for mutation;
// const members may be called concurrently.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "collision/mesh_collider.h"
#include "core/cell.h"
#include "core/mesh.h"
#include "core/status.h"

namespace bp {

// One part class a pile is drawn from.
struct PileClass {
  int class_id = 0;
  std::string name;
  std::shared_ptr<const TriangleMesh> mesh;  // in the part frame O
};

struct PileOptions {
  int num_parts = 20;
  uint64_t seed = 1;
  double coarse_step = 0.002;  // m; lowering step before bisection (keep < thinnest wall)
  double tolerance = 0.0002;   // m; bisection stops when the bracket is this small
  int attempts_per_part = 8;   // random poses tried before a part is skipped
  // A part whose centre comes to rest higher than this above the floor does
  // not fit (bin full) and another pose is tried. <= 0: the bin's inner height.
  double max_rest_height = 0.0;
  int settle_iterations = 2;  // rounds of "tilt a little if it lowers the part" (0 = off)
};

struct PilePart {
  int instance_id = 0;  // 1, 2, ... in drop order; never reused within a pile
  int class_id = 0;
  size_t class_index = 0;  // into SyntheticPile::classes()
  Pose X_WO = Pose::Identity();
};

class SyntheticPile {
 public:
  // Drops options.num_parts parts, classes drawn uniformly from `classes`.
  // `bin_mesh` is in W. Parts that cannot be placed are skipped (see skipped()).
  // @returns InvalidArgument for empty classes / meshes.
  static Result<SyntheticPile> Generate(const BinSpec& bin, const TriangleMesh& bin_mesh,
                                        std::vector<PileClass> classes, const PileOptions& options);

  SyntheticPile(SyntheticPile&&) noexcept;
  SyntheticPile& operator=(SyntheticPile&&) noexcept;
  ~SyntheticPile();

  // Parts in the pile, in instance id order.
  const std::vector<PilePart>& parts() const { return parts_; }
  const PilePart* Find(int instance_id) const;
  // Number of parts that could not be placed (bin full).
  int skipped() const { return skipped_; }
  const std::vector<PileClass>& classes() const { return classes_; }
  const CollisionGeometryPtr& class_geometry(size_t class_index) const {
    return geometries_[class_index];
  }
  const CollisionGeometryPtr& bin_geometry() const { return bin_geometry_; }
  // Bin (id kBinId) and every part (id = instance_id) at their poses.
  const CollisionScene& scene() const { return scene_; }
  static constexpr int kBinId = 0;

  // Removes a part, then lets the pile resettle: every part is lowered
  // straight down from its current pose (orientation kept), lowest first,
  // in passes until none falls, so a part held by one that fell falls too
  // and no part is left resting on nothing.
  // @returns NotFound for an unknown instance id.
  Status RemovePart(int instance_id);

 private:
  SyntheticPile() = default;
  // Lowers part `index` (not in the scene) from X_WO straight down until contact.
  // @returns the lowest collision-free pose; nullopt if X_WO itself collides.
  // `self_id` (if in the scene) is ignored.
  std::optional<Pose> Drop(size_t class_index, const Pose& X_WO, int self_id) const;
  // Tries small tilts that lower the part's centre without collision.
  Pose Settle(size_t class_index, const Pose& X_WO, int self_id) const;
  bool InsideInterior(const Eigen::AlignedBox3d& box) const;

  BinSpec bin_;
  PileOptions options_;
  std::vector<PileClass> classes_;
  std::vector<CollisionGeometryPtr> geometries_;
  CollisionGeometryPtr bin_geometry_;
  CollisionScene scene_;
  std::vector<PilePart> parts_;
  std::vector<Eigen::AlignedBox3d> bounds_W_;  // world bounds of parts_[i]
  int skipped_ = 0;
};

}  // namespace bp
