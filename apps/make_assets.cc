// Writes the procedural meshes of the shipped assets (see assets/README.md).
// Run from the repository root:  ./build/bin/bp_make_assets [--out assets]
#include <cstdio>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>

#include "core/cell.h"
#include "core/mesh.h"
#include "core/mesh_gen.h"

int main(int argc, char** argv) {
  CLI::App app{"Generate the binpick part, gripper and bin meshes (binary PLY)"};
  std::string out = "assets";
  app.add_option("--out", out, "assets directory to write into");
  CLI11_PARSE(app, argc, argv);

  // The bin mesh is the default cell's bin (assets/cells/default.yaml).
  const bp::Result<bp::Cell> cell = bp::LoadDefaultCell();
  if (!cell.ok()) {
    std::fprintf(stderr, "bp_make_assets: %s\n", cell.status().ToString().c_str());
    return 1;
  }
  const bp::BinSpec& bin = cell->bin;

  const std::vector<std::pair<std::string, bp::TriangleMesh>> assets = {
      {"parts/flanged_bushing.ply", bp::MakeFlangedBushing()},
      {"parts/l_bracket.ply", bp::MakeLBracket()},
      {"parts/pipe_tee.ply", bp::MakePipeTee()},
      {"grippers/suction_cup.ply", bp::MakeSuctionGripper()},
      {"grippers/parallel_jaw.ply", bp::MakeParallelJawGripper()},
      {"bin/default_bin.ply", bp::MakeBinMesh(bin)},
      {"fixtures/place_nest.ply", bp::MakePlaceNest()},
  };
  for (const auto& [name, mesh] : assets) {
    const std::filesystem::path path = std::filesystem::path(out) / name;
    std::error_code ec;
    std::filesystem::create_directories(path.parent_path(), ec);
    if (const bp::Status s = bp::SaveMeshPly(mesh, path.string()); !s.ok()) {
      std::fprintf(stderr, "%s\n", s.ToString().c_str());
      return 1;
    }
    const Eigen::AlignedBox3f box = mesh.Bounds();
    std::printf("%-28s %6zu vertices %6zu triangles  bounds [%.4f %.4f %.4f]..[%.4f %.4f %.4f] m\n", name.c_str(),
                mesh.vertices.size(), mesh.triangles.size(), box.min().x(), box.min().y(), box.min().z(),
                box.max().x(), box.max().y(), box.max().z());
  }
  return 0;
}
