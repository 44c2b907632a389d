#include "core/status.h"

#include <gtest/gtest.h>

#include <memory>
#include <string>

namespace bp {
namespace {

TEST(Status, DefaultIsOkWithEmptyMessage) {
  const Status s;
  EXPECT_TRUE(s.ok());
  EXPECT_EQ(s.code(), Status::Code::kOk);
  EXPECT_EQ(s.message(), "");
  EXPECT_EQ(s.ToString(), "OK");
  EXPECT_TRUE(Status::Ok().ok());
}

TEST(Status, FactoriesSetCodeMessageAndReadableString) {
  struct Case {
    Status s;
    Status::Code code;
    const char* text;
  };
  const Case cases[] = {
      {Status::InvalidArgument("m"), Status::Code::kInvalidArgument, "Invalid argument: m"},
      {Status::NotFound("m"), Status::Code::kNotFound, "Not found: m"},
      {Status::Corruption("m"), Status::Code::kCorruption, "Corruption: m"},
      {Status::OutOfRange("m"), Status::Code::kOutOfRange, "Out of range: m"},
      {Status::Unavailable("m"), Status::Code::kUnavailable, "Unavailable: m"},
      {Status::Internal("m"), Status::Code::kInternal, "Internal: m"},
  };
  for (const Case& c : cases) {
    EXPECT_FALSE(c.s.ok()) << c.text;
    EXPECT_EQ(c.s.code(), c.code) << c.text;
    EXPECT_EQ(c.s.message(), "m");
    EXPECT_EQ(c.s.ToString(), c.text);
  }
}

TEST(Result, HoldsAValueAndReportsOk) {
  Result<std::string> r = std::string("pose");
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(static_cast<bool>(r));
  EXPECT_TRUE(r.status().ok());
  EXPECT_EQ(*r, "pose");
  EXPECT_EQ(r->size(), 4u);
  r.value() += "s";
  EXPECT_EQ(r.value(), "poses");
}

TEST(Result, HoldsAnErrorStatus) {
  const Result<int> r = Status::NotFound("no part");
  EXPECT_FALSE(r.ok());
  EXPECT_FALSE(static_cast<bool>(r));
  EXPECT_EQ(r.status().code(), Status::Code::kNotFound);
  EXPECT_EQ(r.status().message(), "no part");
}

TEST(Result, MovesOutMoveOnlyValues) {
  Result<std::unique_ptr<int>> r = std::make_unique<int>(7);
  ASSERT_TRUE(r.ok());
  std::unique_ptr<int> p = std::move(r).value();
  ASSERT_NE(p, nullptr);
  EXPECT_EQ(*p, 7);
}

}  // namespace
}  // namespace bp
