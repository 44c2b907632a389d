#include "fuzz/gri_fuzz.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  bp::fuzz::CheckGri(bp::gri::Format::kV2, data, size);
  return 0;
}
