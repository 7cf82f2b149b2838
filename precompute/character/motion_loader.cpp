#include "character/motion_loader.hpp"

#include <assimp/config.h>
#include <assimp/scene.h>
#include <assimp/version.h>

#include <algorithm>
#include <assimp/Importer.hpp>
#include <cctype>
#include <cmath>
#include <fstream>
#include <limits>
#include <map>
#include <stdexcept>

namespace clothdb {

const char* up_axis_name(UpAxis axis) {
  switch (axis) {
    case UpAxis::X:
      return "x";
    case UpAxis::Y:
      return "y";
    case UpAxis::Z:
      return "z";
  }
  return "?";
}

UpAxis parse_up_axis(const std::string& text) {
  std::string t = text;
  std::transform(t.begin(), t.end(), t.begin(), [](unsigned char c) { return std::tolower(c); });
  if (t == "x") return UpAxis::X;
  if (t == "y") return UpAxis::Y;
  if (t == "z") return UpAxis::Z;
  throw std::invalid_argument("unknown up axis '" + text + "' (expected x, y or z)");
}

Eigen::Matrix3d up_axis_rotation(UpAxis axis) {
  Eigen::Matrix3d r;
  switch (axis) {
    case UpAxis::Y:
      r.setIdentity();
      break;
    case UpAxis::Z:  // -90 degrees about x: (x, y, z) -> (x, z, -y)
      r << 1, 0, 0, 0, 0, 1, 0, -1, 0;
      break;
    case UpAxis::X:  // +90 degrees about z: (x, y, z) -> (-y, x, z)
      r << 0, -1, 0, 1, 0, 0, 0, 0, 1;
      break;
  }
  return r;
}

namespace {

Eigen::Affine3d to_eigen(const aiMatrix4x4& m) {
  Eigen::Matrix4d e;
  e << m.a1, m.a2, m.a3, m.a4, m.b1, m.b2, m.b3, m.b4, m.c1, m.c2, m.c3, m.c4, m.d1, m.d2, m.d3,
      m.d4;
  Eigen::Affine3d a;
  a.matrix() = e;
  return a;
}

Eigen::Vector3d to_eigen(const aiVector3D& v) {
  return {v.x, v.y, v.z};
}
Eigen::Quaterniond to_eigen(const aiQuaternion& q) {
  return Eigen::Quaterniond(q.w, q.x, q.y, q.z).normalized();
}

// Rate printed with a few digits (BVH's "Frame Time: .0083333" is 1/120 rounded): snap to the
// integer when that close, so that 120 Hz -> 30 fps lands exactly on every fourth source frame.
double snap_rate(double rate) {
  const double r = std::round(rate);
  return r > 0 && std::abs(rate - r) <= 1e-4 * r ? r : rate;
}

// The local transform of one animated node at a tick: assimp's channel replaces the node's
// transformation entirely (translation * rotation * scaling); a track without keys keeps the
// node's rest component.
struct Track {
  const aiNodeAnim* channel = nullptr;
  Eigen::Vector3d rest_position, rest_scaling;
  Eigen::Quaterniond rest_rotation;
};

// Interval of keys around `tick`: index i of the key at or before it and the blend factor towards
// key i + 1 (0 at a key's exact time, so a sample on a key returns that key unchanged).
template <class Key>
std::pair<unsigned, double> bracket(const Key* keys, unsigned count, double tick) {
  if (count == 1 || tick <= keys[0].mTime) return {0u, 0.0};
  if (tick >= keys[count - 1].mTime) return {count - 1, 0.0};
  const Key* upper = std::upper_bound(keys, keys + count, tick,
                                      [](double t, const Key& k) { return t < k.mTime; });
  const unsigned i = static_cast<unsigned>(upper - keys) - 1;
  const double span = keys[i + 1].mTime - keys[i].mTime;
  return {i, span > 0 ? (tick - keys[i].mTime) / span : 0.0};
}

Eigen::Vector3d sample_vector(const aiVectorKey* keys, unsigned count, double tick,
                              const Eigen::Vector3d& fallback) {
  if (count == 0) return fallback;
  const auto [i, s] = bracket(keys, count, tick);
  const Eigen::Vector3d a = to_eigen(keys[i].mValue);
  if (s == 0.0) return a;
  return (1.0 - s) * a + s * to_eigen(keys[i + 1].mValue);
}

Eigen::Quaterniond sample_rotation(const aiQuatKey* keys, unsigned count, double tick,
                                   const Eigen::Quaterniond& fallback) {
  if (count == 0) return fallback;
  const auto [i, s] = bracket(keys, count, tick);
  const Eigen::Quaterniond a = to_eigen(keys[i].mValue);
  if (s == 0.0) return a;
  // Eigen's slerp takes the shorter arc, as key frames of one rotation may flip sign.
  return a.slerp(s, to_eigen(keys[i + 1].mValue)).normalized();
}

Eigen::Affine3d sample_track(const Track& track, double tick) {
  const aiNodeAnim* c = track.channel;
  Eigen::Affine3d t = Eigen::Affine3d::Identity();
  t.translate(sample_vector(c->mPositionKeys, c->mNumPositionKeys, tick, track.rest_position));
  t.rotate(sample_rotation(c->mRotationKeys, c->mNumRotationKeys, tick, track.rest_rotation));
  t.scale(sample_vector(c->mScalingKeys, c->mNumScalingKeys, tick, track.rest_scaling));
  return t;
}

template <class Key>
bool keys_valid(const Key* keys, unsigned count) {
  for (unsigned k = 0; k < count; ++k) {
    if (!std::isfinite(keys[k].mTime)) return false;
    if (k > 0 && keys[k].mTime < keys[k - 1].mTime) return false;
  }
  return true;
}

bool finite(const aiVectorKey& k) {
  return std::isfinite(k.mValue.x) && std::isfinite(k.mValue.y) && std::isfinite(k.mValue.z);
}
bool finite(const aiQuatKey& k) {
  return std::isfinite(k.mValue.w) && std::isfinite(k.mValue.x) && std::isfinite(k.mValue.y) &&
         std::isfinite(k.mValue.z);
}
template <class Key>
bool values_finite(const Key* keys, unsigned count) {
  for (unsigned k = 0; k < count; ++k)
    if (!finite(keys[k])) return false;
  return true;
}

// True when a channel never moves its node: no channel, or every key of each track equal to the
// track's first key.
bool channel_static(const aiNodeAnim* c) {
  if (!c) return true;
  constexpr double kTol = 1e-9;
  for (unsigned k = 1; k < c->mNumPositionKeys; ++k)
    if ((to_eigen(c->mPositionKeys[k].mValue) - to_eigen(c->mPositionKeys[0].mValue)).norm() >
        kTol * (1.0 + to_eigen(c->mPositionKeys[0].mValue).norm()))
      return false;
  for (unsigned k = 1; k < c->mNumRotationKeys; ++k)
    if (std::abs(to_eigen(c->mRotationKeys[k].mValue).dot(to_eigen(c->mRotationKeys[0].mValue))) <
        1.0 - kTol)
      return false;
  for (unsigned k = 1; k < c->mNumScalingKeys; ++k)
    if ((to_eigen(c->mScalingKeys[k].mValue) - to_eigen(c->mScalingKeys[0].mValue)).norm() > kTol)
      return false;
  return true;
}

// The local transform a static channel holds (its first keys; the node's own for a track without
// keys), as the channel replaces the node's transformation.
Eigen::Affine3d channel_value(const aiNodeAnim* c, const aiNode& node) {
  aiVector3D s, p;
  aiQuaternion r;
  node.mTransformation.Decompose(s, r, p);
  Eigen::Affine3d t = Eigen::Affine3d::Identity();
  t.translate(c->mNumPositionKeys ? to_eigen(c->mPositionKeys[0].mValue) : to_eigen(p));
  t.rotate(c->mNumRotationKeys ? to_eigen(c->mRotationKeys[0].mValue) : to_eigen(r));
  t.scale(c->mNumScalingKeys ? to_eigen(c->mScalingKeys[0].mValue) : to_eigen(s));
  return t;
}

// Frame count declared in a BVH header ("Frames: N"), or -1 if the header has none. assimp reads
// exactly that many frames and fails on a short file; checking it here as well keeps that
// guarantee independent of the assimp version.
int bvh_declared_frames(const std::filesystem::path& file) {
  std::ifstream in(file);
  std::string token;
  while (in >> token) {
    if (token == "Frames:") {
      long long n = -1;
      if (in >> n) return n >= 0 && n <= (1LL << 30) ? static_cast<int>(n) : -1;
      return -1;
    }
  }
  return -1;
}

std::string lower_extension(const std::filesystem::path& file) {
  std::string ext = file.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  return ext;
}

// Metadata helpers: assimp stores FBX's UnitScaleFactor as float or double depending on the file.
std::optional<double> meta_number(const aiScene* scene, const char* key) {
  if (!scene->mMetaData) return std::nullopt;
  const aiMetadata* md = scene->mMetaData;
  for (unsigned i = 0; i < md->mNumProperties; ++i) {
    if (std::string(md->mKeys[i].C_Str()) != key) continue;
    const aiMetadataEntry& e = md->mValues[i];
    switch (e.mType) {
      case AI_INT32:
        return *static_cast<const int32_t*>(e.mData);
      case AI_UINT64:
        return static_cast<double>(*static_cast<const uint64_t*>(e.mData));
      case AI_FLOAT:
        return *static_cast<const float*>(e.mData);
      case AI_DOUBLE:
        return *static_cast<const double*>(e.mData);
      default:
        return std::nullopt;
    }
  }
  return std::nullopt;
}

struct NodeInfo {
  const aiNode* node = nullptr;
  int parent = -1;  // index into the flattened node list
  bool joint = false;
};

void flatten(const aiNode* node, int parent, std::vector<NodeInfo>& out) {
  out.push_back({node, parent, false});
  const int self = static_cast<int>(out.size()) - 1;
  for (unsigned c = 0; c < node->mNumChildren; ++c) flatten(node->mChildren[c], self, out);
}

}  // namespace

LoadedMotion load_motion(const std::filesystem::path& file, const MotionLoadOptions& options) {
  const std::string where = file.string();
  auto fail = [&](const std::string& what) -> MotionError {
    return MotionError(where + ": " + what);
  };

  std::error_code ec;
  if (!std::filesystem::exists(file, ec)) throw fail("file not found");
  if (!std::filesystem::is_regular_file(file, ec)) throw fail("not a regular file");
  if (std::filesystem::file_size(file, ec) == 0) throw fail("empty file");

  Assimp::Importer importer;
  // No placeholder bone meshes for BVH, and FBX pivots collapsed into their node so that every
  // joint is one node (no "$AssimpFbx$" helpers between a bone and its parent).
  importer.SetPropertyBool(AI_CONFIG_IMPORT_NO_SKELETON_MESHES, true);
  importer.SetPropertyBool(AI_CONFIG_IMPORT_FBX_PRESERVE_PIVOTS, false);
  // No aiProcess_ValidateDataStructure: it rejects scenes without meshes, i.e. every BVH file
  // (and animation-only FBX); the channels used here are checked below instead.
  const aiScene* scene = importer.ReadFile(where, 0);
  if (!scene)
    throw fail(std::string("cannot read it (malformed or truncated): ") +
               importer.GetErrorString());
  if (!scene->mRootNode) throw fail("no skeleton: the file has no node hierarchy");

  // The animation: by name, or the first one that moves nodes.
  if (scene->mNumAnimations == 0) {
    unsigned bones = 0;
    for (unsigned m = 0; m < scene->mNumMeshes; ++m) bones += scene->mMeshes[m]->mNumBones;
    if (bones == 0)
      throw fail("no skeleton and no animation as read by assimp " +
                 std::to_string(aiGetVersionMajor()) + "." + std::to_string(aiGetVersionMinor()) +
                 ": if the file does hold a skeleton, this assimp cannot read it from this "
                 "format; convert it to BVH, glTF or FBX (e.g. in Blender)");
    throw fail("no animation: the file has a skinned mesh but no animation clips");
  }
  const aiAnimation* anim = nullptr;
  if (!options.animation.empty()) {
    std::string names;
    for (unsigned a = 0; a < scene->mNumAnimations; ++a) {
      const std::string n = scene->mAnimations[a]->mName.C_Str();
      if (n == options.animation) anim = scene->mAnimations[a];
      names += (names.empty() ? "'" : ", '") + n + "'";
    }
    if (!anim) throw fail("no animation named '" + options.animation + "' (it has " + names + ")");
  } else {
    for (unsigned a = 0; a < scene->mNumAnimations && !anim; ++a)
      if (scene->mAnimations[a]->mNumChannels > 0) anim = scene->mAnimations[a];
  }
  if (!anim || anim->mNumChannels == 0)
    throw fail(
        "no skeleton: its animation moves no nodes (only mesh or morph animation), so there are "
        "no joints to follow");

  // Joints: the animated nodes and the nodes skinned meshes name as bones, plus any node lying
  // between two of them so that the hierarchy has no gaps. Other nodes (meshes, cameras, BVH end
  // sites, the scene root) are not joints; those above a root joint become its static frame.
  std::vector<NodeInfo> nodes;
  flatten(scene->mRootNode, -1, nodes);
  std::map<std::string, int> by_name;
  std::map<const aiNode*, int> index_of;
  for (int i = 0; i < static_cast<int>(nodes.size()); ++i) {
    by_name.emplace(nodes[i].node->mName.C_Str(), i);
    index_of.emplace(nodes[i].node, i);
  }

  std::vector<const aiNodeAnim*> channel_of(nodes.size(), nullptr);
  for (unsigned c = 0; c < anim->mNumChannels; ++c) {
    const aiNodeAnim* ch = anim->mChannels[c];
    const std::string name = ch->mNodeName.C_Str();
    const auto it = by_name.find(name);
    if (it == by_name.end())
      throw fail("animation channel for node '" + name + "', which is not in the hierarchy");
    if (!keys_valid(ch->mPositionKeys, ch->mNumPositionKeys) ||
        !keys_valid(ch->mRotationKeys, ch->mNumRotationKeys) ||
        !keys_valid(ch->mScalingKeys, ch->mNumScalingKeys))
      throw fail("animation channel '" + name + "' has key times out of order");
    if (!values_finite(ch->mPositionKeys, ch->mNumPositionKeys) ||
        !values_finite(ch->mRotationKeys, ch->mNumRotationKeys) ||
        !values_finite(ch->mScalingKeys, ch->mNumScalingKeys))
      throw fail("animation channel '" + name + "' has non-finite values");
    channel_of[it->second] = ch;
    nodes[it->second].joint = true;
  }
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh* mesh = scene->mMeshes[m];
    for (unsigned b = 0; b < mesh->mNumBones; ++b) {
      const auto it = by_name.find(mesh->mBones[b]->mName.C_Str());
      if (it != by_name.end()) nodes[it->second].joint = true;
    }
  }
  // Gap filling: walking up from each joint, a joint ancestor marks everything in between.
  for (int i = static_cast<int>(nodes.size()) - 1; i >= 0; --i) {
    if (!nodes[i].joint) continue;
    int p = nodes[i].parent;
    while (p >= 0 && !nodes[p].joint) p = nodes[p].parent;
    if (p < 0) continue;
    for (int q = nodes[i].parent; q != p; q = nodes[q].parent) nodes[q].joint = true;
  }

