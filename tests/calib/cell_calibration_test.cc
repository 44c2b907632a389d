// The cell's calibration section: defaults, strict validation with the key
// named, and the default result file next to the cell.
#include <gtest/gtest.h>

#include <string>

#include "core/cell.h"
#include "tests/testing/files.h"

namespace bp {
namespace {

std::string DefaultYaml() {
  return testing::ReadBytes(std::string(BINPICK_SOURCE_DIR) + "/assets/cells/default.yaml");
}
const std::string kPath = std::string(BINPICK_SOURCE_DIR) + "/assets/cells/default.yaml";

// The default cell with its calibration target line replaced.
Result<Cell> WithTarget(const std::string& target) {
  std::string yaml = DefaultYaml();
  const size_t at = yaml.find("  target: {type: checkerboard");
  const size_t end = yaml.find('\n', at);
  yaml.replace(at, end - at, "  target: " + target);
  return ParseCell(yaml, kPath);
}

TEST(CellCalibration, DefaultCellHasTheSection) {
  Result<Cell> cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  ASSERT_TRUE(cell->calibration.has_value());
  EXPECT_EQ(cell->calibration->cols, 9);
  EXPECT_EQ(cell->calibration->rows, 6);
  EXPECT_DOUBLE_EQ(cell->calibration->square_size, 0.018);
  EXPECT_EQ(cell->calibration->auto_poses, 12);
  // The embedded default has no file to write next to.
  EXPECT_TRUE(cell->camera.hand_eye_file.empty());
}

TEST(CellCalibration, ResultFileDefaultsToTheCellsName) {
  // (Relative asset paths resolve next to the cell: keep it in assets/cells.)
  const std::string path = std::string(BINPICK_SOURCE_DIR) + "/assets/cells/no_such_cell.yaml";
  Result<Cell> cell = ParseCell(DefaultYaml(), path);
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->camera.hand_eye_file, path + ".calibration.yaml");
}

TEST(CellCalibration, TrueTransformDefaultsToTheNominalPose) {
  std::string yaml = DefaultYaml();
  const size_t at = yaml.find("  true_pose:");
  yaml.erase(at, yaml.find('\n', at) - at + 1);
  Result<Cell> cell = ParseCell(yaml, kPath);
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_TRUE(cell->calibration->true_pose.isApprox(cell->camera.X_BC));
}

TEST(CellCalibration, BadValuesNameTheKey) {
  struct Case {
    std::string target;
    std::string message;
  };
  const Case cases[] = {
      {"{type: checkerboard, squares: [8, 6], square_size: 0.02}", "calibration.target.squares"},
      {"{type: checkerboard, squares: [9], square_size: 0.02}", "calibration.target.squares"},
      {"{type: charuco, squares: [9, 6], square_size: 0.02}", "unknown calibration target 'charuco'"},
      {"{type: checkerboard, squares: [9, 6], square_size: 0}", "calibration.target.square_size"},
      {"{type: checkerboard, squares: [9, 6]}", "calibration.target.square_size: missing required key"},
      {"{type: checkerboard, squares: [9, 6], square_size: 0.02, colour: red}", "colour"},
  };
  for (const Case& c : cases) {
    Result<Cell> cell = WithTarget(c.target);
    ASSERT_FALSE(cell.ok()) << c.target;
    EXPECT_EQ(cell.status().code(), Status::Code::kInvalidArgument) << c.target;
    EXPECT_NE(cell.status().message().find(c.message), std::string::npos) << cell.status().message();
  }
  std::string yaml = DefaultYaml();
  const size_t at = yaml.find("  auto_poses: 12");
  yaml.replace(at, 16, "  auto_poses: 16");
  Result<Cell> cell = ParseCell(yaml, kPath);
  ASSERT_FALSE(cell.ok());
  EXPECT_NE(cell.status().message().find("calibration.auto_poses: must be within min_poses..15"), std::string::npos)
      << cell.status().message();
}

}  // namespace
}  // namespace bp
