#include "garment/garment.hpp"

#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <algorithm>
#include <assimp/Importer.hpp>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <map>
#include <set>

#include "character/body.hpp"
#include "database/format/artist_mesh.hpp"
#include "exchange/point_cache.hpp"
#include "garment/placement.hpp"

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
  const double t =
      ab.squaredNorm() > 1e-18 ? std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
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

// Garment geometry checks at load (docs/GUIDE.md#limits): damage and unit mistakes are reported
// against the file, not found later as a blank preview or a solver blow-up.
constexpr double kMaxGarmentExtent = 20.0;    // m: bounding-box diagonal of any plausible garment
constexpr double kNeedleQuality = 0.01;       // 2 area / longest edge^2 (equilateral: 0.87)
constexpr double kSeamFactor = 5.0;           // open seams: gaps up to this many weld tolerances
constexpr double kWeldRefuseFraction = 0.25;  // of distinct positions merged by the weld
constexpr double kWeldWarnFraction = 0.02;

std::string vec_text(const Vec3& p) {
  char b[96];
  std::snprintf(b, sizeof b, "(%g, %g, %g)", p.x(), p.y(), p.z());
  return b;
}

std::string id_list(const std::vector<size_t>& ids) {
  std::string out;
  for (size_t i = 0; i < ids.size() && i < 10; ++i) out += (i ? ", " : "") + std::to_string(ids[i]);
  if (ids.size() > 10) out += ", ... (" + std::to_string(ids.size()) + " in all)";
  return out;
}

// Before welding: every coordinate finite and the whole inside a plausible garment size.
void check_points(const Eigen::Matrix3Xd& points, const MeshGarmentSpec& spec) {
  for (Eigen::Index v = 0; v < points.cols(); ++v)
    if (!points.col(v).allFinite())
      throw GarmentError(spec.file + ": a vertex has a non-finite coordinate " +
                         vec_text(points.col(v)) + ": the file is damaged");
  if (points.cols() == 0) return;
  const Vec3 lo = points.rowwise().minCoeff(), hi = points.rowwise().maxCoeff();
  const double extent = (hi - lo).norm();
  if (extent > kMaxGarmentExtent) {
    // The vertex farthest from the median point: the stray one, not one of the main body.
    Vec3 median;
    for (int k = 0; k < 3; ++k) {
      std::vector<double> c;
      for (Eigen::Index v = 0; v < points.cols(); ++v) c.push_back(points(k, v));
      std::nth_element(c.begin(), c.begin() + long(c.size() / 2), c.end());
      median[k] = c[c.size() / 2];
    }
    Eigen::Index far = 0;
    (points.colwise() - median).colwise().norm().maxCoeff(&far);
    char b[160];
    std::snprintf(b, sizeof b, "%g m across (at most %g m is plausible; garment.scale is %g)",
                  extent, kMaxGarmentExtent, spec.scale);
    // Positions, not indices: the importer's vertex order need not be the file's.
    throw GarmentError(spec.file + ": the garment is " + b + "; a vertex is at " +
                       vec_text(points.col(far)) +
                       " m: fix the file or set garment.scale to its units");
  }
}

