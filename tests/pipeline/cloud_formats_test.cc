// Point clouds as other tools write them (issue 46): PCL's writers in every
// PCD encoding and PLY, double-precision coordinates (Open3D's default PLY),
// extra fields, organized clouds with NaN holes and a VIEWPOINT, millimetre
// clouds with a declared unit; and the errors, which name the format and
// the field.
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include "pipeline/frame_io.h"
#include "test_frames.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using testing::FreshDir;
using testing::WriteText;

// A seeded cloud a camera could see (0.8 to 1.1 m ahead), with colour,
// normals and curvature, as PCL tools carry them.
pcl::PointCloud<pcl::PointXYZRGBNormal> SomeCloud(size_t n = 200) {
  std::mt19937 rng{46};
  std::uniform_real_distribution<float> xy(-0.3f, 0.3f), z(0.8f, 1.1f), unit(-1.f, 1.f);
  pcl::PointCloud<pcl::PointXYZRGBNormal> cloud;
  for (size_t i = 0; i < n; ++i) {
    pcl::PointXYZRGBNormal p;
    p.x = xy(rng);
    p.y = xy(rng);
    p.z = z(rng);
    p.r = static_cast<uint8_t>(i);
    p.g = 7;
    p.b = 200;
    p.normal_x = unit(rng);
    p.normal_y = unit(rng);
    p.normal_z = -1.f;
    p.curvature = 0.01f;
    cloud.push_back(p);
  }
  return cloud;
}

void ExpectSamePoints(const pcl::PointCloud<pcl::PointXYZRGBNormal>& cloud, const Frame& frame, float tol) {
  ASSERT_EQ(frame.points_C.size(), cloud.size());
  for (size_t i = 0; i < cloud.size(); ++i) {
    EXPECT_NEAR(frame.points_C[i].x(), cloud[i].x, tol) << i;
    EXPECT_NEAR(frame.points_C[i].y(), cloud[i].y, tol) << i;
    EXPECT_NEAR(frame.points_C[i].z(), cloud[i].z, tol) << i;
  }
}

TEST(CloudFormats, PclWritersInEveryEncodingLoadTheSamePointsAndListTheExtraFields) {
  const std::string dir = FreshDir("out");
  const auto cloud = SomeCloud();
  ASSERT_EQ(pcl::io::savePCDFileASCII(dir + "/ascii.pcd", cloud), 0);
  ASSERT_EQ(pcl::io::savePCDFileBinary(dir + "/binary.pcd", cloud), 0);
  ASSERT_EQ(pcl::io::savePCDFileBinaryCompressed(dir + "/compressed.pcd", cloud), 0);
  ASSERT_EQ(pcl::io::savePLYFileBinary(dir + "/binary.ply", cloud), 0);
  ASSERT_EQ(pcl::io::savePLYFileASCII(dir + "/ascii.ply", cloud), 0);
  const std::vector<std::pair<std::string, std::string>> files = {
      {"ascii.pcd", "ascii"}, {"binary.pcd", "binary"}, {"compressed.pcd", "binary_compressed"},
      {"binary.ply", "binary_little_endian"}, {"ascii.ply", "ascii"}};
  for (const auto& [name, encoding] : files) {
    FrameFileInfo info;
    Result<Frame> frame = LoadFrameFile(dir + "/" + name, Pose::Identity(), &info);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    EXPECT_FALSE(frame->organized()) << name;
    // ascii: PCL prints 8 significant digits.
    ExpectSamePoints(cloud, *frame, encoding == "ascii" ? 1e-6f : 0.f);
    EXPECT_EQ(info.encoding, encoding) << name;
    EXPECT_EQ(info.coordinates, "float32") << name;
    // As each file names them: PCL writes nx and red green blue into a PLY.
    if (name.find(".pcd") != std::string::npos) {
      EXPECT_THAT(info.extra_fields, ElementsAre("rgb", "normal_x", "normal_y", "normal_z", "curvature")) << name;
    } else {
      EXPECT_THAT(info.extra_fields, ElementsAre("red", "green", "blue", "nx", "ny", "nz", "curvature")) << name;
    }
    EXPECT_EQ(info.unit, "m");
    EXPECT_FALSE(info.unit_declared);
  }
}

