#include "pipeline/internal/pose_search.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <numeric>
#include <functional>
#include <sstream>
#include <utility>
#include <vector>

#include <tbb/parallel_for.h>

#include "pipeline/internal/face_seeds.h"
#include "pipeline/internal/pose_model.h"
#include "pipeline/internal/resting_poses.h"
#include "pipeline/internal/verification.h"

namespace bp::internal {

namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// PoseSearch::stop_score also needs the pose to explain this fraction of the
// view's subsampled points (a view of two touching parts goes on to the
// other part).
constexpr double kStopExplainedFraction = 0.8;
// The first pass keeps a refined coarse pose whose quick verification scores
// at least this fraction of min_score (the fine pass usually raises it).
constexpr double kFirstPassScoreFraction = 0.6;
// PPF peaks kept per reference point for a later search of the same view
// (PreparedView::votes): the second look examines 16.
constexpr size_t kRecordedPeaks = 16;
// A near-symmetric turn of a hypothesis is refined only when, at a quick
// look (every third verification sample), it explains at least this fraction
// of what the hypothesis does.
constexpr double kNearSymmetryScreen = 0.8;
// keep_better_than_fine: a hypothesis the fine pass leaves below this score
// is also verified at its pose before the fine pass.
constexpr double kKeepBetterThanFineBelow = 0.9;
// The quick look of the near-symmetric turns, the turn axes and the
// ambiguity screen, and ChooseTurn's: every third verification sample.
constexpr int kQuickStride = 3;
// ChooseTurn: the grid's best looks examined a step either side.
constexpr size_t kProbedTurns = 3;
// Ambiguity: at most this many times max_alternatives poses are refined
// and verified in full per hypothesis.
constexpr int kAlternativeTriesPerAlternative = 2;

// What a pose explains of the view: supported minus free-space samples.
int Net(const VerifyStats& v) { return v.supported - v.free_space; }

// Estimate's inputs: InvalidArgument naming the first one that is wrong.
Status CheckEstimateInputs(const SceneView& view, const PoseSearch& search) {
  if (!search.IsValid()) {
    return Status::InvalidArgument(
        "PoseSearch: counts must be >= 1, peaks_examined >= peaks_per_reference and stop_score in [0, 1]");
  }
  if (!view.normals_B.empty() && view.normals_B.size() != view.points_B.size()) {
    return Status::InvalidArgument("SceneView: normals_B has " + std::to_string(view.normals_B.size()) +
                                   " entries for " + std::to_string(view.points_B.size()) + " points");
  }
  if (!view.X_BC.matrix().allFinite()) return Status::InvalidArgument("SceneView: X_BC is not finite");
  if (view.support_plane_B &&
      (!view.support_plane_B->allFinite() || std::abs(view.support_plane_B->head<3>().norm() - 1.0) > 1e-3)) {
    return Status::InvalidArgument("SceneView: support_plane_B needs a finite unit normal");
  }
  return Status::Ok();
}

// A pose on its way through the passes.
struct Candidate {
  Pose X_BO;
  VerifyStats stats;
  IcpResult icp;
  int votes = 0;
  std::pair<int, int> holes{0, 0};  // in view, filled
  // The fine pass's quick look (kQuickStride) at X_BO, and the other poses
  // it looked at on the way (turns, the pose a turn replaced) with their
  // quick look's Net: the ambiguity screen's candidates.
  VerifyStats quick;
  std::vector<std::pair<Pose, int>> tried;
};

// One estimate's search: the steps share the view, the model and what the
// earlier steps found.
class SearchRun {
 public:
  SearchRun(const PoseModel& m, const SceneView& view, const PoseSearch& search, const SearchReuse& reuse,
            const PreparedView& prepared, PreparedView* owned, PoseEstimates* out)
      : m_(m), opt_(m.options), view_(view), search_(search), reuse_(reuse), p_(prepared), owned_(owned), out_(*out),
        have_depth_(view.depth != nullptr && !view.depth->empty() && view.intrinsics.valid()),
        min_score_(have_depth_ ? opt_.min_score : opt_.min_score_without_depth),
        camera_B_(view.X_BC.translation()),
        gate0_(static_cast<float>(opt_.icp_initial_relative_distance) * m.step),
        gate1_(static_cast<float>(opt_.icp_final_distance)) {}

  // The coarse poses and seeds the first pass refined.
  std::vector<Pose>& coarse_poses() { return coarse_poses_; }
  int coarse_skipped() const { return coarse_skipped_; }

