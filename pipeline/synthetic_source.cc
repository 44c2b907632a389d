#include "pipeline/synthetic_source.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <mutex>
#include <numbers>
#include <random>
#include <set>
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

constexpr double kDegToRad = std::numbers::pi / 180.0;

// A point uniform over a disc of radius r (in the xy plane).
Vec3 InDisc(std::mt19937_64& rng, double r) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double rho = r * std::sqrt(u(rng)), a = 2 * std::numbers::pi * u(rng);
  return Vec3(rho * std::cos(a), rho * std::sin(a), 0.0);
}

// The offset of fixture `index` from its taught pose after `releases` parts
// were placed, in P: a translation uniform over a disc in P's xy plane and a
// turn about P's z uniform in [-max, max]. Drawn from (seed, releases, index).
Pose FixtureOffset(const SourceSpec& source, int releases, size_t index) {
  std::mt19937_64 rng(Mix(source.seed ^ Mix(0xF17u + 7919u * static_cast<uint64_t>(releases) + index)));
  const Vec3 t = InDisc(rng, source.fixture_offset_translation);
  std::uniform_real_distribution<double> turn(-source.fixture_offset_rotation_deg, source.fixture_offset_rotation_deg);
  return MakePose(Mat3(Eigen::AngleAxisd(turn(rng) * kDegToRad, Vec3::UnitZ())), t);
}

// Where the scene's bin stands relative to its nominal pose (source.bin_offset):
// a translation uniform in the square +-bin_offset_translation of the floor
// plane, a turn about z uniform in +-bin_offset_yaw_deg, then a tilt by an
// angle uniform in [0, bin_offset_tilt_deg] about a horizontal axis of
// uniform azimuth, all about the floor's centre; drawn once per seed.
Pose BinOffset(const SourceSpec& source) {
  if (source.bin_offset_translation <= 0 && source.bin_offset_yaw_deg <= 0 && source.bin_offset_tilt_deg <= 0) {
    return Pose::Identity();
  }
  std::mt19937_64 rng(Mix(source.seed ^ Mix(0xB1D0FF5Eu)));
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Vec3 t(source.bin_offset_translation * u(rng), source.bin_offset_translation * u(rng), 0.0);
  const double yaw = source.bin_offset_yaw_deg * kDegToRad * u(rng);
  const double azimuth = std::numbers::pi * u(rng);
  const double tilt = source.bin_offset_tilt_deg * kDegToRad * 0.5 * (1.0 + u(rng));
  const Mat3 R = Mat3(Eigen::AngleAxisd(tilt, Vec3(std::cos(azimuth), std::sin(azimuth), 0.0))) *
                 Mat3(Eigen::AngleAxisd(yaw, Vec3::UnitZ()));
  return MakePose(R, t);
}

// A part's slip in the gripper at pick `pick`, in T: a translation across
// the tool's z of uniform length in [0, max] and a turn by an angle uniform
// in [0, max] about a uniformly drawn axis through the tool centre point.
Pose Slip(const SourceSpec& source, int pick) {
  if (source.slip_translation <= 0 && source.slip_rotation_deg <= 0) return Pose::Identity();
  std::mt19937_64 rng(Mix(source.seed ^ Mix(0x511Fu + static_cast<uint64_t>(pick))));
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double a = 2 * std::numbers::pi * u(rng);
  const Vec3 t = source.slip_translation * u(rng) * Vec3(std::cos(a), std::sin(a), 0.0);
  std::normal_distribution<double> n(0.0, 1.0);
  Vec3 axis(n(rng), n(rng), n(rng));
  if (axis.norm() < 1e-9) axis = Vec3::UnitZ();
  const double angle = source.slip_rotation_deg * kDegToRad * u(rng);
  return MakePose(Mat3(Eigen::AngleAxisd(angle, axis.normalized())), t);
}

