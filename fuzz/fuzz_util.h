// Helpers shared by the libFuzzer targets (fuzz/README.md).
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <string_view>

namespace bp::fuzz {

// A per-process scratch directory (tmpfs when there is one): the file loaders
// take paths, so each input is written to a file first.
inline const std::string& ScratchDir() {
  static const std::string dir = [] {
    const char* base = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
    std::string d = std::string(base) + "/bp_fuzz_" + std::to_string(getpid());
    std::string cmd = "mkdir -p '" + d + "'";
    if (std::system(cmd.c_str()) != 0) std::abort();
    return d;
  }();
  return dir;
}

inline std::string WriteScratch(const std::string& name, std::string_view bytes) {
  const std::string path = ScratchDir() + "/" + name;
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!out) std::abort();
  return path;
}

inline void RemoveScratch(const std::string& name) {
  std::remove((ScratchDir() + "/" + name).c_str());
}

// Inputs that carry an intrinsics sidecar: [u16 little-endian sidecar
// length][sidecar JSON][data file]. Length 0: no sidecar file.
struct WithSidecar {
  std::string_view sidecar;
  std::string_view data;
  bool has_sidecar = false;
};

inline WithSidecar SplitSidecar(const uint8_t* data, size_t size) {
  WithSidecar out;
  if (size < 2) {
    out.data = std::string_view(reinterpret_cast<const char*>(data), size);
    return out;
  }
  size_t len = static_cast<size_t>(data[0]) | (static_cast<size_t>(data[1]) << 8);
  if (len > size - 2) len = size - 2;
  const char* p = reinterpret_cast<const char*>(data) + 2;
  out.has_sidecar = len > 0;
  out.sidecar = std::string_view(p, len);
  out.data = std::string_view(p + len, size - 2 - len);
  return out;
}

}  // namespace bp::fuzz
