// The cell file parser (core/cell.h): any text is a cell or an error.
#include <cstdint>
#include <string>

#include "core/cell.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  bp::Result<bp::Cell> cell = bp::ParseCell(text, "fuzz.yaml");
  if (cell.ok()) (void)bp::Describe(*cell);
  return 0;
}