// The table a fixture stands on: a 20 mm slab under the task area, in the
// fixture's taught frame P (its top at z = 0), xy from `lo` to `hi`.
TriangleMesh TableSlab(const Eigen::Vector2d& lo, const Eigen::Vector2d& hi) {
  TriangleMesh m;
  for (int i = 0; i < 8; ++i) {
    m.vertices.emplace_back(static_cast<float>(i & 1 ? hi.x() : lo.x()), static_cast<float>(i & 2 ? hi.y() : lo.y()),
                            i & 4 ? 0.0f : -0.02f);
  }
  // Outward-facing quads of the box (corner index bits: x, y, z).
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    m.triangles.emplace_back(q[0], q[1], q[2]);
    m.triangles.emplace_back(q[0], q[2], q[3]);
  }
  return m;
}

bool SameBits(const Pose& a, const Pose& b) {
  return std::memcmp(a.matrix().data(), b.matrix().data(), sizeof(double) * 16) == 0;
}

bool SameIntrinsics(const Intrinsics& a, const Intrinsics& b) {
  return a.width == b.width && a.height == b.height && a.fx == b.fx && a.fy == b.fy && a.cx == b.cx &&
         a.cy == b.cy;
}

// The image bounds (u, v, real) of a mesh's vertices at X_CO seen through
// K, or nullopt when a vertex is at or behind z_near (its projection is not
// bounded). Every pixel the mesh's triangles cover has its centre inside
// them (GL samples pixel (u, v) at the ray through (u, v)).
struct ProjectedBounds {
  double u_min, v_min, u_max, v_max;
  // The pixels within, widened by `margin` and clipped to K's image.
  PixelRect Pixels(const Intrinsics& K, int margin) const {
    return PixelRect{std::max(0, static_cast<int>(std::floor(u_min)) - margin),
                     std::max(0, static_cast<int>(std::floor(v_min)) - margin),
                     std::min(K.width - 1, static_cast<int>(std::ceil(u_max)) + margin),
                     std::min(K.height - 1, static_cast<int>(std::ceil(v_max)) + margin)};
  }
};

std::optional<ProjectedBounds> Project(const TriangleMesh& mesh, const Pose& X_CO, const Intrinsics& K,
                                       double z_near) {
  ProjectedBounds b;
  b.u_min = std::numeric_limits<double>::infinity(), b.v_min = b.u_min, b.u_max = -b.u_min, b.v_max = -b.u_min;
  for (const auto& p : mesh.vertices) {
    const Vec3 q = X_CO * p.cast<double>();
    if (q.z() <= z_near) return std::nullopt;
    const double u = K.fx * q.x() / q.z() + K.cx, v = K.fy * q.y() / q.z() + K.cy;
    b.u_min = std::min(b.u_min, u);
    b.u_max = std::max(b.u_max, u);
    b.v_min = std::min(b.v_min, v);
    b.v_max = std::max(b.v_max, v);
  }
  return b;
}

// The pixels where a render of `now` can differ from one of `before` through
// the same view (K, X_WC, clip planes, light and meshes: the caller checks):
// the projected bounds, 1 pixel wider, of every instance that moved, came or
// went, where it was and where it is. Outside them the same triangles of the
// same instances cover every pixel, drawn in the same order (depth ties go to
// the first drawn), so the pixel is the same. nullopt when that does not
// hold: a label twice, the unchanged instances in another order, a changed
// one reaching behind the near plane.
std::optional<PixelRect> ChangedPixels(const RenderScene& before, const RenderScene& now, const Intrinsics& K,
                                       const Pose& X_WC) {
  std::map<uint16_t, size_t> was;  // label -> index in before
  for (size_t i = 0; i < before.instances.size(); ++i) {
    if (!was.emplace(before.instances[i].label, i).second) return std::nullopt;
  }
  const Pose X_CW = X_WC.inverse();
  PixelRect changed;
  const auto add = [&](const RenderScene& scene, const RenderInstance& inst) {
    const auto b = Project(*scene.meshes[inst.mesh_index], X_CW * inst.X_WO, K, scene.z_near);
    if (!b) return false;
    changed.Extend(b->Pixels(K, 1));
    return true;
  };
  std::vector<bool> kept(before.instances.size(), false);
  std::set<uint16_t> seen;  // labels of `now`: each once
  size_t last_kept = 0;
  bool any_kept = false;
  for (const RenderInstance& inst : now.instances) {
    if (!seen.insert(inst.label).second) return std::nullopt;
    const auto w = was.find(inst.label);
    if (w != was.end()) {
      const RenderInstance& old = before.instances[w->second];
      if (old.mesh_index == inst.mesh_index && SameBits(old.X_WO, inst.X_WO)) {
        if (any_kept && w->second <= last_kept) return std::nullopt;
        last_kept = w->second;
        any_kept = true;
        kept[w->second] = true;
        continue;
      }
    }
    if (!add(now, inst)) return std::nullopt;
  }
  for (size_t i = 0; i < before.instances.size(); ++i) {
    if (!kept[i] && !add(before, before.instances[i])) return std::nullopt;
  }
  return changed;
}

