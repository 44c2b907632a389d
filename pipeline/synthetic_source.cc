#include "pipeline/synthetic_source.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <string>
#include <utility>

#include "pipeline/internal/depth_noise.h"
#include "pipeline/renderer.h"
#include "pipeline/synthetic_variety.h"

namespace bp {

namespace {

// SplitMix64 finaliser: decorrelates (seed, capture index) into a noise seed.
uint64_t Mix(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

const CameraConfig* FindCameraConfig(const CameraSpec& camera, int id) {
  for (const auto& c : camera.configs) {
    if (c.id == id) return &c;
  }
  return nullptr;
}

}  // namespace

class SyntheticSource::Impl {
 public:
  Cell cell;  // with source.variety: the scene's camera pose and configs
  HandEyeProvider hand_eye;  // empty: a perfectly calibrated camera
  std::optional<SceneVariety> variety;
  Pose X_BW = Pose::Identity();
  std::unique_ptr<SyntheticPile> pile;
  std::unique_ptr<DepthRenderer> renderer;
  std::shared_ptr<const TriangleMesh> bin_mesh;
  int captures = 0;
  RenderOutput full, solo, projector;  // buffers reused between captures

  RenderScene Scene(const CameraConfig& config) const {
    RenderScene s;
    s.meshes.push_back(bin_mesh);
    for (const auto& c : pile->classes()) s.meshes.push_back(c.mesh);
    s.instances.push_back({0, Pose::Identity(), GroundTruth::kBinLabel});
    for (const auto& p : pile->parts()) {
      s.instances.push_back({1 + p.class_index, p.X_WO, static_cast<uint16_t>(p.instance_id)});
    }
    s.z_near = std::max(0.01, 0.5 * config.min_depth);
    s.z_far = std::max(s.z_near + 0.1, 2.0 * config.max_depth);
    s.light_C = config.noise.projector_offset;
    return s;
  }

