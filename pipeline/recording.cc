#include "pipeline/recording.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iterator>

#include <nlohmann/json.hpp>

#include "pipeline/file_source.h"
#include "pipeline/frame_io.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

Result<std::string> ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status::NotFound("'" + path + "': cannot open");
  std::string bytes((std::istreambuf_iterator<char>(in)), {});
  if (in.bad()) return Status::Corruption("'" + path + "': read error");
  return bytes;
}

// Sequence number of "cap_<digits>".
uint64_t RecordSeq(const std::string& name) {
  return std::stoull(name.substr(std::char_traits<char>::length(kRecordDirPrefix)));
}

class SessionReplaySource final : public CaptureSource {
 public:
  SessionReplaySource(std::string dir, std::vector<std::string> records)
      : dir_(std::move(dir)), records_(std::move(records)) {}

  Result<Frame> Capture(const CaptureRequest& /*request*/) override {
    Status last = Status::NotFound("'" + dir_ + "': no complete record to replay");
    for (size_t tries = 0; tries < records_.size(); ++tries) {
      const std::string record = records_[next_];
      Advance();
      if (Status s = VerifyRecord(record); !s.ok()) {
        spdlog::warn("replay: skipping {}: {}", record, s.ToString());
        last = s;
        continue;
      }
      Result<Frame> frame = LoadFrameFile((fs::path(record) / kRecordFrameName).string());
      if (!frame.ok()) {
        spdlog::warn("replay: skipping {}: {}", record, frame.status().ToString());
        last = frame.status();
        continue;
      }
      frame->timestamp_ns = NowNs();  // served as if live
      frame->source = "replay " + record;
      return frame;
    }
    return last;
  }

  std::string Describe() const override {
    return "replay: " + dir_ + " (" + std::to_string(records_.size()) + " record" +
           (records_.size() == 1 ? "" : "s") + ", next " + fs::path(records_[next_]).filename().string() +
           ", wraps around)";
  }

 private:
  // Next record; after the last one the session is listed again (it may
  // still be growing) and replay starts over.
  void Advance() {
    if (++next_ < records_.size()) return;
    next_ = 0;
    Result<RecordListing> again = ListRecords(dir_);
    if (again.ok() && !again->records.empty()) records_ = std::move(again->records);
  }

  std::string dir_;
  std::vector<std::string> records_;  // non-empty
  size_t next_ = 0;
};

}  // namespace

uint64_t Fnv1a64(std::string_view bytes) {
  uint64_t h = 0xcbf29ce484222325ULL;
  for (const char c : bytes) {
    h ^= static_cast<unsigned char>(c);
    h *= 0x100000001b3ULL;
  }
  return h;
}

std::string Hex64(uint64_t value) {
  static constexpr char kDigits[] = "0123456789abcdef";
  std::string s(16, '0');
  for (int i = 15; i >= 0; --i, value >>= 4) s[static_cast<size_t>(i)] = kDigits[value & 0xF];
  return s;
}

bool IsRecordDirName(const std::string& name) {
  const size_t n = std::char_traits<char>::length(kRecordDirPrefix);
  if (name.size() <= n || name.compare(0, n, kRecordDirPrefix) != 0) return false;
  if (name.size() - n > 18) return false;  // fits uint64
  return std::all_of(name.begin() + static_cast<std::ptrdiff_t>(n), name.end(),
                     [](char c) { return c >= '0' && c <= '9'; });
}

bool IsRecordedSession(const std::string& dir) {
  std::error_code ec;
  if (fs::exists(fs::path(dir) / kSessionManifestName, ec)) return true;
  if (!fs::is_directory(dir, ec)) return false;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (IsRecordDirName(name) || (name.size() > std::char_traits<char>::length(kPartialSuffix) &&
                                  IsRecordDirName(name.substr(0, name.find('.'))))) {
      return true;
    }
  }
  return false;
}