// Open3D's default PLY: binary, double x y z and normals, uchar colours.
std::string Open3dStylePly(const std::vector<Eigen::Vector3d>& points) {
  std::string bytes =
      "ply\nformat binary_little_endian 1.0\ncomment Created by Open3D\nelement vertex " +
      std::to_string(points.size()) +
      "\nproperty double x\nproperty double y\nproperty double z\nproperty double nx\nproperty double ny\n"
      "property double nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n";
  for (const Eigen::Vector3d& p : points) {
    const double v[6] = {p.x(), p.y(), p.z(), 0.0, 0.0, -1.0};
    bytes.append(reinterpret_cast<const char*>(v), sizeof(v));
    bytes.append("\x10\x20\x30", 3);
  }
  return bytes;
}

TEST(CloudFormats, DoublePrecisionPlyAsOpen3dWritesItLoads) {
  const std::string dir = FreshDir("out");
  const std::vector<Eigen::Vector3d> points = {{0.1, -0.2, 1.0}, {0.123456789012, 0.2, 0.95}, {-0.3, 0.0, 1.1}};
  WriteText(dir + "/f000_cloud.ply", Open3dStylePly(points));
  FrameFileInfo info;
  Result<Frame> frame = LoadFrameFile(dir + "/f000_cloud.ply", Pose::Identity(), &info);
  ASSERT_TRUE(frame.ok()) << frame.status().ToString();
  ASSERT_EQ(frame->points_C.size(), points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    EXPECT_EQ(frame->points_C[i], points[i].cast<float>()) << i;  // rounded to the nearest float
  }
  EXPECT_EQ(info.format, "PLY");
  EXPECT_EQ(info.coordinates, "float64");
  EXPECT_THAT(info.extra_fields, ElementsAre("nx", "ny", "nz", "red", "green", "blue"));
}

TEST(CloudFormats, DoublePrecisionPcdLoadsInAsciiAndBinary) {
  const std::string dir = FreshDir("out");
  const std::string head = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 8 8 8 4\nTYPE F F F F\n"
                           "COUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\n";
  WriteText(dir + "/ascii.pcd", head + "DATA ascii\n0.25 -0.125 1.0000000001 7\n0.5 0.5 2 8\n");
  std::string binary = head + "DATA binary\n";
  const double xyz[2][3] = {{0.25, -0.125, 1.0}, {0.5, 0.5, 2.0}};
  for (const auto& p : xyz) {
    binary.append(reinterpret_cast<const char*>(p), sizeof(p));
    const float intensity = 7.f;
    binary.append(reinterpret_cast<const char*>(&intensity), sizeof(float));
  }
  WriteText(dir + "/binary.pcd", binary);
  for (const char* name : {"ascii.pcd", "binary.pcd"}) {
    FrameFileInfo info;
    Result<Frame> frame = LoadFrameFile(dir + "/" + name, Pose::Identity(), &info);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    ASSERT_EQ(frame->points_C.size(), 2u);
    EXPECT_EQ(frame->points_C[0], Eigen::Vector3f(0.25f, -0.125f, 1.f)) << name;
    EXPECT_EQ(frame->points_C[1], Eigen::Vector3f(0.5f, 0.5f, 2.f)) << name;
    EXPECT_EQ(info.coordinates, "float64");
    EXPECT_THAT(info.extra_fields, ElementsAre("intensity"));
  }
}

TEST(CloudFormats, APlyErrorNamesPlyAndTheProperty) {
  const std::string dir = FreshDir("out");
  WriteText(dir + "/bytes.ply",
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty uchar x\nproperty float y\nproperty float z\n"
            "end_header\n1 0 1\n");
  Result<Frame> frame = LoadFrameFile(dir + "/bytes.ply");
  ASSERT_FALSE(frame.ok());
  EXPECT_EQ(frame.status().code(), Status::Code::kInvalidArgument);
  EXPECT_THAT(frame.status().message(), HasSubstr("bytes.ply"));
  EXPECT_THAT(frame.status().message(), HasSubstr("PLY property 'x' is uchar"));
  EXPECT_THAT(frame.status().message(), ::testing::Not(HasSubstr("PCD")));
  // No coordinates at all.
  WriteText(dir + "/colours.ply",
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty uchar red\nproperty uchar green\n"
            "property uchar blue\nend_header\n1 2 3\n");
  frame = LoadFrameFile(dir + "/colours.ply");
  ASSERT_FALSE(frame.ok());
  EXPECT_THAT(frame.status().message(), HasSubstr("PLY has no x, y, z vertex properties"));
}

