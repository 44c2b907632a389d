// PCD frames (pipeline/frame_io.h LoadFrameFile), with an optional intrinsics
// sidecar: input = [u16 sidecar length][sidecar JSON][PCD bytes].
#include "fuzz/fuzz_util.h"
#include "pipeline/frame_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const bp::fuzz::WithSidecar in = bp::fuzz::SplitSidecar(data, size);
  if (in.has_sidecar) {
    bp::fuzz::WriteScratch("f.intrinsics.json", in.sidecar);
  } else {
    bp::fuzz::RemoveScratch("f.intrinsics.json");
  }
  const std::string path = bp::fuzz::WriteScratch("f.pcd", in.data);
  (void)bp::LoadFrameFile(path);
  return 0;
}
