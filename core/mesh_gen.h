// Procedural meshes for the shipped parts, the bin and the grippers (the
// generator behind assets/; see assets/README.md). All sizes in metres.
// Triangles face outward (counter-clockwise seen from outside). Parts and the
// bin are closed (watertight) solids; a gripper is a union of closed solids.
//
// Round surfaces use `segments` facets per full turn. It must be a positive
// multiple of 8 so that square tiles, axis directions and the 180 degree
// symmetries land on vertices. Invalid parameters abort (programmer error).
#pragma once

#include "core/cell.h"
#include "core/mesh.h"

namespace bp {

// Rotationally symmetric about z. Frame: origin at the centre of the flange's
// bottom face, z along the axis, the hub rising from the flange.
struct FlangedBushingParams {
  double flange_diameter = 0.060;
  double flange_thickness = 0.008;
  double hub_diameter = 0.036;
  double height = 0.040;  // total, flange bottom to hub top
  double bore_diameter = 0.012;
  int segments = 64;
};
TriangleMesh MakeFlangedBushing(const FlangedBushingParams& p = {});

// A flat base plate (x from 0 to base_length, y centred, z from 0 to
// thickness) and an upright plate (x from 0 to thickness, up to height), with
// through holes placed asymmetrically so the part has no symmetry. Frame:
// origin at the centre of the outer corner edge.
struct LBracketParams {
  double base_length = 0.090;  // x
  double width = 0.050;        // y
  double thickness = 0.005;
  double height = 0.060;       // z, top of the upright
  double hole_diameter = 0.008;
  // Hole centres: base holes (x, y) through z; upright hole (y, z) through x.
  Eigen::Vector2d base_hole_a = Eigen::Vector2d(0.030, 0.010);
  Eigen::Vector2d base_hole_b = Eigen::Vector2d(0.070, -0.012);
  Eigen::Vector2d upright_hole = Eigen::Vector2d(0.012, 0.040);
  int segments = 64;
};
TriangleMesh MakeLBracket(const LBracketParams& p = {});

// Equal tee: a run pipe along x (centred at the origin) and a branch along +z
// from the run axis. The solid is the exact union of the two tubes with both
// bores open into each other (outer and inner walls are cut along their saddle
// curves), up to the facet approximation. Symmetric under a 180 degree
// rotation about z.
struct PipeTeeParams {
  double outer_diameter = 0.040;
  double inner_diameter = 0.030;
  double run_length = 0.100;    // x from -run_length/2 to +run_length/2
  double branch_height = 0.050;  // z of the branch end
  int segments = 64;
};
TriangleMesh MakePipeTee(const PipeTeeParams& p = {});

// A locating block parts are placed on (the default cell's fixture): a
// plate and on it a truncated pyramid whose base and top are off the plate's
// centre and off each other, one closed solid. Its four sloped faces (44 to
// 54 deg) show a camera looking down x, y and the turn about z; no two of
// its faces map onto each other, so it has no symmetry. Frame P: origin at
// the centre of the plate's bottom face, z up.
struct PlaceNestParams {
  Eigen::Vector2d plate_size = Eigen::Vector2d(0.110, 0.090);  // x, y
  double plate_thickness = 0.010;
  // Pyramid base (on the plate's top face) and top rectangles, x-y corners.
  Eigen::Vector2d base_min = Eigen::Vector2d(-0.040, -0.032), base_max = Eigen::Vector2d(0.030, 0.026);
  Eigen::Vector2d top_min = Eigen::Vector2d(-0.014, -0.010), top_max = Eigen::Vector2d(0.010, 0.008);
  double pyramid_height = 0.025;  // above the plate's top face
};
TriangleMesh MakePlaceNest(const PlaceNestParams& p = {});

// Open box in the bin frame W (origin at the centre of the inner floor
// surface, z up): inner size bin.inner_size, walls and floor
// bin.wall_thickness thick; the floor spans z in [-wall_thickness, 0].
TriangleMesh MakeBinMesh(const BinSpec& bin);

// Grippers are in the tool frame T: origin at the tool centre point (the
// contact point), +z the approach direction into the part, so the body
// extends along -z. The flange is at z = -flange_offset.
struct SuctionGripperParams {
  double cup_diameter = 0.016;
  double cup_height = 0.020;   // z in [-cup_height, 0]
  double rod_diameter = 0.020;
  double flange_offset = 0.27;  // rod from -flange_offset to -cup_height
  int segments = 64;
};
TriangleMesh MakeSuctionGripper(const SuctionGripperParams& p = {});

// Palm box (z in [-flange_offset, -flange_offset + palm_size.z()]) and two
// finger boxes with inner faces at x = +-opening/2, from the palm down to
// finger_tip_z (so 110 mm of finger shows by default: the fingers touch the
// palm rather than float below it). Fingers reach up into the palm by
// finger_overlap so the union has no coplanar faces.
struct ParallelJawParams {
  Eigen::Vector3d palm_size = Eigen::Vector3d(0.090, 0.040, 0.060);
  double flange_offset = 0.16;
  Eigen::Vector2d finger_section = Eigen::Vector2d(0.010, 0.020);  // x, y
  double opening = 0.06;
  double finger_tip_z = 0.01;
  double finger_overlap = 0.005;
};
TriangleMesh MakeParallelJawGripper(const ParallelJawParams& p = {});

}  // namespace bp
