#include "core/mesh.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "core/mesh_gen.h"
#include "tests/testing/files.h"

namespace bp {
namespace {

using V3 = Eigen::Vector3d;
constexpr double kPi = std::numbers::pi;

// --- helpers ----------------------------------------------------------------

std::string TempPath(const std::string& name) { return bp::testing::ScratchFile("mesh", name); }

void WriteFile(const std::string& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// ctest sets BINPICK_ASSETS; fall back to the source tree when run by hand.
std::string TestAssetsDir() {
  const char* env = std::getenv("BINPICK_ASSETS");
  return env ? env : BINPICK_SOURCE_DIR "/assets";
}

std::string ReadFile(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(f), {});
}

template <typename T>
void Put(std::string* s, T v) {
  s->append(reinterpret_cast<const char*>(&v), sizeof(T));  // the test host is little-endian
}

// A unit-ish tetrahedron, outward faces.
TriangleMesh Tetrahedron() {
  TriangleMesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  m.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return m;
}

TriangleMesh UnitCube() {
  TriangleMesh m;
  for (int i = 0; i < 8; ++i) m.vertices.emplace_back(i & 1, (i >> 1) & 1, (i >> 2) & 1);
  m.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  return m;
}

double SignedVolume(const TriangleMesh& m) {
  double v = 0;
  for (const auto& t : m.triangles) {
    const V3 a = m.vertices[t[0]].cast<double>(), b = m.vertices[t[1]].cast<double>(),
             c = m.vertices[t[2]].cast<double>();
    v += a.dot(b.cross(c)) / 6.0;
  }
  return v;
}

// Closed, manifold and consistently oriented: every directed edge occurs once
// and its reverse occurs once (so every edge is shared by exactly 2 triangles).
::testing::AssertionResult IsWatertight(const TriangleMesh& m) {
  std::map<std::pair<int, int>, int> directed;
  for (const auto& t : m.triangles) {
    for (int k = 0; k < 3; ++k) ++directed[{t[k], t[(k + 1) % 3]}];
  }
  for (const auto& [e, count] : directed) {
    if (count != 1) return ::testing::AssertionFailure() << "edge " << e.first << "-" << e.second << " used " << count
                                                         << " times in the same direction";
    if (!directed.count({e.second, e.first})) {
      const V3 p = m.vertices[e.first].cast<double>(), q = m.vertices[e.second].cast<double>();
      return ::testing::AssertionFailure() << "edge " << e.first << "-" << e.second << " (" << p.transpose() << ") -> ("
                                           << q.transpose() << ") has no opposite edge";
    }
  }
  return ::testing::AssertionSuccess();
}

V3 ClosestPointOnTriangle(const V3& p, const V3& a, const V3& b, const V3& c) {
  // Ericson, Real-Time Collision Detection, 5.1.5.
  const V3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const V3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + d1 / (d1 - d3) * ab;
  const V3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + d2 / (d2 - d6) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
  const double denom = 1.0 / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

struct Nearest {
  double distance;
  V3 normal;  // unit normal of the nearest triangle
};

Nearest NearestTriangle(const TriangleMesh& m, const V3& p) {
  Nearest best{1e9, V3::Zero()};
  for (const auto& t : m.triangles) {
    const V3 a = m.vertices[t[0]].cast<double>(), b = m.vertices[t[1]].cast<double>(),
             c = m.vertices[t[2]].cast<double>();
    const double d = (ClosestPointOnTriangle(p, a, b, c) - p).norm();
    if (d < best.distance) best = {d, (b - a).cross(c - a).normalized()};
  }
  return best;
}

// Does the transform map the vertex set onto itself (within tol)?
bool VertexSetInvariant(const TriangleMesh& m, const Eigen::Affine3d& X, double tol = 1e-6) {
  for (const auto& v : m.vertices) {
    const V3 q = X * v.cast<double>();
    bool found = false;
    for (const auto& w : m.vertices) {
      if ((w.cast<double>() - q).norm() < tol) {
        found = true;
        break;
      }
    }
    if (!found) return false;
  }
  return true;
}

Eigen::Affine3d RotZ(double angle) { return Eigen::Affine3d(Eigen::AngleAxisd(angle, V3::UnitZ())); }

// Tool z of a default.yaml grasp, rpy_deg with R = Rz * Ry * Rx.
V3 ApproachFromRpyDeg(double roll, double pitch, double yaw) {
  const double d = kPi / 180;
  const Eigen::Matrix3d R = (Eigen::AngleAxisd(yaw * d, V3::UnitZ()) * Eigen::AngleAxisd(pitch * d, V3::UnitY()) *
                             Eigen::AngleAxisd(roll * d, V3::UnitX()))
                                .toRotationMatrix();
  return R.col(2);
}

struct GraspPoint {
  const char* name;
  V3 xyz;
  V3 rpy_deg;
};

// Grasps in the part frame, copied from assets/cells/default.yaml.
void ExpectGraspsOnSurface(const TriangleMesh& m, const std::vector<GraspPoint>& grasps) {
  for (const GraspPoint& g : grasps) {
    const Nearest n = NearestTriangle(m, g.xyz);
    EXPECT_LT(n.distance, 0.5e-3) << g.name;
    // The tool approaches into the part: against the outward surface normal.
    const V3 approach = ApproachFromRpyDeg(g.rpy_deg.x(), g.rpy_deg.y(), g.rpy_deg.z());
    EXPECT_LT(n.normal.dot(approach), -0.99) << g.name << " approach " << approach.transpose() << " normal "
                                             << n.normal.transpose();
  }
}

void ExpectBounds(const TriangleMesh& m, const V3& lo, const V3& hi) {
  const Eigen::AlignedBox3f b = m.Bounds();
  EXPECT_LT((b.min().cast<double>() - lo).norm(), 1e-6) << b.min().transpose();
  EXPECT_LT((b.max().cast<double>() - hi).norm(), 1e-6) << b.max().transpose();
}

// --- geometry -----------------------------------------------------------------

TEST(TriangleMesh, BoundsAreaAndDiameterOfUnitCube) {
  const TriangleMesh cube = UnitCube();
  EXPECT_TRUE(cube.Bounds().min().isZero());
  EXPECT_TRUE(cube.Bounds().max().isOnes());
  EXPECT_NEAR(cube.Area(), 6.0, 1e-12);
  EXPECT_NEAR(cube.Diameter(), std::sqrt(3.0), 1e-6);
  EXPECT_TRUE(IsWatertight(cube));
  EXPECT_NEAR(SignedVolume(cube), 1.0, 1e-12);
}

TEST(TriangleMesh, WatertightCheckCatchesHolesAndFlippedTriangles) {
  TriangleMesh holed = UnitCube();
  holed.triangles.pop_back();
  EXPECT_FALSE(IsWatertight(holed));
  TriangleMesh flipped = UnitCube();
  std::swap(flipped.triangles[3][0], flipped.triangles[3][1]);
  EXPECT_FALSE(IsWatertight(flipped));
}

TEST(TriangleMesh, EmptyMeshHasEmptyBoundsAndZeroMeasures) {
  const TriangleMesh m;
  EXPECT_TRUE(m.empty());
  EXPECT_TRUE(m.Bounds().isEmpty());
  EXPECT_EQ(m.Area(), 0.0);
  EXPECT_EQ(m.Diameter(), 0.0);
}

TEST(TriangleMesh, AppendTransformsAndOffsetsIndicesAndKeepsOrientationUnderReflection) {
  TriangleMesh m = UnitCube();
  const Eigen::Affine3f X = Eigen::Translation3f(2, 0, 0) * Eigen::AngleAxisf(0.5f, Eigen::Vector3f::UnitZ());
  m.Append(UnitCube(), X);
  ASSERT_EQ(m.vertices.size(), 16u);
  ASSERT_EQ(m.triangles.size(), 24u);
  EXPECT_TRUE(m.vertices[8 + 7].isApprox(X * Eigen::Vector3f(1, 1, 1)));
  EXPECT_EQ(m.triangles[12], UnitCube().triangles[0] + Eigen::Vector3i::Constant(8));
  EXPECT_NEAR(SignedVolume(m), 2.0, 1e-5);

  TriangleMesh mirrored;
  Eigen::Affine3f mirror = Eigen::Affine3f::Identity();
  mirror.linear()(0, 0) = -1;
  mirrored.Append(UnitCube(), mirror);
  EXPECT_NEAR(SignedVolume(mirrored), 1.0, 1e-6);  // still outward
}

TEST(TriangleMesh, DiameterOfLargeMeshIsWithinDocumentedBoundOfExact) {
  std::mt19937 rng{42};
  std::normal_distribution<float> gauss(0.f, 1.f);
  TriangleMesh m;
  for (int i = 0; i < 7000; ++i) {  // above the exact-diameter limit
    // Anisotropic blob: the diametral pair is not axis-aligned.
    m.vertices.emplace_back(0.1f * gauss(rng), 0.05f * gauss(rng), 0.02f * gauss(rng));
  }
  // In double, as Diameter() is (a float difference is off by ~1e-7 relative).
  std::vector<Eigen::Vector3d> p;
  for (const auto& v : m.vertices) p.push_back(v.cast<double>());
  double exact2 = 0;
  for (size_t i = 0; i < p.size(); ++i) {
    for (size_t j = i + 1; j < p.size(); ++j) exact2 = std::max(exact2, (p[i] - p[j]).squaredNorm());
  }
  const double exact = std::sqrt(exact2);
  const double approx = m.Diameter();
  EXPECT_LE(approx, exact + 1e-9);
  EXPECT_GE(approx, 0.997 * exact);  // bound documented in mesh.cc
}

// --- file I/O -------------------------------------------------------------------

// Found by fuzz/mesh_fuzz: an element without properties declaring 2^62
// records made the parser loop over them (a hang); they are empty records.
TEST(MeshIo, PropertylessElementWithAHugeCountLoadsAtOnce) {
  const std::string path = TempPath("huge_empty.ply");
  WriteFile(path, "ply\nformat ascii 1.0\nelement nothing 4611686018427387904\n"
                  "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                  "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
  Result<TriangleMesh> mesh = LoadMesh(path);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  EXPECT_EQ(mesh->vertices.size(), 3u);
  EXPECT_EQ(mesh->triangles.size(), 1u);
}

// Found by fuzz/mesh_fuzz: an ASCII face list length of 9.2e18 was converted
// to int (undefined behaviour).
TEST(MeshIo, AsciiListLongerThanTheFileIsCorruption) {
  const std::string path = TempPath("long_list.ply");
  WriteFile(path, "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                  "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                  "0 0 0\n1 0 0\n0 1 0\n9223372036854775807 0 1 2\n");
  Result<TriangleMesh> mesh = LoadMesh(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), Status::Code::kCorruption);
}

TEST(MeshIo, BinaryPlyRoundTripIsBitIdentical) {
  const TriangleMesh m = MakeFlangedBushing();
  const std::string path = TempPath("round_trip.ply");
  ASSERT_TRUE(SaveMeshPly(m, path).ok());
  const Result<TriangleMesh> back = LoadMesh(path);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_EQ(back->vertices.size(), m.vertices.size());
  ASSERT_EQ(back->triangles.size(), m.triangles.size());
  for (size_t i = 0; i < m.vertices.size(); ++i) {
    EXPECT_EQ(std::memcmp(back->vertices[i].data(), m.vertices[i].data(), 12), 0) << i;
  }
  EXPECT_EQ(back->triangles, m.triangles);
}

TEST(MeshIo, SavedPlyHasDocumentedBinaryLayout) {
  const std::string path = TempPath("layout.ply");
  ASSERT_TRUE(SaveMeshPly(Tetrahedron(), path).ok());
  const std::string bytes = ReadFile(path);
  const std::string header_end = "end_header\n";
  const size_t body = bytes.find(header_end) + header_end.size();
  ASSERT_EQ(bytes.rfind("ply\nformat binary_little_endian 1.0\n", 0), 0u);
  // 4 vertices x 3 float32, then 4 faces of (uint8 3, 3 x int32).
  ASSERT_EQ(bytes.size() - body, 4u * 12 + 4u * 13);
  float x1;
  std::memcpy(&x1, bytes.data() + body + 12, 4);
  EXPECT_EQ(x1, 1.0f);
  EXPECT_EQ(bytes[body + 48], 3);
  int32_t i1;
  std::memcpy(&i1, bytes.data() + body + 48 + 1 + 4, 4);
  EXPECT_EQ(i1, 2);
}

TEST(MeshIo, LoadsAsciiPlyWithDoublesExtraPropertiesAndFanTriangulatedQuads) {
  const std::string path = TempPath("ascii.ply");
  WriteFile(path,
            "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\n"
            "element vertex 5\r\nproperty double x\r\nproperty double y\r\nproperty double z\r\n"
            "property uchar red\r\n"
            "element face 2\r\nproperty list uchar uint vertex_index\r\n"
            "element edge 1\r\nproperty int vertex1\r\nproperty int vertex2\r\nend_header\r\n"
            "0 0 0 255\r\n1 0 0 0\r\n1 1 0 0\r\n0 1 0 0\r\n0.5 0.5 1 7\r\n"
            "4 0 3 2 1\r\n3 0 1 4\r\n0 1");  // no final newline
  const Result<TriangleMesh> m = LoadMesh(path);
  ASSERT_TRUE(m.ok()) << m.status().ToString();
  ASSERT_EQ(m->vertices.size(), 5u);
  EXPECT_TRUE(m->vertices[4].isApprox(Eigen::Vector3f(0.5f, 0.5f, 1.0f)));
  ASSERT_EQ(m->triangles.size(), 3u);  // quad -> 2, triangle -> 1
  EXPECT_EQ(m->triangles[0], Eigen::Vector3i(0, 3, 2));
  EXPECT_EQ(m->triangles[1], Eigen::Vector3i(0, 2, 1));
  EXPECT_EQ(m->triangles[2], Eigen::Vector3i(0, 1, 4));
}

TEST(MeshIo, LoadsBinaryPlyWithDoubleCoordinatesAndOtherListTypes) {
  std::string s =
      "ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty double x\nproperty double y\n"
      "property double z\nelement face 4\nproperty list int ushort vertex_indices\nend_header\n";
  const TriangleMesh tet = Tetrahedron();
  for (const auto& v : tet.vertices) {
    for (int k = 0; k < 3; ++k) Put<double>(&s, v[k]);
  }
  for (const auto& t : tet.triangles) {
    Put<int32_t>(&s, 3);
    for (int k = 0; k < 3; ++k) Put<uint16_t>(&s, static_cast<uint16_t>(t[k]));
  }
  const std::string path = TempPath("double.ply");
  WriteFile(path, s);
  const Result<TriangleMesh> m = LoadMesh(path);
  ASSERT_TRUE(m.ok()) << m.status().ToString();
  EXPECT_EQ(m->vertices, tet.vertices);
  EXPECT_EQ(m->triangles, tet.triangles);
}

std::string BinaryStl(const TriangleMesh& m, const std::string& header_text) {
  std::string s = header_text;
  s.resize(80, ' ');
  Put<uint32_t>(&s, static_cast<uint32_t>(m.triangles.size()));
  for (const auto& t : m.triangles) {
    for (int k = 0; k < 3; ++k) Put<float>(&s, 0.f);  // normal (ignored)
    for (int c = 0; c < 3; ++c) {
      for (int k = 0; k < 3; ++k) Put<float>(&s, m.vertices[t[c]][k]);
    }
    Put<uint16_t>(&s, 0);
  }
  return s;
}

std::string AsciiStl(const TriangleMesh& m) {
  std::string s = "solid my test part\n";
  for (const auto& t : m.triangles) {
    s += "  facet normal 0 0 0\n    outer loop\n";
    for (int c = 0; c < 3; ++c) {
      const auto& v = m.vertices[t[c]];
      s += "      vertex " + std::to_string(v.x()) + " " + std::to_string(v.y()) + " " + std::to_string(v.z()) + "\n";
    }
    s += "    endloop\n  endfacet\n";
  }
  return s + "endsolid my test part\n";
}

TEST(MeshIo, LoadsBinaryStlAndMergesRepeatedVertices) {
  const std::string path = TempPath("tet.stl");
  WriteFile(path, BinaryStl(Tetrahedron(), "binary"));
  const Result<TriangleMesh> m = LoadMesh(path);
  ASSERT_TRUE(m.ok()) << m.status().ToString();
  EXPECT_EQ(m->vertices.size(), 4u);
  EXPECT_EQ(m->triangles.size(), 4u);
  EXPECT_TRUE(IsWatertight(*m));
  EXPECT_NEAR(SignedVolume(*m), 1.0 / 6.0, 1e-7);
}

TEST(MeshIo, BinaryStlWhoseHeaderStartsWithSolidIsReadAsBinary) {
  const std::string path = TempPath("solid_header.stl");
  WriteFile(path, BinaryStl(Tetrahedron(), "solid exported by a CAD tool"));
  const Result<TriangleMesh> m = LoadMesh(path);
  ASSERT_TRUE(m.ok()) << m.status().ToString();
  EXPECT_EQ(m->triangles.size(), 4u);
}

TEST(MeshIo, LoadsAsciiStlAndMergesRepeatedVertices) {
  const std::string path = TempPath("tet_ascii.stl");
  WriteFile(path, AsciiStl(Tetrahedron()));
  const Result<TriangleMesh> m = LoadMesh(path);
  ASSERT_TRUE(m.ok()) << m.status().ToString();
  EXPECT_EQ(m->vertices.size(), 4u);
  EXPECT_EQ(m->triangles.size(), 4u);
  EXPECT_TRUE(IsWatertight(*m));
  EXPECT_NEAR(SignedVolume(*m), 1.0 / 6.0, 1e-6);
}

void ExpectError(const std::string& path, Status::Code code, const std::string& reason) {
  const Result<TriangleMesh> m = LoadMesh(path);
  ASSERT_FALSE(m.ok()) << path;
  EXPECT_EQ(m.status().code(), code) << m.status().ToString();
  EXPECT_NE(m.status().message().find(path), std::string::npos) << m.status().ToString();
  EXPECT_NE(m.status().message().find(reason), std::string::npos) << m.status().ToString();
}

TEST(MeshIoErrors, MissingFileIsNotFound) {
  ExpectError(TempPath("does_not_exist.ply"), Status::Code::kNotFound, "no such file");
}

TEST(MeshIoErrors, EmptyFileIsCorruption) {
  const std::string path = TempPath("empty.ply");
  WriteFile(path, "");
  ExpectError(path, Status::Code::kCorruption, "empty file");
}

TEST(MeshIoErrors, WrongMagicIsCorruption) {
  const std::string path = TempPath("wrong_magic.ply");
  std::string bytes = ReadFile(TestAssetsDir() + "/parts/l_bracket.ply");
  ASSERT_FALSE(bytes.empty());
  bytes[2] = 'x';  // "plx"
  WriteFile(path, bytes);
  ExpectError(path, Status::Code::kCorruption, "magic");
  const std::string other = TempPath("garbage.obj");
  WriteFile(other, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  ExpectError(other, Status::Code::kCorruption, "unrecognised");
}

TEST(MeshIoErrors, TruncatedFilesAreCorruption) {
  const std::string good = TempPath("to_truncate.ply");
  ASSERT_TRUE(SaveMeshPly(MakePipeTee(), good).ok());
  const std::string bytes = ReadFile(good);
  const std::string path = TempPath("truncated.ply");
  for (const size_t cut : {size_t{1}, size_t{7}, bytes.size() / 2, bytes.size() - 200}) {
    WriteFile(path, bytes.substr(0, bytes.size() - cut));
    ExpectError(path, Status::Code::kCorruption, "truncated");
  }
  WriteFile(path, bytes.substr(0, 60));  // inside the header
  ExpectError(path, Status::Code::kCorruption, "end_header");

  const std::string stl = BinaryStl(Tetrahedron(), "binary");
  const std::string stl_path = TempPath("truncated.stl");
  WriteFile(stl_path, stl.substr(0, stl.size() - 10));
  ExpectError(stl_path, Status::Code::kCorruption, "truncated");
  const std::string ascii = AsciiStl(Tetrahedron());
  WriteFile(stl_path, ascii.substr(0, ascii.size() / 2));
  ExpectError(stl_path, Status::Code::kCorruption, "truncated");
}

TEST(MeshIoErrors, HugeDeclaredCountIsCorruptionNotAnAllocation) {
  const std::string path = TempPath("huge_count.ply");
  WriteFile(path,
            "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000000\nproperty float x\n"
            "property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
            "end_header\n0123456789");
  ExpectError(path, Status::Code::kCorruption, "truncated");
}

TEST(MeshIoErrors, VertexIndexOutOfRangeIsCorruption) {
  const std::string path = TempPath("bad_index.ply");
  WriteFile(path,
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
            "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 3\n");
  ExpectError(path, Status::Code::kCorruption, "face 1 has vertex index 3 out of range");
  WriteFile(path,
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
            "0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n");
  ExpectError(path, Status::Code::kCorruption, "out of range");
}

TEST(MeshIoErrors, NonFiniteVertexIsCorruption) {
  const std::string path = TempPath("nan.ply");
  WriteFile(path,
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
            "0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n");
  ExpectError(path, Status::Code::kCorruption, "vertex 1 is not finite");

  TriangleMesh tet = Tetrahedron();
  tet.vertices[2].z() = std::numeric_limits<float>::quiet_NaN();
  const std::string stl_path = TempPath("nan.stl");
  WriteFile(stl_path, BinaryStl(tet, "binary"));
  ExpectError(stl_path, Status::Code::kCorruption, "non-finite");
}

TEST(MeshIoErrors, FileWithoutTrianglesIsCorruption) {
  const std::string path = TempPath("no_faces.ply");
  WriteFile(path,
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "end_header\n0 0 0\n1 0 0\n0 1 0\n");
  ExpectError(path, Status::Code::kCorruption, "no triangles");
  const std::string stl_path = TempPath("no_faces.stl");
  WriteFile(stl_path, "solid empty\nendsolid empty\n");
  ExpectError(stl_path, Status::Code::kCorruption, "no triangles");
}

TEST(MeshIoErrors, GarbledHeaderIsCorruption) {
  const std::string path = TempPath("garbled.ply");
  WriteFile(path, "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty flot x\nend_header\n");
  ExpectError(path, Status::Code::kCorruption, "unknown property type");
  WriteFile(path, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
                  "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 zero\n3 0 0 0\n");
  ExpectError(path, Status::Code::kCorruption, "malformed");
}

// Corrupted bytes anywhere (header or body) give either a valid mesh or a
// Corruption status, never a crash or a mesh with bad indices.
TEST(MeshIoErrors, RandomByteFlipsNeverYieldAnInvalidMesh) {
  const std::string good = TempPath("to_flip.ply");
  ASSERT_TRUE(SaveMeshPly(MakeFlangedBushing(), good).ok());
  const std::string bytes = ReadFile(good);
  const std::string ascii = AsciiStl(Tetrahedron());
  std::mt19937 rng{42};
  int rejected = 0;
  for (int trial = 0; trial < 300; ++trial) {
    const bool use_ply = trial % 2 == 0;
    std::string b = use_ply ? bytes : ascii;
    const size_t span = trial % 3 == 0 ? std::min<size_t>(b.size(), 300) : b.size();  // often the header
    for (int k = 0; k < 3; ++k) b[std::uniform_int_distribution<size_t>(0, span - 1)(rng)] ^= 0x5a;
    const std::string path = TempPath(use_ply ? "flipped.ply" : "flipped.stl");
    WriteFile(path, b);
    const Result<TriangleMesh> m = LoadMesh(path);
    if (!m.ok()) {
      EXPECT_EQ(m.status().code(), Status::Code::kCorruption) << m.status().ToString();
      ++rejected;
      continue;
    }
    for (const auto& v : m->vertices) ASSERT_TRUE(v.allFinite());
    for (const auto& t : m->triangles) {
      ASSERT_TRUE((t.array() >= 0).all() && (t.array() < static_cast<int>(m->vertices.size())).all());
    }
  }
  EXPECT_GT(rejected, 0);
}

// --- generated assets ---------------------------------------------------------------

TEST(MeshGen, FlangedBushingIsWatertightRevoluteWithAnalyticVolume) {
  const FlangedBushingParams p;
  const TriangleMesh m = MakeFlangedBushing(p);
  EXPECT_TRUE(IsWatertight(m));
  EXPECT_LT(m.triangles.size(), 10000u);
  const double rb = 0.006, rh = 0.018, rf = 0.030;
  const double analytic = kPi * (rf * rf - rb * rb) * 0.008 + kPi * (rh * rh - rb * rb) * 0.032;
  EXPECT_GT(SignedVolume(m), 0);
  EXPECT_NEAR(SignedVolume(m) / analytic, 1.0, 0.01);
  ExpectBounds(m, V3(-0.03, -0.03, 0), V3(0.03, 0.03, 0.04));
  EXPECT_TRUE(VertexSetInvariant(m, RotZ(2 * kPi / p.segments)));
  EXPECT_TRUE(VertexSetInvariant(m, RotZ(kPi)));
  EXPECT_FALSE(VertexSetInvariant(m, RotZ(kPi / p.segments)));  // the check can fail
  // Not symmetric top to bottom (a 180 degree turn about x).
  EXPECT_FALSE(VertexSetInvariant(m, Eigen::Translation3d(0, 0, 0.04) *
                                         Eigen::AngleAxisd(kPi, V3::UnitX())));
  ExpectGraspsOnSurface(m, {{"hub_top", {0.012, 0.0, 0.040}, {180, 0, 0}},
                            {"flange_top", {0.024, 0.0, 0.008}, {180, 0, 0}},
                            {"flange_bottom", {0.015, 0.0, 0.0}, {0, 0, 0}}});
}

TEST(MeshGen, LBracketIsWatertightAsymmetricWithAnalyticVolume) {
  const TriangleMesh m = MakeLBracket();
  EXPECT_TRUE(IsWatertight(m));
  EXPECT_LT(m.triangles.size(), 10000u);
  const double hole = kPi * 0.004 * 0.004 * 0.005;
  const double analytic = 0.090 * 0.050 * 0.005 + 0.005 * 0.050 * 0.055 - 3 * hole;
  EXPECT_GT(SignedVolume(m), 0);
  EXPECT_NEAR(SignedVolume(m) / analytic, 1.0, 0.01);
  ExpectBounds(m, V3(0, -0.025, 0), V3(0.090, 0.025, 0.060));
  // No proper symmetry; not even the mirror images the plain plates would have.
  Eigen::Affine3d mirror_y = Eigen::Affine3d::Identity();
  mirror_y.linear()(1, 1) = -1;
  EXPECT_FALSE(VertexSetInvariant(m, mirror_y));
  EXPECT_FALSE(VertexSetInvariant(m, RotZ(kPi)));
  // Holes are through: the axis of each hole is outside the material.
  for (const V3& c : {V3(0.030, 0.010, 0.0025), V3(0.070, -0.012, 0.0025), V3(0.0025, 0.012, 0.040)}) {
    EXPECT_NEAR(NearestTriangle(m, c).distance, 0.004, 0.0001) << c.transpose();
  }
  ExpectGraspsOnSurface(m, {{"base_top", {0.045, 0.0, 0.005}, {180, 0, 0}},
                            {"base_bottom", {0.045, 0.0, 0.0}, {0, 0, 0}},
                            {"upright_outer", {0.0, 0.0, 0.035}, {0, 90, 0}}});
}

TEST(MeshGen, PipeTeeIsWatertightUnionSymmetricUnderHalfTurnAboutZ) {
  const PipeTeeParams p;
  const TriangleMesh m = MakePipeTee(p);
  EXPECT_TRUE(IsWatertight(m));
  EXPECT_LT(m.triangles.size(), 10000u);
  const double R = 0.020, r = 0.015, L = 0.100, H = 0.050;
  // Union of two tubes: both cylinders minus the half Steinmetz solid they
  // share (8 R^3 / 3), for the outer surface and the bore.
  const double analytic = kPi * (R * R - r * r) * (L + H) - 8.0 * (R * R * R - r * r * r) / 3.0;
  EXPECT_GT(SignedVolume(m), 0);
  EXPECT_NEAR(SignedVolume(m) / analytic, 1.0, 0.02);
  ExpectBounds(m, V3(-0.05, -0.02, -0.02), V3(0.05, 0.02, 0.05));
  EXPECT_TRUE(VertexSetInvariant(m, RotZ(kPi)));
  EXPECT_FALSE(VertexSetInvariant(m, RotZ(kPi / 2)));
  EXPECT_FALSE(VertexSetInvariant(m, Eigen::Affine3d(Eigen::AngleAxisd(kPi, V3::UnitX()))));
  // No vertex inside the material: walls were cut where the other tube is.
  auto inside_run = [&](const V3& v, double rho) {
    return std::abs(v.x()) < L / 2 - 1e-6 && std::hypot(v.y(), v.z()) < rho - 1e-6;
  };
  auto inside_branch = [&](const V3& v, double rho) {
    return v.z() > 1e-6 && v.z() < H - 1e-6 && std::hypot(v.x(), v.y()) < rho - 1e-6;
  };
  auto outside_bores = [&](const V3& v) {
    const bool in_run_bore = std::abs(v.x()) <= L / 2 && std::hypot(v.y(), v.z()) <= r + 1e-6;
    const bool in_branch_bore = v.z() >= 0 && v.z() <= H && std::hypot(v.x(), v.y()) <= r + 1e-6;
    return !in_run_bore && !in_branch_bore;
  };
  for (const auto& vf : m.vertices) {
    const V3 v = vf.cast<double>();
    EXPECT_FALSE((inside_run(v, R) || inside_branch(v, R)) && outside_bores(v)) << v.transpose();
  }
  ExpectGraspsOnSurface(m, {{"run_bottom", {0.035, 0.0, -0.020}, {0, 0, 0}},
                            {"run_side_pos", {0.035, 0.020, 0.0}, {90, 0, 0}},
                            {"run_side_neg", {0.035, -0.020, 0.0}, {-90, 0, 0}},
                            {"branch_side", {0.0, 0.020, 0.040}, {90, 0, 0}}});
}

TEST(MeshGen, BinIsClosedOpenBoxWithInnerFloorAtOrigin) {
  BinSpec bin;
  bin.inner_size = V3(0.5, 0.36, 0.2);
  bin.wall_thickness = 0.012;
  const TriangleMesh m = MakeBinMesh(bin);
  EXPECT_TRUE(IsWatertight(m));
  const double t = 0.012;
  const double analytic = (0.5 + 2 * t) * (0.36 + 2 * t) * (0.2 + t) - 0.5 * 0.36 * 0.2;
  EXPECT_NEAR(SignedVolume(m), analytic, 1e-6);
  ExpectBounds(m, V3(-0.262, -0.192, -0.012), V3(0.262, 0.192, 0.2));
  // The inner floor is at z = 0 and faces up; the centre of the box is empty.
  const Nearest floor = NearestTriangle(m, V3(0, 0, 0));
  EXPECT_LT(floor.distance, 1e-9);
  EXPECT_GT(floor.normal.z(), 0.99);
  EXPECT_NEAR(NearestTriangle(m, V3(0, 0, 0.1)).distance, 0.1, 1e-6);
}

TEST(MeshGen, SuctionGripperIsClosedAndHangsAboveTheTcpUpToTheFlange) {
  const TriangleMesh m = MakeSuctionGripper();
  EXPECT_TRUE(IsWatertight(m));
  EXPECT_GT(SignedVolume(m), 0);
  ExpectBounds(m, V3(-0.01, -0.01, -0.27), V3(0.01, 0.01, 0.0));
  // The cup face is at the tool centre point, facing the approach direction.
  const Nearest tip = NearestTriangle(m, V3(0, 0, 0));
  EXPECT_LT(tip.distance, 1e-9);
  EXPECT_GT(tip.normal.z(), 0.99);
  EXPECT_TRUE(VertexSetInvariant(m, RotZ(2 * kPi / 64)));
}

TEST(MeshGen, ParallelJawLeavesTheOpeningFreeBetweenFingers) {
  const ParallelJawParams p;
  const TriangleMesh m = MakeParallelJawGripper(p);
  EXPECT_TRUE(IsWatertight(m));  // a union of closed boxes
  EXPECT_GT(SignedVolume(m), 0);
  ExpectBounds(m, V3(-0.045, -0.02, -0.16), V3(0.045, 0.02, 0.01));
  for (const auto& v : m.vertices) {
    if (v.z() > -0.1) {
      EXPECT_GE(std::abs(v.x()), 0.03 - 1e-6) << v.transpose();
    }
  }
  EXPECT_LT(NearestTriangle(m, V3(0.03, 0, 0.0)).distance, 1e-9);   // inner face of a finger
  EXPECT_LT(NearestTriangle(m, V3(-0.03, 0, 0.0)).distance, 1e-9);
}

TEST(MeshGen, PlaceNestIsOneClosedSolidWithoutSymmetryAndSlopesACameraAboveSees) {
  const PlaceNestParams p;
  const TriangleMesh m = MakePlaceNest(p);
  EXPECT_TRUE(IsWatertight(m));
  // Plate plus a frustum with rectangular ends (prismatoid: h/6 (A0 + 4 Am + A1)).
  using V2 = Eigen::Vector2d;
  const V2 b = p.base_max - p.base_min, t = p.top_max - p.top_min, mid = (b + t) / 2;
  const double frustum = p.pyramid_height / 6 * (b.prod() + 4 * mid.prod() + t.prod());
  const double analytic = p.plate_size.prod() * p.plate_thickness + frustum;
  EXPECT_NEAR(SignedVolume(m) / analytic, 1.0, 1e-6);
  ExpectBounds(m, V3(-0.055, -0.045, 0), V3(0.055, 0.045, 0.035));
  EXPECT_FALSE(VertexSetInvariant(m, RotZ(kPi)));
  EXPECT_FALSE(VertexSetInvariant(m, RotZ(kPi / 2)));
  Eigen::Affine3d mirror_x = Eigen::Affine3d::Identity(), mirror_y = Eigen::Affine3d::Identity();
  mirror_x.linear()(0, 0) = -1;
  mirror_y.linear()(1, 1) = -1;
  EXPECT_FALSE(VertexSetInvariant(m, mirror_x));
  EXPECT_FALSE(VertexSetInvariant(m, mirror_y));
  // The four slopes face up and out, 40 to 60 deg from the vertical: seen by
  // a camera above, well before the depth camera's grazing dropout.
  const double z_mid = p.plate_thickness + p.pyramid_height / 2;
  const V2 mid_lo = (p.base_min + p.top_min) / 2, mid_hi = (p.base_max + p.top_max) / 2;
  const V2 c = (mid_lo + mid_hi) / 2;
  const std::vector<std::pair<V3, V3>> faces = {  // a point 1 mm inside each slope, mid-height; its outward side
      {V3(mid_hi.x() - 0.001, c.y(), z_mid), V3(1, 0, 0)},
      {V3(mid_lo.x() + 0.001, c.y(), z_mid), V3(-1, 0, 0)},
      {V3(c.x(), mid_hi.y() - 0.001, z_mid), V3(0, 1, 0)},
      {V3(c.x(), mid_lo.y() + 0.001, z_mid), V3(0, -1, 0)}};
  for (const auto& [probe, dir] : faces) {
    const Nearest slope = NearestTriangle(m, probe);
    const double from_vertical = std::acos(slope.normal.z()) * 180 / kPi;
    EXPECT_GT(slope.normal.dot(dir), 0.5) << dir.transpose();
    EXPECT_GT(from_vertical, 40) << dir.transpose();
    EXPECT_LT(from_vertical, 60) << dir.transpose();
  }
}

// The committed files under assets/ are what the generator makes today.
TEST(MeshGen, CommittedAssetsMatchTheGenerator) {
  const std::string assets = TestAssetsDir();
  const Result<Cell> cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  const BinSpec& bin = cell->bin;
  const std::vector<std::pair<std::string, TriangleMesh>> expected = {
      {"parts/flanged_bushing.ply", MakeFlangedBushing()}, {"parts/l_bracket.ply", MakeLBracket()},
      {"parts/pipe_tee.ply", MakePipeTee()},               {"grippers/suction_cup.ply", MakeSuctionGripper()},
      {"grippers/parallel_jaw.ply", MakeParallelJawGripper()}, {"bin/default_bin.ply", MakeBinMesh(bin)},
      {"fixtures/place_nest.ply", MakePlaceNest()}};
  for (const auto& [name, mesh] : expected) {
    const Result<TriangleMesh> loaded = LoadMesh(assets + "/" + name);
    ASSERT_TRUE(loaded.ok()) << loaded.status().ToString();
    EXPECT_EQ(loaded->vertices, mesh.vertices) << name << ": rerun bp_make_assets";
    EXPECT_EQ(loaded->triangles, mesh.triangles) << name << ": rerun bp_make_assets";
  }
}

}  // namespace
}  // namespace bp
