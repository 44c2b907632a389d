#include "pipeline/frame_io.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <set>
#include <map>
#include <sstream>
#include <system_error>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <pcl/PCLPointCloud2.h>
#include <pcl/console/print.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include "pipeline/pose_json.h"

namespace bp {
namespace {

// Largest cloud a PCD may declare (100 M points: 1.2 GB of xyz).
constexpr uint64_t kMaxPcdPoints = 100000000;

namespace fs = std::filesystem;
using nlohmann::json;

// PNG signature (PNG spec, section 5.2).
constexpr std::array<unsigned char, 8> kPngMagic = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
// Sidecar "format" tag; bump the number on an incompatible change.
constexpr const char* kSidecarFormat = "binpick.intrinsics/1";
constexpr const char* kTruthFormat = "binpick.truth/1";
// Largest count a 16-bit PNG holds.
constexpr double kMaxDepthCount = 65535.0;

std::string Quote(const std::string& path) { return "'" + path + "'"; }

std::string LowerExtension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

// Silences PCL's console output (it prints to stderr on every parse error)
// while a file is parsed; we report through Status instead.
class QuietPcl {
 public:
  QuietPcl() : saved_(pcl::console::getVerbosityLevel()) {
    pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);
  }
  ~QuietPcl() { pcl::console::setVerbosityLevel(saved_); }
  QuietPcl(const QuietPcl&) = delete;
  QuietPcl& operator=(const QuietPcl&) = delete;