  void Run() {
    const auto t1 = Clock::now();
    std::vector<CoarsePose> coarse = Coarse();
    out_.timings.coarse_ms = Ms(t1, Clock::now());
    if (coarse.empty()) {
      out_.no_result_reason = "no pose received enough votes";
      return;
    }
    FirstPass(coarse);
    // Face seeds come last, and only when no coarse pose ended the pass:
    // each costs a quick verification of its own.
    if (!stopped_ && search_.face_seeds > 0 && !m_.faces.empty()) {
      // A planar view (RMS below 1 mm), or one mostly on a plane
      // (planar_view_min_share): the seeds fit the outline of the plane's points.
      const std::vector<Eigen::Vector3f>* plane_pts = &p_.pts();
      std::optional<Eigen::Vector3f> plane = p_.base->view_plane();
      if (!plane && opt_.planar_view_min_share > 0.0) {
        const ViewBase::MostlyPlanar& mostly = p_.base->OnMostlyOnePlane();
        if (mostly.normal && mostly.share >= opt_.planar_view_min_share) {
          plane = mostly.normal;
          plane_pts = &mostly.pts;
        }
      }
      if (plane) {
        std::vector<CoarsePose> seeds;
        Timed(verify_ms_, [&] {
          AppendFaceSeeds(m_, *plane_pts, *plane, view_, *p_.support, p_.segment_depth, search_.face_seeds, seeds);
        });
        FirstPass(seeds);
      }
    }
    out_.coarse_refined = static_cast<int>(coarse_poses_.size());
    if (coarse_poses_.empty()) {
      out_.no_result_reason = "every coarse pose was refined by an earlier estimate of the view";
      return;
    }
    std::vector<Candidate> finals;
    for (const Candidate& c : Survivors()) {
      if (std::optional<Candidate> f = FinePass(c)) finals.push_back(*f);
    }
    Keep(std::move(finals));
  }

 private:
  template <typename F>
  static void Timed(double& acc, F&& f) {
    const auto a = Clock::now();
    f();
    acc += Ms(a, Clock::now());
  }
  bool Passes(const VerifyStats& st, double min_score) const {
    return st.visible - st.occluded - (search_.unmeasured_is_no_evidence ? st.unmeasured : 0) >=
               opt_.min_visible_points &&
           st.score >= min_score;
  }
  VerifyStats VerifyAt(const Pose& X_BO, int stride) const {
    return Verify(m_, X_BO, view_, *p_.support, p_.segment_depth, stride, search_.unmeasured_is_no_evidence);
  }
  // The same where only a score of at least `bar` is of use: a pose that
  // cannot reach it is left half verified (VerifyStats::cut_short, its
  // score below the bar; the passing ones' figures are exact).
  VerifyStats VerifyAt(const Pose& X_BO, int stride, double bar) const {
    return Verify(m_, X_BO, view_, *p_.support, p_.segment_depth, stride, search_.unmeasured_is_no_evidence, bar);
  }
  bool DuplicateOf(const Pose& X, const std::vector<Candidate>& kept) const {
    const double nms = opt_.nms_relative_distance * m_.diameter;
    const Eigen::Vector3d centre = X * m_.centroid_O.cast<double>();
    for (const Candidate& k : kept) {
      if ((k.X_BO * m_.centroid_O.cast<double>() - centre).norm() < nms) return true;
    }
    return false;
  }
  void Reject(const VerifyStats& st) {
    below_support_ += st.below_support;
    best_rejected_ = std::max(best_rejected_, st.score);
  }

  std::vector<CoarsePose> Coarse();
  void DropTried(std::vector<CoarsePose>& list);
  void FirstPass(std::vector<CoarsePose>& list);
  std::vector<Candidate> Survivors();
  std::optional<Candidate> FinePass(Candidate c);
  void TryNearSymmetries(Candidate& c);
  void TryTurns(Candidate& c);
  // PoseSearch::turns_below_bar: c, below the bar, turned by TryTurns;
  // whether it was tried.
  bool TurnBelowBar(Candidate& c);
  // Refines a pose another look found, from X_BO; nullopt when ICP fails.
  std::optional<Candidate> RefineAt(const Pose& X_BO);
  // c replaced by `by` (a turn that explains more), c's pose kept as tried.
  void Replace(Candidate& c, Candidate by);
  bool Distinct(const Pose& a, const Pose& b) const {
    return SymmetricTranslationError(a, b, m_.symmetry) > opt_.ambiguity_translation ||
           SymmetricRotationError(a, b, m_.symmetry) > opt_.ambiguity_rotation_deg * M_PI / 180.0;
  }
  // An alternative pose with its verification figures in full (stride 1;
  // it passed min_score, so a bar did not cut them short).
  struct Alternative {
    Pose X_BO;
    VerifyStats stats;
  };
  std::vector<Alternative> Alternatives(const Candidate& c, const std::vector<const Candidate*>& duplicates);
  // The view's points (PreparedView::index) within the support tolerance
  // of the part's surface at X_BO.
  std::vector<int> ViewPointsOn(const Pose& X_BO) const;
  // `verified`: the figures of h.alternatives, in order (Alternatives).
  void PreferMoreExplained(PoseHypothesis& h, const std::vector<Alternative>& verified);
  void Keep(std::vector<Candidate> finals);