  // A static root above the rig is not a joint: Blender's FBX exporter writes the armature object
  // as a node above the root bone and keys it (constant keys) with the bones, which would make it
  // the root joint of a skeleton whose root never moves (docs/guide/garment_placement.md, "Motion
  // from Blender"). Such a root, keyed or not but never moving, not a skinned bone, with exactly
  // one child joint, becomes part of the static frame above its child, as any non-joint ancestor.
  std::vector<char> skinned(nodes.size(), 0);
  for (unsigned m = 0; m < scene->mNumMeshes; ++m)
    for (unsigned b = 0; b < scene->mMeshes[m]->mNumBones; ++b) {
      const auto it = by_name.find(scene->mMeshes[m]->mBones[b]->mName.C_Str());
      if (it != by_name.end()) skinned[it->second] = 1;
    }
  std::vector<std::optional<Eigen::Affine3d>> static_local(nodes.size());
  for (bool demoted = true; demoted;) {
    demoted = false;
    for (int i = 0; i < static_cast<int>(nodes.size()) && !demoted; ++i) {
      if (!nodes[i].joint || skinned[i] || !channel_static(channel_of[i])) continue;
      int p = nodes[i].parent;
      while (p >= 0 && !nodes[p].joint) p = nodes[p].parent;
      if (p >= 0) continue;  // not a root joint
      int child_joints = 0;
      for (unsigned c = 0; c < nodes[i].node->mNumChildren; ++c)
        child_joints += nodes[index_of.at(nodes[i].node->mChildren[c])].joint ? 1 : 0;
      if (child_joints != 1) continue;
      nodes[i].joint = false;
      if (channel_of[i]) static_local[i] = channel_value(channel_of[i], *nodes[i].node);
      channel_of[i] = nullptr;
      demoted = true;
    }
  }