Status VerifyRecord(const std::string& record_dir) {
  const std::string manifest_path = (fs::path(record_dir) / kRecordManifestName).string();
  std::error_code ec;
  if (!fs::exists(manifest_path, ec)) {
    return Status::Corruption("'" + record_dir + "': no " + kRecordManifestName +
                              " (record cut off before it was complete)");
  }
  Result<std::string> text = ReadAll(manifest_path);
  if (!text.ok()) return Status::Corruption(text.status().message());
  const json manifest = json::parse(*text, nullptr, /*allow_exceptions=*/false);
  if (manifest.is_discarded() || !manifest.is_object()) {
    return Status::Corruption("'" + manifest_path + "': not valid JSON (truncated?)");
  }
  if (manifest.value("format", "") != kRecordFormat) {
    return Status::Corruption("'" + manifest_path + "': format is not " + kRecordFormat);
  }
  const auto files = manifest.find("files");
  if (files == manifest.end() || !files->is_object()) {
    return Status::Corruption("'" + manifest_path + "': no \"files\" map");
  }
  for (const auto& [name, entry] : files->items()) {
    if (name.find('/') != std::string::npos || name == ".." || !entry.is_object() ||
        !entry.contains("bytes") || !entry["bytes"].is_number_unsigned() || !entry.contains("fnv1a64") ||
        !entry["fnv1a64"].is_string()) {
      return Status::Corruption("'" + manifest_path + "': bad entry for file '" + name + "'");
    }
    const std::string path = (fs::path(record_dir) / name).string();
    Result<std::string> bytes = ReadAll(path);
    if (!bytes.ok()) return Status::Corruption("'" + path + "': listed in the manifest but missing");
    const uint64_t want = entry["bytes"].get<uint64_t>();
    if (bytes->size() != want) {
      return Status::Corruption("'" + path + "': " + std::to_string(bytes->size()) + " bytes, the manifest says " +
                                std::to_string(want) + " (truncated?)");
    }
    if (Hex64(Fnv1a64(*bytes)) != entry["fnv1a64"].get<std::string>()) {
      return Status::Corruption("'" + path + "': checksum does not match the manifest");
    }
  }
  return Status::Ok();
}

Result<RecordListing> ListRecords(const std::string& session_dir) {
  std::error_code ec;
  if (!fs::is_directory(session_dir, ec)) return Status::NotFound("'" + session_dir + "': no such directory");
  std::vector<std::pair<uint64_t, std::string>> found;
  RecordListing listing;
  for (const auto& entry : fs::directory_iterator(session_dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (IsRecordDirName(name) && entry.is_directory(ec)) {
      found.emplace_back(RecordSeq(name), entry.path().string());
    } else if (name.rfind(kRecordDirPrefix, 0) == 0) {
      listing.skipped.push_back("'" + entry.path().string() + "': incomplete record (cut off mid-write)");
    }
  }
  if (ec) return Status::NotFound("'" + session_dir + "': cannot list: " + ec.message());
  std::sort(found.begin(), found.end());
  for (auto& [seq, path] : found) {
    if (Status s = VerifyRecord(path); !s.ok()) {
      listing.skipped.push_back(s.message());
      continue;
    }
    listing.records.push_back(std::move(path));
  }
  std::sort(listing.skipped.begin(), listing.skipped.end());
  return listing;
}

Result<std::unique_ptr<CaptureSource>> MakeReplaySource(const std::string& dir, const Cell& cell) {
  if (!IsRecordedSession(dir)) return MakeFileSource(dir, cell);
  Result<RecordListing> listing = ListRecords(dir);
  if (!listing.ok()) return listing.status();
  for (const std::string& s : listing->skipped) spdlog::warn("replay: skipping {}", s);
  if (listing->records.empty()) return Status::NotFound("'" + dir + "': recorded session without a complete record");
  return std::unique_ptr<CaptureSource>(new SessionReplaySource(dir, std::move(listing->records)));
}

}  // namespace bp