TEST(CloudFormats, APcdErrorNamesPcdAndTheField) {
  const std::string dir = FreshDir("out");
  WriteText(dir + "/bytes.pcd", "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 1 4\nTYPE F U F\nCOUNT 1 1 1\n"
                                "WIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n0 1 1\n");
  Result<Frame> frame = LoadFrameFile(dir + "/bytes.pcd");
  ASSERT_FALSE(frame.ok());
  EXPECT_EQ(frame.status().code(), Status::Code::kInvalidArgument);
  EXPECT_THAT(frame.status().message(), HasSubstr("bytes.pcd"));
  EXPECT_THAT(frame.status().message(), HasSubstr("PCD field 'y' is TYPE U SIZE 1 COUNT 1"));
}

TEST(CloudFormats, MillimetreCloudsLoadInMetresWhenTheSidecarDeclaresTheUnit) {
  const std::string dir = FreshDir("out");
  const std::string pcd = "# .PCD v0.7\r\nVERSION 0.7\r\nFIELDS x y z\r\nSIZE 4 4 4\r\nTYPE F F F\r\nCOUNT 1 1 1\r\n"
                          "WIDTH 2\r\nHEIGHT 1\r\nPOINTS 2\r\nDATA ascii\r\n250 -125 1000\r\n-100 40.5 987.25\r\n";
  WriteText(dir + "/scan.pcd", pcd);
  // Undeclared: refused, pointing at the sidecar to fix.
  Result<Frame> frame = LoadFrameFile(dir + "/scan.pcd");
  ASSERT_FALSE(frame.ok());
  EXPECT_EQ(frame.status().code(), Status::Code::kInvalidArgument);
  EXPECT_THAT(frame.status().message(), HasSubstr("millimetres?"));
  EXPECT_THAT(frame.status().message(), HasSubstr("scan.intrinsics.json"));
  WriteText(dir + "/scan.intrinsics.json", R"({"format": "binpick.intrinsics/1", "unit": "mm"})");
  FrameFileInfo info;
  frame = LoadFrameFile(dir + "/scan.pcd", Pose::Identity(), &info);
  ASSERT_TRUE(frame.ok()) << frame.status().ToString();
  ASSERT_EQ(frame->points_C.size(), 2u);
  EXPECT_TRUE(frame->points_C[0].isApprox(Eigen::Vector3f(0.25f, -0.125f, 1.f), 1e-7f));
  EXPECT_TRUE(frame->points_C[1].isApprox(Eigen::Vector3f(-0.1f, 0.0405f, 0.98725f), 1e-7f));
  EXPECT_EQ(info.unit, "mm");
  EXPECT_TRUE(info.unit_declared);
  // The sidecar has no X_BC: the default pose, and it says so.
  EXPECT_FALSE(info.X_BC_known);
  WriteText(dir + "/scan.intrinsics.json", R"({"format": "binpick.intrinsics/1", "unit": "inch"})");
  frame = LoadFrameFile(dir + "/scan.pcd");
  ASSERT_FALSE(frame.ok());
  EXPECT_THAT(frame.status().message(), HasSubstr("unit 'inch' is not m, cm or mm"));
}

TEST(CloudFormats, ADepthPngSidecarWithAUnitIsRefusedNamingDepthScale) {
  const std::string dir = FreshDir("out");
  const Frame f = testing::PlaneWithBox();
  ASSERT_TRUE(WriteDepthPng(f, dir + "/depth.png").ok());
  WriteText(dir + "/depth.intrinsics.json",
            R"({"width": 64, "height": 48, "fx": 80, "fy": 80, "cx": 32, "cy": 24, "unit": "mm"})");
  Result<Frame> frame = LoadFrameFile(dir + "/depth.png");
  ASSERT_FALSE(frame.ok());
  EXPECT_EQ(frame.status().code(), Status::Code::kInvalidArgument);
  EXPECT_THAT(frame.status().message(), HasSubstr("depth_scale"));
}