  const PoseModel& m_;
  const PoseEstimatorOptions& opt_;
  const SceneView& view_;
  const PoseSearch& search_;
  const SearchReuse& reuse_;
  const PreparedView& p_;
  PreparedView* owned_;
  PoseEstimates& out_;
  const bool have_depth_;
  const double min_score_;
  const Vec3 camera_B_;
  const float gate0_, gate1_;  // ICP gates: the first pass's initial one, the final one
  double refine_ms_ = 0, verify_ms_ = 0;
  std::vector<Pose> coarse_poses_;  // refined by the first pass
  int coarse_skipped_ = 0;          // left out by SearchReuse::skip_coarse
  std::vector<Candidate> first_;  // the first pass's refined poses
  bool stopped_ = false;          // a first-pass pose explained the view
  double best_rejected_ = -1;
  int below_support_ = 0, holes_filled_ = 0;
};

// PPF voting and pose clustering; with a support plane, points on it are not
// reference points (the floor would otherwise dominate the votes) and coarse
// poses that sink the part into it are dropped; then the resting seeds.
std::vector<CoarsePose> SearchRun::Coarse() {
  PpfMatchOptions mo;
  mo.reference_stride = std::max(1, static_cast<int>(std::lround(1.0 / opt_.reference_fraction)));
  mo.max_reference_points = search_.max_reference_points;
  mo.max_partners = opt_.ppf_max_partners;
  mo.cluster_translation = opt_.cluster_relative_translation * m_.diameter;
  mo.cluster_rotation = opt_.cluster_rotation_deg * M_PI / 180.0;
  mo.max_poses = 3 * search_.max_coarse_poses;
  std::vector<uint8_t> reference_ok;
  std::function<bool(const Pose&)> above_support;
  if (view_.support_plane_B) {
    const Eigen::Vector3f n = view_.support_plane_B->head<3>().cast<float>();
    const float d = static_cast<float>((*view_.support_plane_B)[3]);
    reference_ok.resize(p_.sub_p.size());
    for (size_t i = 0; i < p_.sub_p.size(); ++i) reference_ok[i] = n.dot(p_.sub_p[i]) + d > 0.5f * m_.step;
    const float limit = -static_cast<float>(opt_.max_support_penetration) - 1.5f * m_.step;
    const PoseModel& m = m_;
    above_support = [&m, n, d, limit](const Pose& X_BO) {
      const Eigen::Matrix3f R = X_BO.linear().cast<float>();
      const Eigen::Vector3f t = X_BO.translation().cast<float>();
      for (const auto& p : m.ppf_extreme) {
        if (n.dot(R * p + t) + d < limit) return false;
      }
      return true;
    };
    mo.accept = above_support;
    mo.peaks_per_reference = search_.peaks_per_reference;
    mo.peaks_examined = search_.peaks_examined;
  }
  if (owned_ != nullptr && reuse_.keep_prepared) {
    mo.record = &owned_->votes;
    mo.record_peaks = kRecordedPeaks;
  } else if (owned_ == nullptr) {
    mo.replay = &p_.votes;
  }
  std::vector<CoarsePose> coarse = m_.ppf.Match(p_.sub_p, p_.sub_n, reference_ok, mo, m_.symmetry);
  if (above_support) {
    std::erase_if(coarse, [&](const CoarsePose& cp) { return !above_support(cp.X_BO); });
  }
  if (static_cast<int>(coarse.size()) > search_.max_coarse_poses) coarse.resize(search_.max_coarse_poses);
  if (search_.resting_seeds && view_.support_plane_B) {
    AppendRestingSeeds(m_, p_.pts(), p_.sub_p, p_.sub_n, *view_.support_plane_B, coarse);
  }
  return coarse;
}

// Coarse poses an earlier estimate of this view refined are left out
// (SearchReuse::skip_coarse).
void SearchRun::DropTried(std::vector<CoarsePose>& list) {
  if (reuse_.skip_coarse.empty()) return;
  const double skip_t = opt_.cluster_relative_translation * m_.diameter;
  const double skip_r = opt_.cluster_rotation_deg * M_PI / 180.0;
  const size_t before = list.size();
  std::erase_if(list, [&](const CoarsePose& cp) {
    return std::any_of(reuse_.skip_coarse.begin(), reuse_.skip_coarse.end(), [&](const Pose& X) {
      return (X.translation() - cp.X_BO.translation()).norm() < skip_t &&
             SymmetricRotationError(X, cp.X_BO, m_.symmetry) < skip_r;
    });
  });
  coarse_skipped_ += static_cast<int>(before - list.size());
}

// The first pass over `list`, in order: ICP on the subsampled points, then a
// quick verification (after a screen on fewer samples); stops at a pose that
// explains the view (PoseSearch::stop_score).
void SearchRun::FirstPass(std::vector<CoarsePose>& list) {
  DropTried(list);
  for (const CoarsePose& cp : list) {
    coarse_poses_.push_back(cp.X_BO);
    IcpResult icp;
    Timed(refine_ms_, [&] {
      icp = m_.Refine(p_.sub_p, p_.sub_boundary, cp.X_BO, camera_B_, gate0_, std::max(gate1_, 0.5f * m_.step),
                      opt_.icp_coarse_iterations, opt_.icp_coarse_convergence);
    });
    if (!icp.ok) continue;
    Candidate c;
    c.X_BO = icp.X_BO;
    c.icp = icp;
    c.votes = cp.votes;
    // Most refined coarse poses are wrong and score far below the pass's
    // bar; the screen's bar is never above the pass's own.
    const double screen_bar = std::min(opt_.quick_screen_min_score, kFirstPassScoreFraction * min_score_);
    if (screen_bar > 0.0) {
      Timed(verify_ms_, [&] { c.stats = VerifyAt(icp.X_BO, opt_.quick_screen_stride, screen_bar); });
      if (c.stats.score < screen_bar) {
        ++out_.screened_out;
        first_.push_back(c);
        continue;
      }
    }
    // Below this Survivors drops it.
    Timed(verify_ms_, [&] { c.stats = VerifyAt(icp.X_BO, 3, kFirstPassScoreFraction * min_score_); });
    first_.push_back(c);
    // The coarse poses after a pose this good have fewer votes and converge
    // to it or fail.
    if (search_.stop_score > 0.0 && c.stats.score >= search_.stop_score && Passes(c.stats, min_score_) &&
        m_.ExplainedFraction(c.X_BO, p_.sub_p) >= kStopExplainedFraction) {
      stopped_ = true;
      return;
    }
  }
}

// The first pass's poses that pass its loose bar, best first, one per part
// (nms_relative_distance), at most max_hypotheses.
std::vector<Candidate> SearchRun::Survivors() {
  std::stable_sort(first_.begin(), first_.end(),
                   [](const Candidate& a, const Candidate& b) { return a.stats.score > b.stats.score; });
  std::vector<Candidate> survivors;
  for (const Candidate& c : first_) {
    if (!Passes(c.stats, kFirstPassScoreFraction * min_score_)) {
      Reject(c.stats);
      continue;
    }
    if (DuplicateOf(c.X_BO, survivors)) continue;
    survivors.push_back(c);
    if (static_cast<int>(survivors.size()) >= opt_.max_hypotheses) break;
  }
  return survivors;
}

// ICP on the fine points, verification in full (keep_better_than_fine: the
// pose before it when that scores better), the near-symmetric turns, the
// filled-hole test. nullopt when it fails.
std::optional<Candidate> SearchRun::FinePass(Candidate c) {
  IcpResult icp;
  Timed(refine_ms_, [&] {
    icp = m_.Refine(p_.fine, p_.fine_boundary, c.X_BO, camera_B_, std::max(gate1_, 0.75f * m_.step), gate1_,
                    opt_.icp_iterations, opt_.icp_convergence);
  });
  if (!icp.ok || !icp.X_BO.matrix().allFinite()) return std::nullopt;
  const Candidate before = c;
  c.X_BO = icp.X_BO;
  c.icp = icp;
  // A pose below the bar is dropped, unless the thorough search compares
  // it with the pose before (keep_better_than_fine) or turns it
  // (turns_below_bar): those need its full figures.
  const bool below_bar_used = search_.keep_better_than_fine ||
                              (search_.turns_below_bar && !m_.turn_axes.empty() && have_depth_);
  Timed(verify_ms_, [&] { c.stats = VerifyAt(icp.X_BO, 1, below_bar_used ? -1.0 : min_score_); });
  if (search_.keep_better_than_fine && c.stats.score < kKeepBetterThanFineBelow) {
    VerifyStats st;
    Timed(verify_ms_, [&] { st = VerifyAt(before.X_BO, 1); });
    if (st.score > c.stats.score) {
      c = before;
      c.stats = st;
    }
  }
  const bool turned_below_bar = !Passes(c.stats, min_score_) && TurnBelowBar(c);
  if (!Passes(c.stats, min_score_)) {
    Reject(c.stats);
    return std::nullopt;
  }
  if (search_.near_symmetries) {
    Timed(verify_ms_, [&] { c.quick = VerifyAt(c.X_BO, kQuickStride); });
    if (!m_.near_symmetries.empty()) TryNearSymmetries(c);
    if (!m_.turn_axes.empty() && !turned_below_bar) TryTurns(c);
  }
  if (opt_.hole_max_filled < 1 && have_depth_) {
    Timed(verify_ms_, [&] { c.holes = HoleStats(m_, c.X_BO, view_); });
    if (c.holes.first >= opt_.hole_min_visible && c.holes.second > opt_.hole_max_filled * c.holes.first) {
      ++holes_filled_;
      return std::nullopt;
    }
  }
  return c;
}

// The part turned by a near symmetry may explain the view better (an
// L-bracket turned over about its upright): a turn that explains nearly as
// much at a quick look is refined and replaces the pose when it explains
// more of the view (supported minus free-space model points) and scores at
// most near_symmetry_score_slack lower. By score alone the turn that hides
// more of the part (its denominator) would win.
void SearchRun::TryNearSymmetries(Candidate& c) {
  const Pose X = c.X_BO;
  const int base = Net(c.quick);
  for (const Pose& F : m_.near_symmetries) {
    VerifyStats q;
    Timed(verify_ms_, [&] { q = VerifyAt(X * F, kQuickStride); });
    c.tried.emplace_back(X * F, Net(q));
    if (Net(q) < kNearSymmetryScreen * base) continue;
    std::optional<Candidate> alt = RefineAt(X * F);
    if (alt && Passes(alt->stats, min_score_) && Net(alt->stats) > Net(c.stats) &&
        alt->stats.score >= c.stats.score - opt_.near_symmetry_score_slack) {
      Replace(c, std::move(*alt));
    }
  }
}

// A tee turned about its run fits the run's points at any angle; what is
// not round (the branch) decides. The part is turned about each turn axis
// by every multiple of turn_step_deg, the best turn (by Net at a quick look;
// no turn when none beats the pose) bisected to an eighth of the step; a
// turn is refined and verified, and replaces the pose by the near
// symmetries' rule. Every look is kept for the ambiguity screen.
void SearchRun::TryTurns(Candidate& c) {
  const double step = opt_.turn_step_deg * M_PI / 180.0;
  const int turns = static_cast<int>(std::floor(2.0 * M_PI / step - 1e-9));
  for (const TurnAxis& axis : m_.turn_axes) {
    const Pose X = c.X_BO;
    int best = Net(c.quick);
    double best_angle = 0.0;
    const auto look = [&](double angle) {
      const Pose turned = X * axis.Turn(angle);
      VerifyStats q;
      Timed(verify_ms_, [&] { q = VerifyAt(turned, kQuickStride); });
      c.tried.emplace_back(turned, Net(q));
      return Net(q);
    };
    for (int k = 1; k <= turns; ++k) {
      const int net = look(k * step);
      if (net > best) {
        best = net;
        best_angle = k * step;
      }
    }
    // Bisected around the pose itself too when no turn beats it: the small
    // turns are the ambiguity screen's candidates (a branch hidden from a
    // turn of 10-20 deg either way), not replacements (ICP converged there).
    const bool turned = best_angle != 0.0;
    for (double h = 0.5 * step; h > step / 16.0; h *= 0.5) {
      const double centre = best_angle;
      for (const double angle : {centre - h, centre + h}) {
        const int net = look(angle);
        if (net > best) {
          best = net;
          best_angle = angle;
        }
      }
    }
    if (!turned) continue;
    std::optional<Candidate> alt = RefineAt(X * axis.Turn(best_angle));
    if (alt && Passes(alt->stats, min_score_) && Net(alt->stats) > Net(c.stats) &&
        alt->stats.score >= c.stats.score - opt_.near_symmetry_score_slack) {
      Replace(c, std::move(*alt));
    }
  }
}

bool SearchRun::TurnBelowBar(Candidate& c) {
  if (!search_.turns_below_bar || m_.turn_axes.empty() || !have_depth_) return false;
  Timed(verify_ms_, [&] { c.quick = VerifyAt(c.X_BO, kQuickStride); });
  TryTurns(c);
  return true;
}

std::optional<Candidate> SearchRun::RefineAt(const Pose& X_BO) {
  IcpResult icp;
  Timed(refine_ms_, [&] {
    icp = m_.Refine(p_.fine, p_.fine_boundary, X_BO, camera_B_, std::max(gate1_, 0.75f * m_.step), gate1_,
                    opt_.icp_iterations, opt_.icp_convergence);
  });
  if (!icp.ok || !icp.X_BO.matrix().allFinite()) return std::nullopt;
  Candidate out;
  out.X_BO = icp.X_BO;
  out.icp = icp;
  Timed(verify_ms_, [&] { out.stats = VerifyAt(icp.X_BO, 1, min_score_); });
  return out;
}

void SearchRun::Replace(Candidate& c, Candidate by) {
  c.tried.emplace_back(c.X_BO, Net(c.quick));
  c.X_BO = by.X_BO;
  c.icp = by.icp;
  c.stats = by.stats;
  Timed(verify_ms_, [&] { c.quick = VerifyAt(c.X_BO, kQuickStride); });
}

// The poses that explain the view about as well as c (Net within
// ambiguity_slack) and lie beyond the ambiguity tolerance of c and of each
// other: the fine pass's other looks (best first; verified in full as they
// are, else refined and verified) and the finals NMS folded into c
// (duplicates).
std::vector<SearchRun::Alternative> SearchRun::Alternatives(const Candidate& c,
                                                            const std::vector<const Candidate*>& duplicates) {
  std::vector<Alternative> out;
  if (opt_.max_alternatives <= 0) return out;
  const double keep = 1.0 - opt_.ambiguity_slack;
  const double full_bar = keep * Net(c.stats);
  const auto take = [&](const Pose& X, const VerifyStats& st) {
    if (!Distinct(X, c.X_BO)) return;
    for (const Alternative& Y : out) {
      if (!Distinct(X, Y.X_BO)) return;
    }
    out.push_back({X, st});
  };
  for (const Candidate* d : duplicates) {
    if (static_cast<int>(out.size()) >= opt_.max_alternatives) return out;
    if (Passes(d->stats, min_score_) && Net(d->stats) >= full_bar) take(d->X_BO, d->stats);
  }
  std::vector<std::pair<Pose, int>> looks;
  const double quick_bar = keep * Net(c.quick);
  for (const auto& [X, net] : c.tried) {
    if (net >= quick_bar && Distinct(X, c.X_BO)) looks.emplace_back(X, net);
  }
  std::stable_sort(looks.begin(), looks.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
  int tries = kAlternativeTriesPerAlternative * opt_.max_alternatives;
  for (const auto& look : looks) {
    // Not a structured binding: clang 14 (the sanitizer builds) cannot
    // capture one in a lambda.
    const Pose& X = look.first;
    if (static_cast<int>(out.size()) >= opt_.max_alternatives || tries-- <= 0) break;
    if (std::any_of(out.begin(), out.end(), [&](const Alternative& Y) { return !Distinct(X, Y.X_BO); })) continue;
    // As looked at first: a turn the view cannot tell from c (a hidden
    // branch) may still be one ICP slides back from; failing that, refined.
    VerifyStats as_is;
    Timed(verify_ms_, [&] { as_is = VerifyAt(X, 1, min_score_); });
    if (Passes(as_is, min_score_) && Net(as_is) >= full_bar) {
      take(X, as_is);
      continue;
    }
    std::optional<Candidate> alt = RefineAt(X);
    if (alt && Passes(alt->stats, min_score_) && Net(alt->stats) >= full_bar) take(alt->X_BO, alt->stats);
  }
  return out;
}

// h's verification figures (score and point counts) from st.
void SetVerifyFigures(const VerifyStats& st, PoseHypothesis& h) {
  h.score = st.score;
  h.visible_points = st.visible;
  h.occluded_points = st.occluded;
  h.supported_points = st.supported;
  h.free_space_points = st.free_space;
  h.unmeasured_points = st.unmeasured;
}

std::vector<int> SearchRun::ViewPointsOn(const Pose& X_BO) const {
  std::vector<int> on;
  const float sup = m_.SupportTolerance();
  const Pose X_OB = X_BO.inverse();
  const Eigen::Matrix3f R = X_OB.linear().cast<float>();
  const Eigen::Vector3f t = X_OB.translation().cast<float>();
  const std::vector<Eigen::Vector3f>& pts = p_.pts();
  for (size_t i = 0; i < pts.size(); ++i) {
    if (m_.OnSurface(R * pts[i] + t, sup)) on.push_back(p_.index()[i]);
  }
  return on;
}

// An alternative that explains more of the view than the hypothesis (Net,
// verified in full) by more than ambiguity_net_gain becomes the hypothesis,
// the hypothesis an alternative. The hypothesis won on score, whose
// denominator is the samples in view: a turn that hides more of the part
// (a tee's branch behind its run) scores higher while explaining less of
// what the camera saw. rms_residual stays the refined hypothesis's (an
// alternative may be unrefined).
void SearchRun::PreferMoreExplained(PoseHypothesis& h, const std::vector<Alternative>& verified) {
  const double gain = opt_.ambiguity_net_gain;
  if (!(gain > 0.0) || h.alternatives.empty()) return;
  double best_net = (1.0 + gain) * (h.supported_points - h.free_space_points);
  size_t best = h.alternatives.size();
  VerifyStats st;
  for (size_t k = 0; k < h.alternatives.size(); ++k) {
    // Alternatives verified it at this pose, as VerifyAt(pose, 1, min_score_) would again.
    const VerifyStats& sk = verified[k].stats;
    if (Passes(sk, min_score_) && Net(sk) > best_net) {
      best = k;
      best_net = Net(sk);
      st = sk;
    }
  }
  if (best == h.alternatives.size()) return;
  std::pair<int, int> holes{0, 0};
  if (opt_.hole_max_filled < 1 && have_depth_) {
    holes = HoleStats(m_, h.alternatives[best], view_);
    if (holes.first >= opt_.hole_min_visible && holes.second > opt_.hole_max_filled * holes.first) return;
  }
  std::swap(h.X_BO, h.alternatives[best]);
  SetVerifyFigures(st, h);
  h.hole_points = holes.first;
  h.filled_hole_points = holes.second;
  h.supporting_indices = ViewPointsOn(h.X_BO);
}

// The fine pass's poses best first, one per part, as hypotheses with their
// supporting scene points; the reason when there is none.
void SearchRun::Keep(std::vector<Candidate> finals) {
  std::stable_sort(finals.begin(), finals.end(),
                   [](const Candidate& a, const Candidate& b) { return a.stats.score > b.stats.score; });
  std::vector<Candidate> kept;
  std::vector<std::vector<const Candidate*>> duplicates;  // per kept: the finals NMS folded into it
  const double nms = opt_.nms_relative_distance * m_.diameter;
  for (const Candidate& c : finals) {
    const Eigen::Vector3d centre = c.X_BO * m_.centroid_O.cast<double>();
    const auto of = std::find_if(kept.begin(), kept.end(), [&](const Candidate& k) {
      return (k.X_BO * m_.centroid_O.cast<double>() - centre).norm() < nms;
    });
    if (of != kept.end()) {
      duplicates[static_cast<size_t>(of - kept.begin())].push_back(&c);
      continue;
    }
    kept.push_back(c);
    duplicates.emplace_back();
  }
  std::vector<std::vector<Alternative>> verified(kept.size());  // per kept: its alternatives' figures
  for (size_t i = 0; i < kept.size(); ++i) {
    const Candidate& c = kept[i];
    PoseHypothesis h;
    h.X_BO = c.X_BO;
    SetVerifyFigures(c.stats, h);
    h.hole_points = c.holes.first;
    h.filled_hole_points = c.holes.second;
    h.rms_residual = c.icp.rms;
    h.coarse_votes = c.votes;
    if (search_.near_symmetries) {
      verified[i] = Alternatives(c, duplicates[i]);
      for (const Alternative& a : verified[i]) h.alternatives.push_back(a.X_BO);
    }
    out_.hypotheses.push_back(std::move(h));
  }
  const auto t3 = Clock::now();
  for (size_t i = 0; i < kept.size(); ++i) {
    PoseHypothesis& h = out_.hypotheses[i];  // Keep alone adds hypotheses
    h.supporting_indices = ViewPointsOn(h.X_BO);
    PreferMoreExplained(h, verified[i]);
  }
  // Best first again: a pose preferred for what it explains may score lower.
  std::stable_sort(out_.hypotheses.begin(), out_.hypotheses.end(),
                   [](const PoseHypothesis& a, const PoseHypothesis& b) { return a.score > b.score; });
  verify_ms_ += Ms(t3, Clock::now());
  out_.timings.refine_ms = refine_ms_;
  out_.timings.verify_ms = verify_ms_;
  if (out_.hypotheses.empty()) {
    std::ostringstream os;
    os << "no hypothesis passed verification (best score " << best_rejected_ << ", need " << min_score_;
    if (below_support_ > 0) os << "; " << below_support_ << " below the support plane";
    if (holes_filled_ > 0) os << "; " << holes_filled_ << " with the view's surface through their holes";
    os << ")";
    out_.no_result_reason = os.str();
  }
}

}  // namespace

TurnChoice ChooseTurn(const PoseModel& m, const SceneView& view, const Pose& X_BO, std::span<const Pose> others,
                      double step_deg) {
  std::vector<Eigen::Vector3f> pts;
  pts.reserve(view.points_B.size());
  for (const Eigen::Vector3f& p : view.points_B) {
    if (p.allFinite()) pts.push_back(p);
  }
  SceneSupport support;
  support.Build(pts, 2.f * static_cast<float>(m.options.support_distance), view);
  const SegmentDepth no_segment_depth;
  const auto verify = [&](const Pose& X, int stride) { return Verify(m, X, view, support, no_segment_depth, stride); };
  const VerifyStats given = verify(X_BO, 1);
  TurnChoice out{X_BO, Net(given), Net(given), given.score};
  const bool have_depth = view.depth != nullptr && !view.depth->empty() && view.intrinsics.valid();
  if (!have_depth || given.below_support || !(step_deg > 0)) return out;
  std::vector<Pose> candidates(others.begin(), others.end());
  const double step = step_deg * M_PI / 180.0;
  const double coarse = 2.0 * step;
  const int turns = static_cast<int>(std::floor(2.0 * M_PI / coarse - 1e-9));
  const int given_quick = Net(verify(X_BO, kQuickStride));
  for (const TurnAxis& axis : m.turn_axes) {
    int best = given_quick;
    double best_angle = 0.0;
    const auto look = [&](double angle) {
      const int net = Net(verify(X_BO * axis.Turn(angle), kQuickStride));
      if (net > best) {
        best = net;
        best_angle = angle;
      }
    };
    // The grid every two steps, then a step either side of its best
    // kProbedTurns looks (a true turn's peak is about 8 deg wide: a grid
    // look within a step of it rises among the best); all on every thread of
    // the caller's arena, judged in order afterwards: the same choice as
    // one pass.
    std::vector<double> angles;
    for (int k = 0; k < turns; ++k) angles.push_back((k + 1) * coarse);
    std::vector<int> nets(angles.size(), 0);
    tbb::parallel_for(size_t{0}, angles.size(),
                      [&](size_t k) { nets[k] = Net(verify(X_BO * axis.Turn(angles[k]), kQuickStride)); });
    std::vector<size_t> order(angles.size());
    std::iota(order.begin(), order.end(), size_t{0});
    const size_t probed = std::min(order.size(), kProbedTurns);
    std::partial_sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(probed), order.end(),
                      [&](size_t a, size_t b) { return nets[a] > nets[b] || (nets[a] == nets[b] && a < b); });
    for (size_t j = 0; j < probed; ++j) {
      const double a = angles[order[j]];
      angles.push_back(a - step);
      angles.push_back(a + step);
    }
    const size_t first_probe = nets.size();
    nets.resize(angles.size(), 0);
    tbb::parallel_for(first_probe, angles.size(),
                      [&](size_t k) { nets[k] = Net(verify(X_BO * axis.Turn(angles[k]), kQuickStride)); });
    for (size_t k = 0; k < angles.size(); ++k) {
      if (nets[k] > best) {
        best = nets[k];
        best_angle = angles[k];
      }
    }
    for (double h = 0.5 * step; h > step / 16.0; h *= 0.5) {
      const double centre = best_angle;
      look(centre - h);
      look(centre + h);
    }
    if (best_angle != 0.0) candidates.push_back(X_BO * axis.Turn(best_angle));
  }
  // The own points strided to about icp_max_points; a turn is refined on
  // them (the turn of the detected pose is off the true one by the
  // detection's own small tilt and shift) and kept as looked at when ICP
  // fails or leaves it explaining less.
  std::vector<Eigen::Vector3f> fine;
  const size_t max_points = static_cast<size_t>(std::max(1, m.options.icp_max_points));
  const size_t stride = std::max<size_t>(1, (pts.size() + max_points - 1) / max_points);
  for (size_t i = 0; i < pts.size(); i += stride) fine.push_back(pts[i]);
  const float gate1 = static_cast<float>(m.options.icp_final_distance);
  for (const Pose& X : candidates) {
    VerifyStats st = verify(X, 1);
    Pose best = X;
    const IcpResult icp = m.Refine(fine, {}, X, view.X_BC.translation(), std::max(gate1, 0.75f * m.step), gate1,
                                   m.options.icp_iterations, m.options.icp_convergence);
    if (icp.ok && icp.X_BO.matrix().allFinite()) {
      const VerifyStats refined = verify(icp.X_BO, 1);
      if (!refined.below_support && Net(refined) > Net(st)) {
        st = refined;
        best = icp.X_BO;
      }
    }
    if (!st.below_support && Net(st) > out.net) out = {best, Net(st), out.given_net, st.score};
  }
  return out;
}

