#include "core/address_list.h"

#include <arpa/inet.h>

#include <cstdlib>

namespace bp {
namespace {

// Parses an address into 16 bytes, IPv4 as IPv4-mapped IPv6. @returns the
// number of bits of the family as written (32 or 128), 0 when not an address.
int ParseAddress(const std::string& text, std::array<uint8_t, 16>& out) {
  in_addr v4{};
  if (inet_pton(AF_INET, text.c_str(), &v4) == 1) {
    out = {};
    out[10] = out[11] = 0xff;
    const auto* b = reinterpret_cast<const uint8_t*>(&v4.s_addr);
    for (int i = 0; i < 4; ++i) out[12 + i] = b[i];
    return 32;
  }
  in6_addr v6{};
  if (inet_pton(AF_INET6, text.c_str(), &v6) == 1) {
    for (int i = 0; i < 16; ++i) out[static_cast<size_t>(i)] = v6.s6_addr[i];
    return 128;
  }
  return 0;
}

bool IsV4Mapped(const std::array<uint8_t, 16>& a) {
  for (int i = 0; i < 10; ++i) {
    if (a[static_cast<size_t>(i)] != 0) return false;
  }
  return a[10] == 0xff && a[11] == 0xff;
}

Result<std::pair<std::array<uint8_t, 16>, int>> ParseEntry(const std::string& entry) {
  const size_t slash = entry.find('/');
  std::array<uint8_t, 16> address{};
  const int bits = ParseAddress(entry.substr(0, slash), address);
  if (bits == 0) {
    return Status::InvalidArgument("'" + entry + "' is not an IP address or ADDR/PREFIX network");
  }
  // An IPv4-mapped IPv6 entry counts as IPv4.
  const int family_bits = bits == 128 && IsV4Mapped(address) ? 32 : bits;
  int prefix = family_bits;
  if (slash != std::string::npos) {
    const std::string p = entry.substr(slash + 1);
    char* end = nullptr;
    const long v = p.empty() ? -1 : std::strtol(p.c_str(), &end, 10);
    if (p.empty() || *end != '\0' || v < 0 || v > family_bits) {
      return Status::InvalidArgument("'" + entry + "': the prefix length must be 0.." +
                                     std::to_string(family_bits));
    }
    prefix = static_cast<int>(v);
  }
  // Stored in 128-bit space: an IPv4 prefix follows the 96 mapping bits.
  return std::make_pair(address, family_bits == 32 ? 96 + prefix : prefix);
}

bool Matches(const std::array<uint8_t, 16>& network, int prefix, const std::array<uint8_t, 16>& a) {
  for (int bit = 0; bit < prefix; ++bit) {
    const size_t byte = static_cast<size_t>(bit / 8);
    const uint8_t mask = static_cast<uint8_t>(0x80u >> (bit % 8));
    if ((network[byte] & mask) != (a[byte] & mask)) return false;
  }
  return true;
}

}  // namespace

Status AddressList::CheckEntry(const std::string& entry) { return ParseEntry(entry).status(); }

Result<AddressList> AddressList::Parse(const std::vector<std::string>& entries) {
  AddressList list;
  for (const std::string& e : entries) {
    Result<std::pair<std::array<uint8_t, 16>, int>> parsed = ParseEntry(e);
    if (!parsed.ok()) return parsed.status();
    list.networks_.push_back(Network{parsed->first, parsed->second});
    list.entries_.push_back(e);
  }
  return list;
}

bool AddressList::Contains(const std::string& address) const {
  if (networks_.empty()) return true;
  std::array<uint8_t, 16> a{};
  if (ParseAddress(address, a) == 0) return false;
  for (const Network& n : networks_) {
    if (Matches(n.address, n.prefix, a)) return true;
  }
  return false;
}

std::string AddressList::Describe() const {
  std::string out;
  for (const std::string& e : entries_) out += (out.empty() ? "" : ", ") + e;
  return out;
}

bool IsLoopbackAddress(const std::string& address) {
  std::array<uint8_t, 16> a{};
  const int bits = ParseAddress(address, a);
  if (bits == 0) return false;
  if (IsV4Mapped(a)) return a[12] == 127;
  std::array<uint8_t, 16> one{};
  one[15] = 1;
  return a == one;
}

}  // namespace bp
