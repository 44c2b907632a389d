#include "record/recorder.h"

#include <fcntl.h>
#include <unistd.h>

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <cstdio>
#include <ctime>
#include <deque>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <mutex>
#include <thread>
#include <variant>

#include "core/atomic_file.h"
#include "grasp/bin_picking_planner.h"
#include "pipeline/frame_io.h"
#include "pipeline/recording.h"
#include "record/internal/record_json.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using record_internal::OrderedJson;

constexpr char kAnswersFormat[] = "binpick.answers/1";
constexpr size_t kAnswersPerChunk = 256;  // answers_<n>.json holds at most this many
constexpr int64_t kRecordOverhead = 64 * 1024;  // manifest, sidecars, truth: upper estimate

int64_t ToNs(std::chrono::system_clock::time_point t) {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
}

// Never throws: strings that are not UTF-8 (peer names, file paths) are
// written with U+FFFD in place of the bad bytes.
std::string Dump(const OrderedJson& j, int indent) {
  return j.dump(indent, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
}

std::string StatusText(const Status& s) { return s.ok() ? "OK" : s.ToString(); }

// Sum of the sizes of the regular files under `path` (or of `path` itself).
int64_t DiskBytes(const fs::path& path) {
  std::error_code ec;
  if (fs::is_regular_file(path, ec)) return static_cast<int64_t>(fs::file_size(path, ec));
  int64_t total = 0;
  for (auto it = fs::recursive_directory_iterator(path, ec); !ec && it != fs::recursive_directory_iterator();
       it.increment(ec)) {
    std::error_code fec;
    if (it->is_regular_file(fec)) total += static_cast<int64_t>(it->file_size(fec));
  }
  return total;
}

Status SyncPath(const std::string& path, int flags) {
  const int fd = ::open(path.c_str(), flags | O_CLOEXEC);
  if (fd < 0) return Status::Internal("'" + path + "': cannot open to sync: " + std::strerror(errno));
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  if (rc != 0) return Status::Internal("'" + path + "': fsync failed: " + std::strerror(err));
  return Status::Ok();
}

Result<std::string> ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status::Internal("'" + path + "': cannot read back");
  return std::string((std::istreambuf_iterator<char>(in)), {});
}

std::string SessionName() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  const int ms = static_cast<int>(ToNs(now) / 1000000 % 1000);
  std::tm utc{};
  gmtime_r(&t, &utc);
  char buf[64];
  std::snprintf(buf, sizeof(buf), "session_%04d%02d%02dT%02d%02d%02d.%03dZ_%d", utc.tm_year + 1900, utc.tm_mon + 1,
                utc.tm_mday, utc.tm_hour, utc.tm_min, utc.tm_sec, ms, static_cast<int>(::getpid()));
  return buf;
}

std::string SeqName(const char* prefix, uint64_t seq) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%06llu", static_cast<unsigned long long>(seq));
  return prefix + std::string(buf);
}

int64_t EstimateBytes(const Frame* frame) {
  if (frame == nullptr) return kRecordOverhead;
  if (!frame->organized()) return static_cast<int64_t>(frame->points_C.size()) * 12 + kRecordOverhead;
  const int64_t pixels = int64_t{frame->depth.width} * frame->depth.height;
  // PCD xyz float32, 16-bit depth PNG (worst case uncompressed), intensity, labels.
  return pixels * (12 + 2 + 1 + (frame->truth ? 2 : 0)) + kRecordOverhead;
}

}  // namespace

std::string BinpickVersion() { return BINPICK_VERSION; }

std::string ConfigHash(const Cell& cell, int task_id) {
  return Hex64(Fnv1a64(cell.yaml_text + "\n#task " + std::to_string(task_id)));
}

RecorderOptions RecorderOptionsFromCell(const Cell& cell) {
  RecorderOptions o;
  if (!cell.recording.directory.empty()) o.directory = cell.recording.directory;
  o.max_disk_bytes = cell.recording.max_disk_mb << 20;
  o.queue_captures = cell.recording.queue_captures;
  return o;
}