// Before welding: the weld should merge duplicates (seams, per-face vertices), not distinct points
// of the garment. Counts distinct positions that have another within the tolerance (a sweep along
// x), stopping once the refusal threshold is passed.
void check_weld(const Eigen::Matrix3Xd& points, const MeshGarmentSpec& spec) {
  std::vector<std::array<double, 3>> distinct;
  distinct.reserve(size_t(points.cols()));
  for (Eigen::Index v = 0; v < points.cols(); ++v)
    distinct.push_back({points(0, v), points(1, v), points(2, v)});
  std::sort(distinct.begin(), distinct.end());
  distinct.erase(std::unique(distinct.begin(), distinct.end()), distinct.end());
  const double tol = spec.weld_tolerance;
  const size_t refuse = size_t(kWeldRefuseFraction * double(distinct.size()));
  std::vector<char> merged(distinct.size(), 0);
  size_t count = 0;
  for (size_t i = 0; i < distinct.size() && count <= refuse; ++i)
    for (size_t j = i + 1; j < distinct.size() && distinct[j][0] - distinct[i][0] <= tol; ++j) {
      const double dx = distinct[j][0] - distinct[i][0], dy = distinct[j][1] - distinct[i][1],
                   dz = distinct[j][2] - distinct[i][2];
      if (dx * dx + dy * dy + dz * dz > tol * tol) continue;
      count += !merged[i] + !merged[j];
      merged[i] = merged[j] = 1;
    }
  const double fraction = double(count) / double(std::max<size_t>(distinct.size(), 1));
  if (fraction <= kWeldWarnFraction) return;
  char b[200];
  std::snprintf(b, sizeof b,
                "garment.weld_tolerance %g m merges %s%.1f%% of the %zu distinct vertex positions",
                tol, count > refuse ? "over " : "", 100 * fraction, distinct.size());
  if (count > refuse)
    throw GarmentError(spec.file + ": " + b + " (at most " +
                       std::to_string(int(100 * kWeldRefuseFraction)) +
                       "%): it would change the garment's shape; lower it");
  std::fprintf(stderr, "%s: warning: %s\n", spec.file.c_str(), b);
}

// After welding: no degenerate or needle triangles, and a warning for seams left open by a gap
// just above the weld tolerance.
void check_welded(const ClothMesh& mesh, const MeshGarmentSpec& spec) {
  std::vector<size_t> degenerate, needles;
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& tri = mesh.triangles[t];
    const Vec3 a = mesh.rest.col(tri[0]), b = mesh.rest.col(tri[1]), c = mesh.rest.col(tri[2]);
    const double area2 = (b - a).cross(c - a).norm();
    const double longest = std::max({(b - a).norm(), (c - b).norm(), (a - c).norm()});
    if (!(area2 > 0) || !(longest > 0))
      degenerate.push_back(t);
    else if (area2 / (longest * longest) < kNeedleQuality)
      needles.push_back(t);
  }
  if (!degenerate.empty() || !needles.empty()) {
    char b[64];
    std::snprintf(b, sizeof b, "%g", kNeedleQuality);
    std::string msg = spec.file + ":";
    if (!degenerate.empty())
      msg += " degenerate (zero-area) triangles " + id_list(degenerate) + ";";
    if (!needles.empty())
      msg += " needle triangles " + id_list(needles) + " (2 area / longest edge^2 < " + b +
             "): they stretch without bound in simulation;";
    throw GarmentError(msg +
                       " fix them in the file, or collapse their short edges with a "
                       "larger garment.weld_tolerance (triangle ids after welding)");
  }
  // Open seams: boundary vertices within a few weld tolerances of another boundary vertex.
  std::map<std::pair<int, int>, int> uses;
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) {
      const int a = t[size_t(k)], b = t[size_t((k + 1) % 3)];
      ++uses[{std::min(a, b), std::max(a, b)}];
    }
  std::vector<std::array<int, 2>> boundary;
  std::vector<int> on_boundary;
  for (const auto& [e, n] : uses)
    if (n == 1) {
      boundary.push_back({e.first, e.second});
      on_boundary.push_back(e.first);
      on_boundary.push_back(e.second);
    }
  std::sort(on_boundary.begin(), on_boundary.end());
  on_boundary.erase(std::unique(on_boundary.begin(), on_boundary.end()), on_boundary.end());
  if (on_boundary.size() > 20000) return;  // the pairwise search below is for garment sizes
  const double reach = kSeamFactor * std::max(spec.weld_tolerance, 1e-9);
  std::set<int> near_partner;
  double closest = std::numeric_limits<double>::infinity();
  std::vector<int> order = on_boundary;
  std::sort(order.begin(), order.end(),
            [&](int a, int b) { return mesh.rest(0, a) < mesh.rest(0, b); });
  for (size_t i = 0; i < order.size(); ++i)
    for (size_t j = i + 1;
         j < order.size() && mesh.rest(0, order[j]) - mesh.rest(0, order[i]) <= reach; ++j) {
      const double d = (mesh.rest.col(order[i]) - mesh.rest.col(order[j])).norm();
      if (d <= reach && !uses.count({std::min(order[i], order[j]), std::max(order[i], order[j])})) {
        near_partner.insert(order[i]);
        near_partner.insert(order[j]);
        closest = std::min(closest, d);
      }
    }
  if (near_partner.empty()) return;
  double length = 0;  // of the seam: half the open boundary on its two sides
  for (const auto& e : boundary)
    if (near_partner.count(e[0]) && near_partner.count(e[1]))
      length += 0.5 * (mesh.rest.col(e[0]) - mesh.rest.col(e[1])).norm();
  std::fprintf(stderr,
               "%s: warning: an open seam: %zu boundary vertices lie within %g x "
               "garment.weld_tolerance (%g m) of another boundary vertex (closest gap %.3g mm, "
               "seam length %.3g m); if they belong together raise garment.weld_tolerance above "
               "the gap\n",
               spec.file.c_str(), near_partner.size(), kSeamFactor, spec.weld_tolerance,
               1e3 * closest, length);
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
  const double drop =
      std::sqrt(std::max(spec.length * spec.length - (hem - waist) * (hem - waist), 1e-6));
  // Square-ish cells: columns / rows = mean circumference / length.
  const double circumference = kPi * (waist + hem);
  const int columns = std::max(
      8, static_cast<int>(std::lround(std::sqrt(spec.vertices * circumference / spec.length))));
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
    throw GarmentError(skeleton.source +
                       ": cape: cannot find two upper-arm bones for the shoulders");
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
      const Vec3 tip = kids.empty()
                           ? (skeleton.end_site[j] ? point_in_joint(bind[j], *skeleton.end_site[j])
                                                   : bind[j].position)
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
  const double back =
      spec.back_offset > 0 ? spec.back_offset : default_radius(BodyRegion::Torso, size) + 0.03;
  if (spec.vertices < 16 || spec.length <= 0)
    throw GarmentError("cape: vertices must be >= 16, length positive");
  const int columns =
      std::max(4, static_cast<int>(std::lround(std::sqrt(spec.vertices * width / spec.length))));
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

