#include "pipeline/file_source.h"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <filesystem>
#include <set>
#include <system_error>

#include <spdlog/spdlog.h>

#include "pipeline/cloud_projection.h"
#include "pipeline/frame_io.h"

namespace bp {
namespace {

namespace fs = std::filesystem;

std::string Lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

class FileSource final : public CaptureSource {
 public:
  FileSource(std::string origin, std::vector<std::string> files, const Cell& cell)
      : origin_(std::move(origin)), files_(std::move(files)), cell_(cell) {}

  Result<Frame> Capture(const CaptureRequest& request) override {
    const std::string& path = files_[next_];
    next_ = (next_ + 1) % files_.size();  // wrap around; a bad file does not block the rest
    Pose X_BC = cell_.camera.X_BC;
    if (cell_.camera.eye_in_hand && request.X_BF) X_BC = *request.X_BF * cell_.camera.X_FC;
    std::string assumption;
    Result<Frame> frame = LoadFrameForPerception(path, cell_, X_BC, &assumption);
    if (!frame.ok()) return frame;
    if (!assumption.empty() && warned_.insert(path).second) spdlog::warn("files: {}", assumption);
    if (frame->timestamp_ns == 0) frame->timestamp_ns = NowNs();
    return frame;
  }

  std::string Describe() const override {
    return "files: " + origin_ + " (" + std::to_string(files_.size()) + " file" + (files_.size() == 1 ? "" : "s") +
           ", next " + fs::path(files_[next_]).filename().string() + ", wraps around)";
  }

 private:
  std::string origin_;
  std::vector<std::string> files_;  // non-empty
  Cell cell_;
  size_t next_ = 0;
  std::set<std::string> warned_;  // files whose assumed view was logged
};

}  // namespace

Result<Frame> LoadFrameForPerception(const std::string& path, const Cell& cell, const Pose& X_BC_default,
                                     std::string* assumption) {
  if (assumption != nullptr) assumption->clear();
  FrameFileInfo info;
  Result<Frame> frame = LoadFrameFile(path, X_BC_default, &info);
  if (!frame.ok() || frame->organized()) return frame;
  Result<CloudProjection> projected = ProjectCloud(*frame, cell, info.X_BC_known);
  if (!projected.ok()) return projected.status();
  if (assumption != nullptr && projected->view != CloudViewSource::kCamera) {
    *assumption = "'" + path + "': " +
                  (projected->view == CloudViewSource::kAboveBinNoPose
                       ? std::string("no X_BC (no sidecar, or no \"X_BC\" in it): the points are taken as in the "
                                     "cell camera's frame and seen from +z of the bin frame")
                       : std::string("its X_BC does not look down into the bin: the points are seen from +z of the "
                                     "bin frame"));
  }
  return std::move(projected->frame);
}

bool IsFrameFileName(const std::string& file_name) {
  const std::string name = Lower(file_name);
  if (EndsWith(name, ".pcd") || EndsWith(name, ".ply")) return true;
  return EndsWith(name, ".png") && name.find("depth") != std::string::npos;
}

Result<std::vector<std::string>> ListFrameFiles(const std::string& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return Status::NotFound("'" + dir + "': no such directory");
  std::vector<std::string> files;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    if (!entry.is_regular_file(ec)) continue;
    if (IsFrameFileName(entry.path().filename().string())) files.push_back(entry.path().string());
  }
  if (ec) return Status::NotFound("'" + dir + "': cannot list: " + ec.message());
  if (files.empty()) {
    return Status::NotFound("'" + dir + "': no frame files (*.pcd, *.ply, *depth*.png)");
  }
  std::sort(files.begin(), files.end(), [](const std::string& a, const std::string& b) {
    return fs::path(a).filename().string() < fs::path(b).filename().string();
  });
  return files;
}

Result<std::unique_ptr<CaptureSource>> MakeFileSource(const std::string& dir_or_file, const Cell& cell) {
  std::error_code ec;
  std::vector<std::string> files;
  if (fs::is_directory(dir_or_file, ec)) {
    auto listed = ListFrameFiles(dir_or_file);
    if (!listed.ok()) return listed.status();
    files = std::move(*listed);
  } else if (fs::exists(dir_or_file, ec)) {
    files.push_back(dir_or_file);
  } else {
    return Status::NotFound("'" + dir_or_file + "': no such file or directory");
  }
  return std::unique_ptr<CaptureSource>(new FileSource(dir_or_file, std::move(files), cell));
}

}  // namespace bp
