// Where a garment sits on its character when it is loaded: the pins' distance to the capsule of
// the bone each follows, the garment's extent, its gap to the body, and the colliders chosen by
// distance. A garment lives in the skeleton's rest pose (docs/guide/garment_placement.md): one
// modelled around a posed frame, in centimetres or Z-up lands away from its bones, pins there and
// floats, so a pin band far from its bone is refused, and one a little far is warned about.
#pragma once

#include <map>
#include <string>
#include <vector>

#include "character/body.hpp"
#include "character/skeleton.hpp"
#include "garment/garment.hpp"

namespace clothdb {

// Thresholds on the pins' distance from their bone's capsule surface, metres.
struct PlacementLimits {
  double warn = 0.05;
  double refuse = 0.20;
};

// The pins that follow one bone.
struct PinBand {
  std::string bone;
  int pins = 0;
  double max_distance = 0;     // farthest pin from the bone's capsule surface (<= 0: on or inside)
  double median_distance = 0;  // its median pin
  Eigen::Vector3d offset{0, 0, 0};  // pins' centroid minus the nearest point of the bone's capsule
};

// A collider that passes through the garment in the rest pose (its axis crosses a triangle).
struct CrossingCollider {
  std::string bone;
  int triangles = 0;  // garment triangles its axis crosses
};

struct PlacementReport {
  int pin_count = 0;
  Eigen::Vector3d lo{0, 0, 0}, hi{0, 0, 0};  // garment extent, rest pose, metres
  std::vector<PinBand> bands;                // one per bone the pins follow, most pins first
  double body_gap = 0;   // nearest garment vertex to any capsule surface (< 0: inside it)
  std::string gap_bone;  // the capsule it is nearest to
  double worst_pin = 0;  // the largest band max_distance
  std::string cause;     // likely cause when worst_pin is over the warning limit
  std::vector<std::string> colliders;      // bones of the colliders in use
  bool auto_colliders = false;             // chosen by distance (colliders.auto_distance)
  std::vector<CrossingCollider> crossing;  // colliders through the garment at rest
};

// Measures the garment in the rest pose `bind` against `capsules` (every bone, with the scene's
// radius overrides: the pins' distances) and `colliders` (the colliders in use: the crossings).
PlacementReport measure_placement(const Skeleton& skeleton, const std::vector<JointPose>& bind,
                                  const Garment& garment, const std::vector<BoneCapsule>& capsules,
                                  const std::vector<BoneCapsule>& colliders);

// One-line summary of the pins, extent and gap, and of the colliders (printed at load).
std::vector<std::string> placement_lines(const PlacementReport& report);
// Warnings (pins over limits.warn, colliders through the garment), each naming `where` (the
// scene file) and the field to change; empty when there is nothing to say.
std::vector<std::string> placement_warnings(const PlacementReport& report, const std::string& where,
                                            const std::string& field,
                                            const PlacementLimits& limits = {});
// Throws GarmentError "<where>: <field>: ..." naming the distances and the likely cause when the
// pins are more than limits.refuse from their bones.
void refuse_misplaced(const PlacementReport& report, const std::string& where,
                      const std::string& field, const PlacementLimits& limits = {});

// At load: measures the garment against every bone's capsule (with the scene's radius overrides)
// and the colliders in use, prints the warnings to stderr, and refuses a misplaced garment
// (refuse_misplaced). `where` is the scene file, `field` the scene field that places the garment.
PlacementReport check_placement(const Skeleton& skeleton, const std::vector<JointPose>& bind,
                                const Garment& garment,
                                const std::map<std::string, double>& radius_overrides,
                                const std::vector<BoneCapsule>& colliders, bool auto_colliders,
                                const std::string& where, const std::string& field);

// The message for a pin rule that matches no vertex: the rule, the garment's extent and how far
// its nearest vertex is from matching (height band: in y; bone distance: from the bone).
std::string unmatched_pins_message(const Skeleton& skeleton, const std::vector<JointPose>& bind,
                                   const Eigen::Matrix3Xd& rest, const MeshGarmentSpec& spec);

}  // namespace clothdb
