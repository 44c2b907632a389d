// PLY point-cloud frames (pipeline/frame_io.h LoadFrameFile, PCL's reader).
#include "fuzz/fuzz_util.h"
#include "pipeline/frame_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = bp::fuzz::WriteScratch(
      "p.ply", std::string_view(reinterpret_cast<const char*>(data), size));
  (void)bp::LoadFrameFile(path);
  return 0;
}
