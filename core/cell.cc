// The cell file loader. Reference: docs/cell.md.
//
// Parsing walks the YAML tree with the key path of every node, so each error
// can name the file, the line, the key path and the reason. Errors are raised
// inside this file as a private exception (CellError) and turned into a Status
// at the public boundary; yaml-cpp's own exceptions are caught there too.
// A Cell is only returned once every section has been validated.

#include "core/cell.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <numbers>
#include <set>
#include <sstream>
#include <string_view>
#include <tuple>
#include <utility>

#include "core/address_list.h"
#include "core/atomic_file.h"

namespace bp {
namespace internal {
extern const std::string_view kDefaultCellYaml;  // generated from assets/cells/default.yaml
}  // namespace internal

namespace {

namespace fs = std::filesystem;

constexpr const char* kEmbeddedPath = "<embedded default>";
constexpr int kMaxSyntheticParts = 500;
// |q| may differ from 1 by this much before normalisation (hand-typed values).
constexpr double kQuatNormTolerance = 1e-2;
// Largest |(R^T R - I)_ij| accepted for a rotation matrix before re-orthonormalisation.
constexpr double kOrthonormalTolerance = 1e-3;

struct CellError {
  Status status;
};

Status MakeStatus(Status::Code code, std::string msg) {
  switch (code) {
    case Status::Code::kNotFound: return Status::NotFound(std::move(msg));
    case Status::Code::kCorruption: return Status::Corruption(std::move(msg));
    default: return Status::InvalidArgument(std::move(msg));
  }
}

std::string Join(const std::string& path, std::string_view key) {
  return path.empty() ? std::string(key) : path + "." + std::string(key);
}

std::string At(const std::string& path, size_t i) { return path + "[" + std::to_string(i) + "]"; }

// What a user can do about a corrupt calibration result file: restore the
// backup the last rewrite kept, when there is one.
std::string BackupHint(const std::string& file) {
  const std::string bak = AtomicBackupPath(file);
  std::error_code ec;
  if (fs::is_regular_file(bak, ec)) {
    return "; the previous calibration is kept in '" + bak + "': restore it with `cp '" + bak +
           "' '" + file + "'`, or remove the file to use camera.pose";
  }
  return "; there is no backup ('" + bak + "'): remove the file to use camera.pose, or calibrate again";
}

std::string FormatNumber(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

size_t EditDistance(std::string_view a, std::string_view b) {
  std::vector<size_t> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diag = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diag = up;
    }
  }
  return row[b.size()];
}

std::string OneOf(std::initializer_list<std::string_view> names) {
  std::string s;
  for (std::string_view n : names) s += (s.empty() ? "" : ", ") + std::string(n);
  return s;
}

// R = Rz(yaw) * Ry(pitch) * Rx(roll): fixed axes X, then Y, then Z.
Mat3 RotationFromRpyDeg(double roll_deg, double pitch_deg, double yaw_deg) {
  constexpr double kDeg = std::numbers::pi / 180.0;
  return (Eigen::AngleAxisd(yaw_deg * kDeg, Vec3::UnitZ()) *
          Eigen::AngleAxisd(pitch_deg * kDeg, Vec3::UnitY()) *
          Eigen::AngleAxisd(roll_deg * kDeg, Vec3::UnitX()))
      .toRotationMatrix();
}

// Walks one YAML document. `file_` names the document in messages and
// `base_dir_` resolves its relative paths.
class Parser {
 public:
  Parser(std::string file, fs::path base_dir) : file_(std::move(file)), base_dir_(std::move(base_dir)) {}

  Cell ParseCell(const YAML::Node& root);
  Pose ParseHandEye(const YAML::Node& root);

 private:
  using Code = Status::Code;

  // ---- errors -------------------------------------------------------------
  [[noreturn]] void Fail(const YAML::Node& where, const std::string& key, const std::string& reason,
                         Code code = Code::kInvalidArgument) const {
    std::string msg = file_;
    if (const int line = LineOf(where); line > 0) msg += ":" + std::to_string(line);
    msg += ": ";
    if (!key.empty()) msg += key + ": ";
    msg += reason;
    throw CellError{MakeStatus(code, std::move(msg))};
  }
  void Check(bool ok, const YAML::Node& where, const std::string& key, const std::string& reason) const {
    if (!ok) Fail(where, key, reason);
  }
  static int LineOf(const YAML::Node& n) {
    if (!n.IsDefined()) return 0;
    try {
      return n.Mark().line + 1;  // null mark: line -1
    } catch (const YAML::Exception&) {
      return 0;
    }
  }
  static std::string What(const YAML::Node& n) {
    if (!n.IsDefined() || n.IsNull()) return "nothing";
    if (n.IsSequence()) return "a list";
    if (n.IsMap()) return "a map";
    return "'" + n.Scalar() + "'";
  }

  // ---- structure ----------------------------------------------------------
  // Checks that n is a map and that every key is in `allowed`, once.
  void ExpectMap(const YAML::Node& n, const std::string& path,
                 std::initializer_list<std::string_view> allowed) const {
    if (!n.IsMap()) Fail(n, path, "expected a map, got " + What(n));
    std::set<std::string> seen;
    for (const auto& kv : n) {
      const YAML::Node& k = kv.first;
      if (!k.IsScalar()) Fail(k, path, "map keys must be plain names");
      const std::string& name = k.Scalar();
      if (std::find(allowed.begin(), allowed.end(), name) == allowed.end()) {
        std::string reason = "unknown key '" + name + "'";
        std::string_view best;
        size_t best_d = 3;  // suggest only close matches
        for (std::string_view a : allowed) {
          if (const size_t d = EditDistance(name, a); d < best_d) best_d = d, best = a;
        }
        if (!best.empty()) reason += " (did you mean '" + std::string(best) + "'?)";
        reason += "; allowed keys: " + OneOf(allowed);
        Fail(k, Join(path, name), reason);
      }
      if (!seen.insert(name).second) Fail(k, Join(path, name), "duplicate key");
    }
  }
  void ExpectSeq(const YAML::Node& n, const std::string& path) const {
    if (!n.IsSequence()) Fail(n, path, "expected a list, got " + What(n));
  }
  YAML::Node Req(const YAML::Node& map, const std::string& path, std::string_view key) const {
    YAML::Node c = map[std::string(key)];
    if (!c.IsDefined()) Fail(map, Join(path, key), "missing required key");
    return c;
  }

  // ---- scalars ------------------------------------------------------------
  double Number(const YAML::Node& n, const std::string& key) const {
    double v = 0;
    if (!n.IsScalar() || !YAML::convert<double>::decode(n, v)) Fail(n, key, "expected a number, got " + What(n));
    if (!std::isfinite(v)) Fail(n, key, "expected a finite number, got " + What(n));
    return v;
  }
  int Int(const YAML::Node& n, const std::string& key) const {
    int v = 0;
    if (!n.IsScalar() || !YAML::convert<int>::decode(n, v)) Fail(n, key, "expected an integer, got " + What(n));
    return v;
  }
  uint64_t Uint64(const YAML::Node& n, const std::string& key) const {
    uint64_t v = 0;
    if (!n.IsScalar() || !YAML::convert<uint64_t>::decode(n, v)) {
      Fail(n, key, "expected a non-negative integer, got " + What(n));
    }
    return v;
  }
  bool Bool(const YAML::Node& n, const std::string& key) const {
    bool v = false;
    if (!n.IsScalar() || !YAML::convert<bool>::decode(n, v)) Fail(n, key, "expected true or false, got " + What(n));
    return v;
  }
  std::string String(const YAML::Node& n, const std::string& key) const {
    if (!n.IsScalar()) Fail(n, key, "expected a string, got " + What(n));
    return n.Scalar();
  }
  std::string Name(const YAML::Node& n, const std::string& key) const {
    std::string s = String(n, key);
    Check(!s.empty(), n, key, "must not be empty");
    return s;
  }
  template <typename E>
  E Enum(const YAML::Node& n, const std::string& key, std::string_view what,
         std::initializer_list<std::pair<std::string_view, E>> names) const {
    const std::string s = String(n, key);
    std::string all;
    for (const auto& [name, value] : names) {
      if (s == name) return value;
      all += (all.empty() ? "" : ", ") + std::string(name);
    }
    Fail(n, key, "unknown " + std::string(what) + " '" + s + "' (expected one of: " + all + ")");
  }
  // Optional scalars: `def` when the key is absent.
  double OptNumber(const YAML::Node& map, const std::string& path, const char* key, double def) const {
    const YAML::Node c = map[key];
    return c.IsDefined() ? Number(c, Join(path, key)) : def;
  }
  int OptInt(const YAML::Node& map, const std::string& path, const char* key, int def) const {
    const YAML::Node c = map[key];
    return c.IsDefined() ? Int(c, Join(path, key)) : def;
  }
  bool OptBool(const YAML::Node& map, const std::string& path, const char* key, bool def) const {
    const YAML::Node c = map[key];
    return c.IsDefined() ? Bool(c, Join(path, key)) : def;
  }
  std::string OptString(const YAML::Node& map, const std::string& path, const char* key, std::string def) const {
    const YAML::Node c = map[key];
    return c.IsDefined() ? String(c, Join(path, key)) : def;
  }
  int Port(const YAML::Node& map, const std::string& path, const char* key, int def, int lo = 0) const {
    const int p = OptInt(map, path, key, def);
    Check(p >= lo && p <= 65535, map[key], Join(path, key),
          "port " + std::to_string(p) + " is outside " + std::to_string(lo) + "..65535");
    return p;
  }

  // ---- lists, vectors, poses ----------------------------------------------
  std::vector<double> Numbers(const YAML::Node& n, const std::string& key, size_t count) const {
    if (!n.IsSequence() || n.size() != count) {
      Fail(n, key, "expected a list of " + std::to_string(count) + " numbers, got " +
                       (n.IsSequence() ? "a list of " + std::to_string(n.size()) : What(n)));
    }
    std::vector<double> v(count);
    for (size_t i = 0; i < count; ++i) v[i] = Number(n[i], At(key, i));
    return v;
  }
  Vec3 Vector3(const YAML::Node& n, const std::string& key) const {
    const std::vector<double> v = Numbers(n, key, 3);
    return Vec3(v[0], v[1], v[2]);
  }
  std::vector<int> Ints(const YAML::Node& n, const std::string& key) const {
    ExpectSeq(n, key);
    std::vector<int> v;
    for (size_t i = 0; i < n.size(); ++i) v.push_back(Int(n[i], At(key, i)));
    return v;
  }
  Pose ParsePose(const YAML::Node& n, const std::string& key) const;
  // A simple polygon of >= 3 [x, y] points (m) with non-zero area, returned
  // counter-clockwise.
  std::vector<Eigen::Vector2d> Polygon(const YAML::Node& n, const std::string& key) const;
  Flat2DSpec ParseFlat2D(const YAML::Node& n, const std::string& path, const Cell& cell) const;
  PartPerception ParsePartPerception(const YAML::Node& n, const std::string& path) const;