 private:
  pcl::console::VERBOSITY_LEVEL saved_;
};

// Missing / not a regular file / empty, checked before any parser sees it.
Result<uintmax_t> CheckReadable(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return Status::NotFound(Quote(path) + ": no such file");
  if (!fs::is_regular_file(path, ec)) return Status::InvalidArgument(Quote(path) + ": not a regular file");
  const uintmax_t size = fs::file_size(path, ec);
  if (ec) return Status::NotFound(Quote(path) + ": cannot stat: " + ec.message());
  if (size == 0) return Status::Corruption(Quote(path) + ": empty file");
  return size;
}

std::string ReadHead(const std::string& path, size_t n) {
  std::ifstream in(path, std::ios::binary);
  std::string head(n, '\0');
  in.read(head.data(), static_cast<std::streamsize>(n));
  head.resize(static_cast<size_t>(in.gcount()));
  return head;
}

Status CheckPngMagic(const std::string& path) {
  const std::string head = ReadHead(path, kPngMagic.size());
  if (head.size() < kPngMagic.size() || std::memcmp(head.data(), kPngMagic.data(), kPngMagic.size()) != 0) {
    return Status::Corruption(Quote(path) + ": not a PNG file (bad magic)");
  }
  return Status::Ok();
}

// Files are written with keys in a fixed, readable order.
using OrderedJson = nlohmann::ordered_json;

Result<json> ReadJson(const std::string& path) {
  auto size = CheckReadable(path);
  if (!size.ok()) return size.status();
  std::ifstream in(path);
  json j = json::parse(in, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) return Status::Corruption(Quote(path) + ": not valid JSON (truncated?)");
  if (!j.is_object()) return Status::Corruption(Quote(path) + ": expected a JSON object");
  return j;
}

// dump(2), but arrays of plain numbers on one line ("[1.0, 0.0, 0.0, 0.7]"),
// so that matrices and vectors read as such.
std::string PrettyJson(const OrderedJson& j) {
  const std::string text = j.dump(2);
  std::string out;
  out.reserve(text.size());
  size_t i = 0;
  while (i < text.size()) {
    if (text[i] == '[') {
      const size_t close = text.find_first_of("[]{}\"", i + 1);
      if (close != std::string::npos && text[close] == ']') {
        out += '[';
        bool space = false;
        for (size_t k = i + 1; k < close; ++k) {
          const char c = text[k];
          if (c == ' ' || c == '\n') {
            space = true;
            continue;
          }
          if (space && out.back() == ',') out += ' ';
          space = false;
          out += c;
        }
        out += ']';
        i = close + 1;
        continue;
      }
    }
    out += text[i++];
  }
  return out;
}

Status WriteJson(const OrderedJson& j, const std::string& path) {
  std::ofstream out(path, std::ios::trunc);
  if (!out) return Status::Internal(Quote(path) + ": cannot open for writing");
  errno = 0;
  out << PrettyJson(j) << "\n";
  out.close();
  if (!out) {
    const std::string reason = errno != 0 ? std::string(": ") + std::strerror(errno) : "";
    return Status::Internal(Quote(path) + ": write failed" + reason);
  }
  return Status::Ok();
}

// --- Intrinsics sidecar ------------------------------------------------------

struct Sidecar {
  std::optional<Intrinsics> intrinsics;  // absent for unorganized clouds
  double depth_scale = kDepthPngScale;
  std::optional<Pose> X_BC;              // absent: the caller's default
  int64_t timestamp_ns = 0;
  std::optional<std::string> unit;       // clouds: "m", "cm" or "mm"
};

// Metres per unit of a cloud's coordinates ("unit" in the sidecar).
std::optional<double> MetresPerUnit(const std::string& unit) {
  if (unit == "m") return 1.0;
  if (unit == "cm") return 0.01;
  if (unit == "mm") return 0.001;
  return std::nullopt;
}

Status WriteSidecar(const Frame& frame, bool with_intrinsics, std::optional<double> depth_scale,
                    const std::string& data_path) {
  OrderedJson j;
  j["format"] = kSidecarFormat;
  if (with_intrinsics) {
    const Intrinsics& K = frame.intrinsics;
    j["width"] = K.width;
    j["height"] = K.height;
    j["fx"] = K.fx;
    j["fy"] = K.fy;
    j["cx"] = K.cx;
    j["cy"] = K.cy;
    j["distortion"] = K.distortion;
  }
  if (depth_scale) j["depth_scale"] = *depth_scale;
  j["X_BC"] = PoseToJson(frame.X_BC);
  j["timestamp_ns"] = frame.timestamp_ns;
  j["source"] = frame.source;
  return WriteJson(j, IntrinsicsSidecarPath(data_path));
}

Result<Sidecar> ReadSidecarUnnamed(const std::string& sidecar_path);

// Sidecar errors name the data file as well as the sidecar.
Result<Sidecar> ReadSidecar(const std::string& sidecar_path, const std::string& data_path) {
  Result<Sidecar> s = ReadSidecarUnnamed(sidecar_path);
  if (s.ok()) return s;
  const Status& e = s.status();
  const std::string msg = Quote(data_path) + ": sidecar " + e.message();
  switch (e.code()) {
    case Status::Code::kNotFound: return Status::NotFound(msg);
    case Status::Code::kInvalidArgument: return Status::InvalidArgument(msg);
    default: return Status::Corruption(msg);
  }
}

Result<Sidecar> ReadSidecarUnnamed(const std::string& sidecar_path) {
  auto j = ReadJson(sidecar_path);
  if (!j.ok()) return j.status();
  const std::string where = Quote(sidecar_path) + ": ";
  try {
    Sidecar s;
    if (j->contains("width")) {
      Intrinsics K;
      K.width = j->at("width").get<int>();
      K.height = j->at("height").get<int>();
      K.fx = j->at("fx").get<double>();
      K.fy = j->at("fy").get<double>();
      K.cx = j->at("cx").get<double>();
      K.cy = j->at("cy").get<double>();
      if (j->contains("distortion")) K.distortion = j->at("distortion").get<std::array<double, 5>>();
      if (!K.valid()) return Status::Corruption(where + "intrinsics need width, height, fx, fy > 0");
      s.intrinsics = K;
    }
    if (j->contains("depth_scale")) {
      s.depth_scale = j->at("depth_scale").get<double>();
      if (!(s.depth_scale > 0) || !std::isfinite(s.depth_scale)) {
        return Status::Corruption(where + "depth_scale must be > 0");
      }
    }
    if (j->contains("X_BC")) {
      auto X = PoseFromJson(j->at("X_BC"), where + "X_BC");
      if (!X.ok()) return X.status();
      s.X_BC = *X;
    }
    if (j->contains("timestamp_ns")) s.timestamp_ns = j->at("timestamp_ns").get<int64_t>();
    if (j->contains("unit")) {
      s.unit = j->at("unit").get<std::string>();
      if (!MetresPerUnit(*s.unit)) {
        return Status::InvalidArgument(where + "unit '" + s.unit->substr(0, 16) + "' is not m, cm or mm");
      }
    }
    return s;
  } catch (const std::exception& e) {
    return Status::Corruption(where + "bad sidecar: " + e.what());
  }
}

// --- PNG helpers ---------------------------------------------------------------

// Reads a single-channel PNG of the given OpenCV depth (CV_8U / CV_16U).
Result<cv::Mat> ReadGreyPng(const std::string& path, int cv_depth) {
  auto size = CheckReadable(path);
  if (!size.ok()) return size.status();
  if (Status s = CheckPngMagic(path); !s.ok()) return s;
  cv::Mat m;
  try {
    m = cv::imread(path, cv::IMREAD_UNCHANGED);
  } catch (const std::exception& e) {
    return Status::Corruption(Quote(path) + ": cannot decode PNG: " + e.what());
  }
  if (m.empty()) return Status::Corruption(Quote(path) + ": cannot decode PNG (truncated or corrupt)");
  if (m.channels() != 1) {
    return Status::InvalidArgument(Quote(path) + ": PNG has " + std::to_string(m.channels()) +
                                   " channels, expected 1 (grey)");
  }
  if (m.depth() != cv_depth) {
    const char* want = cv_depth == CV_16U ? "16-bit" : "8-bit";
    const char* got = m.depth() == CV_8U ? "8-bit" : m.depth() == CV_16U ? "16-bit" : "non-8/16-bit";
    return Status::InvalidArgument(Quote(path) + ": " + got + " PNG where a " + want + " PNG is expected");
  }
  return m;
}

Status WritePng(const cv::Mat& m, const std::string& path) {
  try {
    if (!cv::imwrite(path, m)) return Status::Internal(Quote(path) + ": cannot write PNG");
  } catch (const std::exception& e) {
    return Status::Internal(Quote(path) + ": cannot write PNG: " + e.what());
  }
  return Status::Ok();
}

template <typename T>
Image<T> ImageFromMat(const cv::Mat& m) {
  Image<T> img(m.cols, m.rows);
  for (int v = 0; v < m.rows; ++v) std::memcpy(&img.at(0, v), m.ptr<T>(v), sizeof(T) * m.cols);
  return img;
}

// --- Loaders per type ------------------------------------------------------------

bool ValidDepth(float z) { return std::isfinite(z) && z > 0.f; }

Status RequireValidPoints(const Frame& frame, const std::string& path) {
  if (frame.ValidPointCount() == 0) return Status::Corruption(Quote(path) + ": no valid points");
  return Status::Ok();
}

Result<Frame> LoadDepthPng(const std::string& path, const Pose& X_BC_default, FrameFileInfo& info) {
  auto m = ReadGreyPng(path, CV_16U);
  if (!m.ok()) return m.status();
  const std::string sidecar_path = IntrinsicsSidecarPath(path);
  std::error_code ec;
  if (!fs::exists(sidecar_path, ec)) {
    return Status::NotFound(Quote(path) + ": depth PNG needs its intrinsics sidecar " + Quote(sidecar_path));
  }
  auto sidecar = ReadSidecar(sidecar_path, path);
  if (!sidecar.ok()) return sidecar.status();
  if (!sidecar->intrinsics) {
    return Status::Corruption(Quote(sidecar_path) + ": no intrinsics (width, height, fx, fy, cx, cy)");
  }
  const Intrinsics& K = *sidecar->intrinsics;
  if (m->cols != K.width || m->rows != K.height) {
    return Status::Corruption(Quote(path) + ": PNG is " + std::to_string(m->cols) + "x" +
                              std::to_string(m->rows) + " but its sidecar says " + std::to_string(K.width) +
                              "x" + std::to_string(K.height));
  }
  if (sidecar->unit) {
    return Status::InvalidArgument(Quote(sidecar_path) + ": \"unit\" is for clouds; a depth PNG's unit is its "
                                   "\"depth_scale\" (metres per count)");
  }
  Frame frame;
  frame.intrinsics = K;
  frame.X_BC = sidecar->X_BC.value_or(X_BC_default);
  frame.timestamp_ns = sidecar->timestamp_ns;
  info.has_sidecar = true;
  info.X_BC_known = sidecar->X_BC.has_value();
  info.width = K.width;
  info.height = K.height;
  frame.depth = DepthImage(K.width, K.height, std::numeric_limits<float>::quiet_NaN());
  const double scale = sidecar->depth_scale;
  for (int v = 0; v < K.height; ++v) {
    const uint16_t* row = m->ptr<uint16_t>(v);
    for (int u = 0; u < K.width; ++u) {
      if (row[u] != 0) frame.depth.at(u, v) = static_cast<float>(row[u] * scale);
    }
  }
  return frame;
}

// True if every valid point of the organized cloud is where Deproject puts
// its z through K (so the depth image alone reproduces the cloud).
bool MatchesPinhole(const pcl::PointCloud<pcl::PointXYZ>& cloud, const Intrinsics& K) {
  for (int v = 0; v < K.height; ++v) {
    for (int u = 0; u < K.width; ++u) {
      const pcl::PointXYZ& p = cloud.at(u, v);
      const bool any_finite = std::isfinite(p.x) || std::isfinite(p.y) || std::isfinite(p.z);
      if (!any_finite) continue;
      if (!std::isfinite(p.x) || !std::isfinite(p.y) || !ValidDepth(p.z)) return false;
      const Eigen::Vector3f q = Deproject(K, static_cast<float>(u), static_cast<float>(v), p.z);
      const float tol = 1e-6f + 1e-5f * p.z;
      if (std::abs(q.x() - p.x) > tol || std::abs(q.y() - p.y) > tol) return false;
    }
  }
  return true;
}

// PCD's TYPE and SIZE of a field's datatype ("F 4"), PLY's type word ("float").
std::string PcdType(uint8_t datatype) {
  switch (datatype) {
    case pcl::PCLPointField::INT8: return "TYPE I SIZE 1";
    case pcl::PCLPointField::UINT8: return "TYPE U SIZE 1";
    case pcl::PCLPointField::INT16: return "TYPE I SIZE 2";
    case pcl::PCLPointField::UINT16: return "TYPE U SIZE 2";
    case pcl::PCLPointField::INT32: return "TYPE I SIZE 4";
    case pcl::PCLPointField::UINT32: return "TYPE U SIZE 4";
    case pcl::PCLPointField::FLOAT32: return "TYPE F SIZE 4";
    case pcl::PCLPointField::FLOAT64: return "TYPE F SIZE 8";
    default: return "an unknown type";
  }
}

// A cloud file's format, for messages and FrameFileInfo.
enum class CloudFormat { kPcd, kPly };
const char* FormatName(CloudFormat f) { return f == CloudFormat::kPcd ? "PCD" : "PLY"; }

// The points of a parsed cloud file, in its own frame F (before the sidecar's
// unit and the PCD VIEWPOINT are applied).
struct CloudData {
  pcl::PointCloud<pcl::PointXYZ> cloud;  // width x height as stored, NaNs in place
  Pose X_FS = Pose::Identity();          // PCD VIEWPOINT: the sensor in F
  bool viewpoint_set = false;
};

// Checks that x, y, z are one float32 or float64 each. Errors name the format
// and the field: PCD "field 'x' is TYPE U SIZE 1", PLY "property 'x' is uchar"
// (`ply_types`: each vertex property's type word as the header gives it).
Status CheckCoordinateFields(const pcl::PCLPointCloud2& blob, const std::string& path, CloudFormat format,
                             const std::map<std::string, std::string>& ply_types, FrameFileInfo& info) {
  std::array<bool, 3> found{};
  bool float64 = false;
  info.extra_fields.clear();
  for (const auto& f : blob.fields) {
    const int axis = f.name == "x" ? 0 : f.name == "y" ? 1 : f.name == "z" ? 2 : -1;
    if (axis < 0) {
      if (f.name != "_") info.extra_fields.push_back(f.name);  // "_": PCL's padding
      continue;
    }
    const bool is_float = f.datatype == pcl::PCLPointField::FLOAT32 || f.datatype == pcl::PCLPointField::FLOAT64;
    if (!is_float || f.count != 1) {
      if (format == CloudFormat::kPly) {
        const auto t = ply_types.find(f.name);
        const std::string type = t != ply_types.end() ? t->second : PcdType(f.datatype);
        return Status::InvalidArgument(Quote(path) + ": PLY property '" + f.name + "' is " + type +
                                       "; coordinates must be float or double");
      }
      return Status::InvalidArgument(Quote(path) + ": PCD field '" + f.name + "' is " + PcdType(f.datatype) +
                                     " COUNT " + std::to_string(f.count) +
                                     "; coordinates must be TYPE F SIZE 4 or 8, COUNT 1");
    }
    float64 = float64 || f.datatype == pcl::PCLPointField::FLOAT64;
    found[static_cast<size_t>(axis)] = true;
  }
  if (!found[0] || !found[1] || !found[2]) {
    return Status::Corruption(Quote(path) + ": " + FormatName(format) + " has no x, y, z " +
                              (format == CloudFormat::kPly ? "vertex properties" : "fields"));
  }
  info.coordinates = float64 ? "float64" : "float32";
  return Status::Ok();
}

// x, y, z of a parsed blob (float32 or float64, checked by
// CheckCoordinateFields), every byte range checked against the data: PCL's
// own conversion (fromPCLPointCloud2) trusts the header, and a hostile one
// made it read past the data (found by fuzz/pcd_fuzz).
Status BlobToXyz(const pcl::PCLPointCloud2& blob, const std::string& path, CloudFormat format,
                 pcl::PointCloud<pcl::PointXYZ>& cloud) {
  std::array<uint32_t, 3> offset{};
  std::array<bool, 3> is_double{};
  for (const auto& f : blob.fields) {
    const int axis = f.name == "x" ? 0 : f.name == "y" ? 1 : f.name == "z" ? 2 : -1;
    if (axis < 0) continue;
    offset[static_cast<size_t>(axis)] = f.offset;
    is_double[static_cast<size_t>(axis)] = f.datatype == pcl::PCLPointField::FLOAT64;
  }
  const uint64_t w = blob.width, h = blob.height;
  if (w * h == 0 || w * h > kMaxPcdPoints) {
    return Status::Corruption(Quote(path) + ": " + FormatName(format) + " has " + std::to_string(w) + "x" +
                              std::to_string(h) + " points");
  }
  cloud.clear();
  cloud.width = static_cast<uint32_t>(w);
  cloud.height = static_cast<uint32_t>(h);
  cloud.points.resize(static_cast<size_t>(w * h));
  cloud.is_dense = blob.is_dense != 0;
  for (uint64_t r = 0; r < h; ++r) {
    for (uint64_t c = 0; c < w; ++c) {
      const uint64_t base = r * blob.row_step + c * blob.point_step;
      pcl::PointXYZ& p = cloud.points[static_cast<size_t>(r * w + c)];
      float* out[3] = {&p.x, &p.y, &p.z};
      for (size_t a = 0; a < 3; ++a) {
        const uint64_t at = base + offset[a];
        const size_t bytes = is_double[a] ? sizeof(double) : sizeof(float);
        if (at + bytes > blob.data.size()) {
          return Status::Corruption(Quote(path) + ": " + FormatName(format) + " data ends before point " +
                                    std::to_string(r * w + c));
        }
        if (is_double[a]) {
          double d;
          std::memcpy(&d, blob.data.data() + at, sizeof(double));
          *out[a] = static_cast<float>(d);
        } else {
          std::memcpy(out[a], blob.data.data() + at, sizeof(float));
        }
      }
    }
  }
  return Status::Ok();
}

// Checks the header strictly before PCL sees it. PCL's parser trusts what it
// reads: a header of a few bytes could make it allocate gigabytes, and
// repeated or inconsistent lines corrupted its memory (found by
// fuzz/pcd_fuzz). Accepted: comment lines, then each of VERSION FIELDS SIZE
// TYPE COUNT WIDTH HEIGHT VIEWPOINT POINTS at most once, then DATA ascii |
// binary | binary_compressed; FIELDS, SIZE, TYPE (and COUNT) of one length;
// WIDTH x HEIGHT = POINTS; the declared data at most 64 times the file
// (binary_compressed's bound; ascii and binary are far below).
// `fields` gets the FIELDS line's names.
Status CheckPcdHeader(const std::string& path, std::vector<std::string>* fields) {
  std::ifstream in(path, std::ios::binary);
  std::error_code ec;
  const uint64_t file_size = fs::file_size(path, ec);
  if (ec || !in) return Status::NotFound(Quote(path) + ": cannot read");
  auto bad = [&](const std::string& why) { return Status::Corruption(Quote(path) + ": PCD header: " + why); };
  std::map<std::string, std::vector<std::string>> keys;
  std::string line;
  bool data = false;
  for (int n = 0; n < 64 && std::getline(in, line); ++n) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    std::istringstream is(line);
    std::string key, tok;
    is >> key;
    static const std::set<std::string> kKeys = {"VERSION", "FIELDS", "SIZE",   "TYPE", "COUNT",
                                                "WIDTH",   "HEIGHT", "VIEWPOINT", "POINTS", "DATA"};
    if (!kKeys.count(key)) return bad("unknown line '" + line.substr(0, 32) + "'");
    if (keys.count(key)) return bad(key + " given twice");
    std::vector<std::string>& v = keys[key];
    while (is >> tok) v.push_back(tok);
    if (key == "DATA") {
      data = true;
      break;
    }
  }
  if (!data) return bad("no DATA line");
  for (const char* k : {"FIELDS", "SIZE", "TYPE", "WIDTH", "POINTS"}) {
    if (keys[k].empty()) return bad(std::string("no ") + k);
  }
  const std::string& d = keys["DATA"].empty() ? std::string() : keys["DATA"][0];
  if (keys["DATA"].size() != 1 || (d != "ascii" && d != "binary" && d != "binary_compressed")) {
    return bad("DATA must be ascii, binary or binary_compressed");
  }
  const size_t nf = keys["FIELDS"].size();
  if (keys["SIZE"].size() != nf || keys["TYPE"].size() != nf || (keys.count("COUNT") && keys["COUNT"].size() != nf)) {
    return bad("FIELDS, SIZE, TYPE and COUNT differ in length");
  }
  auto number = [](const std::string& t, uint64_t& out) {
    if (t.empty() || t.size() > 12 || t.find_first_not_of("0123456789") != std::string::npos) return false;
    out = std::stoull(t);
    return true;
  };
  uint64_t point_step = 0;
  for (size_t i = 0; i < nf; ++i) {
    uint64_t size = 0, count = 1;
    if (!number(keys["SIZE"][i], size) || (size != 1 && size != 2 && size != 4 && size != 8)) return bad("bad SIZE");
    if (keys.count("COUNT") && (!number(keys["COUNT"][i], count) || count == 0 || count > (1u << 20))) {
      return bad("bad COUNT");
    }
    const std::string& t = keys["TYPE"][i];
    if (t != "F" && t != "I" && t != "U") return bad("bad TYPE");
    point_step += size * count;
  }
  uint64_t width = 0, height = 1, points = 0;
  if (keys["WIDTH"].size() != 1 || !number(keys["WIDTH"][0], width)) return bad("bad WIDTH");
  if (keys.count("HEIGHT") && (keys["HEIGHT"].size() != 1 || !number(keys["HEIGHT"][0], height))) return bad("bad HEIGHT");
  if (keys["POINTS"].size() != 1 || !number(keys["POINTS"][0], points)) return bad("bad POINTS");
  if (width > (1u << 30) || height > (1u << 30) || width * height != points) return bad("WIDTH x HEIGHT is not POINTS");
  if (points * point_step > 64 * file_size + 4096) return bad("declares more data than the file can hold");
  *fields = keys["FIELDS"];
  return Status::Ok();
}

