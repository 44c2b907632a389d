#include "pipeline/frame_io.h"

#include <cmath>
#include <cstring>
#include <filesystem>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "test_frames.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using testing::FreshDir;
using testing::PlaneWithBox;
using testing::ReadBytes;
using testing::Truncate;
using testing::WriteText;

bool SameBits(float a, float b) { return std::memcmp(&a, &b, sizeof(float)) == 0; }

void ExpectSameIntrinsics(const Intrinsics& a, const Intrinsics& b) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  EXPECT_EQ(a.fx, b.fx);
  EXPECT_EQ(a.fy, b.fy);
  EXPECT_EQ(a.cx, b.cx);
  EXPECT_EQ(a.cy, b.cy);
  EXPECT_EQ(a.distortion, b.distortion);
}

// Asserts `path` fails to load with `code`, and the message names the file.
void ExpectLoadError(const std::string& path, Status::Code code, const std::string& reason = "") {
  Result<Frame> frame = LoadFrameFile(path);
  ASSERT_FALSE(frame.ok()) << path;
  EXPECT_EQ(frame.status().code(), code) << frame.status().ToString();
  EXPECT_THAT(frame.status().message(), HasSubstr(fs::path(path).filename().string()));
  if (!reason.empty()) {
    EXPECT_THAT(frame.status().message(), HasSubstr(reason));
  }
}

TEST(CompanionPath, ReplacesDepthOrCloudWordElseAppendsRole) {
  EXPECT_EQ(CompanionPath("/d/depth.png", "truth.json"), "/d/truth.json");
  EXPECT_EQ(CompanionPath("/d/f007_depth.png", "intensity.png"), "/d/f007_intensity.png");
  EXPECT_EQ(CompanionPath("/d/f007_cloud.pcd", "truth.json"), "/d/f007_truth.json");
  EXPECT_EQ(CompanionPath("/d/scan.pcd", "truth.json"), "/d/scan.truth.json");
  EXPECT_EQ(IntrinsicsSidecarPath("/d/depth.png"), "/d/depth.intrinsics.json");
}

TEST(DepthPng, RoundTripIsWithinHalfACountAndKeepsInvalidPixels) {
  const std::string dir = FreshDir("out");
  const Frame f = PlaneWithBox();
  const std::string path = dir + "/depth.png";
  ASSERT_TRUE(WriteDepthPng(f, path).ok());
  EXPECT_TRUE(fs::exists(dir + "/depth.intrinsics.json"));
  Result<Frame> g = LoadFrameFile(path);
  ASSERT_TRUE(g.ok()) << g.status().ToString();
  ASSERT_TRUE(g->organized());
  ExpectSameIntrinsics(f.intrinsics, g->intrinsics);
  EXPECT_TRUE(f.X_BC.matrix() == g->X_BC.matrix());
  EXPECT_EQ(f.timestamp_ns, g->timestamp_ns);
  EXPECT_EQ(g->source, path);
  for (size_t i = 0; i < f.depth.data.size(); ++i) {
    const float a = f.depth.data[i], b = g->depth.data[i];
    ASSERT_EQ(std::isnan(a), std::isnan(b)) << "pixel " << i;
    if (!std::isnan(a)) {
      ASSERT_NEAR(a, b, 0.5 * kDepthPngScale + 1e-7) << "pixel " << i;
    }
  }
}

TEST(DepthPng, RejectsDepthBeyondTheSixteenBitRange) {
  const std::string dir = FreshDir("out");
  Frame f = PlaneWithBox();
  f.depth.at(3, 4) = 6.6f;
  const Status s = WriteDepthPng(f, dir + "/depth.png");
  EXPECT_EQ(s.code(), Status::Code::kOutOfRange);
  EXPECT_THAT(s.message(), HasSubstr("6.5535"));
  f.depth.at(3, 4) = 6.5535f;  // the largest count still fits
  EXPECT_TRUE(WriteDepthPng(f, dir + "/depth.png").ok());
}

TEST(DepthPng, RejectsUnorganizedFrame) {
  Frame f;
  f.points_C = {Eigen::Vector3f(0, 0, 1)};
  EXPECT_EQ(WriteDepthPng(f, FreshDir("out") + "/depth.png").code(), Status::Code::kInvalidArgument);
}