  // ---- paths --------------------------------------------------------------
  std::string Resolve(const std::string& p) const {
    fs::path path(p);
    if (path.is_relative()) path = base_dir_ / path;
    return path.lexically_normal().string();
  }
  // A mesh path, resolved; the file must exist (it is parsed later, by LoadMesh).
  std::string MeshPath(const YAML::Node& n, const std::string& key) const {
    const std::string resolved = Resolve(Name(n, key));
    std::error_code ec;
    if (!fs::is_regular_file(resolved, ec)) {
      Fail(n, key, "mesh file '" + resolved + "' does not exist", Code::kNotFound);
    }
    return resolved;
  }

  // ---- sections -----------------------------------------------------------
  void ParseCamera(const YAML::Node& n, Cell& cell) const;
  CameraConfig ParseCameraConfig(const YAML::Node& n, const std::string& path) const;
  NoiseModel ParseNoise(const YAML::Node& n, const std::string& path) const;
  VarietySpec ParseVariety(const YAML::Node& n, const std::string& path) const;
  void ParseSource(const YAML::Node& n, Cell& cell) const;
  void ParseBin(const YAML::Node& n, Cell& cell) const;
  void ParseRoi(const YAML::Node& n, Cell& cell) const;
  void ParseGrippers(const YAML::Node& n, Cell& cell) const;
  SeenContactRule ParseSeenContact(const YAML::Node& n, const std::string& path, GripperSpec::Kind kind) const;
  void ParseParts(const YAML::Node& n, Cell& cell) const;
  Symmetry ParseSymmetry(const YAML::Node& n, const std::string& path) const;
  void ParseFixtures(const YAML::Node& n, Cell& cell) const;
  void ParseTasks(const YAML::Node& n, Cell& cell) const;
  // tasks[i]: fixture and roi of the kinds that look elsewhere than the bin.
  void ParseTaskRegion(const YAML::Node& t, const std::string& path, const Cell& cell, TaskSpec& task) const;
  // A {min, max} box (max > min on every axis).
  Eigen::AlignedBox3d ParseBox(const YAML::Node& n, const std::string& path) const;
  // {translation (m), rotation_deg} with both >= 0; `with_tilt`: a
  // tilt_deg key is allowed too (read by the caller).
  std::pair<double, double> ParseOffsetRange(const YAML::Node& n, const std::string& path,
                                             std::pair<double, double> fallback, bool with_tilt = false) const;
  void ParseRobot(const YAML::Node& n, Cell& cell) const;
  void ParseEndpoints(const YAML::Node& n, Cell& cell) const;
  // endpoints.<name>: a list of IPv4 / IPv6 addresses (absent: empty).
  std::vector<std::string> IpList(const YAML::Node& n, const char* name) const;
  void ParseCalibration(const YAML::Node& n, const YAML::Node& camera, Cell& cell) const;
  void ParseRecording(const YAML::Node& n, Cell& cell) const;