// Checks PCL's parse of a PCD header against what its reader will do with
// the data. PCL trusts SIZE / TYPE / COUNT: a field that does not fit in its
// point made its conversion read past the data; it checks WIDTH x HEIGHT
// against POINTS in 32 bits, so a product that wraps passed and its
// conversion then indexed an empty cloud (both found by fuzz/pcd_fuzz).
Status CheckParsedPcdHeader(const pcl::PCLPointCloud2& header, int data_type, unsigned int data_idx,
                            const std::string& path) {
  for (const auto& f : header.fields) {
    size_t bytes = 0;
    switch (f.datatype) {
      case pcl::PCLPointField::INT8: case pcl::PCLPointField::UINT8: bytes = 1; break;
      case pcl::PCLPointField::INT16: case pcl::PCLPointField::UINT16: bytes = 2; break;
      case pcl::PCLPointField::INT32: case pcl::PCLPointField::UINT32:
      case pcl::PCLPointField::FLOAT32: bytes = 4; break;
      case pcl::PCLPointField::FLOAT64: bytes = 8; break;
      default: break;
    }
    if (bytes == 0 || f.count == 0 ||
        static_cast<uint64_t>(f.offset) + static_cast<uint64_t>(bytes) * f.count > header.point_step) {
      return Status::Corruption(Quote(path) + ": PCD field '" + f.name +
                                "' does not fit its point (SIZE, TYPE, COUNT disagree)");
    }
  }
  // Zero points: PCL's conversion would take &cloud[0] of an empty cloud.
  const uint64_t points = static_cast<uint64_t>(header.width) * header.height;
  if (points == 0) return Status::Corruption(Quote(path) + ": PCD declares no points");
  if (points > kMaxPcdPoints) {
    return Status::Corruption(Quote(path) + ": PCD header says " + std::to_string(header.width) + "x" +
                              std::to_string(header.height) + " points, more than " + std::to_string(kMaxPcdPoints));
  }
  // Binary data must fill width * height points; PCL checks this too, but
  // its message goes to stderr.
  if (data_type == 1) {
    const uintmax_t need = static_cast<uintmax_t>(data_idx) + points * header.point_step;
    std::error_code ec;
    const uintmax_t have = fs::file_size(path, ec);
    if (have < need) {
      return Status::Corruption(Quote(path) + ": truncated PCD: " + std::to_string(have) + " bytes, header needs " +
                                std::to_string(need));
    }
  }
  return Status::Ok();
}