TEST(CloudPcd, OrganizedRoundTripIsBitExactWithNaNsInPlace) {
  const std::string dir = FreshDir("out");
  const Frame f = PlaneWithBox();
  ASSERT_TRUE(WriteCloudPcd(f, dir + "/cloud.pcd").ok());
  Result<Frame> g = LoadFrameFile(dir + "/cloud.pcd");
  ASSERT_TRUE(g.ok()) << g.status().ToString();
  ASSERT_TRUE(g->organized());
  ExpectSameIntrinsics(f.intrinsics, g->intrinsics);
  EXPECT_TRUE(f.X_BC.matrix() == g->X_BC.matrix());
  for (size_t i = 0; i < f.depth.data.size(); ++i) {
    ASSERT_TRUE(SameBits(f.depth.data[i], g->depth.data[i]) ||
                (std::isnan(f.depth.data[i]) && std::isnan(g->depth.data[i])))
        << "pixel " << i;
  }
  const auto a = f.PointsInCamera(), b = g->PointsInCamera();
  ASSERT_EQ(a.size(), b.size());
  ASSERT_EQ(0, std::memcmp(a.data(), b.data(), a.size() * sizeof(Eigen::Vector3f)));
}

TEST(CloudPcd, UnorganizedRoundTripIsBitExactWithNaNsInPlace) {
  const std::string dir = FreshDir("out");
  Frame f;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  f.points_C = {{0.1f, -0.2f, 1.0f}, {nan, nan, nan}, {1e-7f, 3.3333333f, 0.95f}, {nan, nan, nan}, {-0.5f, 0.25f, 2.f}};
  f.X_BC = testing::SomeCameraPose();
  ASSERT_TRUE(WriteCloudPcd(f, dir + "/scan.pcd").ok());
  Result<Frame> g = LoadFrameFile(dir + "/scan.pcd");
  ASSERT_TRUE(g.ok()) << g.status().ToString();
  EXPECT_FALSE(g->organized());
  ASSERT_EQ(g->points_C.size(), f.points_C.size());
  for (size_t i = 0; i < f.points_C.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      const float x = f.points_C[i][k], y = g->points_C[i][k];
      EXPECT_TRUE(SameBits(x, y) || (std::isnan(x) && std::isnan(y))) << i << "," << k;
      EXPECT_EQ(std::isnan(x), std::isnan(y));
    }
  }
  EXPECT_TRUE(f.X_BC.matrix() == g->X_BC.matrix());
  EXPECT_EQ(g->ValidPointCount(), 3u);
}

TEST(CloudPcd, OrganizedCloudWithoutSidecarBecomesPointListWithDefaultPose) {
  const std::string dir = FreshDir("out");
  const Frame f = PlaneWithBox();
  ASSERT_TRUE(WriteCloudPcd(f, dir + "/cloud.pcd").ok());
  fs::remove(dir + "/cloud.intrinsics.json");
  const Pose X_BC_default = MakePose(Mat3::Identity(), Vec3(1, 2, 3));
  Result<Frame> g = LoadFrameFile(dir + "/cloud.pcd", X_BC_default);
  ASSERT_TRUE(g.ok()) << g.status().ToString();
  EXPECT_FALSE(g->organized());
  EXPECT_EQ(g->points_C.size(), f.depth.data.size());  // NaNs kept
  EXPECT_EQ(g->ValidPointCount(), f.ValidPointCount());
  EXPECT_TRUE(g->X_BC.matrix() == X_BC_default.matrix());
}

// Found by fuzz/pcd_fuzz: a header declaring no points made PCL take
// &cloud[0] of an empty cloud, and WIDTH x HEIGHT wrapping in 32 bits to
// POINTS passed PCL's own check, then its conversion wrote past the cloud.
TEST(CloudPcd, HeaderWithNoPointsOrAWrappingSizeIsCorruption) {
  const std::string dir = FreshDir("out");
  const std::string head = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n";
  WriteText(dir + "/none.pcd", head + "WIDTH 0\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 0\nDATA ascii\n");
  Result<Frame> none = LoadFrameFile(dir + "/none.pcd");
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.status().code(), Status::Code::kCorruption);
  EXPECT_THAT(none.status().message(), HasSubstr("no points"));
  // 65536 x 65537 = 2^32 + 65536: 65536 in 32 bits, the POINTS given.
  std::string wrap = head + "WIDTH 65536\nHEIGHT 65537\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 65536\nDATA ascii\n";
  for (int i = 0; i < 65536; ++i) wrap += "0 0 1\n";
  WriteText(dir + "/wrap.pcd", wrap);
  Result<Frame> wrapped = LoadFrameFile(dir + "/wrap.pcd");
  ASSERT_FALSE(wrapped.ok());
  EXPECT_EQ(wrapped.status().code(), Status::Code::kCorruption);
  EXPECT_THAT(wrapped.status().message(), HasSubstr("WIDTH x HEIGHT is not POINTS"));
}

