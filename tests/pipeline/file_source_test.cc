#include "pipeline/file_source.h"

#include <filesystem>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "pipeline/capture_source.h"
#include "pipeline/frame_io.h"
#include "test_frames.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using testing::FreshDir;
using testing::PlaneWithBox;
using testing::WriteText;

Cell FilesCell(const std::string& dir) {
  Cell cell;
  cell.path = "test.yaml";
  cell.source.kind = SourceSpec::Kind::kFiles;
  cell.source.dir = dir;
  cell.camera.X_BC = MakePose(Mat3::Identity(), Vec3(0.5, 0.0, 1.2));
  return cell;
}

std::string Name(const Frame& f) { return fs::path(f.source).filename().string(); }

TEST(FileSource, ServesFrameFilesInNameOrderAndWrapsAround) {
  const std::string dir = FreshDir("frames");
  const Frame f = PlaneWithBox();
  ASSERT_TRUE(WriteDepthPng(f, dir + "/b_depth.png").ok());
  ASSERT_TRUE(WriteCloudPcd(f, dir + "/a_cloud.pcd").ok());
  WriteText(dir + "/c.ply",
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
            "end_header\n0 0 1\n");
  // Companions and other files are not frames.
  ASSERT_TRUE(WriteIntensityPng(f, dir + "/b_intensity.png").ok());
  ASSERT_TRUE(WriteGroundTruthJson(f, dir + "/b_truth.json").ok());
  WriteText(dir + "/notes.txt", "hello");
  auto source = MakeFileSource(dir, FilesCell(dir));
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  std::vector<std::string> names;
  for (int i = 0; i < 4; ++i) {
    Result<Frame> frame = (*source)->Capture({});
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    names.push_back(Name(*frame));
  }
  EXPECT_THAT(names, ::testing::ElementsAre("a_cloud.pcd", "b_depth.png", "c.ply", "a_cloud.pcd"));
  EXPECT_THAT((*source)->Describe(), HasSubstr("3 files"));
}

TEST(FileSource, FrameFileNamesAreCloudsAndDepthPngsOnly) {
  EXPECT_TRUE(IsFrameFileName("cloud.pcd"));
  EXPECT_TRUE(IsFrameFileName("SCAN.PLY"));
  EXPECT_TRUE(IsFrameFileName("depth.png"));
  EXPECT_TRUE(IsFrameFileName("f001_Depth.png"));
  EXPECT_FALSE(IsFrameFileName("intensity.png"));
  EXPECT_FALSE(IsFrameFileName("labels.png"));
  EXPECT_FALSE(IsFrameFileName("truth.json"));
  EXPECT_FALSE(IsFrameFileName("depth.intrinsics.json"));
}

TEST(FileSource, SidecarPoseWinsOverTheCellCamera) {
  const std::string dir = FreshDir("frames");
  Frame f = PlaneWithBox();
  ASSERT_TRUE(WriteCloudPcd(f, dir + "/with_sidecar.pcd").ok());
  f.intrinsics = Intrinsics{};  // unorganized copy, then drop its sidecar
  f.points_C = {Eigen::Vector3f(0, 0, 1)};
  ASSERT_TRUE(WriteCloudPcd(f, dir + "/without_sidecar.pcd").ok());
  fs::remove(dir + "/without_sidecar.intrinsics.json");
  const Cell cell = FilesCell(dir);
  auto source = MakeFileSource(dir, cell);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  Result<Frame> a = (*source)->Capture({});
  Result<Frame> b = (*source)->Capture({});
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(Name(*a), "with_sidecar.pcd");
  EXPECT_TRUE(a->X_BC.matrix() == PlaneWithBox().X_BC.matrix());
  // Without a sidecar the point is where the cell's camera puts it; the
  // cloud is served organized, seen from above the bin.
  ASSERT_TRUE(b->organized());
  const std::vector<Eigen::Vector3f> p_V = b->PointsInCamera();
  ASSERT_EQ(p_V.size(), 1u);
  EXPECT_TRUE((b->X_BC * p_V[0].cast<double>()).isApprox(cell.camera.X_BC * Vec3(0, 0, 1), 1e-6));
  EXPECT_GT(b->timestamp_ns, 0);
}

TEST(FileSource, EyeInHandWithoutSidecarUsesFlangePose) {
  const std::string dir = FreshDir("frames");
  WriteText(dir + "/p.ply",
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
            "end_header\n0 0 1\n");
  Cell cell = FilesCell(dir);
  cell.camera.eye_in_hand = true;
  cell.camera.X_FC = MakePose(Mat3::Identity(), Vec3(0, 0.05, 0.1));
  auto source = MakeFileSource(dir + "/p.ply", cell);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  CaptureRequest request;
  request.X_BF = MakePose(Mat3::Identity(), Vec3(0.4, 0, 0.8));
  Result<Frame> frame = (*source)->Capture(request);
  ASSERT_TRUE(frame.ok()) << frame.status().ToString();
  const std::vector<Eigen::Vector3f> p_V = frame->PointsInCamera();
  ASSERT_EQ(p_V.size(), 1u);
  EXPECT_TRUE((frame->X_BC * p_V[0].cast<double>()).isApprox(Vec3(0.4, 0.05, 1.9), 1e-6));
}

TEST(FileSource, BadFileReportsItsNameAndTheNextCaptureMovesOn) {
  const std::string dir = FreshDir("frames");
  WriteText(dir + "/a_bad.pcd", "garbage");
  ASSERT_TRUE(WriteCloudPcd(PlaneWithBox(), dir + "/b_cloud.pcd").ok());
  auto source = MakeFileSource(dir, FilesCell(dir));
  ASSERT_TRUE(source.ok());
  Result<Frame> bad = (*source)->Capture({});
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.status().message(), HasSubstr("a_bad.pcd"));
  Result<Frame> good = (*source)->Capture({});
  ASSERT_TRUE(good.ok()) << good.status().ToString();
  EXPECT_EQ(Name(*good), "b_cloud.pcd");
}

TEST(FileSource, DirectoryWithoutFrameFilesIsNotFound) {
  const std::string dir = FreshDir("frames");
  WriteText(dir + "/readme.txt", "nothing");
  auto source = MakeFileSource(dir, FilesCell(dir));
  EXPECT_EQ(source.status().code(), Status::Code::kNotFound);
  EXPECT_THAT(source.status().message(), HasSubstr(dir));
  EXPECT_EQ(MakeFileSource(dir + "/missing", FilesCell(dir)).status().code(), Status::Code::kNotFound);
}

TEST(MakeCaptureSource, DispatchesOnSourceKind) {
  const std::string dir = FreshDir("frames");
  ASSERT_TRUE(WriteCloudPcd(PlaneWithBox(), dir + "/cloud.pcd").ok());
  Cell cell = FilesCell(dir);
  auto files = MakeCaptureSource(cell);
  ASSERT_TRUE(files.ok()) << files.status().ToString();
  EXPECT_THAT((*files)->Describe(), HasSubstr("files"));
  cell.source.kind = SourceSpec::Kind::kReplay;  // not a recorded session: served as files
  auto replay = MakeCaptureSource(cell);
  ASSERT_TRUE(replay.ok()) << replay.status().ToString();
  EXPECT_THAT((*replay)->Describe(), HasSubstr("files"));
  cell.source.kind = SourceSpec::Kind::kFiles;
  cell.source.dir.clear();
  EXPECT_EQ(MakeCaptureSource(cell).status().code(), Status::Code::kInvalidArgument);
}

}  // namespace
}  // namespace bp