Result<CloudData> ReadPcd(const std::string& path, FrameFileInfo& info) {
  const std::string head = ReadHead(path, 64);
  if (!(head.rfind("#", 0) == 0 || head.rfind("VERSION", 0) == 0 || head.rfind("FIELDS", 0) == 0)) {
    return Status::Corruption(Quote(path) + ": not a PCD file (bad magic)");
  }
  std::vector<std::string> fields;
  if (Status s = CheckPcdHeader(path, &fields); !s.ok()) return s;
  QuietPcl quiet;
  pcl::PCDReader reader;
  pcl::PCLPointCloud2 header;
  Eigen::Vector4f origin;
  Eigen::Quaternionf orientation;
  int pcd_version = 0, data_type = 0;
  unsigned int data_idx = 0;
  if (reader.readHeader(path, header, origin, orientation, pcd_version, data_type, data_idx) < 0) {
    return Status::Corruption(Quote(path) + ": bad PCD header");
  }
  info.encoding = data_type == 0 ? "ascii" : data_type == 1 ? "binary" : "binary_compressed";
  if (Status s = CheckCoordinateFields(header, path, CloudFormat::kPcd, {}, info); !s.ok()) return s;
  if (Status s = CheckParsedPcdHeader(header, data_type, data_idx, path); !s.ok()) return s;
  // The FIELDS line's names (PCL's header drops some, e.g. rgba).
  info.extra_fields.clear();
  for (const std::string& name : fields) {
    if (name != "x" && name != "y" && name != "z" && name != "_") info.extra_fields.push_back(name);
  }
  CloudData data;
  pcl::PCLPointCloud2 blob;
  if (reader.read(path, blob) < 0) return Status::Corruption(Quote(path) + ": cannot parse PCD data (truncated?)");
  if (Status s = BlobToXyz(blob, path, CloudFormat::kPcd, data.cloud); !s.ok()) return s;
  if (data.cloud.size() != static_cast<size_t>(data.cloud.width) * data.cloud.height) {
    return Status::Corruption(Quote(path) + ": PCD has " + std::to_string(data.cloud.size()) + " points, header says " +
                              std::to_string(data.cloud.width) + "x" + std::to_string(data.cloud.height));
  }
  // VIEWPOINT tx ty tz qw qx qy qz: the sensor's pose in the cloud's frame.
  const Quat q = orientation.cast<double>();
  if (!origin.head<3>().allFinite() || !q.coeffs().allFinite() || std::abs(q.norm() - 1.0) > 1e-3) {
    return Status::Corruption(Quote(path) + ": PCD VIEWPOINT is not a position and a unit quaternion");
  }
  data.X_FS = MakePose(q.normalized(), origin.head<3>().cast<double>());
  data.viewpoint_set = !origin.head<3>().isZero() || q.w() != 1.0;
  return data;
}