namespace {

// The artist's mesh of an OBJ, as given (exchange/point_cache.hpp reads it): assimp's OBJ importer
// makes one vertex per face corner, which loses the file's vertex order.
db::ArtistMesh read_artist_obj(const MeshGarmentSpec& spec,
                               std::vector<std::vector<std::string>>* vertex_groups) {
  ObjMesh obj;
  try {
    obj = read_obj(spec.file);
  } catch (const ExchangeError& e) {
    throw GarmentError(std::string("cannot read the garment: ") + e.what());
  }
  db::ArtistMesh a;
  a.positions = std::move(obj.positions);
  a.face_sizes = std::move(obj.face_sizes);
  a.corners = std::move(obj.corners);
  a.uvs = std::move(obj.uvs);
  a.corner_uvs = std::move(obj.corner_uvs);
  a.normals = std::move(obj.normals);
  a.corner_normals = std::move(obj.corner_normals);
  // A face group (`g` or `o`, with or without its own material) is a vertex group of the
  // vertices its faces use.
  vertex_groups->assign(a.vertex_count(), {});
  std::vector<uint32_t> face_start(a.face_sizes.size() + 1, 0);
  for (size_t f = 0; f < a.face_sizes.size(); ++f)
    face_start[f + 1] = face_start[f] + a.face_sizes[f];
  for (ObjGroup& g : obj.face_groups) {
    for (uint32_t f : g.faces)
      for (uint32_t c = face_start[f]; c < face_start[f + 1]; ++c) {
        auto& names = (*vertex_groups)[a.corners[c]];
        if (std::find(names.begin(), names.end(), g.name) == names.end()) names.push_back(g.name);
      }
    a.groups.push_back({std::move(g.name), std::move(g.material), std::move(g.faces)});
  }
  return a;
}

// glTF, FBX and the rest through assimp, without triangulation (faces as given) and with identical
// vertices joined (FBX gives one per corner); its vertices are already split where UVs or normals
// differ, so corners name UVs and normals by vertex.
db::ArtistMesh read_artist_assimp(const MeshGarmentSpec& spec,
                                  std::vector<std::vector<std::string>>* vertex_groups) {
  Assimp::Importer importer;
  const aiScene* scene = importer.ReadFile(
      spec.file, aiProcess_PreTransformVertices | aiProcess_JoinIdenticalVertices);
  if (!scene || !scene->mRootNode)
    throw GarmentError(spec.file + ": cannot read the garment: " + importer.GetErrorString());
  bool any_uv = false, any_normal = false;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    any_uv |= scene->mMeshes[m]->HasTextureCoords(0);
    any_normal |= scene->mMeshes[m]->HasNormals();
  }
  db::ArtistMesh a;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh* mesh = scene->mMeshes[m];
    const uint32_t base = a.vertex_count();
    for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
      const aiVector3D& p = mesh->mVertices[v];
      a.positions.insert(a.positions.end(), {p.x, p.y, p.z});
      if (any_uv) {
        const aiVector3D t = mesh->HasTextureCoords(0) ? mesh->mTextureCoords[0][v] : aiVector3D();
        a.uvs.insert(a.uvs.end(), {t.x, t.y});
      }
      if (any_normal) {
        const aiVector3D n = mesh->HasNormals() ? mesh->mNormals[v] : aiVector3D();
        a.normals.insert(a.normals.end(), {n.x, n.y, n.z});
      }
      vertex_groups->push_back({mesh->mName.C_Str()});
    }
    for (unsigned b = 0; b < mesh->mNumBones; ++b)
      for (unsigned w = 0; w < mesh->mBones[b]->mNumWeights; ++w)
        if (mesh->mBones[b]->mWeights[w].mWeight > 0.5f)
          (*vertex_groups)[base + mesh->mBones[b]->mWeights[w].mVertexId].push_back(
              mesh->mBones[b]->mName.C_Str());
    aiString material;
    if (mesh->mMaterialIndex < scene->mNumMaterials)
      scene->mMaterials[mesh->mMaterialIndex]->Get(AI_MATKEY_NAME, material);
    db::ArtistGroup group{mesh->mName.C_Str(), material.C_Str(), {}};
    for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
      const aiFace& face = mesh->mFaces[f];
      if (face.mNumIndices < 3) continue;  // points and lines
      group.faces.push_back(a.face_count());
      a.face_sizes.push_back(face.mNumIndices);
      for (unsigned k = 0; k < face.mNumIndices; ++k) {
        const uint32_t v = base + face.mIndices[k];
        a.corners.push_back(v);
        if (any_uv) a.corner_uvs.push_back(mesh->HasTextureCoords(0) ? v : db::kNoAttribute);
        if (any_normal) a.corner_normals.push_back(mesh->HasNormals() ? v : db::kNoAttribute);
      }
    }
    a.groups.push_back(std::move(group));
  }
  return a;
}

}  // namespace

