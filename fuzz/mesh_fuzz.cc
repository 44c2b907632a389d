// Meshes (core/mesh.h LoadMesh): PLY when the first byte is 'p', STL
// otherwise (ASCII "solid" or binary).
#include "core/mesh.h"
#include "fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  const bool ply = size > 0 && data[0] == 'p';
  const std::string path = bp::fuzz::WriteScratch(ply ? "m.ply" : "m.stl", bytes);
  bp::Result<bp::TriangleMesh> mesh = bp::LoadMesh(path);
  if (mesh.ok()) {
    (void)mesh->Area();
    if (mesh->vertices.size() < 2000) (void)mesh->Diameter();
  }
  return 0;
}