// Median distance of the finite points from the origin (a sample of at most
// 10000 points), 0 for none.
double MedianRange(const pcl::PointCloud<pcl::PointXYZ>& cloud) {
  const size_t step = std::max<size_t>(1, cloud.size() / 10000);
  std::vector<float> r;
  for (size_t i = 0; i < cloud.size(); i += step) {
    const Eigen::Vector3f p = cloud.points[i].getVector3fMap();
    if (p.allFinite()) r.push_back(p.norm());
  }
  if (r.empty()) return 0.0;
  std::nth_element(r.begin(), r.begin() + static_cast<std::ptrdiff_t>(r.size() / 2), r.end());
  return r[r.size() / 2];
}

// A cloud this far away (median, metres) was written in millimetres:
// binpick's cameras see 0.3 to 2 m, and no bin cell is 50 m across.
constexpr double kUndeclaredMillimetresRange = 50.0;

// The points of a cloud file as a frame: the sidecar's unit, X_BC and
// timestamp; a set VIEWPOINT moves the points into the sensor's frame S
// (X_BC = X_BF * X_FS); an organized cloud whose sidecar intrinsics reproduce
// it becomes a depth image, anything else a point list in points_C.
Result<Frame> CloudToFrame(CloudData data, const std::string& path, const Pose& X_BC_default,
                           FrameFileInfo& info) {
  pcl::PointCloud<pcl::PointXYZ>& cloud = data.cloud;
  info.width = static_cast<int>(cloud.width);
  info.height = static_cast<int>(cloud.height);
  Frame frame;
  frame.X_BC = X_BC_default;
  const std::string sidecar_path = IntrinsicsSidecarPath(path);
  std::optional<Sidecar> sidecar;
  std::error_code ec;
  if (fs::exists(sidecar_path, ec)) {
    auto s = ReadSidecar(sidecar_path, path);
    if (!s.ok()) return s.status();
    sidecar = *s;
    info.has_sidecar = true;
    info.X_BC_known = s->X_BC.has_value();
    frame.X_BC = s->X_BC.value_or(X_BC_default);
    frame.timestamp_ns = s->timestamp_ns;
  }
  if (sidecar && sidecar->unit) {
    info.unit = *sidecar->unit;
    info.unit_declared = true;
    const auto scale = static_cast<float>(*MetresPerUnit(info.unit));
    if (scale != 1.f) {
      for (auto& p : cloud.points) p.getVector3fMap() *= scale;
    }
  } else if (const double range = MedianRange(cloud); range > kUndeclaredMillimetresRange) {
    return Status::InvalidArgument(Quote(path) + ": the points are " + std::to_string(std::lround(range)) +
                                   " units from the origin (median), read as metres: millimetres? declare "
                                   "\"unit\": \"mm\" in " + Quote(sidecar_path));
  }
  if (data.viewpoint_set) {
    // p_S = X_SF p_F; the frame's X_BC is then the sensor's.
    const Eigen::Matrix3f R_SF = data.X_FS.linear().transpose().cast<float>();
    const Eigen::Vector3f t_SF = -(R_SF * data.X_FS.translation().cast<float>());
    for (auto& p : cloud.points) p.getVector3fMap() = R_SF * p.getVector3fMap() + t_SF;
    frame.X_BC = frame.X_BC * data.X_FS;
    info.viewpoint_used = true;
  }
  const bool organized = cloud.height > 1;
  if (organized && sidecar && sidecar->intrinsics) {
    const Intrinsics& K = *sidecar->intrinsics;
    if (static_cast<int>(cloud.width) != K.width || static_cast<int>(cloud.height) != K.height) {
      return Status::Corruption(Quote(path) + ": PCD is " + std::to_string(cloud.width) + "x" +
                                std::to_string(cloud.height) + " but its sidecar says " + std::to_string(K.width) +
                                "x" + std::to_string(K.height));
    }
    if (MatchesPinhole(cloud, K)) {
      frame.intrinsics = K;
      frame.depth = DepthImage(K.width, K.height, std::numeric_limits<float>::quiet_NaN());
      for (int v = 0; v < K.height; ++v) {
        for (int u = 0; u < K.width; ++u) {
          const float z = cloud.at(u, v).z;
          if (ValidDepth(z)) frame.depth.at(u, v) = z;
        }
      }
      return frame;
    }
    // Points are not a pinhole deprojection of their z: keep them as they are.
  }
  frame.points_C.reserve(cloud.size());
  for (const auto& p : cloud.points) frame.points_C.emplace_back(p.x, p.y, p.z);
  return frame;
}

// One vertex property of a PLY header: its name, its type word ("list" for
// a list) and its header line.
struct PlyProperty {
  std::string name, type;
  int line = 0;
};

