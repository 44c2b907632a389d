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

// A frame file as perception takes it: LoadFrameFile (X_BC_default when the
// file has no X_BC), then an unorganized cloud organized by ProjectCloud
// (pipeline/cloud_projection.h). `assumption` (optional) gets a warning when
// the cloud had to be seen from an assumed view (no X_BC, or one not
// looking into the bin), else is cleared. Used by the file source, `binpick
// eval --source files:` and `binpick replay DIR`.
Result<Frame> LoadFrameForPerception(const std::string& path, const Cell& cell, const Pose& X_BC_default,
                                     std::string* assumption = nullptr);

// `dir_or_file`: a directory (see ListFrameFiles) or a single frame file
// (served on every Capture). X_BC comes from a file's sidecar when it has
// one, else from the cell: camera.X_BC (eye-to-hand) or X_BF * camera.X_FC
// (eye-in-hand, when the request carries X_BF). timestamp_ns is the capture
// time (system clock) unless the sidecar recorded one. A file that fails to
// load returns its error and is skipped on the next Capture.
// @returns NotFound if there is nothing to serve.
Result<std::unique_ptr<CaptureSource>> MakeFileSource(const std::string& dir_or_file, const Cell& cell);

}  // namespace bp