  // Unit scale and up axis. FBX declares both (UnitScaleFactor in centimetres per unit).
  double scale = 1.0;
  UpAxis up = UpAxis::Y;
  if (const auto unit = meta_number(scene, "UnitScaleFactor"); unit && *unit > 0)
    scale = *unit / 100.0;
  if (const auto axis = meta_number(scene, "UpAxis")) {
    const auto sign = meta_number(scene, "UpAxisSign");
    const int a = static_cast<int>(*axis);
    if (a >= 0 && a <= 2 && (!sign || *sign > 0)) up = static_cast<UpAxis>(a);
  }
  if (options.scale) scale = *options.scale;
  if (options.up_axis) up = *options.up_axis;
  if (!(scale > 0) || !std::isfinite(scale)) throw fail("scale must be a positive number");
  Eigen::Affine3d conversion = Eigen::Affine3d::Identity();
  conversion.linear() = scale * up_axis_rotation(up);

  // Skeleton, in depth-first order (parents before children, as in the file).
  std::vector<int> joint_of(nodes.size(), -1);
  std::vector<Eigen::Affine3d> static_world(nodes.size());  // file-frame world of non-joint nodes
  LoadedMotion out;
  Skeleton& sk = out.skeleton;
  sk.source = where;
  std::vector<int> joint_node;
  for (int i = 0; i < static_cast<int>(nodes.size()); ++i) {
    const NodeInfo& n = nodes[i];
    const Eigen::Affine3d local =
        static_local[i] ? *static_local[i] : to_eigen(n.node->mTransformation);
    const int p = n.parent;
    static_world[i] = p < 0 ? local : static_world[p] * local;
    if (!n.joint) continue;
    const int parent_joint = p >= 0 ? joint_of[p] : -1;
    joint_of[i] = sk.joint_count();
    joint_node.push_back(i);
    sk.names.push_back(n.node->mName.C_Str());
    sk.parents.push_back(parent_joint);
    if (parent_joint >= 0) {
      sk.rest_local.push_back(local);
    } else {
      const Eigen::Affine3d above = p >= 0 ? static_world[p] : Eigen::Affine3d::Identity();
      sk.rest_local.push_back(conversion * above * local);
    }
  }
  if (sk.joint_count() == 0) throw fail("no skeleton: no joints found");
  for (int j = 0; j < sk.joint_count(); ++j)
    for (int k = j + 1; k < sk.joint_count(); ++k)
      if (sk.names[j] == sk.names[k]) throw fail("two joints are both named '" + sk.names[j] + "'");

