// The synthetic capture source: a seeded pile of parts (SyntheticPile) in the
// cell's bin, rendered with OSMesa through the selected camera configuration,
// with structured-light noise and full ground truth. See docs/synthetic.md.
//
// Camera pose: rendered from the nominal camera pose and stamped with it,
// unless a HandEyeProvider is given (binpickd): then rendered from the true
// pose (calibration.true_pose with a calibration section, hidden from the
// rest of binpick) and stamped with what the provider says at capture time.
//
// Frame content: depth (noisy unless the config's noise is disabled),
// intensity (Lambertian, light at the projector), intrinsics, X_BC, timestamp,
// source "synthetic seed=S capture=N" and truth (labels before noise, per-part
// class, X_BO, visible / unoccluded pixels). A seed reproduces every frame
// exactly: noise uses its own RNG seeded from (seed, capture index).
//
// Variety (cell.source.variety, docs/synthetic.md "Variety"): the scene's
// camera pose, configs (intrinsics, resolution, noise) and drop style are
// drawn from the seed at Create; frames carry the varied X_BC and
// intrinsics, and their source string says what was drawn.
//
// Not thread-safe (one owner calls Capture / NotifyPicked); it owns a GL context.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/cell.h"
#include "core/mesh.h"
#include "pipeline/capture_source.h"
#include "pipeline/synthetic_pile.h"
#include "pipeline/synthetic_variety.h"

namespace bp {

class SyntheticSource final : public CaptureSource {
 public:
  // Builds the pile from cell.source (num_parts, seed, part_classes) using the
  // given class meshes (all classes; part_classes filters them) and the bin
  // mesh in the bin frame W; `hand_eye` as in MakeCaptureSource. @returns
  // InvalidArgument if no class remains, Unavailable without OSMesa.
  static Result<std::unique_ptr<SyntheticSource>> Create(const Cell& cell,
                                                         std::vector<PileClass> classes,
                                                         const TriangleMesh& bin_mesh_W,
                                                         HandEyeProvider hand_eye = {});
  ~SyntheticSource() override;

  // NotFound for an unknown config id; InvalidArgument for eye-in-hand without X_BF.
  Result<Frame> Capture(const CaptureRequest& request) override;
  // With cell.source.simulate_picks: removes the part and lets the rest resettle
  // (effective for the next capture). Unknown ids are ignored.
  void NotifyPicked(int instance_id) override;
  std::string Describe() const override;

  // The current pile, poses in the bin frame W (X_BO = X_BW() * X_WO).
  const SyntheticPile& pile() const;
  const Pose& X_BW() const;
  // Number of frames captured so far.
  int capture_count() const;
  // What this scene drew (cell.source.variety), else nullopt.
  const std::optional<SceneVariety>& variety() const;
  // The camera the frames are rendered from (with variety: the varied one).
  const CameraSpec& camera() const;

 private:
  class Impl;
  explicit SyntheticSource(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Loads the part meshes (LoadMesh) and the bin mesh (cell.bin.mesh, or one
// generated from the bin sizes) and creates the source.
Result<std::unique_ptr<CaptureSource>> MakeSyntheticSource(const Cell& cell, HandEyeProvider hand_eye = {});

}  // namespace bp
