// Float to int conversions for the per-point loops, without the libm calls
// or the long inline sequences baseline x86-64 (no SSE4.1 round) gives
// std::floor.
#pragma once

namespace bp::internal {

// floor(f) as an int, for finite f in int range (as static_cast<int>(std::floor(f))):
// truncate towards zero, then one down for a negative fraction.
inline int FloorToInt(float f) {
  const int i = static_cast<int>(f);
  return i - (f < static_cast<float>(i) ? 1 : 0);
}

}  // namespace bp::internal
