#include "garment/garment.hpp"

#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>

#include "character/body.hpp"

namespace clothdb {

namespace {

constexpr double kPi = 3.14159265358979323846;

Eigen::Isometry3d to_iso(const JointPose& p) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = p.rotation.toRotationMatrix();
  t.translation() = p.position;
  return t;
}

// Distance from p to the bone segment from joint j to its first child (or the joint alone).
double bone_distance(const Skeleton& skeleton, const std::vector<JointPose>& pose, int j,
                     const Vec3& p) {
  const Vec3 a = pose[j].position;
  Vec3 b = a;
  const auto kids = skeleton.children(j);
  if (!kids.empty()) {
    b = pose[kids.front()].position;
  } else if (skeleton.end_site[j]) {
    b = point_in_joint(pose[j], *skeleton.end_site[j]);
  }
  const Vec3 ab = b - a;
  const double t = ab.squaredNorm() > 1e-18 ? std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

int nearest_bone(const Skeleton& skeleton, const std::vector<JointPose>& pose, const Vec3& p) {
  int best = 0;
  double best_d = std::numeric_limits<double>::infinity();
  for (int j = 0; j < skeleton.joint_count(); ++j) {
    const double d = bone_distance(skeleton, pose, j, p);
    if (d < best_d) best_d = d, best = j;
  }
  return best;
}

// A ring-shaped grid: `columns` around (wrapping) by `rows` down, quads split alternately.
void ring_triangles(ClothMesh& mesh, int columns, int rows) {
  for (int r = 0; r + 1 < rows; ++r)
    for (int c = 0; c < columns; ++c) {
      const int c1 = (c + 1) % columns;
      const int a = r * columns + c, b = r * columns + c1, d = (r + 1) * columns + c,
                e = (r + 1) * columns + c1;
      if ((r + c) % 2 == 0) {
        mesh.triangles.push_back({a, e, b});
        mesh.triangles.push_back({a, d, e});
      } else {
        mesh.triangles.push_back({a, d, b});
        mesh.triangles.push_back({b, d, e});
      }
    }
}

Garment pin_rows_to(Garment g, const std::vector<int>& pins, int joint) {
  g.pins = pins;
  g.anchor_joint = joint;
  for (int v : pins) g.bindings.push_back({v, {{joint, 1.0}}});
  return g;
}

}  // namespace

Garment make_skirt(const Skeleton& skeleton, const SkirtSpec& spec) {
  const int hips = skeleton.require(spec.bone);
  const std::vector<JointPose> bind = rest_pose(skeleton);
  const Vec3 centre = bind[hips].position + Vec3(0, spec.raise, 0);
  const double size = skeleton_size(skeleton);
  double waist = spec.waist_radius;
  if (waist <= 0.0) {
    // Wide enough to clear the thighs: the farthest thigh joint from the axis plus a thigh.
    double spread = 0.0;
    for (int j = 0; j < skeleton.joint_count(); ++j)
      if (classify_bone(skeleton, j) == BodyRegion::Thigh) {
        const Vec3 d = bind[j].position - bind[hips].position;
        spread = std::max(spread, std::hypot(d.x(), d.z()));
      }
    waist = spread + default_radius(BodyRegion::Thigh, size) + 0.02;
    if (spread == 0.0) waist = 0.16;
  }
  if (spec.vertices < 16 || spec.length <= 0 || spec.flare <= 0)
    throw GarmentError("skirt: vertices must be >= 16, length and flare positive");
  const double hem = waist * spec.flare;
  const double drop = std::sqrt(std::max(spec.length * spec.length - (hem - waist) * (hem - waist), 1e-6));
  // Square-ish cells: columns / rows = mean circumference / length.
  const double circumference = kPi * (waist + hem);
  const int columns = std::max(8, static_cast<int>(std::lround(std::sqrt(spec.vertices * circumference / spec.length))));
  const int rows = std::max(2, spec.vertices / columns);
  Garment g;
  g.name = "skirt";
  g.mesh.rest.resize(3, columns * rows);
  for (int r = 0; r < rows; ++r) {
    const double s = static_cast<double>(r) / (rows - 1);
    const double radius = waist + s * (hem - waist);
    for (int c = 0; c < columns; ++c) {
      const double phi = 2.0 * kPi * c / columns;
      g.mesh.rest.col(r * columns + c) =
          centre + Vec3(radius * std::sin(phi), -s * drop, radius * std::cos(phi));
    }
  }
  ring_triangles(g.mesh, columns, rows);
  build_topology(g.mesh);
  std::vector<int> waistband(columns);
  for (int c = 0; c < columns; ++c) waistband[c] = c;
  return pin_rows_to(std::move(g), waistband, hips);
}

Garment make_cape(const Skeleton& skeleton, const CapeSpec& spec) {
  const std::vector<JointPose> bind = rest_pose(skeleton);
  const double size = skeleton_size(skeleton);
  // The shoulders: the upper-arm joints (their start is the shoulder joint).
  std::vector<int> arms;
  for (int j = 0; j < skeleton.joint_count(); ++j)
    if (classify_bone(skeleton, j) == BodyRegion::UpperArm) arms.push_back(j);
  if (arms.size() < 2)
    throw GarmentError(skeleton.source + ": cape: cannot find two upper-arm bones for the shoulders");
  // The two upper arms farthest apart.
  int left = arms[0], right = arms[1];
  double span = 0;
  for (size_t i = 0; i < arms.size(); ++i)
    for (size_t k = i + 1; k < arms.size(); ++k) {
      const double d = (bind[arms[i]].position - bind[arms[k]].position).norm();
      if (d > span) span = d, left = arms[i], right = arms[k];
    }
  const Vec3 up(0, 1, 0);
  const Vec3 across = bind[left].position - bind[right].position;
  Vec3 forward = across.cross(up);
  // Which side is the front: the chest is in front of the line through the spine; the toes point
  // forward too. Use the feet (end sites below the ankles) when the skeleton has them.
  for (int j = 0; j < skeleton.joint_count(); ++j)
    if (classify_bone(skeleton, j) == BodyRegion::Foot) {
      const auto kids = skeleton.children(j);
      const Vec3 tip = kids.empty() ? (skeleton.end_site[j] ? point_in_joint(bind[j], *skeleton.end_site[j]) : bind[j].position)
                                    : bind[kids.front()].position;
      Vec3 toe = tip - bind[j].position;
      toe.y() = 0;
      if (toe.norm() > 1e-6 && toe.dot(forward) < 0) forward = -forward;
      break;
    }
  forward.normalize();
  const Vec3 mid = 0.5 * (bind[left].position + bind[right].position);
  int anchor = -1;
  if (!spec.bone.empty()) {
    anchor = skeleton.require(spec.bone);
  } else {
    double best = std::numeric_limits<double>::infinity();
    for (int j = 0; j < skeleton.joint_count(); ++j) {
      const BodyRegion r = classify_bone(skeleton, j);
      if (r != BodyRegion::Torso && r != BodyRegion::Neck) continue;
      const double d = (bind[j].position - mid).norm();
      if (d < best) best = d, anchor = j;
    }
    if (anchor < 0) anchor = skeleton.parents[left] >= 0 ? skeleton.parents[left] : left;
  }
  const double width = spec.width > 0 ? spec.width : span * 0.8 + 0.1;
  const double back = spec.back_offset > 0 ? spec.back_offset
                                           : default_radius(BodyRegion::Torso, size) + 0.03;
  if (spec.vertices < 16 || spec.length <= 0) throw GarmentError("cape: vertices must be >= 16, length positive");
  const int columns = std::max(4, static_cast<int>(std::lround(std::sqrt(spec.vertices * width / spec.length))));
  const int rows = std::max(2, spec.vertices / columns);
  const Vec3 side = across.normalized();
  const Vec3 top_centre = mid - back * forward;
  Garment g;
  g.name = "cape";
  g.mesh.rest.resize(3, columns * rows);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < columns; ++c) {
      const double u = static_cast<double>(c) / (columns - 1) - 0.5;
      const double s = static_cast<double>(r) / (rows - 1);
      g.mesh.rest.col(r * columns + c) = top_centre + u * width * side - s * spec.length * up;
    }
  g.mesh.grid_columns = columns;
  g.mesh.grid_rows = rows;
  for (int r = 0; r + 1 < rows; ++r)
    for (int c = 0; c + 1 < columns; ++c) {
      const int a = r * columns + c, b = a + 1, d = a + columns, e = d + 1;
      if ((r + c) % 2 == 0) {
        g.mesh.triangles.push_back({a, e, b});
        g.mesh.triangles.push_back({a, d, e});
      } else {
        g.mesh.triangles.push_back({a, d, b});
        g.mesh.triangles.push_back({b, d, e});
      }
    }
  build_topology(g.mesh);
  std::vector<int> collar(columns);
  for (int c = 0; c < columns; ++c) collar[c] = c;
  return pin_rows_to(std::move(g), collar, anchor);
}