class Recorder::Impl {
 public:
  Impl(const Cell& cell, RecorderOptions options) : options_(std::move(options)), cell_(cell) {}

  Status Open() {
    std::error_code ec;
    fs::create_directories(options_.directory, ec);
    if (ec) return Status::Internal("recording: cannot create '" + options_.directory + "': " + ec.message());
    // Everything already there counts against the cap; only sessions rotate.
    for (const auto& entry : fs::directory_iterator(options_.directory, ec)) {
      const int64_t bytes = DiskBytes(entry.path());
      disk_bytes_ += bytes;
      const std::string name = entry.path().filename().string();
      if (name.rfind("session_", 0) == 0 && entry.is_directory(ec)) old_sessions_.push_back({entry.path().string(), bytes});
    }
    std::sort(old_sessions_.begin(), old_sessions_.end(),
              [](const Item& a, const Item& b) { return a.path < b.path; });
    std::string name = SessionName();
    for (int n = 2; fs::exists(fs::path(options_.directory) / name, ec); ++n) name = SessionName() + "_" + std::to_string(n);
    session_dir_ = (fs::path(options_.directory) / name).string();
    if (!fs::create_directory(session_dir_, ec) || ec) {
      return Status::Internal("recording: cannot create '" + session_dir_ + "': " + ec.message());
    }
    OrderedJson session;
    session["format"] = kSessionFormat;
    session["binpick_version"] = options_.version;
    session["started_ns"] = ToNs(std::chrono::system_clock::now());
    session["pid"] = static_cast<int>(::getpid());
    session["cell_path"] = cell_.path;
    session["cell_name"] = cell_.name;
    session["cell_hash"] = Hex64(Fnv1a64(cell_.yaml_text));
    OrderedJson tasks = OrderedJson::object();
    for (const TaskSpec& t : cell_.tasks) tasks[std::to_string(t.id)] = ConfigHash(cell_, t.id);
    session["config_hash_by_task"] = tasks;
    const std::string session_text = Dump(session, 2);
    for (const auto& [file, text] : {std::pair<const char*, const std::string&>{kSessionManifestName, session_text},
                                     std::pair<const char*, const std::string&>{kSessionCellName, cell_.yaml_text}}) {
      if (Status s = WriteFileAtomic((fs::path(session_dir_) / file).string(), text); !s.ok()) {
        fs::remove_all(session_dir_, ec);
        return Status::Internal("recording: " + s.message());
      }
      disk_bytes_ += static_cast<int64_t>(text.size());
    }
    {
      std::lock_guard lock(mutex_);
      stats_.disk_bytes = disk_bytes_;
    }
    writer_ = std::thread([this] { Run(); });
    spdlog::info("recording: session {} (cap {} MiB, {} MiB in use)", session_dir_, options_.max_disk_bytes >> 20,
                 disk_bytes_ >> 20);
    return Status::Ok();
  }

  ~Impl() { Stop(); }

  void Enqueue(const DetectionEvent& e) {
    {
      std::lock_guard lock(mutex_);
      if (stopping_) return;
      if (queued_captures_ >= options_.queue_captures) {
        ++stats_.captures_dropped;
        const auto now = std::chrono::steady_clock::now();
        if (now - last_drop_warning_ >= std::chrono::seconds(1)) {  // at most one line a second
          last_drop_warning_ = now;
          spdlog::warn("recording: writer busy ({} captures queued), capture of task {} not recorded ({} dropped "
                       "so far)", queued_captures_, e.task_id, stats_.captures_dropped);
        }
        return;
      }
      ++queued_captures_;
      ++enqueued_;
      queue_.emplace_back(e);
    }
    work_cv_.notify_one();
  }

  void Enqueue(const AnswerEvent& e) {
    {
      std::lock_guard lock(mutex_);
      if (stopping_) return;
      if (queued_answers_ >= options_.queue_answers) {
        if (stats_.answers_dropped++ == 0) spdlog::warn("recording: writer busy, answers not recorded");
        return;
      }
      ++queued_answers_;
      ++enqueued_;
      queue_.emplace_back(e);
    }
    work_cv_.notify_one();
  }

