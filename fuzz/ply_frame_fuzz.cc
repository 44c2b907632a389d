// PLY point-cloud frames (pipeline/frame_io.h LoadFrameFile, PCL's reader).
#include "fuzz/fuzz_util.h"
#include "pipeline/cloud_projection.h"
#include "pipeline/frame_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = bp::fuzz::WriteScratch(
      "p.ply", std::string_view(reinterpret_cast<const char*>(data), size));
  // An unorganized cloud goes on to ProjectCloud, as the file source sends
  // it to perception, from its own frame and from the assumed view.
  const bp::Result<bp::Frame> frame = bp::LoadFrameFile(path);
  if (frame.ok() && !frame->organized()) {
    static const bp::Cell cell{};
    (void)bp::ProjectCloud(*frame, cell, true);
    (void)bp::ProjectCloud(*frame, cell, false);
  }
  return 0;
}