Garment import_garment(const Skeleton& skeleton, const MeshGarmentSpec& spec) {
  if (!std::filesystem::exists(spec.file)) throw GarmentError(spec.file + ": garment file not found");
  Assimp::Importer importer;
  const aiScene* scene = importer.ReadFile(spec.file, aiProcess_Triangulate | aiProcess_PreTransformVertices);
  if (!scene || !scene->mRootNode)
    throw GarmentError(spec.file + ": cannot read the garment: " + importer.GetErrorString());
  Eigen::Matrix3Xd points(3, 0);
  std::vector<std::array<int, 3>> triangles;
  std::vector<std::string> group;  // per input vertex: its mesh's name
  std::vector<std::vector<std::string>> bone_groups;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh* mesh = scene->mMeshes[m];
    const int base = static_cast<int>(points.cols());
    points.conservativeResize(3, base + mesh->mNumVertices);
    for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
      const aiVector3D& p = mesh->mVertices[v];
      points.col(base + v) = spec.scale * Vec3(p.x, p.y, p.z);
      group.push_back(mesh->mName.C_Str());
      bone_groups.emplace_back();
    }
    for (unsigned b = 0; b < mesh->mNumBones; ++b)
      for (unsigned w = 0; w < mesh->mBones[b]->mNumWeights; ++w)
        if (mesh->mBones[b]->mWeights[w].mWeight > 0.5f)
          bone_groups[base + mesh->mBones[b]->mWeights[w].mVertexId].push_back(mesh->mBones[b]->mName.C_Str());
    for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
      const aiFace& face = mesh->mFaces[f];
      if (face.mNumIndices != 3) continue;  // points and lines
      triangles.push_back({base + static_cast<int>(face.mIndices[0]), base + static_cast<int>(face.mIndices[1]),
                           base + static_cast<int>(face.mIndices[2])});
    }
  }
  if (triangles.empty()) throw GarmentError(spec.file + ": the garment has no triangles");
  Garment g;
  g.name = std::filesystem::path(spec.file).stem().string();
  std::vector<int> old_to_new;
  try {
    g.mesh = weld_vertices(points, triangles, spec.weld_tolerance, &old_to_new);
  } catch (const MeshError& e) {
    throw GarmentError(spec.file + ": not a manifold triangle mesh: " + e.what());
  }
  const std::vector<JointPose> bind = rest_pose(skeleton);
  const int bone = spec.bone.empty() ? -1 : skeleton.require(spec.bone);
  const int rule_bone = spec.pins.kind == PinRuleKind::BoneDistance ? skeleton.require(spec.pins.bone) : -1;
  std::vector<char> pinned(g.mesh.vertex_count(), 0);
  for (size_t old = 0; old < old_to_new.size(); ++old) {
    const int v = old_to_new[old];
    const Vec3 p = g.mesh.rest.col(v);
    bool hit = false;
    switch (spec.pins.kind) {
      case PinRuleKind::VertexGroup:
        hit = group[old] == spec.pins.group ||
              std::find(bone_groups[old].begin(), bone_groups[old].end(), spec.pins.group) != bone_groups[old].end();
        break;
      case PinRuleKind::HeightBand: hit = p.y() >= spec.pins.y_min && p.y() <= spec.pins.y_max; break;
      case PinRuleKind::BoneDistance: hit = bone_distance(skeleton, bind, rule_bone, p) <= spec.pins.distance; break;
    }
    if (hit) pinned[v] = 1;
  }
  for (int v = 0; v < g.mesh.vertex_count(); ++v) {
    if (!pinned[v]) continue;
    const int j = bone >= 0 ? bone : (rule_bone >= 0 ? rule_bone : nearest_bone(skeleton, bind, g.mesh.rest.col(v)));
    g.pins.push_back(v);
    g.bindings.push_back({v, {{j, 1.0}}});
  }
  if (g.pins.empty()) {
    std::string rule = spec.pins.kind == PinRuleKind::VertexGroup ? "vertex group '" + spec.pins.group + "'"
                       : spec.pins.kind == PinRuleKind::HeightBand
                           ? "height band [" + std::to_string(spec.pins.y_min) + ", " + std::to_string(spec.pins.y_max) + "] m"
                           : "distance " + std::to_string(spec.pins.distance) + " m of bone '" + spec.pins.bone + "'";
    throw GarmentError(spec.file + ": the pin rule (" + rule + ") matches no vertex");
  }
  // The garment is carried by the bone most of its pins follow.
  std::vector<int> votes(skeleton.joint_count(), 0);
  for (const auto& b : g.bindings) ++votes[b.weights.front().first];
  g.anchor_joint = static_cast<int>(std::max_element(votes.begin(), votes.end()) - votes.begin());
  return g;
}