  void Flush() {
    std::unique_lock lock(mutex_);
    const uint64_t target = enqueued_;
    done_cv_.wait(lock, [&] { return processed_ >= target || writer_done_; });
  }

  void Stop() {
    {
      std::lock_guard lock(mutex_);
      if (stopping_ && !writer_.joinable()) return;
      stopping_ = true;
    }
    work_cv_.notify_all();
    if (writer_.joinable()) writer_.join();
  }

  const std::string& session_dir() const { return session_dir_; }

  RecorderStats stats() const {
    std::lock_guard lock(mutex_);
    return stats_;
  }

 private:
  struct Item {
    std::string path;
    int64_t bytes = 0;
  };
  using Job = std::variant<DetectionEvent, AnswerEvent>;

  void Run() {
    for (;;) {
      std::unique_lock lock(mutex_);
      work_cv_.wait(lock, [&] { return stopping_ || !queue_.empty(); });
      if (queue_.empty()) break;  // stopping, all written
      Job job = std::move(queue_.front());
      queue_.pop_front();
      const bool capture = std::holds_alternative<DetectionEvent>(job);
      --(capture ? queued_captures_ : queued_answers_);
      lock.unlock();
      try {  // nothing may escape the writer thread
        if (capture) {
          WriteCapture(std::get<DetectionEvent>(job));
        } else {
          AddAnswer(std::get<AnswerEvent>(job));
        }
      } catch (const std::exception& e) {
        Pause(Status::Internal(std::string("unexpected error: ") + e.what()));
      }
      lock.lock();
      const bool idle = queue_.empty();
      lock.unlock();
      if (idle) WriteAnswersNoThrow();  // one rewrite per burst, not per answer
      lock.lock();
      ++processed_;
      stats_.disk_bytes = disk_bytes_;
      lock.unlock();
      done_cv_.notify_all();
    }
    WriteAnswersNoThrow(/*last=*/true);
    std::lock_guard lock(mutex_);
    stats_.answers_dropped += answers_pending_;  // the last write failed: lost
    stats_.disk_bytes = disk_bytes_;
    writer_done_ = true;
    done_cv_.notify_all();
  }

  // False while paused after a failure; tries again once retry_after passed.
  bool Writable() {
    if (!paused_) return true;
    if (std::chrono::steady_clock::now() < paused_until_) return false;
    paused_ = false;
    std::lock_guard lock(mutex_);
    stats_.paused = false;
    spdlog::info("recording: resuming after the pause");
    return true;
  }

  // `needed`: bytes the failed write needed. The writers' own messages do not
  // always carry the errno (PCL, OpenCV), so a disk with less than that free
  // (after the failed record was removed) is reported as full.
  void Pause(const Status& why, int64_t needed = kRecordOverhead) {
    paused_ = true;
    paused_until_ = std::chrono::steady_clock::now() + options_.retry_after;
    std::string message = why.message();
    std::error_code ec;
    const fs::space_info space = fs::space(options_.directory, ec);
    if (!ec && space.available < static_cast<uintmax_t>(std::max(needed, kRecordOverhead))) {
      message = "disk full (" + std::to_string(space.available) + " bytes free on the recording disk, ~" +
                std::to_string(std::max(needed, kRecordOverhead)) + " needed): " + message;
    }
    spdlog::error("recording: {}; recording paused for {} s (the server keeps serving)", message,
                  std::chrono::duration<double>(options_.retry_after).count());
    std::lock_guard lock(mutex_);
    stats_.paused = true;
    stats_.last_error = message;
  }

  void CountFailedCapture() {
    std::lock_guard lock(mutex_);
    ++stats_.captures_failed;
  }