Result<PoseEstimates> EstimatePose(const PoseModel& m, const SceneView& view, const PoseSearch& search,
                                   const SearchReuse& reuse, SearchTrace* trace) {
  if (Status s = CheckEstimateInputs(view, search); !s.ok()) return s;
  PoseEstimates out;
  std::shared_ptr<PreparedView> owned;
  const PreparedView* prepared = reuse.prepared.get();
  if (prepared != nullptr) {
    if (prepared->model_id != m.id || prepared->fingerprint != Fingerprint(view.points_B)) {
      return Status::InvalidArgument("SearchReuse: prepared comes from another estimator or view");
    }
  } else {
    // The count only: a fingerprint would cost what sharing the base saves.
    if (reuse.base != nullptr && reuse.base->view_points() != view.points_B.size()) {
      return Status::InvalidArgument("SearchReuse: base comes from another view (" +
                                     std::to_string(reuse.base->view_points()) + " points, the view has " +
                                     std::to_string(view.points_B.size()) + ")");
    }
    owned = std::make_shared<PreparedView>();
    const Preparation p = PrepareView(m, view, reuse.base, owned.get());
    out.scene_points = p.scene_points;
    out.sampled_points = p.sampled_points;
    out.timings.prepare_ms = p.ms;
    if (!p.ok) {
      out.no_result_reason = p.reason;
      return out;
    }
    if (reuse.keep_prepared) owned->fingerprint = Fingerprint(view.points_B);
    prepared = owned.get();
  }
  out.scene_points = static_cast<int>(prepared->pts().size());
  out.sampled_points = static_cast<int>(prepared->sub_p.size());
  SearchRun run(m, view, search, reuse, *prepared, owned.get(), &out);
  run.Run();
  if (trace != nullptr) {
    trace->coarse_poses = std::move(run.coarse_poses());
    trace->coarse_skipped = run.coarse_skipped();
    if (reuse.keep_prepared) trace->prepared = owned ? std::shared_ptr<const PreparedView>(owned) : reuse.prepared;
  }
  return out;
}

}  // namespace bp::internal