Garment import_garment(const Skeleton& skeleton, const MeshGarmentSpec& spec) {
  std::error_code ec;
  if (std::filesystem::is_directory(spec.file, ec))
    throw GarmentError(spec.file + ": is a directory, not a garment mesh file");
  if (!std::filesystem::exists(spec.file))
    throw GarmentError(spec.file + ": garment file not found");
  std::string ext = std::filesystem::path(spec.file).extension().string();
  for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  std::vector<std::vector<std::string>> group;  // per artist vertex: its vertex groups
  db::ArtistMesh artist =
      ext == ".obj" ? read_artist_obj(spec, &group) : read_artist_assimp(spec, &group);
  artist.source = spec.file;
  for (float& x : artist.positions) x = float(spec.scale * x);
  db::derive_render_mesh(&artist);
  const std::vector<uint32_t> fan = db::artist_triangles(artist);
  if (fan.empty()) throw GarmentError(spec.file + ": the garment has no triangles");
  Eigen::Matrix3Xd points(3, artist.vertex_count());
  for (uint32_t v = 0; v < artist.vertex_count(); ++v)
    points.col(v) =
        Vec3(artist.positions[3 * v], artist.positions[3 * v + 1], artist.positions[3 * v + 2]);
  std::vector<std::array<int, 3>> triangles(fan.size() / 3);
  for (size_t t = 0; t < triangles.size(); ++t)
    triangles[t] = {int(fan[3 * t]), int(fan[3 * t + 1]), int(fan[3 * t + 2])};
  check_points(points, spec);
  check_weld(points, spec);
  Garment g;
  g.name = std::filesystem::path(spec.file).stem().string();
  std::vector<int> old_to_new;
  try {
    g.mesh = weld_vertices(points, triangles, spec.weld_tolerance, &old_to_new);
  } catch (const MeshError& e) {
    throw GarmentError(spec.file + ": not a manifold triangle mesh: " + e.what());
  }
  check_welded(g.mesh, spec);
  // The map: each artist vertex is the simulation vertex the weld made of it.
  artist.map_vertices.resize(size_t(artist.vertex_count()) * 3);
  artist.map_weights.assign(size_t(artist.vertex_count()) * 3, 0.0f);
  for (uint32_t v = 0; v < artist.vertex_count(); ++v) {
    for (int k = 0; k < 3; ++k) artist.map_vertices[3 * v + k] = uint32_t(old_to_new[v]);
    artist.map_weights[3 * v] = 1.0f;
  }
  g.artist = std::move(artist);
  const std::vector<JointPose> bind = rest_pose(skeleton);
  const int bone = spec.bone.empty() ? -1 : skeleton.require(spec.bone);
  const int rule_bone =
      spec.pins.kind == PinRuleKind::BoneDistance ? skeleton.require(spec.pins.bone) : -1;
  std::vector<char> pinned(g.mesh.vertex_count(), 0);
  for (size_t old = 0; old < old_to_new.size(); ++old) {
    const int v = old_to_new[old];
    const Vec3 p = g.mesh.rest.col(v);
    bool hit = false;
    switch (spec.pins.kind) {
      case PinRuleKind::VertexGroup:
        hit = std::find(group[old].begin(), group[old].end(), spec.pins.group) != group[old].end();
        break;
      case PinRuleKind::HeightBand:
        hit = p.y() >= spec.pins.y_min && p.y() <= spec.pins.y_max;
        break;
      case PinRuleKind::BoneDistance:
        hit = bone_distance(skeleton, bind, rule_bone, p) <= spec.pins.distance;
        break;
    }
    if (hit) pinned[v] = 1;
  }
  for (int v = 0; v < g.mesh.vertex_count(); ++v) {
    if (!pinned[v]) continue;
    const int j =
        bone >= 0 ? bone
                  : (rule_bone >= 0 ? rule_bone : nearest_bone(skeleton, bind, g.mesh.rest.col(v)));
    g.pins.push_back(v);
    g.bindings.push_back({v, {{j, 1.0}}});
  }
  if (g.pins.empty()) throw GarmentError(unmatched_pins_message(skeleton, bind, g.mesh.rest, spec));
  // The garment is carried by the bone most of its pins follow.
  std::vector<int> votes(skeleton.joint_count(), 0);
  for (const auto& b : g.bindings) ++votes[b.weights.front().first];
  g.anchor_joint = static_cast<int>(std::max_element(votes.begin(), votes.end()) - votes.begin());
  return g;
}

db::ArtistMesh artist_mesh_of(const Garment& garment) {
  if (garment.artist.vertex_count() > 0) return garment.artist;
  db::Garment g;
  for (const auto& t : garment.mesh.triangles)
    for (int k = 0; k < 3; ++k) g.triangles.push_back(uint32_t(t[size_t(k)]));
  g.rest_positions.resize(size_t(garment.mesh.vertex_count()) * 3);
  for (int v = 0; v < garment.mesh.vertex_count(); ++v)
    for (int k = 0; k < 3; ++k)
      g.rest_positions[3 * size_t(v) + size_t(k)] = float(garment.mesh.rest(k, v));
  return db::identity_artist_mesh(g);
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
  const Eigen::Isometry3d motion =
      to_iso(pose[garment.anchor_joint]) * to_iso(bind[garment.anchor_joint]).inverse();
  Eigen::Matrix3Xd x = (motion.linear() * garment.mesh.rest).colwise() + motion.translation();
  const Eigen::Matrix3Xd pins = skin_pins(garment, bind, pose);
  for (size_t k = 0; k < garment.pins.size(); ++k)
    x.col(garment.pins[k]) = pins.col(static_cast<Eigen::Index>(k));
  return x;
}

}  // namespace clothdb
