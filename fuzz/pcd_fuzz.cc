// PCD frames (pipeline/frame_io.h LoadFrameFile), with an optional intrinsics
// sidecar: input = [u16 sidecar length][sidecar JSON][PCD bytes].
#include "fuzz/fuzz_util.h"
#include "pipeline/cloud_projection.h"
#include "pipeline/frame_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const bp::fuzz::WithSidecar in = bp::fuzz::SplitSidecar(data, size);
  if (in.has_sidecar) {
    bp::fuzz::WriteScratch("f.intrinsics.json", in.sidecar);
  } else {
    bp::fuzz::RemoveScratch("f.intrinsics.json");
  }
  const std::string path = bp::fuzz::WriteScratch("f.pcd", in.data);
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