// Everything a render reads: the scene (meshes by identity, instances with
// their pose bits and labels, clip planes, light), the intrinsics and the
// camera pose. Holding the meshes keeps their addresses from being reused.
struct RenderKey {
  RenderScene scene;
  Intrinsics K;
  Pose X_WC = Pose::Identity();

  // The same view: all but the instances.
  bool SameView(const RenderScene& s, const Intrinsics& k, const Pose& x_wc) const {
    return SameIntrinsics(K, k) && SameBits(X_WC, x_wc) && scene.z_near == s.z_near && scene.z_far == s.z_far &&
           scene.light_C == s.light_C && scene.ambient == s.ambient && scene.meshes == s.meshes;
  }

  bool Matches(const RenderScene& s, const Intrinsics& k, const Pose& x_wc) const {
    if (!SameView(s, k, x_wc) || scene.instances.size() != s.instances.size()) return false;
    for (size_t i = 0; i < s.instances.size(); ++i) {
      const RenderInstance &a = scene.instances[i], &b = s.instances[i];
      if (a.mesh_index != b.mesh_index || a.label != b.label || !SameBits(a.X_WO, b.X_WO)) return false;
    }
    return true;
  }
};

// A solo render's pixel count and what it was rendered from (the view is
// RenderCache::solo_view's).
struct SoloCount {
  std::shared_ptr<const TriangleMesh> mesh;
  Pose X_WO = Pose::Identity();
  int pixels = 0;
};

