// Reading and writing frames as files: 16-bit depth PNG + intrinsics sidecar,
// binary PCD, 8-bit intensity PNG, ground-truth JSON. The formats and the
// naming rules are documented in docs/file_formats.md.
//
// No function here throws: every failure is a Status whose message names the
// file and the reason. Thread-safe (no shared state) except that PCL's
// console verbosity is global and is lowered while a PCD/PLY is parsed.
#pragma once

#include <string>
#include <vector>

#include "core/pose.h"
#include "core/status.h"
#include "pipeline/frame.h"

namespace bp {

// Depth PNG unit: one count is 0.1 mm, so depth_m = count * kDepthPngScale.
// Count 0 means "no measurement"; the largest depth is 65535 counts = 6.5535 m.
inline constexpr double kDepthPngScale = 0.0001;

// --- Naming (docs/file_formats.md, "Naming") --------------------------------
// Sidecar of a data file: "<dir>/<stem>.intrinsics.json" (e.g. depth.png ->
// depth.intrinsics.json, cloud.pcd -> cloud.intrinsics.json).
std::string IntrinsicsSidecarPath(const std::string& data_path);
// Companion of a data file for `role` ("truth.json", "intensity.png",
// "labels.png"): a stem ending in "depth" or "cloud" has that word replaced by
// the role ("f01_depth.png" -> "f01_truth.json", "depth.png" -> "truth.json");
// any other stem gets ".<role>" appended ("scan.pcd" -> "scan.truth.json").
std::string CompanionPath(const std::string& data_path, const std::string& role);

// --- Writers ---------------------------------------------------------------
// 16-bit grey PNG of frame.depth in kDepthPngScale units (rounded to nearest;
// NaN / <= 0 -> 0), plus the intrinsics sidecar (intrinsics, depth_scale,
// X_BC, timestamp). @returns InvalidArgument if the frame is not organized,
// OutOfRange if a depth exceeds 6.5535 m, Internal on write failure.
Status WriteDepthPng(const Frame& frame, const std::string& path);
// Binary PCD (x y z float32) of the frame's points in the camera frame C.
// Organized frames give a width x height cloud with NaN for invalid pixels
// (deprojected with Deproject(), so reading back is bit-exact); unorganized
// frames give points_C as a width N, height 1 cloud. VIEWPOINT is left at the
// identity (points are in C); X_BC and intrinsics go to the sidecar.
Status WriteCloudPcd(const Frame& frame, const std::string& path);
// 8-bit grey PNG of frame.intensity. @returns InvalidArgument if it is empty.
Status WriteIntensityPng(const Frame& frame, const std::string& path);
// 16-bit grey PNG of frame.truth->labels (instance ids, 0xFFFF bin).
// @returns InvalidArgument if there is no truth or no label image.
Status WriteLabelPng(const Frame& frame, const std::string& path);
// JSON of frame.truth (schema in docs/file_formats.md); labels are not
// included (see WriteLabelPng). @returns InvalidArgument if there is no truth.
Status WriteGroundTruthJson(const Frame& frame, const std::string& path);

// --- Readers ---------------------------------------------------------------
// Ground truth as written by WriteGroundTruthJson. X_BO comes from the 4x4
// "X_BO" when present, else from "xyz" + "quat_wxyz" (for other tools).
Result<GroundTruth> ReadGroundTruthJson(const std::string& path);
Result<IntensityImage> ReadIntensityPng(const std::string& path);
Result<LabelImage> ReadLabelPng(const std::string& path);

// What a frame file holds, as LoadFrameFile read it (`binpick info`, the
// file source's choice of view for an unorganized cloud).
struct FrameFileInfo {
  std::string format;            // "PCD", "PLY" or "depth PNG"
  std::string encoding;          // PCD: ascii | binary | binary_compressed; PLY: ascii |
                                 // binary_little_endian | binary_big_endian; PNG: 16-bit
  std::string coordinates;       // "float32" or "float64" (clouds), "uint16 depth" (PNG)
  int width = 0, height = 0;     // as stored; a cloud with height 1 is unorganized
  std::vector<std::string> extra_fields;  // fields besides x y z, in file order (read, not used)
  std::string unit = "m";        // the sidecar's "unit" (clouds), else metres
  bool unit_declared = false;
  bool has_sidecar = false;
  // X_BC came from the file (the sidecar's "X_BC"); false: X_BC_default.
  bool X_BC_known = false;
  // PCD VIEWPOINT other than the identity: the points were moved into the
  // sensor's frame and X_BC = X_BF * VIEWPOINT (docs/file_formats.md).
  bool viewpoint_used = false;
};

// Loads one frame file, chosen by extension:
//   .pcd  organized + sidecar      -> depth image (z of each point) + intrinsics
//         organized without sidecar, or points off the sidecar's pinhole
//                                  -> every point, NaNs included, in points_C
//         unorganized              -> points_C (as stored)
//   .ply  vertices (faces ignored) -> points_C
//   .png  16-bit depth + sidecar (required) -> depth image + intrinsics
// Cloud coordinates may be float32 or float64 (read as float32), in the
// sidecar's "unit" (m, cm, mm; default m); other fields are ignored. X_BC and
// timestamp_ns come from the sidecar when it has them, else X_BC =
// X_BC_default and timestamp_ns = 0. Ground truth (CompanionPath "truth.json"
// or "<stem>.truth.json"), intensity and labels PNGs beside the file are
// attached when present. frame.source = path. `info`, if given, says what
// the file held.
// @returns NotFound (file or required sidecar missing), InvalidArgument
// (unsupported extension, 8-bit PNG, coordinates that are not float32 /
// float64, an undeclared millimetre cloud), Corruption (empty, truncated, bad
// magic, size mismatch, no valid points), each naming the file, its format
// and the field.
Result<Frame> LoadFrameFile(const std::string& path, const Pose& X_BC_default, FrameFileInfo* info = nullptr);
Result<Frame> LoadFrameFile(const std::string& path);
// True if LoadFrameFile(path) used a sidecar.
bool HasIntrinsicsSidecar(const std::string& data_path);

}  // namespace bp