// The vertex properties PCL's PLY reader can take without aborting the
// process or shifting the coordinates (found by fuzz/ply_frame_fuzz: a
// "green" and "blue" without "red" hit an assert in
// PLYReader::vertexColorCallback). PCL packs uchar red, green and blue into
// one 4-byte field, written at "blue", and an alpha into it, so they come
// together in that order, once, an alpha (uchar) straight after; it takes a
// list property's size from the first vertex, so vertices hold scalars.
Status CheckPlyVertexProperties(const std::vector<PlyProperty>& props, const std::string& path) {
  auto bad = [&](const PlyProperty& p, const std::string& why) {
    return Status::Corruption(Quote(path) + ": PLY header: line " + std::to_string(p.line) + ": vertex property '" +
                              p.name + "' " + why);
  };
  const auto is_uchar = [](const PlyProperty& p) { return p.type == "uchar" || p.type == "uint8"; };
  const auto is_colour = [](const std::string& name) {
    const std::string c = name.rfind("diffuse_", 0) == 0 ? name.substr(8) : name;
    return c == "red" || c == "green" || c == "blue" || name == "alpha";
  };
  static const char* const kColours =
      "is out of place: PCL reads uchar colours as red, green, blue (then alpha) next to each other, once";
  bool seen_colour = false;
  for (size_t i = 0; i < props.size(); ++i) {
    const PlyProperty& p = props[i];
    if (p.type == "list") return bad(p, "is a list; a point's properties must be scalars");
    if (!is_uchar(p) || !is_colour(p.name)) continue;
    const std::string family = p.name.rfind("diffuse_", 0) == 0 ? "diffuse_" : "";
    const bool triple = p.name == family + "red" && i + 2 < props.size() && is_uchar(props[i + 1]) &&
                        props[i + 1].name == family + "green" && is_uchar(props[i + 2]) &&
                        props[i + 2].name == family + "blue";
    if (!triple || seen_colour) return bad(p, kColours);
    seen_colour = true;
    i += 2;
    if (i + 1 < props.size() && props[i + 1].name == "alpha" && is_uchar(props[i + 1])) ++i;
  }
  return Status::Ok();
}

// Checks the header strictly before PCL sees it, as CheckPcdHeader does.
// PCL's PLY parser asserts (aborting the process) on lines it tokenizes
// differently from how it dispatches them, e.g. "\vobj_info" (found by
// fuzz/ply_frame_fuzz), and allocates every element's declared records up
// front, so a few bytes could ask for gigabytes. Accepted: "ply", one
// "format ascii|binary_little_endian|binary_big_endian 1.0", then comment,
// obj_info, element NAME COUNT and property lines, then "end_header"; lines of
// printable ASCII words separated by single spaces (a trailing CR allowed);
// a property only after an element; no element declaring more records than
// the file has bytes (a record takes at least one); one vertex element, its
// properties as CheckPlyVertexProperties wants them; an obj_info grid
// (num_cols x num_rows, which PCL sizes the cloud by) of at least the vertex
// count and at most one point per byte of the file.
// `format_word` gets the format word, `vertex_properties` each vertex
// property's name and type word, in header order.
Status CheckPlyHeader(const std::string& path, std::string* format_word,
                      std::vector<std::pair<std::string, std::string>>* vertex_properties) {
  std::ifstream in(path, std::ios::binary);
  std::error_code ec;
  const uint64_t file_size = fs::file_size(path, ec);
  if (ec || !in) return Status::NotFound(Quote(path) + ": cannot read");
  auto bad = [&](const std::string& why) { return Status::Corruption(Quote(path) + ": PLY header: " + why); };
  static const std::set<std::string> kTypes = {"char",  "uchar",  "short", "ushort",  "int",     "uint",
                                               "float", "double", "int8",  "uint8",   "int16",   "uint16",
                                               "int32", "uint32", "float32", "float64"};
  std::string line;
  bool format = false, element = false, in_vertex = false, vertex_seen = false;
  uint64_t vertices = 0, grid_cols = 0, grid_rows = 0;
  std::vector<PlyProperty> props;
  for (int n = 0; n < 256 && std::getline(in, line); ++n) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const std::string shown = "line " + std::to_string(n + 1);
    for (char c : line) {
      if (c < 0x20 || c > 0x7e) return bad(shown + " has a control or non-ASCII byte");
    }
    std::vector<std::string> w;
    for (size_t at = 0; at <= line.size();) {
      const size_t sp = std::min(line.find(' ', at), line.size());
      w.push_back(line.substr(at, sp - at));
      at = sp + 1;
    }
    const std::string& key = w[0];
    if (n == 0) {
      if (line != "ply") return bad("does not start with 'ply'");
      continue;
    }
    if (key == "obj_info") {
      // Free text, but PCL sizes the cloud by "num_cols N" and "num_rows N"
      // (split at runs of spaces, N read by atoi into an unsigned int).
      std::vector<std::string> t;
      for (const std::string& word : w) {
        if (!word.empty()) t.push_back(word);
      }
      if (t.size() >= 3 && (t[1] == "num_cols" || t[1] == "num_rows")) {
        (t[1] == "num_cols" ? grid_cols : grid_rows) = static_cast<uint32_t>(std::atoi(t[2].c_str()));
      }
      continue;
    }
    if (key == "comment") continue;  // free text after the keyword
    for (const std::string& word : w) {
      if (word.empty()) return bad(shown + " has leading, trailing or doubled spaces");
    }
    if (key == "end_header") {
      if (w.size() != 1) return bad(shown + ": end_header takes no words");
      if (!format) return bad("no format line");
      if (!element) return bad("no element");
      if (grid_cols > 0 && grid_rows > 0 && (grid_cols * grid_rows < vertices || grid_cols * grid_rows > file_size)) {
        return bad("obj_info num_cols x num_rows (" + std::to_string(grid_cols) + " x " + std::to_string(grid_rows) +
                   ") is fewer points than the " + std::to_string(vertices) + " vertices or more than the file holds");
      }
      return CheckPlyVertexProperties(props, path);
    }
    if (key == "format") {
      if (format) return bad("format given twice");
      if (w.size() != 3 || w[2] != "1.0" ||
          (w[1] != "ascii" && w[1] != "binary_little_endian" && w[1] != "binary_big_endian")) {
        return bad(shown + ": format must be ascii, binary_little_endian or binary_big_endian 1.0");
      }
      format = true;
      *format_word = w[1];
    } else if (key == "element") {
      if (w.size() != 3) return bad(shown + ": element takes a name and a count");
      in_vertex = w[1] == "vertex";
      if (in_vertex && vertex_seen) return bad(shown + ": a second vertex element");
      vertex_seen = vertex_seen || in_vertex;
      const std::string& count = w[2];
      if (count.size() > 19 || count.find_first_not_of("0123456789") != std::string::npos ||
          std::stoull(count) > file_size) {
        return bad("element '" + w[1] + "' declares more records than the file holds");
      }
      if (in_vertex) vertices = std::stoull(count);
      element = true;
    } else if (key == "property") {
      if (!element) return bad(shown + ": property before any element");
      const bool list = w.size() == 5 && w[1] == "list" && kTypes.count(w[2]) && kTypes.count(w[3]);
      if (!list && !(w.size() == 3 && kTypes.count(w[1]))) return bad(shown + ": malformed property");
      if (in_vertex) {
        vertex_properties->emplace_back(w.back(), list ? "a list of " + w[3] : w[1]);
        props.push_back({w.back(), list ? "list" : w[1], n + 1});
      }
    } else {
      return bad(shown + ": unknown keyword '" + key.substr(0, 32) + "'");
    }
  }
  return bad("no end_header in the first 256 lines");
}

