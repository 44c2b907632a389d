#include "core/address_list.h"

#include <gtest/gtest.h>

#include <random>
#include <string>

namespace bp {
namespace {

AddressList List(const std::vector<std::string>& entries) {
  Result<AddressList> l = AddressList::Parse(entries);
  EXPECT_TRUE(l.ok()) << l.status().ToString();
  return l.ok() ? *l : AddressList{};
}

TEST(AddressList, EmptyAllowsEveryPeer) {
  const AddressList any;
  EXPECT_TRUE(any.empty());
  EXPECT_TRUE(any.Contains("10.1.2.3"));
  EXPECT_TRUE(any.Contains("::1"));
}

TEST(AddressList, ExactAddressesAndNetworksInCidrNotation) {
  const AddressList l = List({"192.168.10.21", "10.0.0.0/8", "fd00:1::/32", "::1"});
  EXPECT_TRUE(l.Contains("192.168.10.21"));
  EXPECT_FALSE(l.Contains("192.168.10.22"));
  EXPECT_TRUE(l.Contains("10.255.0.7"));
  EXPECT_FALSE(l.Contains("11.0.0.1"));
  EXPECT_TRUE(l.Contains("fd00:1:ffff::5"));
  EXPECT_FALSE(l.Contains("fd00:2::5"));
  EXPECT_TRUE(l.Contains("::1"));
  EXPECT_FALSE(l.Contains("127.0.0.1"));
  // IPv4-mapped IPv6 peers (a dual-stack listener) are compared as IPv4.
  EXPECT_TRUE(l.Contains("::ffff:10.3.4.5"));
  EXPECT_TRUE(List({"::ffff:192.168.1.0/24"}).Contains("192.168.1.9"));
  EXPECT_FALSE(l.Contains("not an address"));
  EXPECT_EQ(l.Describe(), "192.168.10.21, 10.0.0.0/8, fd00:1::/32, ::1");
}

// Property: for random addresses and prefix lengths, an address is in the
// network made of its own first bits, and flipping a bit inside the prefix
// takes it out while flipping one after the prefix does not.
TEST(AddressList, NetworkMembershipFollowsThePrefixBitsOnRandomAddresses) {
  std::mt19937 rng{39};
  for (int trial = 0; trial < 2000; ++trial) {
    uint32_t a = rng();
    const int prefix = static_cast<int>(rng() % 33);
    auto text = [](uint32_t v) {
      return std::to_string(v >> 24) + "." + std::to_string((v >> 16) & 255) + "." +
             std::to_string((v >> 8) & 255) + "." + std::to_string(v & 255);
    };
    const AddressList l = List({text(a) + "/" + std::to_string(prefix)});
    ASSERT_TRUE(l.Contains(text(a)));
    if (prefix > 0) {
      const int inside = static_cast<int>(rng() % static_cast<uint32_t>(prefix));
      EXPECT_FALSE(l.Contains(text(a ^ (0x80000000u >> inside)))) << text(a) << "/" << prefix;
    }
    if (prefix < 32) {
      const int outside = prefix + static_cast<int>(rng() % static_cast<uint32_t>(32 - prefix));
      EXPECT_TRUE(l.Contains(text(a ^ (0x80000000u >> outside)))) << text(a) << "/" << prefix;
    }
  }
}

TEST(AddressList, BadEntriesAreRefusedNamingThem) {
  for (const std::string bad : {"192.168.1.300", "10.0.0.0/33", "10.0.0.0/", "10.0.0.0/-1",
                                "10.0.0.0/8x", "::1/129", "robot.local", ""}) {
    const Result<AddressList> l = AddressList::Parse({"127.0.0.1", bad});
    ASSERT_FALSE(l.ok()) << bad;
    EXPECT_EQ(l.status().code(), Status::Code::kInvalidArgument);
    EXPECT_NE(l.status().message().find("'" + bad + "'"), std::string::npos) << l.status().message();
  }
}

TEST(AddressList, LoopbackAddresses) {
  EXPECT_TRUE(IsLoopbackAddress("127.0.0.1"));
  EXPECT_TRUE(IsLoopbackAddress("127.4.5.6"));
  EXPECT_TRUE(IsLoopbackAddress("::1"));
  EXPECT_TRUE(IsLoopbackAddress("::ffff:127.0.0.1"));
  EXPECT_FALSE(IsLoopbackAddress("0.0.0.0"));
  EXPECT_FALSE(IsLoopbackAddress("::"));
  EXPECT_FALSE(IsLoopbackAddress("192.168.10.5"));
}

}  // namespace
}  // namespace bp
