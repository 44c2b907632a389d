// Reading recorded sessions (what record/recorder.h writes; layout in
// docs/file_formats.md "Recordings"), and the `replay` capture source that
// serves their clouds as if they were live.
//
// A session directory holds session.json, cell.yaml and one directory per
// capture, "cap_<seq, 6+ digits>". A capture directory is the frame layout
// of `binpick render --out` (cloud.pcd + sidecar, depth.png + sidecar,
// intensity.png, truth.json / labels.png when synthetic) plus record.json,
// the manifest written last, which lists every data file with its size and
// FNV-1a 64 checksum. A capture directory without a readable manifest, or
// whose files do not match it, is incomplete (cut off mid-write) and skipped.
//
// Thread-safe: no shared state.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "core/cell.h"
#include "core/status.h"
#include "pipeline/capture_source.h"

namespace bp {

inline constexpr char kSessionManifestName[] = "session.json";
inline constexpr char kSessionCellName[] = "cell.yaml";
inline constexpr char kRecordManifestName[] = "record.json";
inline constexpr char kRecordAnswersName[] = "answers.json";
// The frame file of a record: organized binary PCD, bit-exact depth.
inline constexpr char kRecordFrameName[] = "cloud.pcd";
inline constexpr char kRecordDirPrefix[] = "cap_";
// A capture directory being written: "cap_000012.partial" (never read).
inline constexpr char kPartialSuffix[] = ".partial";
// "format" of record.json / session.json; bump on an incompatible change.
inline constexpr char kRecordFormat[] = "binpick.record/1";
inline constexpr char kSessionFormat[] = "binpick.session/1";

// FNV-1a, 64 bit (offset basis 0xcbf29ce484222325, prime 0x100000001b3).
uint64_t Fnv1a64(std::string_view bytes);
// 16 lower-case hex digits.
std::string Hex64(uint64_t value);

// True for "cap_" followed by one or more digits only.
bool IsRecordDirName(const std::string& name);
// True if `dir` holds a session.json or at least one capture directory.
bool IsRecordedSession(const std::string& dir);

// Checks a capture directory against its manifest: record.json parses, has
// the record format, and every file it lists exists with the listed size and
// checksum. @returns Corruption naming the file and the reason.
Status VerifyRecord(const std::string& record_dir);

struct RecordListing {
  std::vector<std::string> records;  // complete capture directories, by sequence number
  std::vector<std::string> skipped;  // one message per directory that was skipped, and why
};
// Capture directories of a session, verified (VerifyRecord). Incomplete ones
// (partial directories, missing or truncated manifest or data, leftover
// temporary files only) are listed in `skipped`, never returned.
// @returns NotFound if `session_dir` is not a directory.
Result<RecordListing> ListRecords(const std::string& session_dir);

// The replay source (source.kind replay, `binpickd --source replay:DIR`):
// `dir` a recorded session serves its complete records' frames in order
// (each record's cloud.pcd with its companions: X_BC and intrinsics from the
// sidecar, intensity, truth), wrapping around; a record that fails to verify
// or load is skipped with a warning. Any other directory of PCD / PLY /
// depth PNG files is served like source.kind files (pipeline/file_source.h).
// @returns NotFound if there is nothing to serve.
Result<std::unique_ptr<CaptureSource>> MakeReplaySource(const std::string& dir, const Cell& cell);

}  // namespace bp