// Found by fuzz/pcd_fuzz: fields whose SIZE / TYPE / COUNT do not fit the
// point made PCL's conversion read past its data (heap overflow under ASan).
TEST(CloudPcd, FieldsThatDoNotFitTheirPointAreCorruption) {
  const std::string dir = FreshDir("out");
  const std::string points = "-0.25 -0.25 1\n0.25 -0.25 1\n-0.25 0.25 1\n0.25 0.25 1\n";
  WriteText(dir + "/sizes.pcd", "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 3 4 2\nWIDTH 4\nHEIGHT 1\n"
                                "POINTS 4\nDATA ascii\n" + points);
  Result<Frame> sizes = LoadFrameFile(dir + "/sizes.pcd");
  ASSERT_FALSE(sizes.ok());
  EXPECT_EQ(sizes.status().code(), Status::Code::kCorruption);
  // A repeated FIELDS line corrupted PCL's memory (bad free under ASan).
  WriteText(dir + "/twice.pcd", "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                                "FIELDS x y z 0\nWIDTH 4\nHEIGHT 1\nPOINTS 4\nDATA ascii\n" + points);
  Result<Frame> twice = LoadFrameFile(dir + "/twice.pcd");
  ASSERT_FALSE(twice.ok());
  EXPECT_THAT(twice.status().message(), HasSubstr("FIELDS given twice"));
}

// Found by fuzz/ply_frame_fuzz: a PLY whose vertex element is unrecognised
// (no points) made PCL's conversion take &cloud[0] of an empty cloud.
TEST(CloudPly, NoVerticesIsCorruption) {
  const std::string dir = FreshDir("out");
  WriteText(dir + "/none.ply", std::string("ply\nformat binary_little_endian 1.0\nelement v\0\0\0x 2\n"
                                           "property float x\nproperty float y\nproperty float z\n"
                                           "end_header\n", 114) + std::string(24, '\0'));
  Result<Frame> none = LoadFrameFile(dir + "/none.ply");
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.status().code(), Status::Code::kCorruption);
}

