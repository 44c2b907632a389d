// The recorder: a ServerObserver that writes every capture (depth,
// intensity, cloud, intrinsics, robot pose, config hash, binpick version),
// its results (detections, the grasp queue, stage times) and every status
// sent to a robot into one session directory per server run. Layout:
// docs/file_formats.md "Recordings"; reading it back: pipeline/recording.h.
//
// Threading (docs/architecture.md "Recording"): OnDetection / OnAnswer only
// queue (the frame is shared, not copied) and return; one writer thread owned
// by the Recorder does all file I/O, rotation and accounting. The capture
// queue is bounded (options.queue_captures): a capture arriving when it is
// full is dropped with a warning and counted, so recording never slows the
// detection worker down. A write failure (disk full, permission) is logged
// as an error ("disk full (N bytes free ...)" when the disk has less room
// than the write needed), the half-written record is removed, and recording
// pauses for options.retry_after: captures and answers arriving meanwhile are
// counted as failed / dropped, not queued. Then the next capture is tried
// again; it pauses again if the disk is still full, or recording resumes
// (tested on a real full tmpfs: tests/record/disk_full_test.cc). Answers
// whose file could not be written stay in memory and go out with the next
// successful write. The server keeps serving throughout.
//
// Crash safety: a capture is written into "cap_N.partial/", each file is
// fsync'ed, the manifest record.json (sizes + checksums of every file) is
// written with WriteFileAtomic, then the directory is renamed to "cap_N".
// answers.json and session.json are replaced with WriteFileAtomic. A crash at
// any point leaves either no record or a complete one; readers skip partial
// directories and records that no longer match their manifest.
//
// Disk cap: after every record, sessions under options.directory are deleted
// oldest first (then the oldest records of the current session) until
// everything under the directory fits in options.max_disk_bytes; before a
// record, room for its estimated size is made the same way.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "comms/server_observer.h"
#include "core/cell.h"
#include "core/status.h"

namespace bp {

// The version string recordings carry (the CMake project version).
std::string BinpickVersion();

// Hash of a cell and one of its tasks: FNV-1a 64 (pipeline/recording.h) of
// the cell's YAML text followed by "\n#task <id>", as 16 hex digits. Two
// records with the same hash ran with the same configuration.
std::string ConfigHash(const Cell& cell, int task_id);

struct RecorderOptions {
  std::string directory = "binpick_recordings";  // root of the session directories
  int64_t max_disk_bytes = int64_t{1024} << 20;
  int queue_captures = 8;
  int queue_answers = 4096;
  std::chrono::milliseconds retry_after{30000};  // pause after a write failure
  std::string version = BinpickVersion();
  // Tests only: runs on the writer thread before each capture is written.
  std::function<void()> before_write;
};

// From the cell's `recording:` section.
RecorderOptions RecorderOptionsFromCell(const Cell& cell);

struct RecorderStats {
  uint64_t captures_recorded = 0;
  uint64_t captures_dropped = 0;   // queue full
  uint64_t captures_failed = 0;    // not written: write error, paused, larger than the cap
  uint64_t answers_recorded = 0;
  uint64_t answers_dropped = 0;    // queue full, paused, or not written at Stop (or chunk end)
  uint64_t records_rotated = 0;    // of the current session
  uint64_t sessions_rotated = 0;
  int64_t disk_bytes = 0;          // everything under options.directory, as accounted
  bool paused = false;
  std::string last_error;
};

class Recorder final : public ServerObserver {
 public:
  // Creates options.directory if needed and the session directory
  // "session_<UTC yyyymmddThhmmss.mmm>Z_<pid>" in it, writes session.json and
  // cell.yaml, and starts the writer thread. @returns Internal (with the path
  // and the reason) when the directory cannot be created or written.
  static Result<std::shared_ptr<Recorder>> Start(const Cell& cell, RecorderOptions options);
  ~Recorder() override;  // Stop()

  Recorder(const Recorder&) = delete;
  Recorder& operator=(const Recorder&) = delete;

  // Both: queue and return; never block on I/O. Thread-safe.
  void OnDetection(const DetectionEvent& event) override;
  void OnAnswer(const AnswerEvent& event) override;

  // Waits until everything queued so far is written (or dropped). Thread-safe.
  void Flush();
  // Writes what is queued, then stops the writer thread. Idempotent; events
  // after Stop are ignored.
  void Stop();

  const std::string& session_dir() const;
  RecorderStats stats() const;

  class Impl;

 private:
  explicit Recorder(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace bp
