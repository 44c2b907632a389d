// A capture source that serves frames from files (PCD, PLY, 16-bit depth PNG),
// one file per Capture, in lexicographic order of file name, wrapping around
// after the last file so a server can run indefinitely on a recording.
// Naming and formats: docs/file_formats.md.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "core/cell.h"
#include "core/status.h"
#include "pipeline/capture_source.h"

namespace bp {

// True for the files a directory source serves: *.pcd, *.ply and *.png whose
// name contains "depth" (so intensity.png / labels.png beside them are not
// frames). Case-insensitive.
bool IsFrameFileName(const std::string& file_name);

// Frame files of a directory (IsFrameFileName), sorted by file name.
// @returns NotFound if the directory does not exist or holds no frame file.
Result<std::vector<std::string>> ListFrameFiles(const std::string& dir);

// `dir_or_file`: a directory (see ListFrameFiles) or a single frame file
// (served on every Capture). X_BC comes from a file's sidecar when it has
// one, else from the cell: camera.X_BC (eye-to-hand) or X_BF * camera.X_FC
// (eye-in-hand, when the request carries X_BF). timestamp_ns is the capture
// time (system clock) unless the sidecar recorded one. A file that fails to
// load returns its error and is skipped on the next Capture.
// @returns NotFound if there is nothing to serve.
Result<std::unique_ptr<CaptureSource>> MakeFileSource(const std::string& dir_or_file, const Cell& cell);

}  // namespace bp
