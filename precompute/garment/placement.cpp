#include "garment/placement.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>

#include "character/motion_loader.hpp"

namespace clothdb {

namespace {

std::string fmt(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, format, value);
  return buffer;
}
std::string metres(double value) {
  return fmt("%.3f m", value);
}
std::string vec(const Eigen::Vector3d& v) {
  char buffer[96];
  std::snprintf(buffer, sizeof buffer, "(%.3f, %.3f, %.3f)", v.x(), v.y(), v.z());
  return buffer;
}

Eigen::Vector3d closest_on_segment(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                   const Eigen::Vector3d& b) {
  const Eigen::Vector3d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return a + t * ab;
}

Eigen::Vector3d capsule_end(const BoneCapsule& c, const Skeleton& skeleton,
                            const std::vector<JointPose>& pose) {
  if (c.child >= 0) return pose[c.child].position;
  return point_in_joint(pose[c.joint], *skeleton.end_site[c.joint]);
}

// Distance from p to the surface of the capsules of joint j, and the nearest point on the nearest
// capsule's axis. A joint without a capsule of its own (CMU's Hips: its children LHipJoint,
// RHipJoint and LowerBack sit on it) is covered by its children's capsules that start where it
// is; else by the capsules ending at it; else the joint itself.
double bone_surface_distance(const Skeleton& skeleton, const std::vector<JointPose>& bind,
                             const std::vector<BoneCapsule>& capsules, int j,
                             const Eigen::Vector3d& p, Eigen::Vector3d* nearest) {
  double best = std::numeric_limits<double>::infinity();
  for (int pass = 0; pass < 3 && !std::isfinite(best); ++pass)
    for (const BoneCapsule& c : capsules) {
      const bool covers = pass == 0 ? c.joint == j
                          : pass == 1
                              ? skeleton.parents[c.joint] == j &&
                                    (bind[c.joint].position - bind[j].position).norm() < 1e-3
                              : c.child == j;
      if (!covers) continue;
      const Eigen::Vector3d q =
          closest_on_segment(p, bind[c.joint].position, capsule_end(c, skeleton, bind));
      const double d = (p - q).norm() - c.radius;
      if (d < best) best = d, *nearest = q;
    }
  if (!std::isfinite(best)) *nearest = bind[j].position, best = (p - bind[j].position).norm();
  return best;
}

// Segment a-b against triangle (p0, p1, p2) (Moller and Trumbore 1997, "Fast, minimum storage
// ray-triangle intersection", restricted to the segment).
bool segment_crosses(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& p0,
                     const Eigen::Vector3d& p1, const Eigen::Vector3d& p2) {
  const Eigen::Vector3d dir = b - a, e1 = p1 - p0, e2 = p2 - p0;
  const Eigen::Vector3d h = dir.cross(e2);
  const double det = e1.dot(h);
  if (std::abs(det) < 1e-14) return false;
  const Eigen::Vector3d s = a - p0;
  const double u = s.dot(h) / det;
  if (u < 0 || u > 1) return false;
  const Eigen::Vector3d q = s.cross(e1);
  const double v = dir.dot(q) / det;
  if (v < 0 || u + v > 1) return false;
  const double t = e2.dot(q) / det;
  return t >= 0 && t <= 1;
}

struct PinDistances {
  std::map<int, std::vector<double>> by_joint;
  std::map<int, Eigen::Vector3d> offset_sum;
};

PinDistances pin_distances(const Skeleton& skeleton, const std::vector<JointPose>& bind,
                           const Garment& garment, const std::vector<BoneCapsule>& capsules,
                           const Eigen::Matrix3d& turn) {
  PinDistances out;
  for (const PinBinding& b : garment.bindings) {
    const int j = b.weights.front().first;  // the bone with the largest weight comes first
    const Eigen::Vector3d p = turn * garment.mesh.rest.col(b.vertex);
    Eigen::Vector3d nearest = Eigen::Vector3d::Zero();
    out.by_joint[j].push_back(bone_surface_distance(skeleton, bind, capsules, j, p, &nearest));
    auto [it, fresh] = out.offset_sum.emplace(j, Eigen::Vector3d::Zero());
    it->second += p - nearest;
  }
  return out;
}

double worst_of(const PinDistances& d) {
  double worst = -std::numeric_limits<double>::infinity();
  for (const auto& [j, list] : d.by_joint)
    for (double v : list) worst = std::max(worst, v);
  return worst;
}

}  // namespace