// Found by fuzz/ply_frame_fuzz: PCL's parser aborted the process (an
// assert) on an obj_info line with a leading vertical tab, and allocated an
// element's declared records before reading them. Both are refused up front.
TEST(CloudPly, HeadersPclCannotTakeAreCorruption) {
  const std::string dir = FreshDir("out");
  const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"ply\ntpe\n\n\n\n\vobj_info\n\n\n\n\n\n\n\n\nd", "unknown keyword 'tpe'"},  // the fuzz input
      {"ply\nformat ascii 1.0\n\vobj_info x\nelement vertex 1\n" + xyz + "end_header\n0 0 1\n",
       "control or non-ASCII byte"},
      {"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\n" + xyz + "end_header\n",
       "declares more records than the file holds"},
      {"ply\nformat ascii 1.0\nelement vertex 99999999999999999999\n" + xyz + "end_header\n",
       "declares more records than the file holds"},
      {"ply\nformat ascii 1.0\nformat ascii 1.0\nelement vertex 1\n" + xyz + "end_header\n0 0 1\n",
       "format given twice"},
      {"ply\nformat ascii 2.0\nelement vertex 1\n" + xyz + "end_header\n0 0 1\n", "format must be"},
      {"ply\nformat ascii 1.0\nproperty float x\nelement vertex 1\nend_header\n0\n", "property before any element"},
      {"ply\nformat ascii 1.0\nelement vertex 1\nproperty float64x x\nend_header\n0\n", "malformed property"},
      {"ply\nformat ascii 1.0\nelement  vertex 1\n" + xyz + "end_header\n0 0 1\n", "doubled spaces"},
      {"ply\nformat ascii 1.0\nelement vertex 1\n" + xyz, "no end_header"},
      {"ply\nformat ascii 1.0\nvertex 1\nend_header\n", "unknown keyword 'vertex'"},
      // PCL packs uchar colours into one field written at "blue": without
      // "red" first it aborted (fuzz input regress-assert-colour-without-red),
      // apart or out of order they shift the coordinates.
      {"ply\nformat ascii 1.0\nelement vertex 1\n" + xyz + "property uchar green\nproperty uchar blue\n"
       "end_header\n0 0 1 2 3\n", "vertex property 'green' is out of place"},
      {"ply\nformat ascii 1.0\nelement vertex 1\nproperty uchar blue\nproperty uchar green\nproperty uchar red\n" +
           xyz + "end_header\n3 2 1 0 0 1\n", "vertex property 'blue' is out of place"},
      {"ply\nformat ascii 1.0\nelement vertex 1\nproperty uchar red\n" + xyz +
           "property uchar green\nproperty uchar blue\nend_header\n1 0 0 1 2 3\n",
       "vertex property 'red' is out of place"},
      {"ply\nformat ascii 1.0\nelement vertex 1\n" + xyz +
           "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar red\n"
           "property uchar green\nproperty uchar blue\nend_header\n0 0 1 1 2 3 1 2 3\n",
       "line 10: vertex property 'red' is out of place"},
      // A list's size is taken from the first vertex.
      {"ply\nformat ascii 1.0\nelement vertex 2\n" + xyz + "property list uchar float w\nend_header\n"
       "0 0 1 1 5\n0 0 1 3 5 5 5\n", "vertex property 'w' is a list"},
      // PCL sizes the cloud by obj_info's grid.
      {"ply\nformat ascii 1.0\nobj_info num_cols 1\nobj_info num_rows 1\nelement vertex 2\n" + xyz +
           "end_header\n0 0 1\n0 0 1\n", "obj_info num_cols x num_rows (1 x 1)"},
      {"ply\nformat ascii 1.0\nobj_info num_cols 100000\nobj_info num_rows -1\nelement vertex 1\n" + xyz +
           "end_header\n0 0 1\n", "obj_info num_cols x num_rows (100000 x 4294967295)"},
      {"ply\nformat ascii 1.0\nelement vertex 1\n" + xyz + "element vertex 1\n" + xyz + "end_header\n0 0 1\n0 0 1\n",
       "a second vertex element"},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    const std::string path = dir + "/case" + std::to_string(i) + ".ply";
    WriteText(path, cases[i].first);
    Result<Frame> r = LoadFrameFile(path);
    ASSERT_FALSE(r.ok()) << "case " << i;
    EXPECT_EQ(r.status().code(), Status::Code::kCorruption) << "case " << i;
    EXPECT_THAT(r.status().message(), HasSubstr(cases[i].second)) << "case " << i;
  }
  // Comments and obj_info are free text; CRLF line ends are accepted.
  WriteText(dir + "/ok.ply", "ply\r\nformat ascii 1.0\r\ncomment made by  a  scanner\r\nobj_info serial 42\r\n"
                             "element vertex 1\r\nproperty float32 x\r\nproperty float32 y\r\nproperty float32 z\r\n"
                             "end_header\r\n0.5 0.25 1\r\n");
  Result<Frame> ok = LoadFrameFile(dir + "/ok.ply");
  ASSERT_TRUE(ok.ok()) << ok.status().ToString();
  ASSERT_EQ(ok->points_C.size(), 1u);
  EXPECT_EQ(ok->points_C[0], Eigen::Vector3f(0.5f, 0.25f, 1.f));
  // Colours as tools write them (red green blue, then alpha, or diffuse_*,
  // before or after x y z; a float named after a colour anywhere) and an
  // obj_info grid as PCL writes it load.
  const std::vector<std::string> colour_headers = {
      "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n" + xyz +
          "property float confidence\n",
      xyz + "property uchar diffuse_red\nproperty uchar diffuse_green\nproperty uchar diffuse_blue\n"
            "property float red\n"};
  for (size_t i = 0; i < colour_headers.size(); ++i) {
    const std::string path = dir + "/colours" + std::to_string(i) + ".ply";
    const bool alpha = i == 0;
    const std::string row0 = alpha ? "1 2 3 4 0.5 0.25 1 0.5\n" : "0.5 0.25 1 1 2 3 0.5\n";
    const std::string row1 = alpha ? "1 2 3 4 -0.5 -0.25 2 0.5\n" : "-0.5 -0.25 2 1 2 3 0.5\n";
    WriteText(path, "ply\nformat ascii 1.0\nobj_info num_cols 2\nobj_info num_rows 1\nelement vertex 2\n" +
                        colour_headers[i] + "end_header\n" + row0 + row1);
    Result<Frame> colours = LoadFrameFile(path);
    ASSERT_TRUE(colours.ok()) << colours.status().ToString();
    ASSERT_EQ(colours->points_C.size(), 2u);
    EXPECT_EQ(colours->points_C[0], Eigen::Vector3f(0.5f, 0.25f, 1.f)) << i;
    EXPECT_EQ(colours->points_C[1], Eigen::Vector3f(-0.5f, -0.25f, 2.f)) << i;
  }
}

