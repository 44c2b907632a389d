// MakeSyntheticSource(const Cell&): loads the meshes the cell names. Kept in
// its own translation unit so that code building sources from in-memory
// meshes (SyntheticSource::Create) does not link the mesh loaders.
#include <memory>
#include <utility>

#include "core/mesh.h"
#include "core/mesh_gen.h"
#include "pipeline/synthetic_source.h"

namespace bp {

Result<std::unique_ptr<CaptureSource>> MakeSyntheticSource(const Cell& cell, HandEyeProvider hand_eye) {
  std::vector<PileClass> classes;
  for (const auto& part : cell.parts) {
    auto mesh = LoadMesh(part.mesh);
    if (!mesh.ok()) {
      return Status(mesh.status().code() == Status::Code::kNotFound
                        ? Status::NotFound("synthetic source: part " + part.name + ": " +
                                           mesh.status().message())
                        : Status::Corruption("synthetic source: part " + part.name + ": " +
                                             mesh.status().message()));
    }
    classes.push_back({part.class_id, part.name, std::make_shared<TriangleMesh>(std::move(*mesh))});
  }
  TriangleMesh bin_mesh;
  if (!cell.bin.mesh.empty()) {
    auto loaded = LoadMesh(cell.bin.mesh);
    if (!loaded.ok())
      return Status::NotFound("synthetic source: bin mesh: " + loaded.status().message());
    bin_mesh = std::move(*loaded);
  } else {
    bin_mesh = MakeBinMesh(cell.bin);
  }
  // Gripper and fixture meshes only matter to in-hand and fixture views: one
  // that does not load is left out (those views then fail naming it).
  SceneMeshes scene;
  for (const GripperSpec& g : cell.grippers) {
    if (auto mesh = LoadMesh(g.mesh); mesh.ok()) scene.grippers[g.name] = std::make_shared<TriangleMesh>(std::move(*mesh));
  }
  for (const FixtureSpec& f : cell.fixtures) {
    if (auto mesh = LoadMesh(f.mesh); mesh.ok()) scene.fixtures[f.name] = std::make_shared<TriangleMesh>(std::move(*mesh));
  }
  auto source =
      SyntheticSource::Create(cell, std::move(classes), bin_mesh, std::move(hand_eye), std::move(scene));
  if (!source.ok()) return source.status();
  return std::unique_ptr<CaptureSource>(std::move(*source));
}

}  // namespace bp
