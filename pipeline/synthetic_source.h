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
// Renders are reused between captures while their inputs are bit for bit the
// same (ForgetRenders): a capture without a pick in between renders nothing,
// and after a pick only the parts that moved get a new solo render.
//
// Variety (cell.source.variety, docs/synthetic.md "Variety"): the scene's
// camera pose, configs (intrinsics, resolution, noise) and drop style are
// drawn from the seed at Create; frames carry the varied X_BC and
// intrinsics, and their source string says what was drawn.
//
// The robot and the fixtures (docs/synthetic.md "In hand and fixtures"): with
// simulate_picks, a picked part stays in the gripper where the grasp really
// met it (X_TO = X_BT^-1 * X_BO, true X_BO), moved by a seeded slip
// (source.in_hand_slip), until NotifyReleased; kInHand captures render the
// gripper and that part at the robot's tool pose. Each fixture stands at its
// taught pose moved by a seeded offset (source.fixture_offset), drawn anew
// after each release; kFixture captures render it on a table.
//
// Not thread-safe (one owner calls Capture / NotifyPicked); it owns a GL
// context. The truth accessors (held(), fixture_truth(), releases()) lock
// and may be called from any thread.
#pragma once

#include <map>
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

// The meshes of what else the cell holds: grippers (tool frame T) and
// fixtures (frame P), by cell name.
struct SceneMeshes {
  std::map<std::string, std::shared_ptr<const TriangleMesh>> grippers;
  std::map<std::string, std::shared_ptr<const TriangleMesh>> fixtures;
};

// The part in the gripper, as it really is.
struct HeldPartTruth {
  int instance_id = 0;  // its instance in the pile it was taken from
  int class_id = 0;
  Pose X_TO = Pose::Identity();     // in the tool frame, slip included
  Pose slip_T = Pose::Identity();   // the slip alone: X_TO = slip_T * X_BT^-1 * X_BO
};

class SyntheticSource final : public CaptureSource {
 public:
  // Ground-truth labels of the robot's gripper and of fixture i (kFixtureLabel - i).
  static constexpr uint16_t kToolLabel = 0xFFFE;
  static constexpr uint16_t kFixtureLabel = 0xFFFD;

  // Builds the pile from cell.source (num_parts, seed, part_classes) using the
  // given class meshes (all classes; part_classes filters them) and the bin
  // mesh in the bin frame W; `hand_eye` as in MakeCaptureSource. @returns
  // InvalidArgument if no class remains, Unavailable without OSMesa.
  // `scene`: gripper and fixture meshes (kInHand / kFixture captures need
  // the ones they name: NotFound otherwise).
  static Result<std::unique_ptr<SyntheticSource>> Create(const Cell& cell,
                                                         std::vector<PileClass> classes,
                                                         const TriangleMesh& bin_mesh_W,
                                                         HandEyeProvider hand_eye = {},
                                                         SceneMeshes scene = {});
  ~SyntheticSource() override;

  // NotFound for an unknown config id, gripper or fixture; InvalidArgument
  // for eye-in-hand without X_BF, or an in-hand view without the robot's pose.
  Result<Frame> Capture(const CaptureRequest& request) override;
  // With cell.source.simulate_picks: removes the part and lets the rest resettle
  // (effective for the next capture); with X_BT the part is then held (the
  // one held before is dropped). Unknown ids are ignored.
  void NotifyPicked(int instance_id, const std::optional<Pose>& X_BT = std::nullopt) override;
  // The held part is gone (placed); the fixtures move to their next offset.
  void NotifyReleased() override;
  // Drops the renders kept between captures (the full and projector renders
  // while the scene is bit for bit unchanged, each part's solo pixel count
  // while its pose is): the next capture renders everything again. Frames do
  // not depend on it; tests compare the two paths.
  void ForgetRenders();
  std::string Describe() const override;

  // The current pile, poses in the bin frame W (X_BO = X_BW() * X_WO).
  const SyntheticPile& pile() const;
  // Where the bin really stands: the cell's bin.pose moved by the seeded
  // source.bin_offset (the nominal pose without one).
  const Pose& X_BW() const;
  // Number of frames captured so far.
  int capture_count() const;
  // Pixels the last capture rendered of the scene and of the projector's
  // depth map (solo renders aside): 0 for a pile untouched since the capture
  // before, the pixels the moved parts can reach after a pick, both images
  // whole for a new view or after ForgetRenders.
  int64_t rendered_pixels() const;
  // What this scene drew (cell.source.variety), else nullopt.
  const std::optional<SceneVariety>& variety() const;
  // The camera the frames are rendered from (with variety: the varied one).
  const CameraSpec& camera() const;
  // The part in the gripper now, if any.
  std::optional<HeldPartTruth> held() const;
  // Where fixture `name` really stands now (X_BP); NotFound for an unknown name.
  Result<Pose> fixture_truth(const std::string& name) const;
  int releases() const;  // NotifyReleased calls so far

 private:
  class Impl;
  explicit SyntheticSource(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Loads the part meshes (LoadMesh) and the bin mesh (cell.bin.mesh, or one
// generated from the bin sizes) and creates the source.
Result<std::unique_ptr<CaptureSource>> MakeSyntheticSource(const Cell& cell, HandEyeProvider hand_eye = {});

}  // namespace bp