  // Deletes the oldest sessions, then the oldest items of this session, until
  // `incoming` more bytes fit under the cap.
  void MakeRoom(int64_t incoming) {
    while (disk_bytes_ + incoming > options_.max_disk_bytes) {
      std::error_code ec;
      bool session = !old_sessions_.empty();
      std::deque<Item>& from = session ? old_sessions_ : items_;
      if (from.empty()) return;
      const Item victim = from.front();
      from.pop_front();
      fs::remove_all(victim.path, ec);
      if (ec) spdlog::warn("recording: cannot remove {}: {}", victim.path, ec.message());
      disk_bytes_ -= victim.bytes;
      if (victim.path == answers_chunk_) {
        answers_chunk_.clear();
        answers_chunk_bytes_ = 0;
      }
      spdlog::info("recording: disk cap: removed {} ({} bytes)", victim.path, victim.bytes);
      std::lock_guard lock(mutex_);
      ++(session ? stats_.sessions_rotated : stats_.records_rotated);
    }
  }

  void WriteCapture(const DetectionEvent& e) {
    if (options_.before_write) options_.before_write();
    if (!Writable()) return CountFailedCapture();
    const auto* captured = dynamic_cast<const CapturedFrame*>(e.scene.get());
    const Frame* frame = captured ? &captured->frame() : nullptr;
    const int64_t estimate = EstimateBytes(frame);
    if (estimate > options_.max_disk_bytes) {
      spdlog::warn("recording: a capture of ~{} bytes does not fit the {} byte cap; not recorded", estimate,
                   options_.max_disk_bytes);
      return CountFailedCapture();
    }
    MakeRoom(estimate);
    const std::string final_dir = (fs::path(session_dir_) / SeqName(kRecordDirPrefix, next_seq_)).string();
    const std::string staging = final_dir + kPartialSuffix;
    Status s = WriteRecord(staging, e, frame, next_seq_);
    std::error_code ec;
    if (s.ok()) {
      fs::rename(staging, final_dir, ec);
      if (ec) s = Status::Internal("'" + staging + "': cannot rename: " + ec.message());
    }
    if (s.ok()) s = SyncPath(session_dir_, O_RDONLY | O_DIRECTORY);
    if (!s.ok()) {
      fs::remove_all(staging, ec);
      fs::remove_all(final_dir, ec);
      Pause(s, estimate);
      return CountFailedCapture();
    }
    ++next_seq_;
    const int64_t bytes = DiskBytes(final_dir);
    disk_bytes_ += bytes;
    items_.push_back({final_dir, bytes});
    {
      std::lock_guard lock(mutex_);
      ++stats_.captures_recorded;
    }
    last_record_seq_ = next_seq_ - 1;
    MakeRoom(0);
  }

