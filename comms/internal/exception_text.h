// The text of the exception being handled, for the log lines of the places
// that contain exceptions (docs/reliability.md "Faults").
#pragma once

#include <exception>

namespace bp::internal {

// Call inside a catch block only; the pointer lives as long as the
// exception. Never throws.
inline const char* ExceptionText() noexcept {
  try {
    throw;
  } catch (const std::exception& e) {
    return e.what();
  } catch (...) {
    return "an exception that is not a std::exception";
  }
}

}  // namespace bp::internal