  // End sites: a leaf joint whose only child is an empty node (BVH's "End Site") marks where the
  // last bone of the chain ends. Stored in metres in the joint's frame.
  {
    std::vector<Eigen::Affine3d> rest_world(sk.joint_count());
    sk.end_site.assign(sk.joint_count(), std::nullopt);
    sk.end_site_from_file.assign(sk.joint_count(), false);
    for (int j = 0; j < sk.joint_count(); ++j) {
      const int p = sk.parents[j];
      rest_world[j] = p < 0 ? sk.rest_local[j] : rest_world[p] * sk.rest_local[j];
      const aiNode* node = nodes[joint_node[j]].node;
      if (node->mNumChildren != 1) continue;
      const aiNode* child = node->mChildren[0];
      if (nodes[index_of.at(child)].joint || child->mNumChildren > 0 || child->mNumMeshes > 0)
        continue;
      const double unit = std::cbrt(std::abs(rest_world[j].linear().determinant()));
      const aiMatrix4x4& m = child->mTransformation;
      const Eigen::Vector3d t(m.a4, m.b4, m.c4);
      sk.end_site[j] = unit * t;
      sk.end_site_from_file[j] = true;
    }
    // A leaf joint without an end site (glTF stores none; Blender's FBX has one only with "Add
    // Leaf Bones") gets one, so that the head, hands and feet get a capsule whatever the format.
    // Blender writes every bone's frame with +y along the bone (its head to its tail), and for a
    // BVH-imported leaf the tail is the BVH's End Site: in such a rig (every child offset along
    // its parent's +y) the leaf's own +y is the direction the BVH had, and only the length is
    // lost. Elsewhere the parent bone is continued. The length is the parent bone's in both cases
    // (the head's end on CMU's rig is 0.100 m against 0.0998 m for the neck:
    // docs/guide/garment_placement.md, "Motion from Blender").
    bool bone_axes = false;
    for (int j = 0; j < sk.joint_count(); ++j) {
      const int p = sk.parents[j];
      if (p < 0) continue;
      const Eigen::Vector3d t = sk.rest_local[j].translation();
      // A joint on its parent (CMU's Neck, LeftShoulder: a few 1e-9 m of float noise in glTF).
      if (t.norm() < 1e-6) continue;
      bone_axes =
          std::abs(t.x()) <= 1e-4 * t.norm() && std::abs(t.z()) <= 1e-4 * t.norm() && t.y() > 0;
      if (!bone_axes) break;
    }
    for (int j = 0; j < sk.joint_count(); ++j) {
      const int p = sk.parents[j];
      if (sk.end_site[j] || p < 0 || !sk.children(j).empty()) continue;
      const Eigen::Vector3d bone = rest_world[j].translation() - rest_world[p].translation();
      if (bone.norm() < 1e-6) continue;
      const Eigen::Matrix3d frame = pose_from_affine(rest_world[j]).rotation.toRotationMatrix();
      sk.end_site[j] = bone_axes ? Eigen::Vector3d(0, bone.norm(), 0)
                                 : Eigen::Vector3d(frame.transpose() * bone);
    }
  }