  Status WriteRecord(const std::string& dir, const DetectionEvent& e, const Frame* frame, uint64_t seq) {
    std::error_code ec;
    fs::remove_all(dir, ec);  // a leftover of a crash
    fs::create_directories(dir, ec);
    if (ec) return Status::Internal("'" + dir + "': cannot create: " + ec.message());
    const fs::path d(dir);
    if (frame != nullptr) {
      if (Status s = WriteCloudPcd(*frame, (d / kRecordFrameName).string()); !s.ok()) return s;
      if (frame->organized()) {
        Status s = WriteDepthPng(*frame, (d / "depth.png").string());
        if (s.code() == Status::Code::kOutOfRange) {
          spdlog::debug("recording: no depth.png: {}", s.ToString());  // the PCD holds the depth
          fs::remove(d / "depth.png", ec);
          fs::remove(d / "depth.intrinsics.json", ec);
        } else if (!s.ok()) {
          return s;
        }
      }
      if (!frame->intensity.empty()) {
        if (Status s = WriteIntensityPng(*frame, (d / "intensity.png").string()); !s.ok()) return s;
      }
      if (frame->truth) {
        if (Status s = WriteGroundTruthJson(*frame, (d / "truth.json").string()); !s.ok()) return s;
        if (!frame->truth->labels.empty()) {
          if (Status s = WriteLabelPng(*frame, (d / "labels.png").string()); !s.ok()) return s;
        }
      }
    }
    // Every data file: synced, then listed with its size and checksum.
    OrderedJson files = OrderedJson::object();
    std::vector<std::string> names;
    for (const auto& entry : fs::directory_iterator(d, ec)) names.push_back(entry.path().filename().string());
    std::sort(names.begin(), names.end());
    for (const std::string& name : names) {
      const std::string path = (d / name).string();
      if (Status s = SyncPath(path, O_RDONLY); !s.ok()) return s;
      Result<std::string> bytes = ReadAll(path);
      if (!bytes.ok()) return bytes.status();
      files[name] = {{"bytes", bytes->size()}, {"fnv1a64", Hex64(Fnv1a64(*bytes))}};
    }
    OrderedJson m;
    m["format"] = kRecordFormat;
    m["seq"] = seq;
    m["time_ns"] = ToNs(e.time);
    m["task_id"] = e.task_id;
    m["task_name"] = e.request.task.name;
    m["camera_config_id"] = e.request.camera_config_id;
    m["X_BF"] = e.request.X_BF ? PoseToJson(*e.request.X_BF) : OrderedJson();
    m["binpick_version"] = options_.version;
    m["config_hash"] = ConfigHash(cell_, e.task_id);
    OrderedJson capture;
    capture["status"] = StatusText(e.capture_status);
    capture["ms"] = e.capture_ms;
    if (frame != nullptr) {
      capture["source"] = frame->source;
      capture["timestamp_ns"] = frame->timestamp_ns;
      capture["X_BC"] = PoseToJson(frame->X_BC);
      capture["width"] = frame->organized() ? frame->depth.width : static_cast<int>(frame->points_C.size());
      capture["height"] = frame->organized() ? frame->depth.height : 1;
    } else if (e.scene) {
      capture["source"] = e.scene->Describe();  // not a frame: results only
    }
    m["capture"] = capture;
    OrderedJson plan;
    plan["status"] = StatusText(e.plan_status);
    plan["ms"] = e.plan_ms;
    plan["result"] = e.plan ? record_internal::PlanResultJson(*e.plan) : OrderedJson();
    m["plan"] = plan;
    m["files"] = files;
    return WriteFileAtomic((d / kRecordManifestName).string(), Dump(m, 1));
  }

  void AddAnswer(const AnswerEvent& e) {
    if (!Writable()) {
      std::lock_guard lock(mutex_);
      ++stats_.answers_dropped;
      return;
    }
    if (answers_.size() >= kAnswersPerChunk) {
      WriteAnswers();
      if (answers_pending_ > 0) {  // could not write them: they go with the chunk
        std::lock_guard lock(mutex_);
        stats_.answers_dropped += answers_pending_;
        answers_pending_ = 0;
      }
      answers_ = OrderedJson::array();
      answers_chunk_.clear();
    }
    OrderedJson a;
    a["time_ns"] = ToNs(e.time);
    a["after_record"] = last_record_seq_;  // 0: before the first record
    a["client_id"] = e.client_id;
    a["peer"] = e.peer;
    a["X_BF"] = e.X_BF ? PoseToJson(*e.X_BF) : OrderedJson();
    a["request"] = record_internal::RequestJson(e.request);
    a["response"] = record_internal::ResponseJson(e.response);
    answers_.push_back(std::move(a));
    ++answers_pending_;
  }

  void WriteAnswersNoThrow(bool last = false) {
    try {
      WriteAnswers(last);
    } catch (const std::exception& e) {
      Pause(Status::Internal(std::string("unexpected error: ") + e.what()));
    }
  }