TEST(CloudPly, LoadsVerticesAndIgnoresFaces) {
  const std::string dir = FreshDir("out");
  WriteText(dir + "/mesh.ply",
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
            "0 0 1\n0.1 0 1\n0.1 0.1 1.5\n0 0.1 1.25\n3 0 1 2\n3 0 2 3\n");
  Result<Frame> g = LoadFrameFile(dir + "/mesh.ply");
  ASSERT_TRUE(g.ok()) << g.status().ToString();
  EXPECT_FALSE(g->organized());
  ASSERT_EQ(g->points_C.size(), 4u);
  EXPECT_EQ(g->points_C[2], Eigen::Vector3f(0.1f, 0.1f, 1.5f));
}

TEST(CloudPly, LoadsVerticesOfABinaryMeshWithFaces) {
  Result<Frame> g = LoadFrameFile(std::string(BINPICK_SOURCE_DIR) + "/assets/parts/pipe_tee.ply");
  ASSERT_TRUE(g.ok()) << g.status().ToString();
  EXPECT_FALSE(g->organized());
  EXPECT_EQ(g->points_C.size(), 512u);
  EXPECT_EQ(g->ValidPointCount(), 512u);
}

TEST(CloudPly, LoadsBinaryPointCloud) {
  const std::string dir = FreshDir("out");
  std::string bytes = "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n"
                      "property float y\nproperty float z\nend_header\n";
  const float xyz[6] = {0.5f, -0.25f, 1.f, 0.125f, 0.f, 2.f};
  bytes.append(reinterpret_cast<const char*>(xyz), sizeof(xyz));
  WriteText(dir + "/points.ply", bytes);
  Result<Frame> g = LoadFrameFile(dir + "/points.ply");
  ASSERT_TRUE(g.ok()) << g.status().ToString();
  ASSERT_EQ(g->points_C.size(), 2u);
  EXPECT_EQ(g->points_C[1], Eigen::Vector3f(0.125f, 0.f, 2.f));
}

TEST(IntensityPng, RoundTripIsIdenticalAndAttachesToItsDepthFrame) {
  const std::string dir = FreshDir("out");
  const Frame f = PlaneWithBox();
  ASSERT_TRUE(WriteIntensityPng(f, dir + "/intensity.png").ok());
  Result<IntensityImage> img = ReadIntensityPng(dir + "/intensity.png");
  ASSERT_TRUE(img.ok()) << img.status().ToString();
  EXPECT_EQ(img->width, f.intensity.width);
  EXPECT_EQ(img->data, f.intensity.data);
  ASSERT_TRUE(WriteDepthPng(f, dir + "/depth.png").ok());
  Result<Frame> g = LoadFrameFile(dir + "/depth.png");
  ASSERT_TRUE(g.ok()) << g.status().ToString();
  EXPECT_EQ(g->intensity.data, f.intensity.data);
}

void ExpectSameTruth(const GroundTruth& a, const GroundTruth& b) {
  EXPECT_EQ(a.seed, b.seed);
  ASSERT_EQ(a.parts.size(), b.parts.size());
  for (size_t i = 0; i < a.parts.size(); ++i) {
    EXPECT_EQ(a.parts[i].instance_id, b.parts[i].instance_id);
    EXPECT_EQ(a.parts[i].class_id, b.parts[i].class_id);
    EXPECT_EQ(a.parts[i].class_name, b.parts[i].class_name);
    EXPECT_TRUE(a.parts[i].X_BO.matrix() == b.parts[i].X_BO.matrix()) << i;
    EXPECT_EQ(a.parts[i].visible_pixels, b.parts[i].visible_pixels);
    EXPECT_EQ(a.parts[i].unoccluded_pixels, b.parts[i].unoccluded_pixels);
    EXPECT_EQ(a.parts[i].visible_fraction, b.parts[i].visible_fraction);
  }
}