  // Timing. assimp's ticks are frames for BVH and FBX (ticks per second = frame rate) and
  // milliseconds for glTF and Collada; there the key times give the frame rate. Source frame 0 is
  // the first key: Blender's glTF exporter writes frame f at f / fps seconds, so its first key
  // (frame 1 of the scene) is at 1 / fps, not 0 (docs/guide/garment_placement.md, "Motion from
  // Blender").
  const double tps = anim->mTicksPerSecond > 0 ? anim->mTicksPerSecond : 25.0;
  double max_tick = 0.0, min_spacing = 0.0;
  double first_tick = std::numeric_limits<double>::infinity();  // of tracks with 2+ keys
  double first_any = std::numeric_limits<double>::infinity();   // of every track
  for (unsigned c = 0; c < anim->mNumChannels; ++c) {
    const aiNodeAnim* ch = anim->mChannels[c];
    auto scan = [&](auto* keys, unsigned count) {
      if (count > 0) first_any = std::min(first_any, keys[0].mTime);
      if (count > 1) first_tick = std::min(first_tick, keys[0].mTime);
      for (unsigned k = 0; k < count; ++k) {
        max_tick = std::max(max_tick, keys[k].mTime);
        const double d = k > 0 ? keys[k].mTime - keys[k - 1].mTime : 0.0;
        if (d > 1e-9 && (min_spacing == 0.0 || d < min_spacing)) min_spacing = d;
      }
    };
    scan(ch->mPositionKeys, ch->mNumPositionKeys);
    scan(ch->mRotationKeys, ch->mNumRotationKeys);
    scan(ch->mScalingKeys, ch->mNumScalingKeys);
  }
  if (!std::isfinite(first_tick)) first_tick = std::isfinite(first_any) ? first_any : 0.0;
  // Only a later start is honoured: tracks keyed before 0 are sampled from 0, as before.
  first_tick = std::max(first_tick, 0.0);
  const double span = std::max(0.0, max_tick - first_tick);
  double ticks_per_frame = tps <= 480.0 || min_spacing == 0.0 ? 1.0 : min_spacing;
  // Key times written in single precision (Collada, glTF) make the smallest spacing a little off
  // the true one, and the error grows with the time: Blender's glTF of 01_03 (37.5 s) has a
  // smallest spacing of 8.328 ms for 8.333, so the span over it counts 4,503 frames for 4,500 and
  // reads 120.08 Hz. The number of distinct key times over all tracks counts the frames exactly
  // when every frame is keyed somewhere (baked files); the span from the first key to the last
  // divided by it gives the spacing to the precision of the last key. Otherwise (keys thinned
  // out), the span over the smallest spacing, rounded.
  if (ticks_per_frame != 1.0 && span > 0) {
    std::vector<double> times;
    for (unsigned c = 0; c < anim->mNumChannels; ++c) {
      const aiNodeAnim* ch = anim->mChannels[c];
      for (unsigned k = 0; k < ch->mNumPositionKeys; ++k)
        times.push_back(ch->mPositionKeys[k].mTime);
      for (unsigned k = 0; k < ch->mNumRotationKeys; ++k)
        times.push_back(ch->mRotationKeys[k].mTime);
      for (unsigned k = 0; k < ch->mNumScalingKeys; ++k) times.push_back(ch->mScalingKeys[k].mTime);
    }
    std::sort(times.begin(), times.end());
    int distinct = 0;
    double last_time = -std::numeric_limits<double>::infinity();
    for (double t : times)
      if (t >= first_tick && t - last_time > 0.25 * min_spacing) ++distinct, last_time = t;
    const double by_count = distinct > 1 ? span / (distinct - 1) : 0.0;
    ticks_per_frame = by_count > 0 && std::abs(by_count / min_spacing - 1.0) < 0.01
                          ? by_count
                          : span / std::max(1.0, std::round(span / ticks_per_frame));
  }
  const double native_rate = snap_rate(tps / ticks_per_frame);
  const int source_frames = static_cast<int>(std::floor(span / ticks_per_frame + 1e-6)) + 1;

