// 16-bit depth PNG frames and their intrinsics sidecar (pipeline/frame_io.h
// LoadFrameFile): input = [u16 sidecar length][sidecar JSON][PNG bytes].
#include "fuzz/fuzz_util.h"
#include "pipeline/frame_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const bp::fuzz::WithSidecar in = bp::fuzz::SplitSidecar(data, size);
  if (in.has_sidecar) {
    bp::fuzz::WriteScratch("d.intrinsics.json", in.sidecar);
  } else {
    bp::fuzz::RemoveScratch("d.intrinsics.json");
  }
  const std::string path = bp::fuzz::WriteScratch("d.png", in.data);
  (void)bp::LoadFrameFile(path);
  return 0;
}
