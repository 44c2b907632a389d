// A list of peer addresses allowed to connect or to change the cell
// (docs/reliability.md "Threat model"): exact IPv4 / IPv6 addresses or
// networks in CIDR notation ("192.168.10.21", "192.168.10.0/24",
// "fd00::/8"). IPv4-mapped IPv6 addresses (::ffff:a.b.c.d) are compared as
// IPv4, both in the list and in the peer. An empty list allows every peer.
//
// Thread-safety: immutable after Parse; Contains is const and safe
// concurrently.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "core/status.h"

namespace bp {

class AddressList {
 public:
  AddressList() = default;  // empty: every peer
  // @returns InvalidArgument naming the first entry that is neither an
  // address nor ADDR/PREFIX with PREFIX in 0..32 (IPv4) or 0..128 (IPv6).
  static Result<AddressList> Parse(const std::vector<std::string>& entries);
  // Whether `entry` parses (for validating a configuration key).
  static Status CheckEntry(const std::string& entry);

  bool empty() const { return networks_.empty(); }
  // Whether the peer address (text, as inet_ntop writes it) is listed; true
  // for an empty list; false for text that is not an address.
  bool Contains(const std::string& address) const;
  // The entries as given, joined by ", " (for log lines).
  std::string Describe() const;

 private:
  struct Network {
    std::array<uint8_t, 16> address{};  // IPv4 as ::ffff:a.b.c.d
    int prefix = 128;                   // significant leading bits of `address`
  };
  std::vector<Network> networks_;
  std::vector<std::string> entries_;
};

// Whether `address` (text) is a loopback address (127.0.0.0/8, ::1, or
// IPv4-mapped loopback).
bool IsLoopbackAddress(const std::string& address);

}  // namespace bp