  if (lower_extension(file) == ".bvh") {
    const int declared = bvh_declared_frames(file);
    if (declared <= 0) throw fail("no animation: the BVH header declares no frames");
    if (declared != source_frames)
      throw fail("truncated or inconsistent: the header says Frames: " + std::to_string(declared) +
                 " but " + std::to_string(source_frames) + " frames of motion were read");
  }

  const double source_rate = options.source_rate.value_or(native_rate);
  if (!(source_rate > 0) || !std::isfinite(source_rate))
    throw fail("source rate must be a positive number");
  const double output_rate = options.output_rate > 0 ? options.output_rate : source_rate;
  const int first = options.first_frame;
  const int last = options.last_frame < 0 ? source_frames - 1 : options.last_frame;
  if (first < 0 || first > last || last >= source_frames)
    throw fail("frame range " + std::to_string(first) + ".." + std::to_string(last) +
               " is outside the file's " + std::to_string(source_frames) + " frames (0.." +
               std::to_string(source_frames - 1) + ")");

  // Output frame k samples source frame first + k * step (fractional frames blend two keys).
  const double step = source_rate / output_rate;
  const int frame_count = static_cast<int>(std::floor((last - first) / step + 1e-9)) + 1;

  std::vector<Track> tracks(sk.joint_count());
  for (int j = 0; j < sk.joint_count(); ++j) {
    const aiNode* node = nodes[joint_node[j]].node;
    tracks[j].channel = channel_of[joint_node[j]];
    aiVector3D s, p;
    aiQuaternion r;
    node->mTransformation.Decompose(s, r, p);
    tracks[j].rest_position = to_eigen(p);
    tracks[j].rest_rotation = to_eigen(r);
    tracks[j].rest_scaling = to_eigen(s);
  }
  // Roots' static frames (non-joint ancestors, then the unit/up conversion).
  std::vector<Eigen::Affine3d> root_frame(sk.joint_count(), Eigen::Affine3d::Identity());
  for (int j = 0; j < sk.joint_count(); ++j) {
    const int p = nodes[joint_node[j]].parent;
    if (sk.parents[j] < 0)
      root_frame[j] = conversion * (p >= 0 ? static_world[p] : Eigen::Affine3d::Identity());
  }