TEST(GroundTruthJson, RoundTripIsIdentical) {
  const std::string dir = FreshDir("out");
  const Frame f = PlaneWithBox();
  ASSERT_TRUE(WriteGroundTruthJson(f, dir + "/truth.json").ok());
  Result<GroundTruth> t = ReadGroundTruthJson(dir + "/truth.json");
  ASSERT_TRUE(t.ok()) << t.status().ToString();
  ExpectSameTruth(*f.truth, *t);
}

TEST(GroundTruthJson, AttachesToCloudAndDepthWithLabels) {
  const std::string dir = FreshDir("out");
  Frame f = PlaneWithBox();
  f.truth->labels = LabelImage(f.depth.width, f.depth.height);
  f.truth->labels.at(30, 20) = 7;
  f.truth->labels.at(0, 0) = GroundTruth::kBinLabel;
  ASSERT_TRUE(WriteGroundTruthJson(f, dir + "/f01_truth.json").ok());
  ASSERT_TRUE(WriteLabelPng(f, dir + "/f01_labels.png").ok());
  ASSERT_TRUE(WriteCloudPcd(f, dir + "/f01_cloud.pcd").ok());
  ASSERT_TRUE(WriteDepthPng(f, dir + "/f01_depth.png").ok());
  for (const char* name : {"/f01_cloud.pcd", "/f01_depth.png"}) {
    Result<Frame> g = LoadFrameFile(dir + name);
    ASSERT_TRUE(g.ok()) << g.status().ToString();
    ASSERT_TRUE(g->truth.has_value()) << name;
    ExpectSameTruth(*f.truth, *g->truth);
    EXPECT_EQ(g->truth->labels.data, f.truth->labels.data) << name;
  }
}

TEST(GroundTruthJson, AcceptsXyzQuatWithoutMatrixFromOtherTools) {
  const std::string dir = FreshDir("out");
  WriteText(dir + "/t.json",
            R"({"seed": 5, "parts": [{"instance_id": 3, "class_id": 1, "xyz": [0.1, 0.2, 0.3],)"
            R"( "quat_wxyz": [0.0, 0.0, 0.0, 1.0]}]})");
  Result<GroundTruth> t = ReadGroundTruthJson(dir + "/t.json");
  ASSERT_TRUE(t.ok()) << t.status().ToString();
  ASSERT_EQ(t->parts.size(), 1u);
  EXPECT_TRUE(t->parts[0].X_BO.translation().isApprox(Vec3(0.1, 0.2, 0.3)));
  EXPECT_TRUE(t->parts[0].X_BO.linear().isApprox(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitZ()))));
}

TEST(GroundTruthJson, MalformedFilesAreCorruptionNamingTheFile) {
  const std::string dir = FreshDir("out");
  const Frame f = PlaneWithBox();
  ASSERT_TRUE(WriteGroundTruthJson(f, dir + "/truth.json").ok());
  Truncate(dir + "/truth.json", 0.5);
  Result<GroundTruth> t = ReadGroundTruthJson(dir + "/truth.json");
  EXPECT_EQ(t.status().code(), Status::Code::kCorruption);
  EXPECT_THAT(t.status().message(), HasSubstr("truth.json"));
  WriteText(dir + "/wrong.json", R"({"parts": [{"instance_id": "one"}]})");
  t = ReadGroundTruthJson(dir + "/wrong.json");
  EXPECT_EQ(t.status().code(), Status::Code::kCorruption);
  EXPECT_THAT(t.status().message(), HasSubstr("wrong.json"));
  // A corrupt truth file beside a frame fails the frame, naming the truth file.
  ASSERT_TRUE(WriteDepthPng(f, dir + "/depth.png").ok());
  Result<Frame> g = LoadFrameFile(dir + "/depth.png");
  EXPECT_EQ(g.status().code(), Status::Code::kCorruption);
  EXPECT_THAT(g.status().message(), HasSubstr("truth.json"));
}

// --- Bad files ---------------------------------------------------------------

TEST(LoadFrameFile, MissingFileIsNotFound) {
  ExpectLoadError(FreshDir("in") + "/nothing_here.pcd", Status::Code::kNotFound);
}

