#include "pipeline/capture_source.h"

#include <utility>

#include "pipeline/file_source.h"
#include "pipeline/recording.h"
#include "pipeline/synthetic_source.h"

namespace bp {

Result<std::unique_ptr<CaptureSource>> MakeCaptureSource(const Cell& cell, HandEyeProvider hand_eye) {
  switch (cell.source.kind) {
    case SourceSpec::Kind::kFiles:
      if (cell.source.dir.empty()) {
        return Status::InvalidArgument(cell.path + ": source.dir is required when source.kind is files");
      }
      return MakeFileSource(cell.source.dir, cell);
    case SourceSpec::Kind::kSynthetic:
      return MakeSyntheticSource(cell, std::move(hand_eye));
    case SourceSpec::Kind::kReplay:
      if (cell.source.dir.empty()) {
        return Status::InvalidArgument(cell.path + ": source.dir is required when source.kind is replay");
      }
      return MakeReplaySource(cell.source.dir, cell);
  }
  return Status::InvalidArgument(cell.path + ": unknown source.kind");
}

}  // namespace bp