PlacementReport measure_placement(const Skeleton& skeleton, const std::vector<JointPose>& bind,
                                  const Garment& garment, const std::vector<BoneCapsule>& capsules,
                                  const std::vector<BoneCapsule>& colliders) {
  PlacementReport r;
  const Eigen::Matrix3Xd& x = garment.mesh.rest;
  r.pin_count = static_cast<int>(garment.pins.size());
  if (x.cols() > 0) {
    r.lo = x.rowwise().minCoeff();
    r.hi = x.rowwise().maxCoeff();
  }
  const PinDistances d =
      pin_distances(skeleton, bind, garment, capsules, Eigen::Matrix3d::Identity());
  for (const auto& [j, list] : d.by_joint) {
    PinBand band;
    band.bone = skeleton.names[j];
    band.pins = static_cast<int>(list.size());
    std::vector<double> sorted = list;
    std::sort(sorted.begin(), sorted.end());
    band.max_distance = sorted.back();
    band.median_distance = sorted[sorted.size() / 2];
    band.offset = d.offset_sum.at(j) / static_cast<double>(list.size());
    r.bands.push_back(band);
  }
  std::stable_sort(r.bands.begin(), r.bands.end(),
                   [](const PinBand& a, const PinBand& b) { return a.pins > b.pins; });
  r.worst_pin = r.bands.empty() ? 0.0 : worst_of(d);

  // The gap: the nearest garment vertex to any capsule's surface.
  r.body_gap = std::numeric_limits<double>::infinity();
  for (const BoneCapsule& c : capsules) {
    const Eigen::Vector3d a = bind[c.joint].position, b = capsule_end(c, skeleton, bind);
    for (Eigen::Index v = 0; v < x.cols(); ++v) {
      const double g = (x.col(v) - closest_on_segment(x.col(v), a, b)).norm() - c.radius;
      if (g < r.body_gap) r.body_gap = g, r.gap_bone = skeleton.names[c.joint];
    }
  }
  if (!std::isfinite(r.body_gap)) r.body_gap = 0;

  // Likely cause of pins far from their bones, tried in this order: a scale off by far more than
  // people differ, a Z-up export (turned upright, the pins land on their bones), else a garment
  // modelled away from the rest pose (a posed frame, or standing on the floor).
  const double size = skeleton_size(skeleton);
  const double extent = (r.hi - r.lo).maxCoeff();
  if (size > 0 && (extent > 3.0 * size || extent < size / 30.0)) {
    r.cause = "wrong scale: the garment is " + metres(extent) + " across on a skeleton " +
              metres(size) + " tall (garment.scale converts file units to metres: 0.01 for " +
              "centimetres)";
  } else {
    const double upright =
        worst_of(pin_distances(skeleton, bind, garment, capsules, up_axis_rotation(UpAxis::Z)));
    if (upright < 0.5 * r.worst_pin && upright < 0.05) {
      r.cause = "Z-up: turned from Z-up to Y-up the pins are " + metres(upright) +
                " from their bones; export the garment with Y up (Blender's OBJ exporter: "
                "Up Axis Y, its default)";
    } else {
      const PinBand& worst = *std::max_element(
          r.bands.begin(), r.bands.end(),
          [](const PinBand& a, const PinBand& b) { return a.max_distance < b.max_distance; });
      r.cause =
          "modelled on a posed frame or away from the rest pose (e.g. standing on the "
          "floor): the pins on '" +
          worst.bone + "' are off its capsule by " + vec(worst.offset) +
          " m, while the rest pose has '" + skeleton.names[0] + "' at " + vec(bind[0].position) +
          " m; model the garment on the skeleton's rest pose (clothdb motion info --joints)";
    }
  }

  // Colliders: their bones, and those whose axis crosses the garment at rest.
  for (const BoneCapsule& c : colliders) {
    const std::string& name = skeleton.names[c.joint];
    if (std::find(r.colliders.begin(), r.colliders.end(), name) == r.colliders.end())
      r.colliders.push_back(name);
    const Eigen::Vector3d a = bind[c.joint].position, b = capsule_end(c, skeleton, bind);
    int crossed = 0;
    for (const auto& t : garment.mesh.triangles)
      crossed += segment_crosses(a, b, x.col(t[0]), x.col(t[1]), x.col(t[2])) ? 1 : 0;
    if (crossed == 0) continue;
    auto it = std::find_if(r.crossing.begin(), r.crossing.end(),
                           [&](const CrossingCollider& k) { return k.bone == name; });
    if (it == r.crossing.end())
      r.crossing.push_back({name, crossed});
    else
      it->triangles += crossed;
  }
  return r;
}

