// binpick render: renders one synthetic frame of the cell and writes it as
// files (docs/file_formats.md): depth.png + depth.intrinsics.json, cloud.pcd +
// cloud.intrinsics.json, intensity.png, truth.json, labels.png.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>

#include <spdlog/spdlog.h>

#include "apps/binpick/command.h"
#include "core/cell.h"
#include "pipeline/capture_source.h"
#include "pipeline/frame_io.h"

namespace bp::cli {
namespace {

struct RenderOptions {
  std::string cell_path;
  uint64_t seed = 1;
  bool variety = false;
  std::string out_dir;
  int config_id = 0;
};

double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

int Run(const RenderOptions& opt) {
  const std::string cmd = "render";
  Result<Cell> cell = LoadCellOrDefault(opt.cell_path);
  if (!cell.ok()) return Fail(cmd, cell.status());
  // render always draws a synthetic pile, whatever source the cell serves.
  cell->source.kind = SourceSpec::Kind::kSynthetic;
  cell->source.seed = opt.seed;
  if (opt.variety && !cell->source.variety) cell->source.variety = VarietySpec{};

  const auto t_setup = std::chrono::steady_clock::now();
  auto source = MakeCaptureSource(*cell);
  if (!source.ok()) return Fail(cmd, source.status());
  const double setup_ms = MsSince(t_setup);

  CaptureRequest request;
  request.config_id = opt.config_id;
  const auto t_capture = std::chrono::steady_clock::now();
  Result<Frame> frame = (*source)->Capture(request);
  if (!frame.ok()) return Fail(cmd, frame.status());
  const double capture_ms = MsSince(t_capture);

  std::error_code ec;
  std::filesystem::create_directories(opt.out_dir, ec);
  if (ec) return Fail(cmd, Status::Internal("cannot create '" + opt.out_dir + "': " + ec.message()));
  const auto t_write = std::chrono::steady_clock::now();
  const std::filesystem::path dir(opt.out_dir);
  if (Status s = WriteDepthPng(*frame, (dir / "depth.png").string()); !s.ok()) return Fail(cmd, s);
  if (Status s = WriteCloudPcd(*frame, (dir / "cloud.pcd").string()); !s.ok()) return Fail(cmd, s);
  if (!frame->intensity.empty()) {
    if (Status s = WriteIntensityPng(*frame, (dir / "intensity.png").string()); !s.ok()) return Fail(cmd, s);
  }
  size_t placed = 0, visible = 0;
  if (frame->truth) {
    if (Status s = WriteGroundTruthJson(*frame, (dir / "truth.json").string()); !s.ok()) return Fail(cmd, s);
    if (!frame->truth->labels.empty()) {
      if (Status s = WriteLabelPng(*frame, (dir / "labels.png").string()); !s.ok()) return Fail(cmd, s);
    }
    placed = frame->truth->parts.size();
    for (const PartTruth& p : frame->truth->parts) visible += p.visible_pixels > 0 ? 1 : 0;
  }
  const double write_ms = MsSince(t_write);

  const size_t pixels = frame->depth.data.size();
  const size_t valid = frame->ValidPointCount();
  std::printf(
      "render seed=%llu: %zu parts placed, %zu visible, %zu/%zu valid pixels (%.1f%%); "
      "setup %.0f ms, capture %.0f ms, write %.0f ms -> %s\n",
      static_cast<unsigned long long>(opt.seed), placed, visible, valid, pixels,
      pixels ? 100.0 * static_cast<double>(valid) / static_cast<double>(pixels) : 0.0, setup_ms, capture_ms,
      write_ms, opt.out_dir.c_str());
  return kExitOk;
}

}  // namespace

Command RenderCommand() {
  return {"render", "Render one synthetic frame of a cell to files (depth, cloud, intensity, truth)",
          [](CLI::App& sub) -> std::function<int()> {
            auto opt = std::make_shared<RenderOptions>();
            sub.add_option("--cell", opt->cell_path, "Cell YAML file (default: the embedded default cell)");
            sub.add_option("--seed", opt->seed, "Scene seed (a seed reproduces a pile exactly)")->required();
            sub.add_option("--out", opt->out_dir, "Output directory (created if missing)")->required();
            sub.add_option("--config", opt->config_id, "Camera config id (0: the cell's default)");
            sub.add_flag("--variety", opt->variety,
                         "draw the scene's camera pose, intrinsics, noise and drop style from the seed "
                         "(the cell's source.variety, else the defaults; docs/synthetic.md)");
            return [opt] { return Run(*opt); };
          }};
}

}  // namespace bp::cli