Result<CloudData> ReadPly(const std::string& path, FrameFileInfo& info) {
  const std::string head = ReadHead(path, 5);
  if (!(head.rfind("ply\n", 0) == 0 || head.rfind("ply\r\n", 0) == 0)) {
    return Status::Corruption(Quote(path) + ": not a PLY file (bad magic)");
  }
  std::vector<std::pair<std::string, std::string>> properties;
  if (Status s = CheckPlyHeader(path, &info.encoding, &properties); !s.ok()) return s;
  QuietPcl quiet;
  pcl::PLYReader reader;
  pcl::PCLPointCloud2 blob;
  if (reader.read(path, blob) < 0) return Status::Corruption(Quote(path) + ": cannot parse PLY (truncated?)");
  const std::map<std::string, std::string> types(properties.begin(), properties.end());
  if (Status s = CheckCoordinateFields(blob, path, CloudFormat::kPly, types, info); !s.ok()) return s;
  // The header's names (PCL renames nx to normal_x and packs red green blue into rgb).
  info.extra_fields.clear();
  for (const auto& [name, type] : properties) {
    if (name != "x" && name != "y" && name != "z") info.extra_fields.push_back(name);
  }
  CloudData data;
  if (Status s = BlobToXyz(blob, path, CloudFormat::kPly, data.cloud); !s.ok()) return s;
  // PCL's PLY reader makes a cloud of width x 1 (or its obj_info's grid); a
  // PLY is a point list either way.
  data.cloud.width = static_cast<uint32_t>(data.cloud.size());
  data.cloud.height = 1;
  return data;
}

// Attaches truth / intensity / labels found beside `path`.
Status AttachCompanions(const std::string& path, Frame& frame) {
  std::error_code ec;
  const fs::path p(path);
  const std::string own_truth = (p.parent_path() / (p.stem().string() + ".truth.json")).string();
  for (const std::string& truth_path : {own_truth, CompanionPath(path, "truth.json")}) {
    if (!fs::exists(truth_path, ec)) continue;
    auto truth = ReadGroundTruthJson(truth_path);
    if (!truth.ok()) return truth.status();
    frame.truth = std::move(*truth);
    break;
  }
  if (!frame.organized()) return Status::Ok();
  const std::string intensity_path = CompanionPath(path, "intensity.png");
  if (fs::exists(intensity_path, ec)) {
    auto img = ReadIntensityPng(intensity_path);
    if (!img.ok()) return img.status();
    if (img->width != frame.depth.width || img->height != frame.depth.height) {
      return Status::Corruption(Quote(intensity_path) + ": intensity size differs from " + Quote(path));
    }
    frame.intensity = std::move(*img);
  }
  const std::string labels_path = CompanionPath(path, "labels.png");
  if (frame.truth && fs::exists(labels_path, ec)) {
    auto img = ReadLabelPng(labels_path);
    if (!img.ok()) return img.status();
    if (img->width != frame.depth.width || img->height != frame.depth.height) {
      return Status::Corruption(Quote(labels_path) + ": label image size differs from " + Quote(path));
    }
    frame.truth->labels = std::move(*img);
  }
  return Status::Ok();
}

Result<Frame> LoadFrameFileUnchecked(const std::string& path, const Pose& X_BC_default, FrameFileInfo& info) {
  const std::string ext = LowerExtension(path);
  if (ext != ".pcd" && ext != ".ply" && ext != ".png") {
    return Status::InvalidArgument(Quote(path) + ": unsupported file type '" + ext +
                                   "' (expected .pcd, .ply or a 16-bit depth .png)");
  }
  auto size = CheckReadable(path);
  if (!size.ok()) return size.status();
  Result<Frame> frame = Status::Internal("not read");
  if (ext == ".png") {
    info.format = "depth PNG";
    info.encoding = "16-bit";
    info.coordinates = "uint16 depth";
    frame = LoadDepthPng(path, X_BC_default, info);
  } else {
    const CloudFormat format = ext == ".pcd" ? CloudFormat::kPcd : CloudFormat::kPly;
    info.format = FormatName(format);
    Result<CloudData> data = format == CloudFormat::kPcd ? ReadPcd(path, info) : ReadPly(path, info);
    if (!data.ok()) return data.status();
    frame = CloudToFrame(std::move(*data), path, X_BC_default, info);
  }
  if (!frame.ok()) return frame;
  if (Status s = RequireValidPoints(*frame, path); !s.ok()) return s;
  if (Status s = AttachCompanions(path, *frame); !s.ok()) return s;
  frame->source = path;
  return frame;
}

}  // namespace

std::string IntrinsicsSidecarPath(const std::string& data_path) {
  const fs::path p(data_path);
  return (p.parent_path() / (p.stem().string() + ".intrinsics.json")).string();
}

std::string CompanionPath(const std::string& data_path, const std::string& role) {
  const fs::path p(data_path);
  const std::string stem = p.stem().string();
  for (const char* word : {"depth", "cloud"}) {
    const size_t n = std::strlen(word);
    if (stem.size() >= n && stem.compare(stem.size() - n, n, word) == 0) {
      return (p.parent_path() / (stem.substr(0, stem.size() - n) + role)).string();
    }
  }
  return (p.parent_path() / (stem + "." + role)).string();
}

bool HasIntrinsicsSidecar(const std::string& data_path) {
  std::error_code ec;
  return fs::exists(IntrinsicsSidecarPath(data_path), ec);
}

Status WriteDepthPng(const Frame& frame, const std::string& path) {
  if (!frame.organized()) return Status::InvalidArgument(Quote(path) + ": frame has no depth image to write");
  const DepthImage& D = frame.depth;
  if (D.width != frame.intrinsics.width || D.height != frame.intrinsics.height) {
    return Status::InvalidArgument(Quote(path) + ": depth image size differs from the intrinsics");
  }
  cv::Mat m(D.height, D.width, CV_16UC1);
  for (int v = 0; v < D.height; ++v) {
    uint16_t* row = m.ptr<uint16_t>(v);
    for (int u = 0; u < D.width; ++u) {
      const float z = D.at(u, v);
      if (!ValidDepth(z)) {
        row[u] = 0;
        continue;
      }
      const double count = std::round(z / kDepthPngScale);
      if (count > kMaxDepthCount) {
        return Status::OutOfRange(Quote(path) + ": depth " + std::to_string(z) + " m at pixel (" +
                                  std::to_string(u) + ", " + std::to_string(v) +
                                  ") exceeds the 16-bit PNG range (6.5535 m)");
      }
      row[u] = static_cast<uint16_t>(std::max(1.0, count));  // a positive depth never becomes "invalid"
    }
  }
  if (Status s = WritePng(m, path); !s.ok()) return s;
  return WriteSidecar(frame, /*with_intrinsics=*/true, kDepthPngScale, path);
}