std::vector<std::string> placement_lines(const PlacementReport& r) {
  std::vector<std::string> lines;
  std::string pins = std::to_string(r.pin_count) + " pins";
  for (size_t i = 0; i < r.bands.size(); ++i) {
    const PinBand& b = r.bands[i];
    pins += std::string(i == 0 ? ": " : "; ") + std::to_string(b.pins) + " on '" + b.bone + "', " +
            fmt("%.1f", 100 * b.median_distance) + " cm (median) to " +
            fmt("%.1f", 100 * b.max_distance) + " cm from its capsule";
    if (i == 3 && r.bands.size() > 4) {
      pins += "; " + std::to_string(r.bands.size() - 4) + " more bones";
      break;
    }
  }
  lines.push_back("garment (rest pose): " + pins);
  lines.push_back("garment extent " + vec(r.lo) + " .. " + vec(r.hi) + " m, " +
                  (r.body_gap >= 0 ? fmt("%.1f cm", 100 * r.body_gap) + " from the body"
                                   : fmt("%.1f cm", -100 * r.body_gap) + " inside the body") +
                  " (nearest: '" + r.gap_bone + "')");
  std::string list;
  for (const std::string& c : r.colliders) list += (list.empty() ? "" : ", ") + c;
  lines.push_back(std::string("colliders") + (r.auto_colliders ? " (auto_distance)" : "") + ": " +
                  std::to_string(r.colliders.size()) + " bones: " + list);
  return lines;
}

std::vector<std::string> placement_warnings(const PlacementReport& r, const std::string& where,
                                            const std::string& field,
                                            const PlacementLimits& limits) {
  std::vector<std::string> out;
  if (r.worst_pin > limits.warn && r.worst_pin <= limits.refuse)
    out.push_back(where + ": warning: " + field + ": pinned vertices are up to " +
                  fmt("%.1f cm", 100 * r.worst_pin) + " from their bone's capsule (over " +
                  fmt("%.0f cm", 100 * limits.warn) + "); likely cause: " + r.cause);
  for (const CrossingCollider& c : r.crossing)
    out.push_back(where + ": warning: colliders" +
                  (r.auto_colliders ? ".auto_distance" : ".bones") + ": the collider of bone '" +
                  c.bone + "' crosses the garment at rest (" + std::to_string(c.triangles) +
                  " triangles): it will push the cloth through itself; list colliders.bones "
                  "without it, or give it a smaller colliders.radius");
  return out;
}