  // Pixels of `instance` rendered alone: rendered through intrinsics cropped
  // to the instance's projected bounds (same pixel grid, fewer pixels).
  Result<int> UnoccludedPixels(const RenderScene& scene, const RenderInstance& instance,
                               const Intrinsics& K, const Pose& X_WC) {
    const TriangleMesh& mesh = *scene.meshes[instance.mesh_index];
    const Pose X_CO = X_WC.inverse() * instance.X_WO;
    double u_min = std::numeric_limits<double>::infinity(), v_min = u_min, u_max = -u_min,
           v_max = -u_min;
    bool behind = false;
    for (const auto& p : mesh.vertices) {
      const Vec3 q = X_CO * p.cast<double>();
      if (q.z() <= scene.z_near) {
        behind = true;
        break;
      }
      const double u = K.fx * q.x() / q.z() + K.cx, v = K.fy * q.y() / q.z() + K.cy;
      u_min = std::min(u_min, u);
      u_max = std::max(u_max, u);
      v_min = std::min(v_min, v);
      v_max = std::max(v_max, v);
    }
    Intrinsics crop = K;
    if (!behind) {
      const int u0 = std::max(0, static_cast<int>(std::floor(u_min)) - 1);
      const int v0 = std::max(0, static_cast<int>(std::floor(v_min)) - 1);
      const int u1 = std::min(K.width - 1, static_cast<int>(std::ceil(u_max)) + 1);
      const int v1 = std::min(K.height - 1, static_cast<int>(std::ceil(v_max)) + 1);
      if (u1 < u0 || v1 < v0) return 0;
      crop.width = u1 - u0 + 1;
      crop.height = v1 - v0 + 1;
      crop.cx -= u0;
      crop.cy -= v0;
    }
    RenderScene alone;
    alone.meshes = scene.meshes;
    alone.instances = {instance};
    alone.z_near = scene.z_near;
    alone.z_far = scene.z_far;
    if (Status s = renderer->RenderInto(alone, crop, X_WC, solo); !s.ok()) return s;
    int n = 0;
    for (uint16_t l : solo.labels.data) n += l == instance.label ? 1 : 0;
    return n;
  }
};

SyntheticSource::SyntheticSource(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
SyntheticSource::~SyntheticSource() = default;

Result<std::unique_ptr<SyntheticSource>> SyntheticSource::Create(const Cell& cell,
                                                                 std::vector<PileClass> classes,
                                                                 const TriangleMesh& bin_mesh_W,
                                                                 HandEyeProvider hand_eye) {
  const auto& wanted = cell.source.part_classes;
  if (!wanted.empty()) {
    std::erase_if(classes, [&](const PileClass& c) {
      return std::find(wanted.begin(), wanted.end(), c.class_id) == wanted.end();
    });
  }
  if (classes.empty())
    return Status::InvalidArgument("synthetic source: no part class to draw from");
  if (cell.camera.configs.empty())
    return Status::InvalidArgument("synthetic source: no camera config");
  if (cell.source.num_parts < 0 || cell.source.num_parts > 0xFFFE) {
    return Status::InvalidArgument("synthetic source: num_parts out of range");
  }
  auto impl = std::make_unique<Impl>();
  impl->cell = cell;
  impl->hand_eye = std::move(hand_eye);
  impl->X_BW = cell.bin.X_BW;
  impl->bin_mesh = std::make_shared<TriangleMesh>(bin_mesh_W);
  PileOptions options;
  options.num_parts = cell.source.num_parts;
  options.seed = cell.source.seed;
  if (cell.source.variety) {
    if (impl->hand_eye || cell.camera.eye_in_hand) {
      return Status::InvalidArgument(
          "synthetic source: source.variety needs an eye-to-hand camera without a hand-eye provider");
    }
    const SceneVariety v = DrawSceneVariety(*cell.source.variety, cell.source.seed);
    CameraSpec& camera = impl->cell.camera;
    for (CameraConfig& c : camera.configs) c = VariedConfig(c, v);
    auto X_BC = VariedCameraPose(camera.X_BC, cell.bin, camera.configs, v);
    if (!X_BC.ok()) return X_BC.status();
    camera.X_BC = *X_BC;
    options.settle_iterations = v.drop_style == DropStyle::kSettled   ? 8
                                : v.drop_style == DropStyle::kJumbled ? 0
                                                                      : options.settle_iterations;
    impl->variety = v;
  }
  auto pile = SyntheticPile::Generate(cell.bin, bin_mesh_W, std::move(classes), options);
  if (!pile.ok()) return pile.status();
  impl->pile = std::make_unique<SyntheticPile>(std::move(*pile));
  auto renderer = MakeOsMesaRenderer();
  if (!renderer.ok()) return renderer.status();
  impl->renderer = std::move(*renderer);
  return std::unique_ptr<SyntheticSource>(new SyntheticSource(std::move(impl)));
}

Result<Frame> SyntheticSource::Capture(const CaptureRequest& request) {
  Impl& m = *impl_;
  const int config_id = request.config_id == 0 ? m.cell.camera.default_config : request.config_id;
  const CameraConfig* config = FindCameraConfig(m.cell.camera, config_id);
  if (!config)
    return Status::NotFound("synthetic source: no camera config " + std::to_string(config_id));
  const CameraSpec& camera = m.cell.camera;
  if (camera.eye_in_hand && !request.X_BF)
    return Status::InvalidArgument("synthetic source: eye-in-hand capture needs X_BF");
  // The hand-eye transform (X_BC or X_FC) the camera really has, and the one
  // binpick believes in (stamped on the frame).
  const Pose nominal = camera.eye_in_hand ? camera.X_FC : camera.X_BC;
  const Pose real = m.hand_eye && m.cell.calibration ? m.cell.calibration->true_pose : nominal;
  const Pose believed = m.hand_eye ? m.hand_eye() : nominal;
  const Pose X_BC_real = camera.eye_in_hand ? Pose(*request.X_BF * real) : real;
  const Pose X_BC = camera.eye_in_hand ? Pose(*request.X_BF * believed) : believed;
  const Pose X_WC = m.X_BW.inverse() * X_BC_real;
  const Intrinsics& K = config->intrinsics;
  const RenderScene scene = m.Scene(*config);
  if (Status s = m.renderer->RenderInto(scene, K, X_WC, m.full); !s.ok()) return s;

  Frame frame;
  frame.intrinsics = K;
  frame.X_BC = X_BC;
  frame.depth = m.full.depth;
  frame.intensity = m.full.intensity;

  // Ground truth from the clean label image.
  GroundTruth truth;
  truth.seed = m.cell.source.seed;
  truth.labels = m.full.labels;
  std::vector<int> histogram(0x10000, 0);
  for (uint16_t l : truth.labels.data) ++histogram[l];
  for (size_t i = 0; i < m.pile->parts().size(); ++i) {
    const PilePart& p = m.pile->parts()[i];
    PartTruth t;
    t.instance_id = p.instance_id;
    t.class_id = p.class_id;
    t.class_name = m.pile->classes()[p.class_index].name;
    t.X_BO = m.X_BW * p.X_WO;
    t.visible_pixels = histogram[static_cast<uint16_t>(p.instance_id)];
    auto unoccluded = m.UnoccludedPixels(scene, scene.instances[i + 1], K, X_WC);
    if (!unoccluded.ok()) return unoccluded.status();
    // The solo render samples the same pixel centres, so visible <= unoccluded;
    // the clamp only guards against a float rounding flip on an edge pixel.
    t.unoccluded_pixels = *unoccluded;
    t.visible_fraction = t.unoccluded_pixels > 0
                             ? std::min(1.0, double(t.visible_pixels) / t.unoccluded_pixels)
                             : 0.0;
    truth.parts.push_back(std::move(t));
  }

  // Noise (own RNG: seed and capture index), projector shadow from a second render.
  const NoiseModel& noise = config->noise;
  internal::NoiseInputs in;
  in.K = &K;
  in.min_depth = config->min_depth;
  in.max_depth = config->max_depth;
  Intrinsics K_P;
  if (noise.enabled && noise.projector_shadow) {
    K_P = internal::ProjectorIntrinsics(K, noise.projector_offset, config->min_depth);
    Pose X_CP = Pose::Identity();
    X_CP.translation() = noise.projector_offset;
    if (Status s = m.renderer->RenderInto(scene, K_P, X_WC * X_CP, m.projector); !s.ok()) return s;
    in.projector_depth = &m.projector.depth;
    in.K_projector = &K_P;
    in.projector_offset = noise.projector_offset;
  }
  const uint64_t noise_seed = Mix(m.cell.source.seed ^ Mix(static_cast<uint64_t>(m.captures)));
  internal::ApplyDepthNoise(noise, in, noise_seed, frame.depth);

  frame.source = "synthetic seed=" + std::to_string(m.cell.source.seed) +
                 " capture=" + std::to_string(m.captures);
  if (m.variety) frame.source += " variety: " + m.variety->Describe();
  frame.timestamp_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                           std::chrono::system_clock::now().time_since_epoch())
                           .count();
  frame.truth = std::move(truth);
  ++m.captures;
  return frame;
}

void SyntheticSource::NotifyPicked(int instance_id) {
  if (!impl_->cell.source.simulate_picks) return;
  (void)impl_->pile->RemovePart(instance_id);  // unknown ids: nothing to remove
}

std::string SyntheticSource::Describe() const {
  return "synthetic pile: " + std::to_string(impl_->pile->parts().size()) + " parts (" +
         std::to_string(impl_->pile->skipped()) + " skipped), seed " +
         std::to_string(impl_->cell.source.seed) +
         (impl_->cell.source.simulate_picks ? ", simulating picks" : "");
}

const SyntheticPile& SyntheticSource::pile() const { return *impl_->pile; }
const Pose& SyntheticSource::X_BW() const { return impl_->X_BW; }
const std::optional<SceneVariety>& SyntheticSource::variety() const { return impl_->variety; }
const CameraSpec& SyntheticSource::camera() const { return impl_->cell.camera; }
int SyntheticSource::capture_count() const { return impl_->captures; }

}  // namespace bp
