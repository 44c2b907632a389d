// The shipped default cell (assets/), loaded once per test binary: the
// cell the grasp and projection tests build their scenes in.
#pragma once

#include <gtest/gtest.h>

#include "core/cell.h"

namespace bp::testing {

// A failed load is a test failure, not a crash: the cell is then empty.
inline const Cell& DefaultCell() {
  static const Cell cell = [] {
    Result<Cell> c = LoadDefaultCell();
    EXPECT_TRUE(c.ok()) << c.status().ToString();
    return c.ok() ? *c : Cell{};
  }();
  return cell;
}

}  // namespace bp::testing
