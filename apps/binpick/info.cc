// binpick info FILE: describes a frame file (PCD, PLY cloud, depth PNG), an
// intensity / label PNG, a ground-truth JSON, a mesh (PLY / STL with faces) or
// a cell YAML file. Results on stdout; errors as one line on stderr.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "apps/binpick/command.h"
#include "core/cell.h"
#include "core/mesh.h"
#include "pipeline/cloud_projection.h"
#include "pipeline/frame_io.h"

namespace bp::cli {
namespace {

namespace fs = std::filesystem;
const char* const kCmd = "info";

std::string Lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

std::string HumanSize(uintmax_t bytes) {
  char buf[32];
  if (bytes >= (1u << 20)) {
    std::snprintf(buf, sizeof(buf), "%.1f MiB", static_cast<double>(bytes) / (1u << 20));
  } else if (bytes >= (1u << 10)) {
    std::snprintf(buf, sizeof(buf), "%.1f KiB", static_cast<double>(bytes) / (1u << 10));
  } else {
    std::snprintf(buf, sizeof(buf), "%ju B", bytes);
  }
  return buf;
}

std::string FormatPose(const Pose& X) {
  const Vec3 t = X.translation();
  const Quat q(X.linear());
  char buf[160];
  std::snprintf(buf, sizeof(buf), "xyz [%.4f, %.4f, %.4f] m, quat_wxyz [%.4f, %.4f, %.4f, %.4f]", t.x(), t.y(),
                t.z(), q.w(), q.x(), q.y(), q.z());
  return buf;
}

// Number of faces declared in a PLY header (0 if none or unreadable).
long PlyFaceCount(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string line;
  for (int i = 0; i < 200 && std::getline(in, line); ++i) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line == "end_header") break;
    std::istringstream words(line);
    std::string element, name;
    long count = 0;
    if (words >> element >> name >> count && element == "element" && name == "face") return count;
  }
  return 0;
}

void PrintTruth(const GroundTruth& truth) {
  std::map<std::string, int> per_class;
  int visible = 0;
  for (const PartTruth& p : truth.parts) {
    ++per_class[p.class_name.empty() ? "class " + std::to_string(p.class_id) : p.class_name];
    visible += p.visible_pixels > 0 ? 1 : 0;
  }
  std::printf("truth:       seed %llu, %zu parts (%d visible)", static_cast<unsigned long long>(truth.seed),
              truth.parts.size(), visible);
  for (const auto& [name, n] : per_class) std::printf(", %s x%d", name.c_str(), n);
  std::printf("\n");
  if (!truth.labels.empty()) std::printf("labels:      %dx%d\n", truth.labels.width, truth.labels.height);
}

std::string Join(const std::vector<std::string>& words) {
  std::string out;
  for (const std::string& w : words) out += (out.empty() ? "" : " ") + w;
  return out;
}

// How perception will take the frame: as stored, or the cloud organized
// through a virtual pinhole (the file source's LoadFrameForPerception).
std::string PerceptionLine(const Frame& frame, const FrameFileInfo& info, const Cell& cell) {
  if (frame.organized()) return "the depth image as stored (organized path)";
  Result<CloudProjection> p = ProjectCloud(frame, cell, info.X_BC_known);
  if (!p.ok()) return "cannot be organized: " + p.status().ToString();
  std::string line = p->Describe();
  if (p->view != CloudViewSource::kCamera) line += " [warning: assumed view]";
  return line;
}

int DescribeFrame(const std::string& path, const std::string& cell_path) {
  Result<Cell> cell = LoadCellOrDefault(cell_path);
  if (!cell.ok()) return Fail(kCmd, cell.status());
  FrameFileInfo info;
  Result<Frame> frame = LoadFrameFile(path, cell->camera.X_BC, &info);
  if (!frame.ok()) return Fail(kCmd, frame.status());
  std::error_code ec;
  std::printf("file:        %s\n", path.c_str());
  const std::string kind = info.format == "depth PNG" ? "16-bit depth PNG" : info.format + " point cloud";
  std::printf("type:        %s (%s, %s coordinates), %s\n", kind.c_str(), info.encoding.c_str(),
              info.coordinates.c_str(), HumanSize(fs::file_size(path, ec)).c_str());
  const auto points = frame->PointsInCamera();
  const size_t total = frame->organized() ? frame->depth.data.size() : frame->points_C.size();
  if (frame->organized()) {
    const Intrinsics& K = frame->intrinsics;
    std::printf("layout:      organized %dx%d\n", K.width, K.height);
    std::printf("intrinsics:  fx %.3f fy %.3f cx %.3f cy %.3f, distortion [%g, %g, %g, %g, %g]\n", K.fx, K.fy,
                K.cx, K.cy, K.distortion[0], K.distortion[1], K.distortion[2], K.distortion[3], K.distortion[4]);
  } else if (info.height > 1) {
    std::printf("layout:      unorganized: stored as a %dx%d grid, but no sidecar intrinsics reproduce it "
                "(point list)\n", info.width, info.height);
  } else {
    std::printf("layout:      unorganized (point list)\n");
  }
  if (info.format != "depth PNG") {
    std::printf("fields:      x y z%s%s\n", info.extra_fields.empty() ? "" : "; not used: ",
                Join(info.extra_fields).c_str());
    std::printf("units:       %s\n", info.unit_declared ? (info.unit + " (the sidecar's \"unit\")").c_str()
                                                        : "m (no \"unit\" declared)");
  }
  std::printf("points:      %zu valid of %zu (%.1f%%)\n", points.size(), total,
              total ? 100.0 * static_cast<double>(points.size()) / static_cast<double>(total) : 0.0);
  Eigen::AlignedBox3f box;
  for (const auto& p : points) box.extend(p);
  std::printf("depth range: %.4f .. %.4f m (z in the camera frame)\n", box.min().z(), box.max().z());
  std::printf("bounds (C):  x [%.4f, %.4f] y [%.4f, %.4f] z [%.4f, %.4f] m\n", box.min().x(), box.max().x(),
              box.min().y(), box.max().y(), box.min().z(), box.max().z());
  const char* pose_from = info.X_BC_known ? (info.viewpoint_used ? "the sidecar's X_BC times the PCD VIEWPOINT"
                                                                  : "from the sidecar")
                                          : (info.viewpoint_used ? "no X_BC: the cell camera's times the PCD VIEWPOINT"
                                                                 : "no X_BC: the cell camera's (assumed)");
  std::printf("X_BC:        %s (%s)\n", FormatPose(frame->X_BC).c_str(), pose_from);
  std::printf("perception:  %s\n", PerceptionLine(*frame, info, *cell).c_str());
  if (!frame->intensity.empty()) std::printf("intensity:   %dx%d\n", frame->intensity.width, frame->intensity.height);
  if (frame->truth) PrintTruth(*frame->truth);
  return kExitOk;
}

