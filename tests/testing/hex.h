// TEST HELPER. Golden byte vectors written as hex text: "0000FA43 02" ->
// {0x00, 0x00, 0xFA, 0x43, 0x02}. Whitespace and any non-hex characters are
// ignored, so vectors can be laid out field by field.
#pragma once

#include <cctype>
#include <cstdint>
#include <string>
#include <vector>

namespace bp::testing {

inline std::vector<uint8_t> FromHex(const std::string& hex) {
  std::vector<uint8_t> out;
  std::string digits;
  for (char c : hex) {
    if (std::isxdigit(static_cast<unsigned char>(c))) digits += c;
  }
  for (size_t i = 0; i + 1 < digits.size(); i += 2) {
    out.push_back(static_cast<uint8_t>(std::stoi(digits.substr(i, 2), nullptr, 16)));
  }
  return out;
}

}  // namespace bp::testing