Status WriteCloudPcd(const Frame& frame, const std::string& path) {
  pcl::PointCloud<pcl::PointXYZ> cloud;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  if (frame.organized()) {
    const Intrinsics& K = frame.intrinsics;
    if (frame.depth.width != K.width || frame.depth.height != K.height) {
      return Status::InvalidArgument(Quote(path) + ": depth image size differs from the intrinsics");
    }
    cloud.width = K.width;
    cloud.height = K.height;
    cloud.points.resize(static_cast<size_t>(K.width) * K.height, pcl::PointXYZ(nan, nan, nan));
    for (int v = 0; v < K.height; ++v) {
      for (int u = 0; u < K.width; ++u) {
        const float z = frame.depth.at(u, v);
        if (!ValidDepth(z)) continue;
        const Eigen::Vector3f p = Deproject(K, static_cast<float>(u), static_cast<float>(v), z);
        cloud.at(u, v) = pcl::PointXYZ(p.x(), p.y(), p.z());
      }
    }
  } else {
    if (frame.points_C.empty()) return Status::InvalidArgument(Quote(path) + ": frame has no points to write");
    cloud.width = static_cast<uint32_t>(frame.points_C.size());
    cloud.height = 1;
    cloud.points.reserve(frame.points_C.size());
    for (const auto& p : frame.points_C) cloud.points.emplace_back(p.x(), p.y(), p.z());
  }
  cloud.is_dense = false;
  try {
    QuietPcl quiet;
    if (pcl::io::savePCDFileBinary(path, cloud) < 0) return Status::Internal(Quote(path) + ": cannot write PCD");
  } catch (const std::exception& e) {
    return Status::Internal(Quote(path) + ": cannot write PCD: " + e.what());
  }
  return WriteSidecar(frame, frame.organized(), std::nullopt, path);
}

Status WriteIntensityPng(const Frame& frame, const std::string& path) {
  const IntensityImage& I = frame.intensity;
  if (I.empty()) return Status::InvalidArgument(Quote(path) + ": frame has no intensity image");
  cv::Mat m(I.height, I.width, CV_8UC1, const_cast<uint8_t*>(I.data.data()));
  return WritePng(m, path);
}

Status WriteLabelPng(const Frame& frame, const std::string& path) {
  if (!frame.truth || frame.truth->labels.empty()) {
    return Status::InvalidArgument(Quote(path) + ": frame has no label image");
  }
  const LabelImage& L = frame.truth->labels;
  cv::Mat m(L.height, L.width, CV_16UC1, const_cast<uint16_t*>(L.data.data()));
  return WritePng(m, path);
}

Result<IntensityImage> ReadIntensityPng(const std::string& path) {
  auto m = ReadGreyPng(path, CV_8U);
  if (!m.ok()) return m.status();
  return ImageFromMat<uint8_t>(*m);
}

Result<LabelImage> ReadLabelPng(const std::string& path) {
  auto m = ReadGreyPng(path, CV_16U);
  if (!m.ok()) return m.status();
  return ImageFromMat<uint16_t>(*m);
}

Status WriteGroundTruthJson(const Frame& frame, const std::string& path) {
  if (!frame.truth) return Status::InvalidArgument(Quote(path) + ": frame has no ground truth");
  const GroundTruth& truth = *frame.truth;
  OrderedJson j;
  j["format"] = kTruthFormat;
  j["seed"] = truth.seed;
  j["source"] = frame.source;
  j["X_BC"] = PoseToJson(frame.X_BC);
  if (truth.X_BW) j["X_BW"] = PoseToJson(*truth.X_BW);
  j["parts"] = OrderedJson::array();
  for (const PartTruth& part : truth.parts) {
    const Quat q(part.X_BO.linear());
    const Vec3 t = part.X_BO.translation();
    j["parts"].push_back({
        {"instance_id", part.instance_id},
        {"class_id", part.class_id},
        {"class_name", part.class_name},
        {"X_BO", PoseToJson(part.X_BO)},
        {"xyz", {t.x(), t.y(), t.z()}},
        {"quat_wxyz", {q.w(), q.x(), q.y(), q.z()}},
        {"visible_pixels", part.visible_pixels},
        {"unoccluded_pixels", part.unoccluded_pixels},
        {"visible_fraction", part.visible_fraction},
    });
  }
  return WriteJson(j, path);
}

Result<GroundTruth> ReadGroundTruthJson(const std::string& path) {
  auto j = ReadJson(path);
  if (!j.ok()) return j.status();
  const std::string where = Quote(path) + ": ";
  try {
    GroundTruth truth;
    truth.seed = j->value("seed", uint64_t{0});
    if (j->contains("X_BW")) {
      auto X = PoseFromJson(j->at("X_BW"), where + "X_BW");
      if (!X.ok()) return X.status();
      truth.X_BW = *X;
    }
    if (!j->contains("parts") || !j->at("parts").is_array()) {
      return Status::Corruption(where + "no \"parts\" array");
    }
    int index = 0;
    for (const json& jp : j->at("parts")) {
      const std::string at = where + "parts[" + std::to_string(index++) + "]";
      PartTruth part;
      part.instance_id = jp.at("instance_id").get<int>();
      part.class_id = jp.at("class_id").get<int>();
      part.class_name = jp.value("class_name", std::string());
      if (jp.contains("X_BO")) {
        auto X = PoseFromJson(jp.at("X_BO"), at + ".X_BO");
        if (!X.ok()) return X.status();
        part.X_BO = *X;
      } else {
        const auto xyz = jp.at("xyz").get<std::array<double, 3>>();
        const auto wxyz = jp.at("quat_wxyz").get<std::array<double, 4>>();
        const Quat q(wxyz[0], wxyz[1], wxyz[2], wxyz[3]);
        if (!(q.norm() > 0.5)) return Status::Corruption(at + ".quat_wxyz is not a unit quaternion");
        part.X_BO = MakePose(q, Vec3(xyz[0], xyz[1], xyz[2]));
      }
      part.visible_pixels = jp.value("visible_pixels", 0);
      part.unoccluded_pixels = jp.value("unoccluded_pixels", 0);
      part.visible_fraction = jp.value("visible_fraction", 0.0);
      truth.parts.push_back(std::move(part));
    }
    return truth;
  } catch (const std::exception& e) {
    return Status::Corruption(where + "bad ground truth: " + e.what());
  }
}

Result<Frame> LoadFrameFile(const std::string& path, const Pose& X_BC_default, FrameFileInfo* info) {
  // Last line of defence: PCL, OpenCV and nlohmann may throw on malformed
  // input; nothing crosses this boundary.
  FrameFileInfo own;
  FrameFileInfo& out = info != nullptr ? *info : own;
  out = FrameFileInfo{};
  try {
    return LoadFrameFileUnchecked(path, X_BC_default, out);
  } catch (const std::exception& e) {
    return Status::Corruption(Quote(path) + ": " + e.what());
  } catch (...) {
    return Status::Corruption(Quote(path) + ": unknown error while reading");
  }
}

Result<Frame> LoadFrameFile(const std::string& path) { return LoadFrameFile(path, Pose::Identity()); }

}  // namespace bp