  // Replaces the current answers chunk with everything it holds so far. On a
  // failure the answers stay pending (in memory, counted neither recorded nor
  // dropped) and are written with the next successful write; not tried while
  // paused, except the `last` write at Stop.
  void WriteAnswers(bool last = false) {
    if (answers_pending_ == 0) return;
    if (!last && paused_ && std::chrono::steady_clock::now() < paused_until_) return;
    const uint64_t pending = answers_pending_;
    OrderedJson chunk;
    chunk["format"] = kAnswersFormat;
    chunk["answers"] = answers_;
    const std::string text = Dump(chunk, 1);
    MakeRoom(static_cast<int64_t>(text.size()) - answers_chunk_bytes_);
    if (answers_chunk_.empty()) {  // a new chunk, or the open one was rotated out
      answers_chunk_ = (fs::path(session_dir_) / (SeqName("answers_", ++next_chunk_) + ".json")).string();
      answers_chunk_bytes_ = 0;
    }
    const int64_t grow = static_cast<int64_t>(text.size()) - answers_chunk_bytes_;
    if (Status s = WriteFileAtomic(answers_chunk_, text); !s.ok()) {
      Pause(s, static_cast<int64_t>(text.size()));
      return;
    }
    answers_pending_ = 0;
    disk_bytes_ += grow;
    answers_chunk_bytes_ = static_cast<int64_t>(text.size());
    auto it = std::find_if(items_.begin(), items_.end(), [&](const Item& i) { return i.path == answers_chunk_; });
    if (it == items_.end()) {
      items_.push_back({answers_chunk_, answers_chunk_bytes_});
    } else {
      it->bytes = answers_chunk_bytes_;
    }
    std::lock_guard lock(mutex_);
    stats_.answers_recorded += pending;
  }

  const RecorderOptions options_;
  const Cell cell_;
  std::string session_dir_;

  mutable std::mutex mutex_;
  std::condition_variable work_cv_;
  std::condition_variable done_cv_;
  std::deque<Job> queue_;      // GUARDED_BY(mutex_)
  int queued_captures_ = 0;    // GUARDED_BY(mutex_)
  int queued_answers_ = 0;     // GUARDED_BY(mutex_)
  uint64_t enqueued_ = 0;      // GUARDED_BY(mutex_)
  uint64_t processed_ = 0;     // GUARDED_BY(mutex_)
  bool stopping_ = false;      // GUARDED_BY(mutex_)
  bool writer_done_ = false;   // GUARDED_BY(mutex_)
  RecorderStats stats_;        // GUARDED_BY(mutex_)
  std::chrono::steady_clock::time_point last_drop_warning_{};  // GUARDED_BY(mutex_)
  std::thread writer_;

  // Writer thread only.
  int64_t disk_bytes_ = 0;
  std::deque<Item> old_sessions_;  // other sessions, oldest first
  std::deque<Item> items_;         // this session's records and answer chunks, oldest first
  uint64_t next_seq_ = 1;
  uint64_t last_record_seq_ = 0;
  OrderedJson answers_ = OrderedJson::array();  // of the current chunk
  uint64_t answers_pending_ = 0;                // added since the chunk was last written
  std::string answers_chunk_;                   // its path; empty before its first write
  int64_t answers_chunk_bytes_ = 0;
  uint64_t next_chunk_ = 0;
  bool paused_ = false;
  std::chrono::steady_clock::time_point paused_until_{};
};

Result<std::shared_ptr<Recorder>> Recorder::Start(const Cell& cell, RecorderOptions options) {
  auto impl = std::make_unique<Impl>(cell, std::move(options));
  if (Status s = impl->Open(); !s.ok()) return s;
  return std::shared_ptr<Recorder>(new Recorder(std::move(impl)));
}

Recorder::Recorder(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Recorder::~Recorder() { Stop(); }
void Recorder::OnDetection(const DetectionEvent& event) { impl_->Enqueue(event); }
void Recorder::OnAnswer(const AnswerEvent& event) { impl_->Enqueue(event); }
void Recorder::Flush() { impl_->Flush(); }
void Recorder::Stop() { impl_->Stop(); }
const std::string& Recorder::session_dir() const { return impl_->session_dir(); }
RecorderStats Recorder::stats() const { return impl_->stats(); }

}  // namespace bp