// What the last captures rendered, reused while the inputs are bit for bit
// the same: the pile untouched since the last capture (no pick, no resettle)
// and the same view. A hit returns the very bytes a new render would give
// (the renderer is a deterministic function of these inputs), so frames of
// a seed do not depend on the cache (test SyntheticSource.CachedRendersGive
// TheFramesOfFreshOnes).
struct RenderCache {
  std::optional<RenderKey> full, projector;  // of Impl::full / Impl::projector
  // Solo counts by label, valid for solo_view (intrinsics, X_WC, clip planes).
  std::optional<RenderKey> solo_view;  // scene holds the clip planes only
  std::map<uint16_t, SoloCount> solo;
};

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
  RenderCache cache;                   // what full / projector / the solo counts were rendered from
  // The noise's seed-independent part of each pixel, and where full.depth
  // and projector.depth changed since it was computed.
  internal::NoiseGeometry noise_geometry;
  internal::NoiseChanges noise_changes;
  int64_t rendered_pixels = 0;  // by the last capture, full and projector
  SceneMeshes scene_meshes;
  int picks = 0;  // NotifyPicked calls with a tool pose (the slip's draw)

  mutable std::mutex world_mutex;            // the truth accessors read from other threads
  std::optional<HeldPartTruth> held;         // GUARDED_BY(world_mutex)
  int releases = 0;                          // GUARDED_BY(world_mutex)

  // What a view shows besides the bin and the pile: instances after the
  // pile's, with the truth they stand for (held part, fixture) or none.
  struct Extra {
    RenderInstance instance;
    std::optional<PartTruth> truth;
  };

  RenderScene Scene(const CameraConfig& config, std::vector<Extra>* extras,
                    std::vector<std::shared_ptr<const TriangleMesh>> extra_meshes) const {
    RenderScene s;
    s.meshes.push_back(bin_mesh);
    for (const auto& c : pile->classes()) s.meshes.push_back(c.mesh);
    const size_t first_extra_mesh = s.meshes.size();
    for (auto& m : extra_meshes) s.meshes.push_back(std::move(m));
    s.instances.push_back({0, Pose::Identity(), GroundTruth::kBinLabel});
    for (const auto& p : pile->parts()) {
      s.instances.push_back({1 + p.class_index, p.X_WO, static_cast<uint16_t>(p.instance_id)});
    }
    for (Extra& e : *extras) {
      e.instance.mesh_index += first_extra_mesh;
      s.instances.push_back(e.instance);
    }
    s.z_near = std::max(0.01, 0.5 * config.min_depth);
    s.z_far = std::max(s.z_near + 0.1, 2.0 * config.max_depth);
    s.light_C = config.noise.projector_offset;
    return s;
  }

  // The gripper at the robot's tool pose and the part it holds (kInHand), or
  // the fixture and its table (kFixture), in W; mesh indices count from the
  // first of `meshes`.
  Status Extras(const CaptureRequest& request, std::vector<Extra>* extras,
                std::vector<std::shared_ptr<const TriangleMesh>>* meshes) const {
    const Pose X_WB = X_BW.inverse();
    if (request.view == CaptureRequest::View::kInHand) {
      if (!request.X_BF) return Status::InvalidArgument("synthetic source: an in-hand view needs the robot's pose");
      const auto g = scene_meshes.grippers.find(request.gripper);
      if (g == scene_meshes.grippers.end()) {
        return Status::NotFound("synthetic source: no mesh for gripper '" + request.gripper + "'");
      }
      const Pose& X_BT = *request.X_BF;
      meshes->push_back(g->second);
      extras->push_back({{meshes->size() - 1, X_WB * X_BT, SyntheticSource::kToolLabel}, std::nullopt});
      std::lock_guard lock(world_mutex);
      if (held) {
        for (const PileClass& c : pile->classes()) {
          if (c.class_id != held->class_id) continue;
          meshes->push_back(c.mesh);
          PartTruth t;
          t.instance_id = held->instance_id;
          t.class_id = c.class_id;
          t.class_name = c.name;
          t.X_BO = X_BT * held->X_TO;
          extras->push_back({{meshes->size() - 1, X_WB * t.X_BO, static_cast<uint16_t>(held->instance_id)}, t});
          break;
        }
      }
    } else if (request.view == CaptureRequest::View::kFixture) {
      const FixtureSpec* fixture = cell.FindFixture(request.fixture);
      const auto f = scene_meshes.fixtures.find(request.fixture);
      if (fixture == nullptr || f == scene_meshes.fixtures.end()) {
        return Status::NotFound("synthetic source: no mesh for fixture '" + request.fixture + "'");
      }
      const size_t index = static_cast<size_t>(fixture - cell.fixtures.data());
      PartTruth t;
      t.instance_id = SyntheticSource::kFixtureLabel - static_cast<int>(index);
      t.class_id = fixture->class_id;
      t.class_name = fixture->name;
      {
        std::lock_guard lock(world_mutex);
        t.X_BO = fixture->X_BP_taught * FixtureOffset(cell.source, releases, index);
      }
      // The table under the task's area: the largest roi of a task looking at this fixture, 10 mm wider.
      Eigen::AlignedBox3d area(Vec3(-0.05, -0.05, 0), Vec3(0.05, 0.05, 0));
      for (const TaskSpec& task : cell.tasks) {
        if (LooksAtFixture(task) && task.fixture == fixture->name) area.extend(task.roi);
      }
      meshes->push_back(std::make_shared<const TriangleMesh>(
          TableSlab(area.min().head<2>() - Eigen::Vector2d::Constant(0.01),
                    area.max().head<2>() + Eigen::Vector2d::Constant(0.01))));
      extras->push_back({{meshes->size() - 1, X_WB * fixture->X_BP_taught, GroundTruth::kBinLabel}, std::nullopt});
      meshes->push_back(f->second);
      extras->push_back({{meshes->size() - 1, X_WB * t.X_BO, static_cast<uint16_t>(t.instance_id)}, t});
    }
    return Status::Ok();
  }

  // Renders `scene` into `out` unless `key` says `out` already holds that
  // render; `key` is updated (cleared while `out` is being overwritten).
  // When `out` holds a render of the same view whose instances partly
  // changed (a pick, a resettle), only the pixels they can reach are
  // rendered again (ChangedPixels; the other pixels are the same bytes).
  // `changed` is extended by the pixels rendered (the whole image for a
  // whole render), for the noise's geometry.
  Status RenderCached(const RenderScene& scene, const Intrinsics& K, const Pose& X_WC, RenderOutput& out,
                      std::optional<RenderKey>& key, PixelRect& changed) {
    if (key && key->Matches(scene, K, X_WC)) return Status::Ok();
    std::optional<PixelRect> region;
    if (key && key->SameView(scene, K, X_WC)) region = ChangedPixels(key->scene, scene, K, X_WC);
    key.reset();
    const PixelRect rendered = region.value_or(PixelRect{0, 0, K.width - 1, K.height - 1});
    changed.Extend(rendered);
    rendered_pixels += rendered.area();
    const Status s = region ? renderer->RenderRegion(scene, K, X_WC, *region, out)
                            : renderer->RenderInto(scene, K, X_WC, out);
    if (!s.ok()) return s;
    key = RenderKey{scene, K, X_WC};
    return Status::Ok();
  }

  // UnoccludedPixels, reusing the count of the same mesh at the same pose
  // bits seen through the same view.
  Result<int> UnoccludedPixelsCached(const RenderScene& scene, const RenderInstance& instance,
                                     const Intrinsics& K, const Pose& X_WC) {
    RenderScene planes;
    planes.z_near = scene.z_near;
    planes.z_far = scene.z_far;
    if (!cache.solo_view || !cache.solo_view->Matches(planes, K, X_WC)) {
      cache.solo.clear();
      cache.solo_view = RenderKey{planes, K, X_WC};
    }
    const auto& mesh = scene.meshes[instance.mesh_index];
    const auto hit = cache.solo.find(instance.label);
    if (hit != cache.solo.end() && hit->second.mesh == mesh && SameBits(hit->second.X_WO, instance.X_WO)) {
      return hit->second.pixels;
    }
    auto pixels = UnoccludedPixels(scene, instance, K, X_WC);
    if (pixels.ok()) cache.solo[instance.label] = SoloCount{mesh, instance.X_WO, *pixels};
    return pixels;
  }

  // Pixels of `instance` rendered alone: rendered through intrinsics cropped
  // to the instance's projected bounds (same pixel grid, fewer pixels).
  Result<int> UnoccludedPixels(const RenderScene& scene, const RenderInstance& instance,
                               const Intrinsics& K, const Pose& X_WC) {
    const TriangleMesh& mesh = *scene.meshes[instance.mesh_index];
    const auto bounds = Project(mesh, X_WC.inverse() * instance.X_WO, K, scene.z_near);
    Intrinsics crop = K;
    if (bounds) {
      const PixelRect r = bounds->Pixels(K, 1);
      if (r.empty()) return 0;
      crop.width = r.u1 - r.u0 + 1;
      crop.height = r.v1 - r.v0 + 1;
      crop.cx -= r.u0;
      crop.cy -= r.v0;
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
                                                                 HandEyeProvider hand_eye, SceneMeshes scene) {
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
  impl->X_BW = cell.bin.X_BW * BinOffset(cell.source);
  impl->bin_mesh = std::make_shared<TriangleMesh>(bin_mesh_W);
  impl->scene_meshes = std::move(scene);
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
  std::vector<Impl::Extra> extras;
  std::vector<std::shared_ptr<const TriangleMesh>> extra_meshes;
  if (Status s = m.Extras(request, &extras, &extra_meshes); !s.ok()) return s;
  const RenderScene scene = m.Scene(*config, &extras, std::move(extra_meshes));
  m.rendered_pixels = 0;
  if (Status s = m.RenderCached(scene, K, X_WC, m.full, m.cache.full, m.noise_changes.depth); !s.ok()) return s;

  Frame frame;
  frame.intrinsics = K;
  frame.X_BC = X_BC;
  frame.intensity = m.full.intensity;

  // Ground truth from the clean label image.
  GroundTruth truth;
  truth.seed = m.cell.source.seed;
  truth.labels = m.full.labels;
  truth.X_BW = m.X_BW;
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
    auto unoccluded = m.UnoccludedPixelsCached(scene, scene.instances[i + 1], K, X_WC);
    if (!unoccluded.ok()) return unoccluded.status();
    // The solo render samples the same pixel centres, so visible <= unoccluded;
    // the clamp only guards against a float rounding flip on an edge pixel.
    t.unoccluded_pixels = *unoccluded;
    t.visible_fraction = t.unoccluded_pixels > 0
                             ? std::min(1.0, double(t.visible_pixels) / t.unoccluded_pixels)
                             : 0.0;
    truth.parts.push_back(std::move(t));
  }
  const size_t first_extra = 1 + m.pile->parts().size();
  for (size_t i = 0; i < extras.size(); ++i) {
    if (!extras[i].truth) continue;
    PartTruth t = *extras[i].truth;
    t.visible_pixels = histogram[static_cast<uint16_t>(t.instance_id)];
    auto unoccluded = m.UnoccludedPixelsCached(scene, scene.instances[first_extra + i], K, X_WC);
    if (!unoccluded.ok()) return unoccluded.status();
    t.unoccluded_pixels = *unoccluded;
    t.visible_fraction =
        t.unoccluded_pixels > 0 ? std::min(1.0, double(t.visible_pixels) / t.unoccluded_pixels) : 0.0;
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
    if (Status s = m.RenderCached(scene, K_P, X_WC * X_CP, m.projector, m.cache.projector,
                                  m.noise_changes.projector);
        !s.ok()) {
      return s;
    }
    in.projector_depth = &m.projector.depth;
    in.K_projector = &K_P;
    in.projector_offset = noise.projector_offset;
  }
  const uint64_t noise_seed = Mix(m.cell.source.seed ^ Mix(static_cast<uint64_t>(m.captures)));
  internal::ApplyDepthNoise(noise, in, noise_seed, m.full.depth, frame.depth, m.noise_geometry, m.noise_changes);
  m.noise_changes = internal::NoiseChanges::None();

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

void SyntheticSource::NotifyPicked(int instance_id, const std::optional<Pose>& X_BT) {
  Impl& m = *impl_;
  if (!m.cell.source.simulate_picks) return;
  std::optional<HeldPartTruth> taken;
  for (const PilePart& p : m.pile->parts()) {
    if (p.instance_id != instance_id || !X_BT) continue;
    // The part stays where the grasp met it, then slips.
    HeldPartTruth h;
    h.instance_id = p.instance_id;
    h.class_id = p.class_id;
    h.slip_T = Slip(m.cell.source, m.picks++);
    h.X_TO = h.slip_T * X_BT->inverse() * m.X_BW * p.X_WO;
    taken = h;
  }
  if (!m.pile->RemovePart(instance_id).ok()) return;  // unknown ids: nothing to remove
  std::lock_guard lock(m.world_mutex);
  if (taken) m.held = taken;
}

void SyntheticSource::ForgetRenders() {
  impl_->cache = {};
  impl_->noise_changes = internal::NoiseChanges{};  // all
}

void SyntheticSource::NotifyReleased() {
  std::lock_guard lock(impl_->world_mutex);
  impl_->held.reset();
  ++impl_->releases;
}

std::optional<HeldPartTruth> SyntheticSource::held() const {
  std::lock_guard lock(impl_->world_mutex);
  return impl_->held;
}

Result<Pose> SyntheticSource::fixture_truth(const std::string& name) const {
  const FixtureSpec* fixture = impl_->cell.FindFixture(name);
  if (fixture == nullptr) return Status::NotFound("synthetic source: no fixture '" + name + "'");
  std::lock_guard lock(impl_->world_mutex);
  return Pose(fixture->X_BP_taught *
              FixtureOffset(impl_->cell.source, impl_->releases,
                            static_cast<size_t>(fixture - impl_->cell.fixtures.data())));
}

int SyntheticSource::releases() const {
  std::lock_guard lock(impl_->world_mutex);
  return impl_->releases;
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
int64_t SyntheticSource::rendered_pixels() const { return impl_->rendered_pixels; }

}  // namespace bp