TEST(LoadFrameFile, EmptyFilesAreCorruption) {
  const std::string dir = FreshDir("in");
  for (const char* name : {"/empty.pcd", "/empty.ply", "/empty_depth.png"}) {
    WriteText(dir + name, "");
    ExpectLoadError(dir + name, Status::Code::kCorruption, "empty");
  }
}

TEST(LoadFrameFile, UnknownExtensionIsInvalidArgument) {
  const std::string dir = FreshDir("in");
  WriteText(dir + "/scan.xyz", "0 0 1\n");
  ExpectLoadError(dir + "/scan.xyz", Status::Code::kInvalidArgument, "unsupported");
}

TEST(LoadFrameFile, WrongMagicIsCorruption) {
  const std::string dir = FreshDir("in");
  for (const char* name : {"/junk.pcd", "/junk.ply", "/junk_depth.png"}) {
    WriteText(dir + name, "this is not a point cloud at all, just some text\n");
    ExpectLoadError(dir + name, Status::Code::kCorruption, "magic");
  }
}

TEST(LoadFrameFile, PcdCutInHalfIsCorruption) {
  const std::string dir = FreshDir("in");
  ASSERT_TRUE(WriteCloudPcd(PlaneWithBox(), dir + "/cloud.pcd").ok());
  Truncate(dir + "/cloud.pcd", 0.5);
  ExpectLoadError(dir + "/cloud.pcd", Status::Code::kCorruption, "truncated");
  Truncate(dir + "/cloud.pcd", 0.02);  // inside the header
  ExpectLoadError(dir + "/cloud.pcd", Status::Code::kCorruption);
}

TEST(LoadFrameFile, PcdHeaderPointCountDifferentFromDataIsCorruption) {
  const std::string dir = FreshDir("in");
  const std::string header_10 =
      "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
      "WIDTH 10\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 10\nDATA ascii\n";
  WriteText(dir + "/short.pcd", header_10 + "0 0 1\n0 0 1\n0 0 1\n");
  ExpectLoadError(dir + "/short.pcd", Status::Code::kCorruption);
  const std::string mismatched =
      "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
      "WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 5\nDATA ascii\n0 0 1\n0 0 1\n0 0 1\n";
  WriteText(dir + "/mismatch.pcd", mismatched);
  ExpectLoadError(dir + "/mismatch.pcd", Status::Code::kCorruption);
}

TEST(LoadFrameFile, PngCutInHalfIsCorruption) {
  const std::string dir = FreshDir("in");
  ASSERT_TRUE(WriteDepthPng(PlaneWithBox(), dir + "/depth.png").ok());
  Truncate(dir + "/depth.png", 0.5);
  ExpectLoadError(dir + "/depth.png", Status::Code::kCorruption, "decode");
}