// An organized cloud as another tool writes it: the points in a frame F (here
// the bin's), NaN holes, the sensor's pose in F as VIEWPOINT, no intrinsics.
TEST(CloudFormats, OrganizedPcdWithAViewpointIsReadInTheSensorFrame) {
  const std::string dir = FreshDir("out");
  const Frame camera = testing::PlaneWithBox();
  const Pose X_FS = MakePose(Quat(Eigen::AngleAxisd(3.0, Vec3(0.1, 1.0, 0.05).normalized())), Vec3(0.1, -0.2, 1.1));
  pcl::PointCloud<pcl::PointXYZ> cloud(camera.depth.width, camera.depth.height);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int v = 0; v < camera.depth.height; ++v) {
    for (int u = 0; u < camera.depth.width; ++u) {
      const float z = camera.depth.at(u, v);
      if (!std::isfinite(z)) {
        cloud.at(u, v) = pcl::PointXYZ(nan, nan, nan);
        continue;
      }
      const Vec3 p_F = X_FS * Deproject(camera.intrinsics, u, v, z).cast<double>();
      cloud.at(u, v) = pcl::PointXYZ(static_cast<float>(p_F.x()), static_cast<float>(p_F.y()),
                                     static_cast<float>(p_F.z()));
    }
  }
  cloud.is_dense = false;
  cloud.sensor_origin_ = Eigen::Vector4f(0.1f, -0.2f, 1.1f, 0.f);
  cloud.sensor_orientation_ = Quat(X_FS.linear()).cast<float>();
  ASSERT_EQ(pcl::io::savePCDFileBinary(dir + "/grid.pcd", cloud), 0);
  const Pose X_BF = MakePose(Mat3::Identity(), Vec3(0.7, 0.0, 0.0));
  WriteText(dir + "/grid.intrinsics.json",
            "{\"X_BC\": [[1, 0, 0, 0.7], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}");
  FrameFileInfo info;
  Result<Frame> frame = LoadFrameFile(dir + "/grid.pcd", Pose::Identity(), &info);
  ASSERT_TRUE(frame.ok()) << frame.status().ToString();
  EXPECT_TRUE(info.viewpoint_used);
  EXPECT_TRUE(info.X_BC_known);
  EXPECT_EQ(info.width, camera.depth.width);
  EXPECT_EQ(info.height, camera.depth.height);
  // X_BC is the sensor's; the points are back in the sensor's frame, NaNs in place.
  EXPECT_TRUE(frame->X_BC.isApprox(X_BF * X_FS, 1e-6));
  ASSERT_EQ(frame->points_C.size(), camera.depth.data.size());
  for (int v = 0; v < camera.depth.height; ++v) {
    for (int u = 0; u < camera.depth.width; ++u) {
      const float z = camera.depth.at(u, v);
      const Eigen::Vector3f& p = frame->points_C[static_cast<size_t>(v) * camera.depth.width + u];
      if (!std::isfinite(z)) {
        EXPECT_FALSE(p.allFinite());
        continue;
      }
      EXPECT_TRUE(p.isApprox(Deproject(camera.intrinsics, u, v, z), 2e-6f)) << u << "," << v;
    }
  }
}

TEST(CloudFormats, PoseComesFromTheSidecarOnlyWhenItHasAnXbc) {
  const std::string dir = FreshDir("out");
  WriteText(dir + "/p.ply",
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
            "end_header\n0 0 1\n");
  const Pose X_BC_default = MakePose(Mat3::Identity(), Vec3(1, 2, 3));
  FrameFileInfo info;
  Result<Frame> frame = LoadFrameFile(dir + "/p.ply", X_BC_default, &info);
  ASSERT_TRUE(frame.ok());
  EXPECT_FALSE(info.has_sidecar);
  EXPECT_FALSE(info.X_BC_known);
  EXPECT_TRUE(frame->X_BC.matrix() == X_BC_default.matrix());
  WriteText(dir + "/p.intrinsics.json", R"({"timestamp_ns": 5})");
  frame = LoadFrameFile(dir + "/p.ply", X_BC_default, &info);
  ASSERT_TRUE(frame.ok());
  EXPECT_TRUE(info.has_sidecar);
  EXPECT_FALSE(info.X_BC_known);
  EXPECT_TRUE(frame->X_BC.matrix() == X_BC_default.matrix());
  EXPECT_EQ(frame->timestamp_ns, 5);
}

}  // namespace
}  // namespace bp
