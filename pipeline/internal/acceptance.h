// Perception's acceptance stage: one detection per physical part, greedy by
// score across views, classes and passes (docs/perception_pipeline.md,
// "Acceptance"). Private to bp_pipeline. Frames: B base, O part. SI units.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "pipeline/internal/class_model.h"
#include "pipeline/internal/segmentation.h"
#include "pipeline/internal/view_matching.h"
#include "pipeline/perception.h"

namespace bp::internal {

// The detections of one frame so far. A candidate conflicts with an accepted
// detection whose surface centre is within 0.3 of the larger diameter of its
// own (and, with near_centre_min_shared > 0, on whose surface that
// fraction of the candidate's support lies), that holds a tenth of its
// support when more than half of that is already claimed, or that it
// interpenetrates (3% of either's surface samples inside the other,
// ClassModel::inside_depth: parts of a pile never do). It is dropped when a
// detection it conflicts with scores as well, else it replaces them all. Not thread-safe; Accept runs its interpenetration
// tests in parallel on the caller's oneTBB arena.
class Acceptance {
 public:
  // roi_points: the frame's ROI point count (support indices are below it).
  // models: the class models candidates may name (must outlive this).
  // near_centre_min_shared: PerceptionOptions::near_centre_min_shared,
  // with roi_points_B the frame's ROI points (support indices point into
  // them; must outlive this); ignored when they are empty.
  Acceptance(size_t roi_points, std::span<const ClassModel* const> models, double near_centre_min_shared = 0.0,
             std::span<const Eigen::Vector3f> roi_points_B = {});

  // Accepts `candidates` in order of score (stable).
  void Accept(std::vector<Candidate> candidates);

  // Fraction of the view's points within 2.5 mm of the surface of a live
  // detection scoring at least min_score: 0.6 or more is a piece of a part
  // already found.
  double ExplainedFraction(const Segments& segments, const ViewIndices& view, double min_score = 0.0) const;

  // Per sample of segments.points: 1 when no live detection explains it
  // (in no live detection's support and farther than 2.5 mm from every live
  // detection's surface), else 0.
  std::vector<uint8_t> UnexplainedSamples(const Segments& segments) const;

  // The live detections' indices (for detection()), in acceptance order.
  std::vector<size_t> Live() const;
  const Detection& detection(size_t k) const { return detections_[k]; }
  // Replaces live detection k by c when c conflicts with no other live
  // detection (a larger part that explains k's points and more,
  // internal::ReplaceEnclosed), whatever their scores. @returns whether it did.
  bool Supersede(size_t k, Candidate c);

  // True when no candidate was ever accepted (dropped ones included).
  bool never_accepted() const { return detections_.empty(); }
  // How many live detections' support holds the ROI point.
  int claims(int32_t roi_index) const { return claims_[static_cast<size_t>(roi_index)]; }

  // The live detections, in the order they were accepted.
  std::vector<Detection> TakeDetections();

 private:
  struct Accepted {
    double diameter = 0.0;
    Eigen::Vector3d centre_B;                // of the part's surface
    std::vector<Eigen::Vector3f> surface_B;  // the model's surface samples at the detection
    bool dropped = false;                    // replaced by a later, better candidate
  };
  const ClassModel* ModelOf(int class_id) const;
  // Whether at least near_centre_min_shared_ of c's support lies on live
  // detection k's surface (within kExplainedDistance): the same part.
  // Always true when that is 0, without ROI points or support.
  bool SamePart(size_t k, const Candidate& c) const;
  // The live detections c conflicts with; nullopt when most of its support
  // is claimed, but by no live detection holding a tenth of it (c adds
  // nothing).
  std::optional<std::vector<size_t>> Conflicts(const Candidate& c);
  // Those c's part interpenetrates.
  std::vector<size_t> Interpenetrated(const Candidate& c) const;
  // Drops the detections `conflicts` (their support released) and adds c.
  void Add(Candidate c, const std::vector<size_t>& conflicts);

  std::span<const ClassModel* const> models_;
  std::vector<Detection> detections_;  // with accepted_, one per accepted candidate
  std::vector<Accepted> accepted_;
  std::vector<uint16_t> claims_;  // per ROI point: live detections supported by it
  std::vector<uint8_t> mark_;     // scratch: a candidate's support
  double near_centre_min_shared_ = 0.0;
  std::span<const Eigen::Vector3f> roi_points_B_;
};

// Removes the detections whose pose is ambiguous (Detection::pose_ambiguous)
// and of which less than min_visible of the camera-facing surface is seen
// (Detection::visible_fraction): mostly hidden, the feature that tells
// their poses apart is likely among the hidden (PerceptionOptions::
// ambiguous_min_visible). min_visible 0 keeps all. The others keep their
// order. @returns how many were removed.
int WithholdAmbiguous(double min_visible, std::vector<Detection>* detections);

// The share of `points` within `distance` (metres) of their least-squares
// plane, in [0, 1]; 1 for fewer than 3 points.
double ShareOnOnePlane(std::span<const Eigen::Vector3f> points, double distance);

// Removes the detections of which less than min_visible of the
// camera-facing surface is seen (Detection::visible_fraction) and whose
// support (indices into roi_points_B) lies on one plane: kOnePlaneShare of
// it within kOnePlaneDistance of its least-squares plane. One flat face
// seen alone fixes only the plane; where on it the part lies and which of
// its flat faces it is come from an outline the occluders cut (an
// L-bracket's seen base matched by its upright, 30 mm along; a bushing's
// flange face). PerceptionOptions::one_plane_min_visible; 0 keeps all. The
// others keep their order. @returns how many were removed.
int WithholdOnePlane(double min_visible, std::span<const Eigen::Vector3f> roi_points_B,
                     std::vector<Detection>* detections);

// The model's surface samples at X_BO, in B.
std::vector<Eigen::Vector3f> SurfaceAt(const ClassModel& model, const Pose& X_BO);

}  // namespace bp::internal