TEST(LoadFrameFile, PlyCutInHalfIsCorruption) {
  const std::string dir = FreshDir("in");
  std::string bytes = "ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\n"
                      "property float y\nproperty float z\nend_header\n";
  bytes.append(std::string(50 * 12, '\x01'));
  WriteText(dir + "/points.ply", bytes);
  ExpectLoadError(dir + "/points.ply", Status::Code::kCorruption);
  WriteText(dir + "/ascii.ply",
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "end_header\n0 0 1\n0.1 0 1\n");
  ExpectLoadError(dir + "/ascii.ply", Status::Code::kCorruption);
  WriteText(dir + "/header_only.ply",
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n");
  ExpectLoadError(dir + "/header_only.ply", Status::Code::kCorruption);
}

TEST(LoadFrameFile, PngSizeDifferentFromSidecarIsCorruption) {
  const std::string dir = FreshDir("in");
  Frame f = PlaneWithBox();
  ASSERT_TRUE(WriteDepthPng(f, dir + "/depth.png").ok());
  const std::string sidecar = ReadBytes(dir + "/depth.intrinsics.json");
  Frame small = PlaneWithBox();
  small.intrinsics.width = 32;
  small.depth = DepthImage(32, 48, 1.0f);
  ASSERT_TRUE(WriteDepthPng(small, dir + "/depth.png").ok());
  WriteText(dir + "/depth.intrinsics.json", sidecar);  // says 64x48
  ExpectLoadError(dir + "/depth.png", Status::Code::kCorruption, "64x48");
}

TEST(LoadFrameFile, DepthPngWithoutSidecarIsNotFoundNamingTheSidecar) {
  const std::string dir = FreshDir("in");
  ASSERT_TRUE(WriteDepthPng(PlaneWithBox(), dir + "/depth.png").ok());
  fs::remove(dir + "/depth.intrinsics.json");
  ExpectLoadError(dir + "/depth.png", Status::Code::kNotFound, "depth.intrinsics.json");
}

TEST(LoadFrameFile, CorruptSidecarIsCorruptionNamingTheSidecar) {
  const std::string dir = FreshDir("in");
  ASSERT_TRUE(WriteDepthPng(PlaneWithBox(), dir + "/depth.png").ok());
  Truncate(dir + "/depth.intrinsics.json", 0.5);
  ExpectLoadError(dir + "/depth.png", Status::Code::kCorruption, "depth.intrinsics.json");
  WriteText(dir + "/depth.intrinsics.json", R"({"width": 64, "height": 48, "fx": "eighty"})");
  ExpectLoadError(dir + "/depth.png", Status::Code::kCorruption, "depth.intrinsics.json");
}

TEST(LoadFrameFile, EightBitPngAsDepthIsInvalidArgument) {
  const std::string dir = FreshDir("in");
  const Frame f = PlaneWithBox();
  ASSERT_TRUE(WriteIntensityPng(f, dir + "/grey_depth.png").ok());
  ExpectLoadError(dir + "/grey_depth.png", Status::Code::kInvalidArgument, "8-bit");
}

TEST(LoadFrameFile, NaNOnlyCloudIsCorruptionNoValidPoints) {
  const std::string dir = FreshDir("in");
  Frame f;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  f.points_C.assign(10, Eigen::Vector3f(nan, nan, nan));
  ASSERT_TRUE(WriteCloudPcd(f, dir + "/nan.pcd").ok());
  ExpectLoadError(dir + "/nan.pcd", Status::Code::kCorruption, "no valid points");
  Frame d = PlaneWithBox();
  for (float& z : d.depth.data) z = nan;
  ASSERT_TRUE(WriteDepthPng(d, dir + "/nan_depth.png").ok());
  ExpectLoadError(dir + "/nan_depth.png", Status::Code::kCorruption, "no valid points");
}

}  // namespace
}  // namespace bp

namespace bp {
namespace {

// Cuts each kind of file at many lengths: every cut is reported, none crashes.
TEST(LoadFrameFile, FilesCutAtAnyLengthAreReportedNotCrashed) {
  const std::string dir = testing::FreshDir("in");
  const Frame f = testing::PlaneWithBox();
  ASSERT_TRUE(WriteCloudPcd(f, dir + "/cloud.pcd").ok());
  ASSERT_TRUE(WriteDepthPng(f, dir + "/depth.png").ok());
  Frame list;
  list.points_C = f.PointsInCamera();
  ASSERT_TRUE(WriteCloudPcd(list, dir + "/list.pcd").ok());
  std::string ply = "ply\nformat binary_little_endian 1.0\nelement vertex 200\nproperty float x\n"
                    "property float y\nproperty float z\nend_header\n";
  for (int i = 0; i < 600; ++i) {
    const float x = 0.001f * static_cast<float>(i + 1);
    ply.append(reinterpret_cast<const char*>(&x), sizeof(x));
  }
  testing::WriteText(dir + "/points.ply", ply);
  for (const char* name : {"cloud.pcd", "depth.png", "list.pcd", "points.ply"}) {
    const std::string whole = testing::ReadBytes(dir + "/" + name);
    const std::string cut_path = dir + "/cut_" + name;
    if (std::string(name) == "depth.png") {
      fs::copy_file(dir + "/depth.intrinsics.json", dir + "/cut_depth.intrinsics.json",
                    fs::copy_options::overwrite_existing);
    }
    for (int k = 1; k < 40; ++k) {
      const size_t len = whole.size() * k / 40;
      testing::WriteText(cut_path, whole.substr(0, len));
      Result<Frame> g = LoadFrameFile(cut_path);
      ASSERT_FALSE(g.ok()) << name << " cut at " << len << " of " << whole.size();
      EXPECT_EQ(g.status().code(), Status::Code::kCorruption) << g.status().ToString();
      EXPECT_THAT(g.status().message(), HasSubstr("cut_")) << g.status().ToString();
    }
  }
}

}  // namespace
}  // namespace bp