  MotionClip& clip = out.clip;
  clip.name = options.name.empty() ? file.stem().string() : options.name;
  clip.source = where;
  clip.rate = output_rate;
  clip.frame_count = frame_count;
  clip.joint_count = sk.joint_count();
  clip.source_rate = source_rate;
  clip.first_source_frame = first;
  clip.source_frame_count = source_frames;
  clip.scale = scale;
  clip.positions.resize(static_cast<size_t>(frame_count) * clip.joint_count);
  clip.rotations.resize(clip.positions.size());
  std::vector<Eigen::Affine3d> world(sk.joint_count());
  for (int k = 0; k < frame_count; ++k) {
    const double tick = first_tick + (first + k * step) * ticks_per_frame;
    for (int j = 0; j < sk.joint_count(); ++j) {
      const Eigen::Affine3d local = tracks[j].channel
                                        ? sample_track(tracks[j], tick)
                                        : to_eigen(nodes[joint_node[j]].node->mTransformation);
      const int p = sk.parents[j];
      world[j] = p < 0 ? root_frame[j] * local : world[p] * local;
      const JointPose pose = pose_from_affine(world[j]);
      const size_t e = static_cast<size_t>(k) * clip.joint_count + j;
      clip.positions[e] = pose.position;
      clip.rotations[e] = pose.rotation;
    }
  }
  return out;
}

}  // namespace clothdb