  std::string file_;
  fs::path base_dir_;
};

Pose Parser::ParsePose(const YAML::Node& n, const std::string& key) const {
  ExpectMap(n, key, {"xyz", "rpy_deg", "quat_wxyz", "matrix"});
  const YAML::Node xyz = n["xyz"], rpy = n["rpy_deg"], quat = n["quat_wxyz"], matrix = n["matrix"];
  const int rotations = rpy.IsDefined() + quat.IsDefined() + matrix.IsDefined();
  if (rotations > 1) Fail(n, key, "give at most one of rpy_deg, quat_wxyz, matrix");
  Pose X = Pose::Identity();
  if (xyz.IsDefined()) X.translation() = Vector3(xyz, Join(key, "xyz"));
  if (rpy.IsDefined()) {
    const std::vector<double> a = Numbers(rpy, Join(key, "rpy_deg"), 3);
    X.linear() = RotationFromRpyDeg(a[0], a[1], a[2]);
  } else if (quat.IsDefined()) {
    const std::string qkey = Join(key, "quat_wxyz");
    const std::vector<double> q = Numbers(quat, qkey, 4);
    const Quat Q(q[0], q[1], q[2], q[3]);
    if (std::abs(Q.norm() - 1.0) > kQuatNormTolerance) {
      Fail(quat, qkey, "quaternion norm " + FormatNumber(Q.norm()) + " is not 1");
    }
    X.linear() = Q.normalized().toRotationMatrix();
  } else if (matrix.IsDefined()) {
    const std::string mkey = Join(key, "matrix");
    if (xyz.IsDefined()) Fail(n, key, "give the translation either in xyz or in matrix, not both");
    if (!matrix.IsSequence() || matrix.size() != 4) Fail(matrix, mkey, "expected 4 rows of 4 numbers");
    Eigen::Matrix4d M;
    for (int r = 0; r < 4; ++r) {
      const std::vector<double> row = Numbers(matrix[r], At(mkey, r), 4);
      for (int c = 0; c < 4; ++c) M(r, c) = row[c];
    }
    if ((M.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > 1e-9) {
      Fail(matrix, At(mkey, 3), "last row must be [0, 0, 0, 1]");
    }
    const Mat3 R = M.topLeftCorner<3, 3>();
    const double err = (R.transpose() * R - Mat3::Identity()).cwiseAbs().maxCoeff();
    if (err > kOrthonormalTolerance || R.determinant() < 0) {
      Fail(matrix, mkey, "rotation part is not orthonormal with determinant +1");
    }
    X.linear() = Quat(R).normalized().toRotationMatrix();
    X.translation() = M.topRightCorner<3, 1>();
  }
  return X;
}

NoiseModel Parser::ParseNoise(const YAML::Node& n, const std::string& path) const {
  ExpectMap(n, path, {"axial_sigma_base", "axial_sigma_quadratic", "grazing_start_deg", "grazing_full_deg",
                      "random_dropout", "projector_shadow", "projector_offset", "enabled", "mixed_pixels",
                      "mixed_pixel_jump", "speckle", "speckle_sigma"});
  NoiseModel m;
  m.axial_sigma_base = OptNumber(n, path, "axial_sigma_base", m.axial_sigma_base);
  Check(m.axial_sigma_base >= 0, n["axial_sigma_base"], Join(path, "axial_sigma_base"), "must be >= 0");
  m.axial_sigma_quadratic = OptNumber(n, path, "axial_sigma_quadratic", m.axial_sigma_quadratic);
  Check(m.axial_sigma_quadratic >= 0, n["axial_sigma_quadratic"], Join(path, "axial_sigma_quadratic"),
        "must be >= 0");
  m.grazing_start_deg = OptNumber(n, path, "grazing_start_deg", m.grazing_start_deg);
  Check(m.grazing_start_deg >= 0 && m.grazing_start_deg <= 90, n["grazing_start_deg"],
        Join(path, "grazing_start_deg"), "must be in [0, 90]");
  m.grazing_full_deg = OptNumber(n, path, "grazing_full_deg", m.grazing_full_deg);
  Check(m.grazing_full_deg >= m.grazing_start_deg && m.grazing_full_deg <= 90, n["grazing_full_deg"],
        Join(path, "grazing_full_deg"), "must be in [grazing_start_deg, 90]");
  m.random_dropout = OptNumber(n, path, "random_dropout", m.random_dropout);
  Check(m.random_dropout >= 0 && m.random_dropout <= 1, n["random_dropout"], Join(path, "random_dropout"),
        "must be in [0, 1]");
  m.projector_shadow = OptBool(n, path, "projector_shadow", m.projector_shadow);
  if (n["projector_offset"].IsDefined()) {
    m.projector_offset = Vector3(n["projector_offset"], Join(path, "projector_offset"));
  }
  m.enabled = OptBool(n, path, "enabled", m.enabled);
  m.mixed_pixels = OptNumber(n, path, "mixed_pixels", m.mixed_pixels);
  Check(m.mixed_pixels >= 0 && m.mixed_pixels <= 1, n["mixed_pixels"], Join(path, "mixed_pixels"), "must be in [0, 1]");
  m.mixed_pixel_jump = OptNumber(n, path, "mixed_pixel_jump", m.mixed_pixel_jump);
  Check(m.mixed_pixel_jump > 0, n["mixed_pixel_jump"], Join(path, "mixed_pixel_jump"), "must be > 0");
  m.speckle = OptNumber(n, path, "speckle", m.speckle);
  Check(m.speckle >= 0 && m.speckle <= 1, n["speckle"], Join(path, "speckle"), "must be in [0, 1]");
  m.speckle_sigma = OptNumber(n, path, "speckle_sigma", m.speckle_sigma);
  Check(m.speckle_sigma >= 0, n["speckle_sigma"], Join(path, "speckle_sigma"), "must be >= 0");
  return m;
}

VarietySpec Parser::ParseVariety(const YAML::Node& n, const std::string& path) const {
  ExpectMap(n, path, {"max_tilt_deg", "max_roll_deg", "focal_scale", "resolution_scale", "principal_offset",
                      "axial_noise_scale", "grazing_start_deg", "mixed_pixels", "speckle", "drop_styles"});
  VarietySpec v;
  const auto range = [&](const char* key, std::array<double, 2>& r, double lo, double hi) {
    const YAML::Node k = n[key];
    if (!k.IsDefined()) return;
    const std::vector<double> x = Numbers(k, Join(path, key), 2);
    Check(x[0] >= lo && x[0] <= x[1] && x[1] <= hi, k, Join(path, key),
          "must be [a, b] with " + FormatNumber(lo) + " <= a <= b <= " + FormatNumber(hi));
    r = {x[0], x[1]};
  };
  v.max_tilt_deg = OptNumber(n, path, "max_tilt_deg", v.max_tilt_deg);
  Check(v.max_tilt_deg >= 0 && v.max_tilt_deg <= 45, n["max_tilt_deg"], Join(path, "max_tilt_deg"),
        "must be in [0, 45]");
  v.max_roll_deg = OptNumber(n, path, "max_roll_deg", v.max_roll_deg);
  Check(v.max_roll_deg >= 0 && v.max_roll_deg <= 180, n["max_roll_deg"], Join(path, "max_roll_deg"),
        "must be in [0, 180]");
  range("focal_scale", v.focal_scale, 0.5, 2.0);
  range("resolution_scale", v.resolution_scale, 0.25, 4.0);
  v.principal_offset = OptNumber(n, path, "principal_offset", v.principal_offset);
  Check(v.principal_offset >= 0 && v.principal_offset <= 0.2, n["principal_offset"], Join(path, "principal_offset"),
        "must be in [0, 0.2]");
  range("axial_noise_scale", v.axial_noise_scale, 0.0, 20.0);
  range("grazing_start_deg", v.grazing_start_deg, 0.0, 78.0);
  range("mixed_pixels", v.mixed_pixels, 0.0, 1.0);
  range("speckle", v.speckle, 0.0, 0.1);
  if (const YAML::Node d = n["drop_styles"]; d.IsDefined()) {
    const std::string key = Join(path, "drop_styles");
    if (!d.IsSequence() || d.size() == 0) Fail(d, key, "expected a non-empty list of settled / jumbled / default");
    v.drop_styles.clear();
    for (size_t i = 0; i < d.size(); ++i) {
      v.drop_styles.push_back(Enum<DropStyle>(d[i], At(key, i), "drop style",
                                              {{"default", DropStyle::kDefault},
                                               {"settled", DropStyle::kSettled},
                                               {"jumbled", DropStyle::kJumbled}}));
    }
  }
  return v;
}

CameraConfig Parser::ParseCameraConfig(const YAML::Node& n, const std::string& path) const {
  ExpectMap(n, path, {"id", "name", "resolution", "intrinsics", "depth_range", "noise"});
  CameraConfig c;
  c.id = Int(Req(n, path, "id"), Join(path, "id"));
  Check(c.id >= 0, n["id"], Join(path, "id"), "must be >= 0");
  c.name = OptString(n, path, "name", "config" + std::to_string(c.id));

  const std::string rkey = Join(path, "resolution");
  const YAML::Node res = Req(n, path, "resolution");
  if (!res.IsSequence() || res.size() != 2) Fail(res, rkey, "expected [width, height] in pixels");
  c.intrinsics.width = Int(res[0], At(rkey, 0));
  c.intrinsics.height = Int(res[1], At(rkey, 1));
  Check(c.intrinsics.width > 0, res[0], At(rkey, 0), "width must be > 0");
  Check(c.intrinsics.height > 0, res[1], At(rkey, 1), "height must be > 0");

  const std::string ikey = Join(path, "intrinsics");
  const YAML::Node in = Req(n, path, "intrinsics");
  ExpectMap(in, ikey, {"fx", "fy", "cx", "cy", "distortion"});
  Intrinsics& K = c.intrinsics;
  K.fx = Number(Req(in, ikey, "fx"), Join(ikey, "fx"));
  K.fy = Number(Req(in, ikey, "fy"), Join(ikey, "fy"));
  K.cx = Number(Req(in, ikey, "cx"), Join(ikey, "cx"));
  K.cy = Number(Req(in, ikey, "cy"), Join(ikey, "cy"));
  Check(K.fx > 0, in["fx"], Join(ikey, "fx"), "focal length must be > 0");
  Check(K.fy > 0, in["fy"], Join(ikey, "fy"), "focal length must be > 0");
  Check(K.cx >= 0 && K.cx <= K.width, in["cx"], Join(ikey, "cx"), "principal point must lie in [0, width]");
  Check(K.cy >= 0 && K.cy <= K.height, in["cy"], Join(ikey, "cy"), "principal point must lie in [0, height]");
  if (const YAML::Node d = in["distortion"]; d.IsDefined()) {
    const std::string dkey = Join(ikey, "distortion");
    if (!d.IsSequence() || (d.size() != 4 && d.size() != 5)) Fail(d, dkey, "expected [k1, k2, p1, p2(, k3)]");
    for (size_t i = 0; i < d.size(); ++i) K.distortion[i] = Number(d[i], At(dkey, i));
  }

  if (const YAML::Node r = n["depth_range"]; r.IsDefined()) {
    const std::string dkey = Join(path, "depth_range");
    const std::vector<double> v = Numbers(r, dkey, 2);
    Check(v[0] > 0 && v[0] < v[1], r, dkey,
          "expected [min, max] with 0 < min < max (m), got [" + FormatNumber(v[0]) + ", " + FormatNumber(v[1]) + "]");
    c.min_depth = v[0];
    c.max_depth = v[1];
  }
  if (const YAML::Node m = n["noise"]; m.IsDefined()) c.noise = ParseNoise(m, Join(path, "noise"));
  return c;
}

void Parser::ParseCamera(const YAML::Node& n, Cell& cell) const {
  const std::string path = "camera";
  ExpectMap(n, path, {"mount", "pose", "hand_eye_file", "plane_calibration_file", "default_config", "configs"});
  CameraSpec& cam = cell.camera;
  if (const YAML::Node m = n["mount"]; m.IsDefined()) {
    cam.eye_in_hand = Enum<bool>(m, "camera.mount", "mount", {{"eye_to_hand", false}, {"eye_in_hand", true}});
  }

  // The camera pose: from the hand-eye file when it exists, else from `pose`.
  std::optional<Pose> pose;
  if (const YAML::Node p = n["pose"]; p.IsDefined()) pose = ParsePose(p, "camera.pose");
  if (const YAML::Node f = n["plane_calibration_file"]; f.IsDefined()) {
    cam.plane_calibration_file = Resolve(Name(f, "camera.plane_calibration_file"));
  }
  const YAML::Node given = n["hand_eye_file"];
  // With a calibration section, the result file defaults to "<cell file>.calibration.yaml",
  // next to the cell file (its name alone: Resolve puts it in the cell's directory).
  const YAML::Node h = given.IsDefined() || !cell.calibration || file_ == kEmbeddedPath
                           ? given
                           : YAML::Node(fs::path(file_).filename().string() + ".calibration.yaml");
  if (h.IsDefined()) {
    cam.hand_eye_file = Resolve(Name(h, "camera.hand_eye_file"));
    std::error_code ec;
    if (fs::exists(cam.hand_eye_file, ec)) {
      std::ifstream in(cam.hand_eye_file);
      std::stringstream text;
      text << in.rdbuf();
      if (!in) Fail(h, "camera.hand_eye_file", "cannot read '" + cam.hand_eye_file + "'", Code::kNotFound);
      // A calibration rewrite keeps the previous file as <file>.bak
      // (core/atomic_file.h): name it, so the user knows what to restore.
      const std::string of = " (camera.hand_eye_file of " + file_ + ")" + BackupHint(cam.hand_eye_file);
      try {
        Parser calib(cam.hand_eye_file, fs::path(cam.hand_eye_file).parent_path());
        pose = calib.ParseHandEye(YAML::Load(text.str()));
      } catch (const CellError& e) {
        throw CellError{MakeStatus(e.status.code(), e.status.message() + of)};
      } catch (const YAML::ParserException& e) {
        throw CellError{Status::Corruption(cam.hand_eye_file + ":" + std::to_string(e.mark.line + 1) +
                                           ": YAML syntax error: " + e.msg + of)};
      }
    }
  }
  if (!pose) Fail(n, "camera.pose", "missing required key (no hand-eye calibration file found either)");
  (cam.eye_in_hand ? cam.X_FC : cam.X_BC) = *pose;

  const YAML::Node configs = Req(n, path, "configs");
  ExpectSeq(configs, "camera.configs");
  Check(configs.size() > 0, configs, "camera.configs", "at least one camera configuration is required");
  for (size_t i = 0; i < configs.size(); ++i) {
    const std::string ckey = At("camera.configs", i);
    CameraConfig c = ParseCameraConfig(configs[i], ckey);
    if (cam.FindConfig(c.id) != nullptr) {
      Fail(configs[i]["id"], Join(ckey, "id"), "duplicate camera config id " + std::to_string(c.id));
    }
    cam.configs.push_back(std::move(c));
  }
  cam.default_config = OptInt(n, path, "default_config", cam.configs.front().id);
  if (cam.FindConfig(cam.default_config) == nullptr) {
    Fail(n["default_config"], "camera.default_config",
         "config id " + std::to_string(cam.default_config) + " is not among camera.configs");
  }
}

void Parser::ParseCalibration(const YAML::Node& n, const YAML::Node& camera, Cell& cell) const {
  const std::string path = "calibration";
  ExpectMap(n, path, {"target", "true_pose", "target_pose", "image_noise", "blur_sigma", "seed", "min_poses",
                      "auto_poses", "precision_target"});
  CalibrationSpec c;
  const YAML::Node t = Req(n, path, "target");
  ExpectMap(t, "calibration.target", {"type", "squares", "square_size"});
  if (const YAML::Node ty = t["type"]; ty.IsDefined()) {
    Enum<int>(ty, "calibration.target.type", "calibration target", {{"checkerboard", 0}});
  }
  const std::vector<int> sq = Ints(Req(t, "calibration.target", "squares"), "calibration.target.squares");
  Check(sq.size() == 2, t["squares"], "calibration.target.squares", "expected [cols, rows] of inner corners");
  Check(sq[0] >= 3 && sq[1] >= 3 && sq[0] <= 30 && sq[1] <= 30 && (sq[0] + sq[1]) % 2 == 1, t["squares"],
        "calibration.target.squares",
        "inner corners must be 3..30 each, one count even and one odd (a board that cannot be read upside down)");
  c.cols = sq[0];
  c.rows = sq[1];
  c.square_size = Number(Req(t, "calibration.target", "square_size"), "calibration.target.square_size");
  Check(c.square_size > 0.001 && c.square_size < 0.5, t["square_size"], "calibration.target.square_size",
        "must be within 0.001..0.5 m");
  if (const YAML::Node p = n["true_pose"]; p.IsDefined()) {
    c.true_pose = ParsePose(p, "calibration.true_pose");
  } else {
    c.true_pose = ParsePose(Req(camera, "camera", "pose"), "camera.pose");
  }
  c.target_pose = ParsePose(Req(n, path, "target_pose"), "calibration.target_pose");
  c.image_noise = OptNumber(n, path, "image_noise", c.image_noise);
  Check(c.image_noise >= 0 && c.image_noise <= 50, n["image_noise"], "calibration.image_noise", "must be within 0..50");
  c.blur_sigma = OptNumber(n, path, "blur_sigma", c.blur_sigma);
  Check(c.blur_sigma >= 0 && c.blur_sigma <= 5, n["blur_sigma"], "calibration.blur_sigma", "must be within 0..5 px");
  if (const YAML::Node s = n["seed"]; s.IsDefined()) c.seed = Uint64(s, "calibration.seed");
  c.min_poses = OptInt(n, path, "min_poses", c.min_poses);
  Check(c.min_poses >= 3, n["min_poses"], "calibration.min_poses", "must be at least 3");
  c.auto_poses = OptInt(n, path, "auto_poses", c.auto_poses);
  Check(c.auto_poses >= c.min_poses && c.auto_poses <= 15, n["auto_poses"], "calibration.auto_poses",
        "must be within min_poses..15");
  if (const YAML::Node p = n["precision_target"]; p.IsDefined()) {
    c.precision_target = ParsePose(p, "calibration.precision_target");
  }
  cell.calibration = c;
}

Pose Parser::ParseHandEye(const YAML::Node& root) {
  if (!root.IsMap()) Fail(root, "", "expected a map with a 'pose' key");
  return ParsePose(Req(root, "", "pose"), "pose");  // other keys (residuals, dates, ...) are ignored
}

void Parser::ParseSource(const YAML::Node& n, Cell& cell) const {
  const std::string path = "source";
  ExpectMap(n, path, {"kind", "dir", "num_parts", "seed", "simulate_picks", "part_classes", "variety", "in_hand_slip",
                      "fixture_offset", "bin_offset"});
  SourceSpec& s = cell.source;
  if (const YAML::Node k = n["kind"]; k.IsDefined()) {
    s.kind = Enum<SourceSpec::Kind>(k, "source.kind", "source kind",
                                    {{"synthetic", SourceSpec::Kind::kSynthetic},
                                     {"files", SourceSpec::Kind::kFiles},
                                     {"replay", SourceSpec::Kind::kReplay}});
  }
  if (const YAML::Node d = n["dir"]; d.IsDefined()) s.dir = Resolve(Name(d, "source.dir"));
  if (s.kind != SourceSpec::Kind::kSynthetic && s.dir.empty()) {
    Fail(n, "source.dir", "missing required key (source kind files / replay reads from a directory)");
  }
  s.num_parts = OptInt(n, path, "num_parts", s.num_parts);
  Check(s.num_parts >= 0 && s.num_parts <= kMaxSyntheticParts, n["num_parts"], "source.num_parts",
        "must be in 0.." + std::to_string(kMaxSyntheticParts) + ", got " + std::to_string(s.num_parts));
  if (const YAML::Node v = n["seed"]; v.IsDefined()) s.seed = Uint64(v, "source.seed");
  s.simulate_picks = OptBool(n, path, "simulate_picks", s.simulate_picks);
  if (const YAML::Node pc = n["part_classes"]; pc.IsDefined()) {
    s.part_classes = Ints(pc, "source.part_classes");
    for (size_t i = 0; i < s.part_classes.size(); ++i) {
      Check(cell.FindPart(s.part_classes[i]) != nullptr, pc[i], At("source.part_classes", i),
            "unknown part class " + std::to_string(s.part_classes[i]));
    }
  }
  if (const YAML::Node v = n["variety"]; v.IsDefined()) s.variety = ParseVariety(v, "source.variety");
  if (const YAML::Node v = n["in_hand_slip"]; v.IsDefined()) {
    std::tie(s.slip_translation, s.slip_rotation_deg) =
        ParseOffsetRange(v, "source.in_hand_slip", {s.slip_translation, s.slip_rotation_deg});
  }
  if (const YAML::Node v = n["fixture_offset"]; v.IsDefined()) {
    std::tie(s.fixture_offset_translation, s.fixture_offset_rotation_deg) = ParseOffsetRange(
        v, "source.fixture_offset", {s.fixture_offset_translation, s.fixture_offset_rotation_deg});
  }
  if (const YAML::Node v = n["bin_offset"]; v.IsDefined()) {
    std::tie(s.bin_offset_translation, s.bin_offset_yaw_deg) =
        ParseOffsetRange(v, "source.bin_offset", {s.bin_offset_translation, s.bin_offset_yaw_deg}, true);
    s.bin_offset_tilt_deg = OptNumber(v, "source.bin_offset", "tilt_deg", s.bin_offset_tilt_deg);
    Check(s.bin_offset_tilt_deg >= 0 && s.bin_offset_tilt_deg <= 5, v["tilt_deg"], "source.bin_offset.tilt_deg",
          "must be in [0, 5] deg");
  }
}

std::pair<double, double> Parser::ParseOffsetRange(const YAML::Node& n, const std::string& path,
                                                   std::pair<double, double> fallback, bool with_tilt) const {
  if (with_tilt) {
    ExpectMap(n, path, {"translation", "rotation_deg", "tilt_deg"});
  } else {
    ExpectMap(n, path, {"translation", "rotation_deg"});
  }
  const double t = OptNumber(n, path, "translation", fallback.first);
  const double r = OptNumber(n, path, "rotation_deg", fallback.second);
  Check(t >= 0 && t <= 0.1, n["translation"], Join(path, "translation"), "must be in [0, 0.1] m");
  Check(r >= 0 && r <= 45, n["rotation_deg"], Join(path, "rotation_deg"), "must be in [0, 45] deg");
  return {t, r};
}

Eigen::AlignedBox3d Parser::ParseBox(const YAML::Node& n, const std::string& path) const {
  ExpectMap(n, path, {"min", "max"});
  const Vec3 lo = Vector3(Req(n, path, "min"), Join(path, "min"));
  const Vec3 hi = Vector3(Req(n, path, "max"), Join(path, "max"));
  Check((lo.array() < hi.array()).all(), n["max"], Join(path, "max"), "must be > min on every axis");
  return Eigen::AlignedBox3d(lo, hi);
}

void Parser::ParseBin(const YAML::Node& n, Cell& cell) const {
  ExpectMap(n, "bin", {"inner_size", "wall_thickness", "pose", "mesh", "detect", "detect_search", "detect_warn"});
  BinSpec& b = cell.bin;
  if (const YAML::Node s = n["inner_size"]; s.IsDefined()) {
    b.inner_size = Vector3(s, "bin.inner_size");
    for (int i = 0; i < 3; ++i) Check(b.inner_size[i] > 0, s[i], At("bin.inner_size", i), "must be > 0");
  }
  b.wall_thickness = OptNumber(n, "bin", "wall_thickness", b.wall_thickness);
  Check(b.wall_thickness > 0, n["wall_thickness"], "bin.wall_thickness", "must be > 0");
  if (const YAML::Node p = n["pose"]; p.IsDefined()) b.X_BW = ParsePose(p, "bin.pose");
  if (const YAML::Node m = n["mesh"]; m.IsDefined()) b.mesh = MeshPath(m, "bin.mesh");
  BinDetectSpec& d = b.detect;
  if (const YAML::Node m = n["detect"]; m.IsDefined()) {
    d.mode = Enum<BinDetectSpec::Mode>(m, "bin.detect", "bin detection mode",
                                       {{"off", BinDetectSpec::Mode::kOff},
                                        {"on", BinDetectSpec::Mode::kOn},
                                        {"required", BinDetectSpec::Mode::kRequired}});
  }
  if (const YAML::Node v = n["detect_search"]; v.IsDefined()) {
    // A free-standing bin may stand at any yaw: rotation_deg up to 180, or
    // "any" (180); the detection finds yaw modulo the rim's symmetry.
    const std::string path = "bin.detect_search";
    YAML::Node ranged = YAML::Clone(v);
    const YAML::Node r = v.IsMap() ? v["rotation_deg"] : YAML::Node();
    double yaw = d.search_yaw_deg;
    if (r.IsDefined()) {
      if (r.IsScalar() && r.Scalar() == "any") {
        yaw = 180.0;
      } else {
        yaw = Number(r, Join(path, "rotation_deg"));
        Check(yaw >= 0 && yaw <= 180, r, Join(path, "rotation_deg"), "must be in [0, 180] deg or \"any\"");
      }
      ranged.remove("rotation_deg");
    }
    d.search_translation = ParseOffsetRange(ranged, path, {d.search_translation, 0.0}).first;
    d.search_yaw_deg = yaw;
  }
  if (const YAML::Node v = n["detect_warn"]; v.IsDefined()) {
    std::tie(d.warn_offset, d.warn_offset_deg) =
        ParseOffsetRange(v, "bin.detect_warn", {d.warn_offset, d.warn_offset_deg});
  }
}

void Parser::ParseRoi(const YAML::Node& n, Cell& cell) const {
  ExpectMap(n, "roi", {"wall_margin", "floor_margin", "height"});
  RoiSpec& r = cell.roi;
  r.wall_margin = OptNumber(n, "roi", "wall_margin", r.wall_margin);
  r.floor_margin = OptNumber(n, "roi", "floor_margin", r.floor_margin);
  r.height = OptNumber(n, "roi", "height", r.height);
  Check(r.wall_margin >= 0, n["wall_margin"], "roi.wall_margin", "must be >= 0");
  Check(r.floor_margin >= 0, n["floor_margin"], "roi.floor_margin", "must be >= 0");
  Check(r.height > 0, n["height"], "roi.height", "must be > 0");
  const double min_side = std::min(cell.bin.inner_size.x(), cell.bin.inner_size.y());
  Check(2 * r.wall_margin < min_side, n["wall_margin"], "roi.wall_margin",
        "leaves an empty region of interest (2 * " + FormatNumber(r.wall_margin) + " m >= bin inner side " +
            FormatNumber(min_side) + " m)");
  Check(r.floor_margin < r.height, n["floor_margin"], "roi.floor_margin",
        "leaves an empty region of interest (floor_margin >= roi.height)");
}

void Parser::ParseGrippers(const YAML::Node& n, Cell& cell) const {
  ExpectSeq(n, "grippers");
  Check(n.size() > 0, n, "grippers", "at least one gripper is required");
  for (size_t i = 0; i < n.size(); ++i) {
    const YAML::Node g = n[i];
    const std::string path = At("grippers", i);
    ExpectMap(g, path, {"name", "kind", "mesh", "tcp", "approach_distance", "opening", "footprint", "seen_contact"});
    GripperSpec spec;
    spec.name = Name(Req(g, path, "name"), Join(path, "name"));
    Check(cell.FindGripper(spec.name) == nullptr, g["name"], Join(path, "name"),
          "duplicate gripper name '" + spec.name + "'");
    spec.kind = Enum<GripperSpec::Kind>(Req(g, path, "kind"), Join(path, "kind"), "gripper kind",
                                        {{"suction", GripperSpec::Kind::kSuction},
                                         {"parallel_jaw", GripperSpec::Kind::kParallelJaw}});
    spec.mesh = MeshPath(Req(g, path, "mesh"), Join(path, "mesh"));
    if (const YAML::Node t = g["tcp"]; t.IsDefined()) spec.X_FT = ParsePose(t, Join(path, "tcp"));
    spec.approach_distance = OptNumber(g, path, "approach_distance", spec.approach_distance);
    Check(spec.approach_distance > 0, g["approach_distance"], Join(path, "approach_distance"), "must be > 0 (m)");
    spec.opening = OptNumber(g, path, "opening", spec.opening);
    Check(spec.opening >= 0, g["opening"], Join(path, "opening"), "must be >= 0 (m)");
    if (spec.kind == GripperSpec::Kind::kParallelJaw) {
      Check(spec.opening > 0, g["opening"].IsDefined() ? g["opening"] : g, Join(path, "opening"),
            "a parallel_jaw gripper needs an opening > 0 (m)");
    }
    if (const YAML::Node f = g["footprint"]; f.IsDefined()) spec.footprint = Polygon(f, Join(path, "footprint"));
    spec.seen_contact = ParseSeenContact(g["seen_contact"], Join(path, "seen_contact"), spec.kind);
    cell.grippers.push_back(std::move(spec));
  }
}

// Absent: the kind's default rule with default thresholds.
SeenContactRule Parser::ParseSeenContact(const YAML::Node& n, const std::string& path, GripperSpec::Kind kind) const {
  SeenContactRule r;
  r.when = kind == GripperSpec::Kind::kSuction ? SeenContactRule::When::kAlways : SeenContactRule::When::kIfAmbiguous;
  if (!n.IsDefined()) return r;
  ExpectMap(n, path, {"rule", "max_distance", "min_fraction", "radius", "pad_width", "pad_depth"});
  if (const YAML::Node w = n["rule"]; w.IsDefined()) {
    r.when = Enum<SeenContactRule::When>(w, Join(path, "rule"), "seen_contact rule",
                                         {{"always", SeenContactRule::When::kAlways},
                                          {"if_ambiguous", SeenContactRule::When::kIfAmbiguous},
                                          {"off", SeenContactRule::When::kOff}});
  }
  r.max_distance = OptNumber(n, path, "max_distance", r.max_distance);
  Check(r.max_distance > 0 && r.max_distance <= 0.05, n["max_distance"], Join(path, "max_distance"),
        "must be in (0, 0.05] (m)");
  r.min_fraction = OptNumber(n, path, "min_fraction", r.min_fraction);
  Check(r.min_fraction > 0 && r.min_fraction <= 1, n["min_fraction"], Join(path, "min_fraction"), "must be in (0, 1]");
  r.radius = OptNumber(n, path, "radius", r.radius);
  Check(r.radius >= 0, n["radius"], Join(path, "radius"), "must be >= 0 (m; 0 = from the mesh)");
  r.pad_width = OptNumber(n, path, "pad_width", r.pad_width);
  Check(r.pad_width > 0, n["pad_width"], Join(path, "pad_width"), "must be > 0 (m)");
  r.pad_depth = OptNumber(n, path, "pad_depth", r.pad_depth);
  Check(r.pad_depth > 0, n["pad_depth"], Join(path, "pad_depth"), "must be > 0 (m)");
  return r;
}

Symmetry Parser::ParseSymmetry(const YAML::Node& n, const std::string& path) const {
  ExpectMap(n, path, {"type", "axis", "order", "extra"});
  Symmetry s;
  s.kind = Enum<Symmetry::Kind>(Req(n, path, "type"), Join(path, "type"), "symmetry type",
                                {{"none", Symmetry::Kind::kNone},
                                 {"revolute", Symmetry::Kind::kRevolute},
                                 {"discrete", Symmetry::Kind::kDiscrete}});
  if (const YAML::Node a = n["axis"]; a.IsDefined()) {
    const Vec3 axis = Vector3(a, Join(path, "axis"));
    Check(axis.norm() > 1e-9, a, Join(path, "axis"), "axis must be non-zero");
    s.axis = axis.normalized();
  }
  if (s.kind == Symmetry::Kind::kDiscrete) {
    s.order = Int(Req(n, path, "order"), Join(path, "order"));
    Check(s.order >= 2, n["order"], Join(path, "order"),
          "a discrete symmetry needs order >= 2, got " + std::to_string(s.order));
  } else if (n["order"].IsDefined()) {
    Fail(n["order"], Join(path, "order"), "order applies only to type discrete");
  }
  if (const YAML::Node e = n["extra"]; e.IsDefined()) {
    ExpectSeq(e, Join(path, "extra"));
    for (size_t i = 0; i < e.size(); ++i) s.extra.push_back(ParsePose(e[i], At(Join(path, "extra"), i)));
  }
  return s;
}

void Parser::ParseParts(const YAML::Node& n, Cell& cell) const {
  ExpectSeq(n, "parts");
  Check(n.size() > 0, n, "parts", "at least one part is required");
  for (size_t i = 0; i < n.size(); ++i) {
    const YAML::Node p = n[i];
    const std::string path = At("parts", i);
    ExpectMap(p, path, {"class_id", "name", "mesh", "symmetry", "grasps", "flat_2d", "optional", "perception"});
    PartSpec part;
    part.class_id = Int(Req(p, path, "class_id"), Join(path, "class_id"));
    Check(part.class_id >= 0, p["class_id"], Join(path, "class_id"), "must be >= 0");
    Check(cell.FindPart(part.class_id) == nullptr, p["class_id"], Join(path, "class_id"),
          "duplicate part class id " + std::to_string(part.class_id));
    part.name = Name(Req(p, path, "name"), Join(path, "name"));
    part.mesh = MeshPath(Req(p, path, "mesh"), Join(path, "mesh"));
    if (const YAML::Node s = p["symmetry"]; s.IsDefined()) part.symmetry = ParseSymmetry(s, Join(path, "symmetry"));
    if (const YAML::Node gs = p["grasps"]; gs.IsDefined()) {
      const std::string gpath = Join(path, "grasps");
      ExpectSeq(gs, gpath);
      for (size_t j = 0; j < gs.size(); ++j) {
        const YAML::Node g = gs[j];
        const std::string key = At(gpath, j);
        ExpectMap(g, key, {"name", "gripper", "pose"});
        GraspSpec grasp;
        grasp.name = Name(Req(g, key, "name"), Join(key, "name"));
        grasp.gripper = Name(Req(g, key, "gripper"), Join(key, "gripper"));
        Check(cell.FindGripper(grasp.gripper) != nullptr, g["gripper"], Join(key, "gripper"),
              "unknown gripper '" + grasp.gripper + "' (not in grippers)");
        grasp.X_OG = ParsePose(Req(g, key, "pose"), Join(key, "pose"));
        part.grasps.push_back(std::move(grasp));
      }
    }
    if (const YAML::Node f = p["flat_2d"]; f.IsDefined()) part.flat_2d = ParseFlat2D(f, Join(path, "flat_2d"), cell);
    part.optional = OptBool(p, path, "optional", false);
    if (const YAML::Node q = p["perception"]; q.IsDefined()) {
      part.perception = ParsePartPerception(q, Join(path, "perception"));
    }
    cell.parts.push_back(std::move(part));
  }
}

namespace {
double SignedArea(const std::vector<Eigen::Vector2d>& poly) {
  double a = 0;
  for (size_t i = 0; i < poly.size(); ++i) {
    const Eigen::Vector2d& p = poly[i];
    const Eigen::Vector2d& q = poly[(i + 1) % poly.size()];
    a += p.x() * q.y() - q.x() * p.y();
  }
  return a / 2;
}
double Cross2(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c) {
  return (b - a).x() * (c - a).y() - (b - a).y() * (c - a).x();
}
bool SegmentsCross(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c,
                   const Eigen::Vector2d& d) {
  return Cross2(a, b, c) * Cross2(a, b, d) < 0 && Cross2(c, d, a) * Cross2(c, d, b) < 0;
}
bool InsidePolygon(const std::vector<Eigen::Vector2d>& poly, const Eigen::Vector2d& p) {
  bool in = false;
  for (size_t i = 0, j = poly.size() - 1; i < poly.size(); j = i++) {
    const Eigen::Vector2d& a = poly[i];
    const Eigen::Vector2d& b = poly[j];
    if ((a.y() > p.y()) != (b.y() > p.y()) &&
        p.x() < (b.x() - a.x()) * (p.y() - a.y()) / (b.y() - a.y()) + a.x()) {
      in = !in;
    }
  }
  return in;
}
}  // namespace

std::vector<Eigen::Vector2d> Parser::Polygon(const YAML::Node& n, const std::string& key) const {
  ExpectSeq(n, key);
  Check(n.size() >= 3, n, key, "a polygon needs at least 3 [x, y] points, got " + std::to_string(n.size()));
  std::vector<Eigen::Vector2d> poly;
  for (size_t i = 0; i < n.size(); ++i) {
    const std::vector<double> v = Numbers(n[i], At(key, i), 2);
    poly.emplace_back(v[0], v[1]);
  }
  const size_t m = poly.size();
  for (size_t i = 0; i < m; ++i) {
    for (size_t j = i + 2; j < m; ++j) {
      if (i == 0 && j == m - 1) continue;  // adjacent through the closing edge
      Check(!SegmentsCross(poly[i], poly[(i + 1) % m], poly[j], poly[(j + 1) % m]), n, key,
            "edges " + std::to_string(i) + " and " + std::to_string(j) + " cross (not a simple polygon)");
    }
  }
  const double area = SignedArea(poly);
  Check(std::abs(area) > 1e-10, n, key, "polygon has no area");
  if (area < 0) std::reverse(poly.begin(), poly.end());
  return poly;
}

PartPerception Parser::ParsePartPerception(const YAML::Node& n, const std::string& path) const {
  ExpectMap(n, path, {"ppf_step", "icp_spacing", "verify_spacing", "support_distance", "free_space_distance",
                      "min_score", "flat_height", "min_view_points"});
  PartPerception q;
  // A length in (0, max] metres.
  const auto length = [&](const char* key, double max, std::optional<double>* out) {
    const YAML::Node v = n[key];
    if (!v.IsDefined()) return;
    const double x = Number(v, Join(path, key));
    Check(x > 0 && x <= max, v, Join(path, key),
          "must be in (0, " + FormatNumber(max) + "] m, got " + FormatNumber(x) + " (metres, not millimetres)");
    *out = x;
  };
  length("ppf_step", 0.1, &q.ppf_step);
  length("icp_spacing", 0.02, &q.icp_spacing);
  length("verify_spacing", 0.05, &q.verify_spacing);
  length("support_distance", 0.05, &q.support_distance);
  length("free_space_distance", 0.1, &q.free_space_distance);
  length("flat_height", 1.0, &q.flat_height);
  if (const YAML::Node v = n["min_score"]; v.IsDefined()) {
    const double x = Number(v, Join(path, "min_score"));
    Check(x >= 0 && x <= 1, v, Join(path, "min_score"), "must be in [0, 1], got " + FormatNumber(x));
    q.min_score = x;
  }
  if (const YAML::Node v = n["min_view_points"]; v.IsDefined()) {
    const int x = Int(v, Join(path, "min_view_points"));
    Check(x >= 10, v, Join(path, "min_view_points"), "must be >= 10 grid points, got " + std::to_string(x));
    q.min_view_points = x;
  }
  if (q.support_distance && q.free_space_distance) {
    Check(*q.free_space_distance > *q.support_distance, n["free_space_distance"], Join(path, "free_space_distance"),
          "must be larger than support_distance");
  }
  return q;
}

Flat2DSpec Parser::ParseFlat2D(const YAML::Node& n, const std::string& path, const Cell& cell) const {
  ExpectMap(n, path, {"outline", "thickness", "grasps"});
  Flat2DSpec f;
  f.outline = Polygon(Req(n, path, "outline"), Join(path, "outline"));
  f.thickness = Number(Req(n, path, "thickness"), Join(path, "thickness"));
  Check(f.thickness > 0, n["thickness"], Join(path, "thickness"), "must be > 0 (m)");
  const std::string gpath = Join(path, "grasps");
  const YAML::Node gs = Req(n, path, "grasps");
  ExpectSeq(gs, gpath);
  Check(gs.size() > 0, gs, gpath, "at least one 2D grasp is required");
  for (size_t j = 0; j < gs.size(); ++j) {
    const YAML::Node g = gs[j];
    const std::string key = At(gpath, j);
    ExpectMap(g, key, {"name", "gripper", "xy", "angle_deg"});
    Grasp2DSpec grasp;
    grasp.name = Name(Req(g, key, "name"), Join(key, "name"));
    grasp.gripper = Name(Req(g, key, "gripper"), Join(key, "gripper"));
    Check(cell.FindGripper(grasp.gripper) != nullptr, g["gripper"], Join(key, "gripper"),
          "unknown gripper '" + grasp.gripper + "' (not in grippers)");
    const std::vector<double> xy = Numbers(Req(g, key, "xy"), Join(key, "xy"), 2);
    grasp.xy = Eigen::Vector2d(xy[0], xy[1]);
    Check(InsidePolygon(f.outline, grasp.xy), g["xy"], Join(key, "xy"), "grasp point is outside the outline");
    grasp.angle = OptNumber(g, key, "angle_deg", 0.0) * M_PI / 180.0;
    f.grasps.push_back(std::move(grasp));
  }
  return f;
}

void Parser::ParseTasks(const YAML::Node& n, Cell& cell) const {
  ExpectSeq(n, "tasks");
  Check(n.size() > 0, n, "tasks", "at least one task is required");
  for (size_t i = 0; i < n.size(); ++i) {
    const YAML::Node t = n[i];
    const std::string path = At("tasks", i);
    ExpectMap(t, path, {"id", "name", "kind", "parts", "gripper", "empty_box", "max_tilt_deg", "ranking", "fixture",
                        "roi", "failed_picks", "place_on"});
    TaskSpec task;
    task.id = Int(Req(t, path, "id"), Join(path, "id"));
    Check(task.id >= 0, t["id"], Join(path, "id"), "must be >= 0");
    Check(cell.FindTask(task.id) == nullptr, t["id"], Join(path, "id"), "duplicate task id " + std::to_string(task.id));
    task.name = OptString(t, path, "name", "task" + std::to_string(task.id));
    if (const YAML::Node k = t["kind"]; k.IsDefined()) {
      task.kind = Enum<TaskSpec::Kind>(k, Join(path, "kind"), "task kind",
                                       {{"pick", TaskSpec::Kind::kPick},
                                        {"place", TaskSpec::Kind::kPlace},
                                        {"in_hand", TaskSpec::Kind::kInHand},
                                        {"place_area", TaskSpec::Kind::kPlaceArea},
                                        {"precision", TaskSpec::Kind::kPrecision},
                                        {"pick_2d", TaskSpec::Kind::kPick2D}});
    }
    if (const YAML::Node ps = t["parts"]; ps.IsDefined()) {
      task.part_classes = Ints(ps, Join(path, "parts"));
      for (size_t j = 0; j < task.part_classes.size(); ++j) {
        Check(cell.FindPart(task.part_classes[j]) != nullptr, ps[j], At(Join(path, "parts"), j),
              "unknown part class " + std::to_string(task.part_classes[j]));
      }
    }
    task.gripper = Name(Req(t, path, "gripper"), Join(path, "gripper"));
    Check(cell.FindGripper(task.gripper) != nullptr, t["gripper"], Join(path, "gripper"),
          "unknown gripper '" + task.gripper + "' (not in grippers)");
    if (const YAML::Node e = t["empty_box"]; e.IsDefined()) {
      const std::string ekey = Join(path, "empty_box");
      ExpectMap(e, ekey, {"threshold_points", "reference_resolution", "mode"});
      task.empty_box.threshold_points = OptInt(e, ekey, "threshold_points", task.empty_box.threshold_points);
      Check(task.empty_box.threshold_points >= 0, e["threshold_points"], Join(ekey, "threshold_points"),
            "must be >= 0");
      if (const YAML::Node res = e["reference_resolution"]; res.IsDefined()) {
        const std::string rkey = Join(ekey, "reference_resolution");
        if (!res.IsSequence() || res.size() != 2) Fail(res, rkey, "expected [width, height] in pixels");
        task.empty_box.reference_width = Int(res[0], At(rkey, 0));
        task.empty_box.reference_height = Int(res[1], At(rkey, 1));
        Check(task.empty_box.reference_width > 0, res[0], At(rkey, 0), "width must be > 0");
        Check(task.empty_box.reference_height > 0, res[1], At(rkey, 1), "height must be > 0");
      }
      if (const YAML::Node m = e["mode"]; m.IsDefined()) {
        task.empty_box.mode = Enum<EmptyBoxRule::Mode>(m, Join(ekey, "mode"), "empty_box mode",
                                                       {{"largest_region", EmptyBoxRule::Mode::kLargestRegion},
                                                        {"total", EmptyBoxRule::Mode::kTotal}});
      }
    }
    task.max_tilt_deg = OptNumber(t, path, "max_tilt_deg", task.max_tilt_deg);
    Check(task.max_tilt_deg >= 0 && task.max_tilt_deg <= 180, t["max_tilt_deg"], Join(path, "max_tilt_deg"),
          "must be in [0, 180]");
    ParseTaskRegion(t, path, cell, task);
    if (const YAML::Node fp = t["failed_picks"]; fp.IsDefined()) {
      const std::string fkey = Join(path, "failed_picks");
      ExpectMap(fp, fkey, {"radius_mm", "captures", "max_failures"});
      task.failed_picks.radius = OptNumber(fp, fkey, "radius_mm", 1000.0 * task.failed_picks.radius) / 1000.0;
      task.failed_picks.captures = OptInt(fp, fkey, "captures", task.failed_picks.captures);
      task.failed_picks.max_failures = OptInt(fp, fkey, "max_failures", task.failed_picks.max_failures);
      Check(task.failed_picks.radius > 0 && task.failed_picks.radius <= 1.0, fp["radius_mm"],
            Join(fkey, "radius_mm"), "must be in (0, 1000]");
      Check(task.failed_picks.captures >= 1, fp["captures"], Join(fkey, "captures"), "must be >= 1");
      Check(task.failed_picks.max_failures >= 1, fp["max_failures"], Join(fkey, "max_failures"), "must be >= 1");
    }
    if (const YAML::Node r = t["ranking"]; r.IsDefined()) {
      const std::string rkey = Join(path, "ranking");
      ExpectMap(r, rkey, {"height", "detection", "tilt"});
      task.ranking.height = OptNumber(r, rkey, "height", task.ranking.height);
      task.ranking.detection = OptNumber(r, rkey, "detection", task.ranking.detection);
      task.ranking.tilt = OptNumber(r, rkey, "tilt", task.ranking.tilt);
      Check(task.ranking.height >= 0, r["height"], Join(rkey, "height"), "must be >= 0");
      Check(task.ranking.detection >= 0, r["detection"], Join(rkey, "detection"), "must be >= 0");
      Check(task.ranking.tilt >= 0, r["tilt"], Join(rkey, "tilt"), "must be >= 0");
    }
    if (task.kind == TaskSpec::Kind::kPick2D) {
      Check(!cell.FindGripper(task.gripper)->footprint.empty(), t["gripper"], Join(path, "gripper"),
            "a pick_2d task's gripper needs a footprint (grippers[].footprint)");
      bool any = false;
      for (const PartSpec& part : cell.parts) {
        const bool listed = task.part_classes.empty() ||
                            std::find(task.part_classes.begin(), task.part_classes.end(), part.class_id) !=
                                task.part_classes.end();
        if (!listed) continue;
        const bool usable = part.flat_2d &&
                            std::any_of(part.flat_2d->grasps.begin(), part.flat_2d->grasps.end(),
                                        [&](const Grasp2DSpec& g) { return g.gripper == task.gripper; });
        Check(usable || task.part_classes.empty(), t["parts"], Join(path, "parts"),
              "part class " + std::to_string(part.class_id) + " has no flat_2d grasp for gripper '" +
                  task.gripper + "'");
        any = any || usable;
      }
      Check(any, t, path, "a pick_2d task needs a part with a flat_2d grasp for gripper '" + task.gripper + "'");
    }
    cell.tasks.push_back(std::move(task));
  }
}

void Parser::ParseTaskRegion(const YAML::Node& t, const std::string& path, const Cell& cell,
                             TaskSpec& task) const {
  const bool fixture = LooksAtFixture(task);
  const bool region = fixture || task.kind == TaskSpec::Kind::kInHand;
  if (const YAML::Node f = t["fixture"]; f.IsDefined()) {
    Check(fixture, f, Join(path, "fixture"), "only place and place_area tasks look for a fixture");
    task.fixture = Name(f, Join(path, "fixture"));
    Check(cell.FindFixture(task.fixture) != nullptr, f, Join(path, "fixture"),
          "unknown fixture '" + task.fixture + "' (not in fixtures)");
  } else {
    Check(!fixture, t, Join(path, "fixture"), "missing required key (a place or place_area task looks for a fixture)");
  }
  if (const YAML::Node r = t["roi"]; r.IsDefined()) {
    Check(region, r, Join(path, "roi"),
          "only in_hand, place and place_area tasks have their own roi (the others look into the bin's)");
    task.roi = ParseBox(r, Join(path, "roi"));
  } else {
    Check(!region, t, Join(path, "roi"),
          "missing required key (an in_hand, place or place_area task looks into its own box)");
  }
  if (fixture) {
    Check(!t["parts"].IsDefined(), t["parts"], Join(path, "parts"), "a fixture task looks for its fixture, not parts");
  }
  if (const YAML::Node p = t["place_on"]; p.IsDefined()) {
    Check(task.kind == TaskSpec::Kind::kPick, p, Join(path, "place_on"),
          "only pick tasks name the fixture their parts are placed on");
    task.place_on = Name(p, Join(path, "place_on"));
    Check(cell.FindFixture(task.place_on) != nullptr, p, Join(path, "place_on"),
          "unknown fixture '" + task.place_on + "' (not in fixtures)");
  }
  if (task.kind == TaskSpec::Kind::kInHand) {
    Check(!cell.camera.eye_in_hand, t["kind"], Join(path, "kind"),
          "an in_hand task needs an eye_to_hand camera (a camera on the flange cannot see the gripper's part)");
  }
}

void Parser::ParseFixtures(const YAML::Node& n, Cell& cell) const {
  ExpectSeq(n, "fixtures");
  for (size_t i = 0; i < n.size(); ++i) {
    const YAML::Node f = n[i];
    const std::string path = At("fixtures", i);
    ExpectMap(f, path, {"class_id", "name", "mesh", "taught_pose", "part_pose"});
    FixtureSpec fixture;
    fixture.class_id = Int(Req(f, path, "class_id"), Join(path, "class_id"));
    Check(fixture.class_id >= 0, f["class_id"], Join(path, "class_id"), "must be >= 0");
    Check(cell.FindPart(fixture.class_id) == nullptr && cell.FindFixture(fixture.class_id) == nullptr,
          f["class_id"], Join(path, "class_id"),
          "class id " + std::to_string(fixture.class_id) + " is already a part's or a fixture's");
    fixture.name = Name(Req(f, path, "name"), Join(path, "name"));
    Check(cell.FindFixture(fixture.name) == nullptr, f["name"], Join(path, "name"),
          "duplicate fixture name '" + fixture.name + "'");
    fixture.mesh = MeshPath(Req(f, path, "mesh"), Join(path, "mesh"));
    fixture.X_BP_taught = ParsePose(Req(f, path, "taught_pose"), Join(path, "taught_pose"));
    if (const YAML::Node p = f["part_pose"]; p.IsDefined()) fixture.X_PO = ParsePose(p, Join(path, "part_pose"));
    cell.fixtures.push_back(std::move(fixture));
  }
}

void Parser::ParseRobot(const YAML::Node& n, Cell& cell) const {
  ExpectMap(n, "robot", {"type", "dialect", "protocol_version", "position_scale", "modbus", "workspace"});
  RobotSpec& r = cell.robot;
  const YAML::Node type = Req(n, "robot", "type");
  const std::string name = Name(type, "robot.type");
  std::optional<RobotModel> model;
  int id = 0;
  if (YAML::convert<int>::decode(type, id)) {
    model = FindRobotModel(static_cast<RobotType>(id));
  } else {
    model = FindRobotModel(std::string_view(name));
  }
  if (!model) Fail(type, "robot.type", "unknown robot type '" + name + "' (a robot name such as ur, abb, kuka, or a meta_1 id)");
  r.model = *model;
  if (const YAML::Node d = n["dialect"]; d.IsDefined()) {
    const std::string dialect = Name(d, "robot.dialect");
    const std::optional<DaoaiDialect> parsed = ParseDaoaiDialect(dialect);
    if (!parsed) Fail(d, "robot.dialect", "unknown dialect '" + dialect + "' (vision_pilot or socket_v1)");
    r.dialect = *parsed;
  }
  r.protocol_version = OptInt(n, "robot", "protocol_version", r.protocol_version);
  Check(r.protocol_version == 1 || r.protocol_version == 2, n["protocol_version"], "robot.protocol_version",
        "must be 1 or 2, got " + std::to_string(r.protocol_version));
  r.position_scale = OptNumber(n, "robot", "position_scale", r.position_scale);
  Check(r.position_scale > 0, n["position_scale"], "robot.position_scale", "must be > 0");
  if (const YAML::Node m = n["modbus"]; m.IsDefined()) {
    ExpectMap(m, "robot.modbus", {"host", "port", "unit_id", "request_base", "request_flag",
                                  "response_base", "response_flag", "poll_ms"});
    r.modbus_host = Name(Req(m, "robot.modbus", "host"), "robot.modbus.host");
    r.modbus_port = Port(m, "robot.modbus", "port", r.modbus_port, 1);
    r.modbus_unit_id = OptInt(m, "robot.modbus", "unit_id", r.modbus_unit_id);
    Check(r.modbus_unit_id >= 0 && r.modbus_unit_id <= 255, m["unit_id"], "robot.modbus.unit_id",
          "must be in 0..255");
    ModbusRegisterMap& map = r.modbus_map;
    map.request_base = OptInt(m, "robot.modbus", "request_base", map.request_base);
    map.request_flag = OptInt(m, "robot.modbus", "request_flag", map.request_flag);
    map.response_base = OptInt(m, "robot.modbus", "response_base", map.response_base);
    map.response_flag = OptInt(m, "robot.modbus", "response_flag", map.response_flag);
    const Status valid = ValidateModbusRegisterMap(map);
    Check(valid.ok(), m, "robot.modbus", valid.message());
    r.modbus_poll_ms = OptInt(m, "robot.modbus", "poll_ms", r.modbus_poll_ms);
    Check(r.modbus_poll_ms >= 0 && r.modbus_poll_ms <= 1000, m["poll_ms"], "robot.modbus.poll_ms",
          "must be in 0..1000");
  }
  if (const YAML::Node w = n["workspace"]; w.IsDefined()) {
    ExpectMap(w, "robot.workspace", {"min", "max"});
    const Vec3 lo = Vector3(Req(w, "robot.workspace", "min"), "robot.workspace.min");
    const Vec3 hi = Vector3(Req(w, "robot.workspace", "max"), "robot.workspace.max");
    Check((lo.array() < hi.array()).all(), w["max"], "robot.workspace.max", "must be > min on every axis");
    r.workspace = Eigen::AlignedBox3d(lo, hi);
  }
}

void Parser::ParseEndpoints(const YAML::Node& n, Cell& cell) const {
  ExpectMap(n, "endpoints", {"bind", "daoai_port", "gri_port", "gri_official_port", "http_port",
                             "max_connections", "max_connections_per_peer", "max_message_rate",
                             "allowlist", "config_allowlist", "http_allowlist",
                             "http_max_connections"});
  Endpoints& e = cell.endpoints;
  e.bind = OptString(n, "endpoints", "bind", e.bind);
  Check(!e.bind.empty(), n["bind"], "endpoints.bind", "must not be empty");
  std::vector<std::pair<const char*, int*>> ports = {{"daoai_port", &e.daoai_port},
                                                     {"gri_port", &e.gri_port},
                                                     {"gri_official_port", &e.gri_official_port},
                                                     {"http_port", &e.http_port}};
  for (size_t i = 0; i < ports.size(); ++i) {
    *ports[i].second = Port(n, "endpoints", ports[i].first, *ports[i].second);
    for (size_t j = 0; j < i; ++j) {  // 0 means "disabled" and may repeat
      Check(*ports[i].second == 0 || *ports[i].second != *ports[j].second, n[ports[i].first],
            Join("endpoints", ports[i].first),
            "port " + std::to_string(*ports[i].second) + " is already used by endpoints." + ports[j].first);
    }
  }
  e.max_connections = OptInt(n, "endpoints", "max_connections", e.max_connections);
  Check(e.max_connections >= 0, n["max_connections"], "endpoints.max_connections",
        "must be >= 0 (0: unlimited)");
  e.max_connections_per_peer =
      OptInt(n, "endpoints", "max_connections_per_peer", e.max_connections_per_peer);
  Check(e.max_connections_per_peer >= 0, n["max_connections_per_peer"],
        "endpoints.max_connections_per_peer", "must be >= 0 (0: unlimited)");
  e.max_message_rate = OptNumber(n, "endpoints", "max_message_rate", e.max_message_rate);
  Check(std::isfinite(e.max_message_rate) && e.max_message_rate >= 0, n["max_message_rate"],
        "endpoints.max_message_rate", "must be >= 0 requests/s (0: unlimited)");
  e.allowlist = IpList(n, "allowlist");
  e.config_allowlist = IpList(n, "config_allowlist");
  e.http_allowlist = IpList(n, "http_allowlist");
  e.http_max_connections = OptInt(n, "endpoints", "http_max_connections", e.http_max_connections);
  Check(e.http_max_connections >= 0, n["http_max_connections"], "endpoints.http_max_connections",
        "must be >= 0 (0: unlimited)");
}

std::vector<std::string> Parser::IpList(const YAML::Node& n, const char* name) const {
  std::vector<std::string> list;
  const YAML::Node a = n[name];
  if (!a.IsDefined()) return list;
  const std::string path = Join("endpoints", name);
  if (!a.IsSequence()) Fail(a, path, "expected a list of IP addresses, got " + What(a));
  for (size_t i = 0; i < a.size(); ++i) {
    const std::string key = path + "[" + std::to_string(i) + "]";
    const std::string ip = String(a[i], key);
    const Status valid = AddressList::CheckEntry(ip);
    Check(valid.ok(), a[i], key, valid.message());
    list.push_back(ip);
  }
  return list;
}

void Parser::ParseRecording(const YAML::Node& n, Cell& cell) const {
  const std::string path = "recording";
  ExpectMap(n, path, {"enabled", "directory", "max_disk_mb", "queue_captures"});
  RecordingSpec& r = cell.recording;
  r.enabled = OptBool(n, path, "enabled", r.enabled);
  if (const YAML::Node d = n["directory"]; d.IsDefined()) r.directory = Resolve(Name(d, "recording.directory"));
  const int cap = OptInt(n, path, "max_disk_mb", static_cast<int>(r.max_disk_mb));
  Check(cap >= 1, n["max_disk_mb"], "recording.max_disk_mb", "must be >= 1, got " + std::to_string(cap));
  r.max_disk_mb = cap;
  r.queue_captures = OptInt(n, path, "queue_captures", r.queue_captures);
  Check(r.queue_captures >= 1 && r.queue_captures <= 1000, n["queue_captures"], "recording.queue_captures",
        "must be in 1..1000, got " + std::to_string(r.queue_captures));
}

Cell Parser::ParseCell(const YAML::Node& root) {
  if (!root.IsDefined() || root.IsNull()) Fail(root, "", "the cell file is empty");
  if (!root.IsMap()) Fail(root, "", "expected a map of sections at the top level, got " + What(root));
  ExpectMap(root, "",
            {"name", "camera", "source", "bin", "roi", "parts", "grippers", "fixtures", "tasks", "robot",
             "endpoints", "calibration", "recording"});
  Cell cell;
  cell.path = file_;
  cell.base_dir = base_dir_.string();
  cell.name = OptString(root, "", "name", file_ == kEmbeddedPath ? "default" : fs::path(file_).stem().string());
  // Sections are parsed in dependency order, not file order: grasps and
  // tasks refer to grippers, the source and tasks to part classes.
  ParseGrippers(Req(root, "", "grippers"), cell);
  ParseParts(Req(root, "", "parts"), cell);
  if (const YAML::Node c = root["calibration"]; c.IsDefined()) ParseCalibration(c, Req(root, "", "camera"), cell);
  ParseCamera(Req(root, "", "camera"), cell);
  if (const YAML::Node s = root["source"]; s.IsDefined()) ParseSource(s, cell);
  else ParseSource(YAML::Node(YAML::NodeType::Map), cell);
  if (const YAML::Node b = root["bin"]; b.IsDefined()) ParseBin(b, cell);
  if (const YAML::Node r = root["roi"]; r.IsDefined()) ParseRoi(r, cell);
  else ParseRoi(YAML::Node(YAML::NodeType::Map), cell);  // still checked against the bin
  if (const YAML::Node f = root["fixtures"]; f.IsDefined()) ParseFixtures(f, cell);
  ParseTasks(Req(root, "", "tasks"), cell);
  ParseRobot(Req(root, "", "robot"), cell);
  if (const YAML::Node e = root["endpoints"]; e.IsDefined()) ParseEndpoints(e, cell);
  if (const YAML::Node r = root["recording"]; r.IsDefined()) ParseRecording(r, cell);
  return cell;
}

Result<Cell> ParseImpl(std::string_view text, const std::string& file, const fs::path& base_dir) {
  try {
    const YAML::Node root = YAML::Load(std::string(text));
    Parser parser(file, base_dir);
    Cell cell = parser.ParseCell(root);
    cell.yaml_text = std::string(text);
    return cell;
  } catch (const CellError& e) {
    return e.status;
  } catch (const YAML::ParserException& e) {
    return Status::Corruption(file + ":" + std::to_string(e.mark.line + 1) + ":" + std::to_string(e.mark.column + 1) +
                              ": YAML syntax error: " + e.msg);
  } catch (const YAML::Exception& e) {
    return Status::Corruption(file + ": " + e.what());
  } catch (const std::exception& e) {
    return Status::Internal(file + ": " + e.what());
  }
}

}  // namespace

const CameraConfig* CameraSpec::FindConfig(int id) const {
  for (const CameraConfig& c : configs) {
    if (c.id == id) return &c;
  }
  return nullptr;
}

const PartSpec* Cell::FindPart(int class_id) const {
  for (const PartSpec& p : parts) {
    if (p.class_id == class_id) return &p;
  }
  return nullptr;
}

const GripperSpec* Cell::FindGripper(const std::string& gripper_name) const {
  for (const GripperSpec& g : grippers) {
    if (g.name == gripper_name) return &g;
  }
  return nullptr;
}

const TaskSpec* Cell::FindTask(int id) const {
  for (const TaskSpec& t : tasks) {
    if (t.id == id) return &t;
  }
  return nullptr;
}

const FixtureSpec* Cell::FindFixture(const std::string& fixture_name) const {
  for (const FixtureSpec& f : fixtures) {
    if (f.name == fixture_name) return &f;
  }
  return nullptr;
}

const FixtureSpec* Cell::FindFixture(int class_id) const {
  for (const FixtureSpec& f : fixtures) {
    if (f.class_id == class_id) return &f;
  }
  return nullptr;
}

Status CheckWorkspace(const RobotSpec& robot, const Pose& X_BF) {
  const Vec3 p = X_BF.translation();
  const Eigen::AlignedBox3d& box = robot.workspace;
  static constexpr const char* kAxis[] = {"x", "y", "z"};
  char where[96];
  std::snprintf(where, sizeof(where), "flange at (%.3f, %.3f, %.3f) m", p.x(), p.y(), p.z());
  if (!p.allFinite()) return Status::OutOfRange(std::string(where) + " is not a position");
  for (int i = 0; i < 3; ++i) {
    char why[96] = "";
    if (p[i] < box.min()[i]) {
      std::snprintf(why, sizeof(why), "%s %.3f < min %.3f", kAxis[i], p[i], box.min()[i]);
    } else if (p[i] > box.max()[i]) {
      std::snprintf(why, sizeof(why), "%s %.3f > max %.3f", kAxis[i], p[i], box.max()[i]);
    }
    if (why[0] != '\0') return Status::OutOfRange(std::string(where) + " is outside robot.workspace: " + why);
  }
  return Status::Ok();
}

std::string AssetsDir() {
  if (const char* env = std::getenv("BINPICK_ASSETS"); env != nullptr && env[0] != '\0') return env;
  // An installed program (/usr/bin/binpickd): the package's assets beside it.
  std::error_code ec;
  const fs::path installed = fs::read_symlink("/proc/self/exe", ec).parent_path().parent_path() / "share" /
                             "binpick" / "assets";
  if (!ec && fs::is_directory(installed, ec)) return installed.string();
  return BINPICK_ASSETS_DIR;
}

Result<Cell> ParseCell(const std::string& yaml_text, const std::string& path) {
  std::error_code ec;
  fs::path base = path.empty() ? fs::current_path(ec) : fs::absolute(path, ec).parent_path();
  return ParseImpl(yaml_text, path.empty() ? std::string("<string>") : path, base);
}

Result<Cell> LoadCell(const std::string& path) {
  if (path.empty()) return Status::InvalidArgument("cell file path is empty");
  std::error_code ec;
  if (!fs::exists(path, ec)) return Status::NotFound(path + ": cell file does not exist");
  if (!fs::is_regular_file(path, ec)) return Status::InvalidArgument(path + ": cell file is not a regular file");
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  if (!in) return Status::NotFound(path + ": cannot read the cell file");
  return ParseCell(text.str(), path);
}

Result<Cell> LoadDefaultCell() {
  return ParseImpl(internal::kDefaultCellYaml, kEmbeddedPath, fs::path(AssetsDir()) / "cells");
}

Result<Cell> LoadCellOrDefault(const std::string& path) {
  return path.empty() ? LoadDefaultCell() : LoadCell(path);
}

int64_t EffectiveThreshold(const EmptyBoxRule& rule, int64_t image_pixels) {
  const double reference = static_cast<double>(rule.reference_width) * rule.reference_height;
  if (image_pixels <= 0 || reference <= 0) return rule.threshold_points;
  return std::llround(rule.threshold_points * (static_cast<double>(image_pixels) / reference));
}

std::string_view ToString(DaoaiDialect dialect) {
  switch (dialect) {
    case DaoaiDialect::kVisionPilot: return "vision_pilot";
    case DaoaiDialect::kSocketV1: return "socket_v1";
  }
  return "?";
}

std::optional<DaoaiDialect> ParseDaoaiDialect(std::string_view name) {
  if (name == "vision_pilot") return DaoaiDialect::kVisionPilot;
  if (name == "socket_v1") return DaoaiDialect::kSocketV1;
  return std::nullopt;
}

Status ValidateModbusRegisterMap(const ModbusRegisterMap& m) {
  constexpr int kRequestFields = 12, kResponseFields = 16, kMaxRead = 125;
  auto in = [](int reg, int base, int count) { return reg >= base && reg < base + count; };
  auto bad = [](const std::string& why) { return Status::InvalidArgument("modbus register map: " + why); };
  // Compared without adding to the base: a cell may give INT_MAX (fuzzed).
  if (m.request_base < 0 || m.request_base > 65536 - kRequestFields) return bad("request_base out of 0..65524");
  if (m.response_base < 0 || m.response_base > 65536 - kResponseFields) return bad("response_base out of 0..65520");
  if (m.request_flag < 0 || m.request_flag > 65535) return bad("request_flag out of 0..65535");
  if (m.response_flag < 0 || m.response_flag > 65535) return bad("response_flag out of 0..65535");
  if (m.request_flag == m.response_flag) return bad("request_flag and response_flag are the same register");
  if (in(m.request_flag, m.request_base, kRequestFields)) return bad("request_flag lies inside the request registers");
  if (in(m.response_flag, m.response_base, kResponseFields)) return bad("response_flag lies inside the response registers");
  if (in(m.response_flag, m.request_base, kRequestFields)) return bad("response_flag lies inside the request registers");
  // A request flag inside the response registers needs the handshake's marker
  // on the request's last register: outside the response, or on payload_3..6.
  const int marker = m.request_base + kRequestFields - 1;
  if (in(m.request_flag, m.response_base, kResponseFields) &&
      in(marker, m.response_base, kResponseFields) && !in(marker, m.response_base + 9, 4)) {
    return bad("request_flag lies inside the response registers, so the request's last register "
               "(request_base + 11, the handshake's marker) must lie outside them or on "
               "payload_3..payload_6");
  }
  const int lo = std::min({m.request_base, m.request_flag, m.response_base, m.response_flag});
  const int hi = std::max({m.request_base + kRequestFields - 1, m.request_flag,
                           m.response_base + kResponseFields - 1, m.response_flag});
  if (hi - lo + 1 > kMaxRead) return bad("registers span " + std::to_string(hi - lo + 1) + " > 125");
  return Status::Ok();
}

std::string Describe(const Cell& cell) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(3);
  os << "cell '" << cell.name << "' (" << cell.path << ")\n";
  const CameraSpec& cam = cell.camera;
  const Vec3 t_cam = (cam.eye_in_hand ? cam.X_FC : cam.X_BC).translation();
  os << "  camera: " << (cam.eye_in_hand ? "eye_in_hand" : "eye_to_hand") << " at [" << t_cam.x() << ", "
     << t_cam.y() << ", " << t_cam.z() << "] m" << (cam.hand_eye_file.empty() ? "" : ", hand-eye " + cam.hand_eye_file)
     << "; configs:";
  for (const CameraConfig& c : cam.configs) {
    os << " " << c.id << "=" << c.name << " " << c.intrinsics.width << "x" << c.intrinsics.height
       << (c.id == cam.default_config ? " (default)" : "");
  }
  os << "\n  source: ";
  const SourceSpec& s = cell.source;
  switch (s.kind) {
    case SourceSpec::Kind::kSynthetic:
      os << "synthetic, " << s.num_parts << " parts, seed " << s.seed << (s.simulate_picks ? ", simulated picks" : "");
      break;
    case SourceSpec::Kind::kFiles: os << "files from " << s.dir; break;
    case SourceSpec::Kind::kReplay: os << "replay of " << s.dir; break;
  }
  const Vec3& b = cell.bin.inner_size;
  os << "\n  bin: " << b.x() << " x " << b.y() << " x " << b.z() << " m at [" << cell.bin.X_BW.translation().x()
     << ", " << cell.bin.X_BW.translation().y() << ", " << cell.bin.X_BW.translation().z() << "]\n  parts:";
  for (const PartSpec& p : cell.parts) {
    const char* sym = p.symmetry.kind == Symmetry::Kind::kNone      ? "no symmetry"
                      : p.symmetry.kind == Symmetry::Kind::kRevolute ? "revolute"
                                                                     : "discrete";
    os << " " << p.class_id << "=" << p.name << " (" << sym;
    if (p.symmetry.kind == Symmetry::Kind::kDiscrete) os << " " << p.symmetry.order;
    os << ", " << p.grasps.size() << " grasps)";
  }
  os << "\n  grippers:";
  for (const GripperSpec& g : cell.grippers) {
    os << " " << g.name << " (" << (g.kind == GripperSpec::Kind::kSuction ? "suction" : "parallel_jaw") << ")";
  }
  if (!cell.fixtures.empty()) os << "\n  fixtures:";
  for (const FixtureSpec& f : cell.fixtures) {
    const Vec3 t = f.X_BP_taught.translation();
    os << " " << f.class_id << "=" << f.name << " taught at [" << t.x() << ", " << t.y() << ", " << t.z() << "]";
  }
  os << "\n  tasks:";
  for (const TaskSpec& t : cell.tasks) os << " " << t.id << "=" << t.name;
  // The pick tasks that hand out only grasps their part can be placed with
  // (place_on: seed 003's pick is one on a seed-003 cell).
  for (const TaskSpec& t : cell.tasks) {
    if (!t.place_on.empty()) os << "\n  task " << t.id << " places on " << t.place_on << " (placeable grasps only)";
  }
  // The empty-box threshold each camera config applies (EffectiveThreshold).
  for (const TaskSpec& t : cell.tasks) {
    if (t.kind != TaskSpec::Kind::kPick && t.kind != TaskSpec::Kind::kPick2D) continue;
    const EmptyBoxRule& r = t.empty_box;
    os << "\n  task " << t.id << " empty box: < " << r.threshold_points << " points at " << r.reference_width
       << "x" << r.reference_height << ", effective:";
    for (const CameraConfig& c : cell.camera.configs) {
      os << " " << c.id << "=" << c.name << " "
         << EffectiveThreshold(r, static_cast<int64_t>(c.intrinsics.width) * c.intrinsics.height);
    }
  }
  os << "\n  robot: " << cell.robot.model.name << " (meta_1 id " << static_cast<int>(cell.robot.model.type) << ", "
     << ToString(cell.robot.model.convention) << "), dialect " << ToString(cell.robot.dialect);
  if (!cell.robot.modbus_host.empty()) os << ", modbus " << cell.robot.modbus_host << ":" << cell.robot.modbus_port;
  const Endpoints& e = cell.endpoints;
  os << "\n  endpoints: " << e.bind << " daoai " << e.daoai_port << ", gri " << e.gri_port << ", gri_official "
     << e.gri_official_port << ", http " << (e.http_port == 0 ? std::string("off") : std::to_string(e.http_port))
     << "\n";
  return os.str();
}

}  // namespace bp