int DescribeMesh(const std::string& path) {
  Result<TriangleMesh> mesh = LoadMesh(path);
  if (!mesh.ok()) return Fail(kCmd, mesh.status());
  const Eigen::AlignedBox3f b = mesh->Bounds();
  std::printf("file:        %s\n", path.c_str());
  std::printf("type:        triangle mesh, %zu vertices, %zu triangles\n", mesh->vertices.size(),
              mesh->triangles.size());
  std::printf("bounds:      x [%.4f, %.4f] y [%.4f, %.4f] z [%.4f, %.4f] m (size %.4f x %.4f x %.4f)\n",
              b.min().x(), b.max().x(), b.min().y(), b.max().y(), b.min().z(), b.max().z(), b.sizes().x(),
              b.sizes().y(), b.sizes().z());
  std::printf("area:        %.6f m^2\n", mesh->Area());
  return kExitOk;
}

int DescribeCell(const std::string& path) {
  Result<Cell> cell = LoadCell(path);
  if (!cell.ok()) return Fail(kCmd, cell.status());
  const std::string text = Describe(*cell);
  std::printf("%s%s", text.c_str(), !text.empty() && text.back() == '\n' ? "" : "\n");
  return kExitOk;
}

int DescribeImage(const std::string& path, bool labels) {
  if (labels) {
    Result<LabelImage> img = ReadLabelPng(path);
    if (!img.ok()) return Fail(kCmd, img.status());
    std::set<uint16_t> ids(img->data.begin(), img->data.end());
    ids.erase(0);
    ids.erase(GroundTruth::kBinLabel);
    std::printf("file:        %s\ntype:        16-bit label PNG %dx%d, %zu part instances\n", path.c_str(),
                img->width, img->height, ids.size());
    return kExitOk;
  }
  Result<IntensityImage> img = ReadIntensityPng(path);
  if (!img.ok()) return Fail(kCmd, img.status());
  const auto [lo, hi] = std::minmax_element(img->data.begin(), img->data.end());
  std::printf("file:        %s\ntype:        8-bit intensity PNG %dx%d, values %d..%d\n", path.c_str(), img->width,
              img->height, img->data.empty() ? 0 : *lo, img->data.empty() ? 0 : *hi);
  return kExitOk;
}

int DescribeJson(const std::string& path) {
  Result<GroundTruth> truth = ReadGroundTruthJson(path);
  if (!truth.ok()) return Fail(kCmd, truth.status());
  std::printf("file:        %s\ntype:        ground-truth JSON\n", path.c_str());
  PrintTruth(*truth);
  return kExitOk;
}

int Run(const std::string& path, const std::string& cell_path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return Fail(kCmd, Status::NotFound("'" + path + "': no such file"));
  if (fs::is_directory(path, ec)) {
    return Fail(kCmd, Status::InvalidArgument("'" + path + "' is a directory; give one file"));
  }
  const std::string name = Lower(fs::path(path).filename().string());
  const std::string ext = Lower(fs::path(path).extension().string());
  if (ext == ".yaml" || ext == ".yml") return DescribeCell(path);
  if (ext == ".stl") return DescribeMesh(path);
  if (ext == ".ply" && PlyFaceCount(path) > 0) return DescribeMesh(path);
  if (ext == ".json") return DescribeJson(path);
  if (ext == ".png" && name.find("depth") == std::string::npos) {
    return DescribeImage(path, name.find("label") != std::string::npos);
  }
  return DescribeFrame(path, cell_path);
}

}  // namespace

Command InfoCommand() {
  return {"info", "Describe a frame file (.pcd, .ply, depth .png), truth .json, mesh (.ply/.stl) or cell .yaml",
          [](CLI::App& sub) -> std::function<int()> {
            auto path = std::make_shared<std::string>();
            auto cell = std::make_shared<std::string>();
            sub.add_option("FILE", *path, "File to describe")->required();
            sub.add_option("--cell", *cell,
                           "cell whose camera and bin a frame is seen with (default: the embedded default cell)");
            return [path, cell] { return Run(*path, *cell); };
          }};
}

}  // namespace bp::cli
