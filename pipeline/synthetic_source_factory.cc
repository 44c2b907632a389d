// MakeSyntheticSource(const Cell&): loads the meshes the cell names. Kept in
// its own translation unit so that code building sources from in-memory
// meshes (SyntheticSource::Create) does not link the mesh loaders.
#include <memory>
#include <utility>

#include <Eigen/Geometry>  // core/mesh.h uses AlignedBox3f without including it

#include "core/mesh.h"
#include "pipeline/synthetic_source.h"

namespace bp {

namespace {

// Open bin in W (origin at the centre of the inner floor surface): a floor
// slab under z = 0 and four walls up to the inner height. Overlapping closed
// boxes are fine for rendering and for FCL.
// TODO(synth): use MakeBinMesh (core/mesh_gen.h) once it is on main.
TriangleMesh OpenBinMesh(const BinSpec& bin) {
  TriangleMesh m;
  auto box = [&m](const Eigen::Vector3f& size, const Eigen::Vector3f& c) {
    const int base = static_cast<int>(m.vertices.size());
    const Eigen::Vector3f h = size / 2;
    for (int i = 0; i < 8; ++i) {
      m.vertices.push_back(c + Eigen::Vector3f((i & 1) ? h.x() : -h.x(), (i & 2) ? h.y() : -h.y(),
                                               (i & 4) ? h.z() : -h.z()));
    }
    static const int f[12][3] = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
    for (const auto& t : f) m.triangles.emplace_back(base + t[0], base + t[1], base + t[2]);
  };
  const float X = static_cast<float>(bin.inner_size.x()), Y = static_cast<float>(bin.inner_size.y());
  const float Z = static_cast<float>(bin.inner_size.z()), t = static_cast<float>(bin.wall_thickness);
  box({X + 2 * t, Y + 2 * t, t}, {0, 0, -t / 2});
  box({t, Y + 2 * t, Z}, {X / 2 + t / 2, 0, Z / 2});
  box({t, Y + 2 * t, Z}, {-X / 2 - t / 2, 0, Z / 2});
  box({X, t, Z}, {0, Y / 2 + t / 2, Z / 2});
  box({X, t, Z}, {0, -Y / 2 - t / 2, Z / 2});
  return m;
}

}  // namespace

Result<std::unique_ptr<CaptureSource>> MakeSyntheticSource(const Cell& cell) {
  std::vector<PileClass> classes;
  for (const auto& part : cell.parts) {
    auto mesh = LoadMesh(part.mesh);
    if (!mesh.ok()) {
      return Status(mesh.status().code() == Status::Code::kNotFound
                        ? Status::NotFound("synthetic source: part " + part.name + ": " + mesh.status().message())
                        : Status::Corruption("synthetic source: part " + part.name + ": " + mesh.status().message()));
    }
    classes.push_back({part.class_id, part.name, std::make_shared<TriangleMesh>(std::move(*mesh))});
  }
  TriangleMesh bin_mesh;
  if (!cell.bin.mesh.empty()) {
    auto loaded = LoadMesh(cell.bin.mesh);
    if (!loaded.ok()) return Status::NotFound("synthetic source: bin mesh: " + loaded.status().message());
    bin_mesh = std::move(*loaded);
  } else {
    bin_mesh = OpenBinMesh(cell.bin);
  }
  auto source = SyntheticSource::Create(cell, std::move(classes), bin_mesh);
  if (!source.ok()) return source.status();
  return std::unique_ptr<CaptureSource>(std::move(*source));
}

}  // namespace bp
