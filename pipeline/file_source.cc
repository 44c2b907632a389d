#include "pipeline/file_source.h"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <filesystem>
#include <system_error>

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
      : origin_(std::move(origin)), files_(std::move(files)), camera_(cell.camera) {}

  Result<Frame> Capture(const CaptureRequest& request) override {
    const std::string& path = files_[next_];
    next_ = (next_ + 1) % files_.size();  // wrap around; a bad file does not block the rest
    Pose X_BC = camera_.X_BC;
    if (camera_.eye_in_hand && request.X_BF) X_BC = *request.X_BF * camera_.X_FC;
    Result<Frame> frame = LoadFrameFile(path, X_BC);
    if (!frame.ok()) return frame;
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
  CameraSpec camera_;
  size_t next_ = 0;
};

}  // namespace

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