Eigen::Matrix3Xd skin_pins(const Garment& garment, const std::vector<JointPose>& bind,
                           const std::vector<JointPose>& pose) {
  Eigen::Matrix3Xd out(3, static_cast<Eigen::Index>(garment.bindings.size()));
  for (size_t k = 0; k < garment.bindings.size(); ++k) {
    const PinBinding& b = garment.bindings[k];
    const Vec3 rest = garment.mesh.rest.col(b.vertex);
    Vec3 p = Vec3::Zero();
    for (const auto& [joint, weight] : b.weights)
      p += weight * (to_iso(pose[joint]) * (to_iso(bind[joint]).inverse() * rest));
    out.col(static_cast<Eigen::Index>(k)) = p;
  }
  return out;
}

Eigen::Matrix3Xd carry_garment(const Garment& garment, const std::vector<JointPose>& bind,
                               const std::vector<JointPose>& pose) {
  const Eigen::Isometry3d motion = to_iso(pose[garment.anchor_joint]) * to_iso(bind[garment.anchor_joint]).inverse();
  Eigen::Matrix3Xd x = (motion.linear() * garment.mesh.rest).colwise() + motion.translation();
  const Eigen::Matrix3Xd pins = skin_pins(garment, bind, pose);
  for (size_t k = 0; k < garment.pins.size(); ++k) x.col(garment.pins[k]) = pins.col(static_cast<Eigen::Index>(k));
  return x;
}

}  // namespace clothdb