void refuse_misplaced(const PlacementReport& r, const std::string& where, const std::string& field,
                      const PlacementLimits& limits) {
  if (!(r.worst_pin > limits.refuse)) return;
  std::string bands;
  for (const PinBand& b : r.bands)
    if (b.max_distance > limits.warn)
      bands += std::string(bands.empty() ? "" : ", ") + std::to_string(b.pins) + " pins on '" +
               b.bone + "' up to " + metres(b.max_distance) + " (median " +
               metres(b.median_distance) + ")";
  throw GarmentError(where + ": " + field + ": the garment's pinned vertices are up to " +
                     metres(r.worst_pin) + " from their bone's capsule surface (" + bands +
                     "; refused over " + metres(limits.refuse) + ", warned over " +
                     metres(limits.warn) +
                     "): a garment is placed on the skeleton's rest pose "
                     "(docs/guide/garment_placement.md). Likely cause: " +
                     r.cause);
}

PlacementReport check_placement(const Skeleton& skeleton, const std::vector<JointPose>& bind,
                                const Garment& garment,
                                const std::map<std::string, double>& radius_overrides,
                                const std::vector<BoneCapsule>& colliders, bool auto_colliders,
                                const std::string& where, const std::string& field) {
  BodySpec every_bone;
  every_bone.radius = radius_overrides;
  PlacementReport r = measure_placement(skeleton, bind, garment,
                                        make_body(skeleton, every_bone).capsules, colliders);
  r.auto_colliders = auto_colliders;
  refuse_misplaced(r, where, field);
  for (const std::string& w : placement_warnings(r, where, field))
    std::fprintf(stderr, "%s\n", w.c_str());
  return r;
}

std::string unmatched_pins_message(const Skeleton& skeleton, const std::vector<JointPose>& bind,
                                   const Eigen::Matrix3Xd& rest, const MeshGarmentSpec& spec) {
  const Eigen::Vector3d lo = rest.rowwise().minCoeff(), hi = rest.rowwise().maxCoeff();
  std::string rule, nearest;
  switch (spec.pins.kind) {
    case PinRuleKind::VertexGroup:
      rule = "vertex group '" + spec.pins.group + "'";
      break;
    case PinRuleKind::HeightBand: {
      rule = "height band [" + fmt("%.3f", spec.pins.y_min) + ", " + fmt("%.3f", spec.pins.y_max) +
             "] m";
      double best = std::numeric_limits<double>::infinity();
      for (Eigen::Index v = 0; v < rest.cols(); ++v)
        best = std::min(best, std::max(spec.pins.y_min - rest(1, v), rest(1, v) - spec.pins.y_max));
      nearest = "; its nearest vertex is " + metres(best) + " " +
                (hi.y() < spec.pins.y_min   ? "below the band"
                 : lo.y() > spec.pins.y_max ? "above the band"
                                            : "outside the band (the band falls between rows)");
      break;
    }
    case PinRuleKind::BoneDistance: {
      rule = "distance " + metres(spec.pins.distance) + " of bone '" + spec.pins.bone + "'";
      const int j = skeleton.find(spec.pins.bone);
      if (j >= 0) {
        const Eigen::Vector3d a = bind[j].position;
        const auto kids = skeleton.children(j);
        const Eigen::Vector3d b = !kids.empty() ? bind[kids.front()].position
                                  : skeleton.end_site[j]
                                      ? point_in_joint(bind[j], *skeleton.end_site[j])
                                      : a;
        double best = std::numeric_limits<double>::infinity();
        for (Eigen::Index v = 0; v < rest.cols(); ++v)
          best = std::min(best, (rest.col(v) - closest_on_segment(rest.col(v), a, b)).norm());
        nearest = "; its nearest vertex is " + metres(best) + " from the bone";
      }
      break;
    }
  }
  return spec.file + ": the pin rule (" + rule +
         ") matches no vertex (0 pins): the garment spans " + vec(lo) + " .. " + vec(hi) +
         " m in the skeleton's rest pose" + nearest;
}

}  // namespace clothdb
