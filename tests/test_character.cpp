// Characters from real motion files (Debian's assimp-testmodels: CMU 01_01, 01_03, Boxing_Toes):
// skeleton and frame counts against the BVH text, forward kinematics against the file's channels,
// resampling, slerp, body capsules, and the errors for bad files and manifests.
#include <assimp/config.h>
#include <assimp/scene.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <assimp/Exporter.hpp>
#include <assimp/Importer.hpp>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "character/body.hpp"
#include "character/manifest.hpp"
#include "character/motion_loader.hpp"
#include "support/temp_dir.hpp"

namespace fs = std::filesystem;
using namespace clothdb;

namespace {

constexpr double kCmuScale = 0.0564444;  // CMU units (1/0.45 inch) -> metres
constexpr double kPi = 3.14159265358979323846;

fs::path testmodel(const std::string& relative) {
  const fs::path dir = assimp_testmodels_dir();
  const fs::path file = dir / relative;
  EXPECT_TRUE(fs::exists(file)) << file << " missing: install Debian's assimp-testmodels";
  return file;
}

// Independent reading of a BVH file: the hierarchy (names, parents, offsets, channel orders) and
// every motion line, straight from the text.
struct BvhText {
  struct Joint {
    std::string name;
    int parent = -1;
    Eigen::Vector3d offset{0, 0, 0};
    std::vector<std::string> channels;
    int first_value = 0;  // index of its first channel value on a motion line
  };
  std::vector<Joint> joints;
  int declared_frames = -1;
  double frame_time = 0.0;
  std::vector<std::vector<double>> frames;
};

BvhText read_bvh(const fs::path& file) {
  BvhText bvh;
  std::ifstream in(file);
  std::string token;
  std::vector<int> stack;  // open joints; -2 marks an End Site block
  int pending = -1, values = 0;
  while (in >> token) {
    if (token == "ROOT" || token == "JOINT") {
      BvhText::Joint j;
      in >> j.name;
      int p = -1;
      for (auto it = stack.rbegin(); it != stack.rend(); ++it)
        if (*it >= 0) {
          p = *it;
          break;
        }
      j.parent = p;
      bvh.joints.push_back(j);
      pending = static_cast<int>(bvh.joints.size()) - 1;
    } else if (token == "End") {
      in >> token;  // "Site"
      pending = -2;
    } else if (token == "{") {
      stack.push_back(pending);
    } else if (token == "}") {
      stack.pop_back();
    } else if (token == "OFFSET") {
      Eigen::Vector3d o;
      in >> o.x() >> o.y() >> o.z();
      if (!stack.empty() && stack.back() >= 0) bvh.joints[stack.back()].offset = o;
    } else if (token == "CHANNELS") {
      int n = 0;
      in >> n;
      BvhText::Joint& j = bvh.joints[stack.back()];
      j.first_value = values;
      values += n;
      for (int c = 0; c < n; ++c) {
        in >> token;
        j.channels.push_back(token);
      }
    } else if (token == "MOTION") {
      break;
    }
  }
  in >> token >> bvh.declared_frames;      // "Frames:" N
  in >> token >> token >> bvh.frame_time;  // "Frame" "Time:" t
  std::string line;
  std::getline(in, line);
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    std::vector<double> v;
    double x;
    while (ls >> x) v.push_back(x);
    if (!v.empty()) bvh.frames.push_back(v);
  }
  return bvh;
}

// Header counts the way a person reads them: lines starting with ROOT or JOINT.
int count_joint_lines(const fs::path& file) {
  std::ifstream in(file);
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    std::string first;
    ls >> first;
    if (first == "ROOT" || first == "JOINT") ++n;
  }
  return n;
}

// Forward kinematics of one motion line, in the file's units and frame: local = translate(offset,
// or the position channels) * the rotations in channel order (BVH's convention).
std::vector<Eigen::Affine3d> bvh_world(const BvhText& bvh, int frame) {
  const std::vector<double>& line = bvh.frames[frame];
  std::vector<Eigen::Affine3d> world(bvh.joints.size());
  for (size_t j = 0; j < bvh.joints.size(); ++j) {
    const BvhText::Joint& joint = bvh.joints[j];
    Eigen::Vector3d t = joint.offset;
    Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
    for (size_t c = 0; c < joint.channels.size(); ++c) {
      const double v = line[joint.first_value + c];
      const std::string& ch = joint.channels[c];
      if (ch == "Xposition") t.x() = v;
      if (ch == "Yposition") t.y() = v;
      if (ch == "Zposition") t.z() = v;
      const double a = v * kPi / 180.0;
      if (ch == "Xrotation") r = r * Eigen::AngleAxisd(a, Eigen::Vector3d::UnitX()).matrix();
      if (ch == "Yrotation") r = r * Eigen::AngleAxisd(a, Eigen::Vector3d::UnitY()).matrix();
      if (ch == "Zrotation") r = r * Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).matrix();
    }
    Eigen::Affine3d local = Eigen::Affine3d::Identity();
    local.linear() = r;
    local.translation() = t;
    world[j] = joint.parent < 0 ? local : world[joint.parent] * local;
  }
  return world;
}

double angle_between(const Eigen::Quaterniond& a, const Eigen::Quaterniond& b) {
  return a.angularDistance(b);
}

struct RealFile {
  const char* path;
  double scale;
  int first_frame;  // frame 0 of the CMU files is the converter's calibration pose
};
const RealFile kRealFiles[] = {
    {"BVH/01_01.bvh", kCmuScale, 1},
    {"BVH/01_03.bvh", kCmuScale, 1},
    {"BVH/Boxing_Toes.bvh", 0.01, 0},
};

LoadedMotion load_at_source_rate(const fs::path& file, double scale, UpAxis up = UpAxis::Y) {
  MotionLoadOptions o;
  o.scale = scale;
  o.up_axis = up;
  return load_motion(file, o);
}

void write_text(const fs::path& file, const std::string& text) {
  std::ofstream(file) << text;
}

// Collada written by assimp 5.2's own exporter from a real BVH. Two defects of that exporter are
// worked around here, on the scene in memory, without changing the motion:
//  - ColladaExporter::WriteAnimationLibrary writes a channel's key sources only when it has as
//    many position and scaling keys as rotation keys, but writes its sampler and channel always.
//    The BVH importer gives a joint without position channels 1 position key and every joint 1
//    scaling key, so the file refers to sources it lacks and assimp's own importer refuses it
//    ("Unable to resolve library reference \"LHipJoint_matrix-input\""). Fix: repeat the constant
//    key at every rotation key's time.
//  - It writes key times in ticks (BVH ticks are frames) where Collada means seconds, so the
//    reloaded clip would play at 1 frame per second. Fix: times divided by ticks per second.
//  - It turns the scene's root node into the <visual_scene> and writes only its children; the
//    BVH's root is the animated Hips joint, which would vanish with its channel. Fix: a new,
//    still root node above it.
// The BVH is read without assimp's made-up skeleton mesh (as the motion loader reads it): with it
// the exported file would carry a skin whose bones include the 7 BVH end sites, and the reloaded
// skeleton would have those as 7 extra joints (38 instead of 31).
void export_collada(const fs::path& bvh, const fs::path& dae) {
  Assimp::Importer importer;
  importer.SetPropertyBool(AI_CONFIG_IMPORT_NO_SKELETON_MESHES, true);
  ASSERT_NE(importer.ReadFile(bvh.string(), 0), nullptr) << importer.GetErrorString();
  std::unique_ptr<aiScene> scene(importer.GetOrphanedScene());
  ASSERT_EQ(scene->mNumAnimations, 1u);
  aiAnimation* anim = scene->mAnimations[0];
  const double tps = anim->mTicksPerSecond;
  for (unsigned c = 0; c < anim->mNumChannels; ++c) {
    aiNodeAnim* ch = anim->mChannels[c];
    const unsigned n = ch->mNumRotationKeys;
    auto pad = [&](aiVectorKey*& keys, unsigned& count) {
      if (count == n) return;
      ASSERT_EQ(count, 1u) << ch->mNodeName.C_Str();
      auto* full = new aiVectorKey[n];
      for (unsigned k = 0; k < n; ++k)
        full[k] = aiVectorKey(ch->mRotationKeys[k].mTime, keys[0].mValue);
      delete[] keys;
      keys = full;
      count = n;
    };
    pad(ch->mPositionKeys, ch->mNumPositionKeys);
    pad(ch->mScalingKeys, ch->mNumScalingKeys);
    for (unsigned k = 0; k < n; ++k) {
      ch->mPositionKeys[k].mTime /= tps;
      ch->mRotationKeys[k].mTime /= tps;
      ch->mScalingKeys[k].mTime /= tps;
    }
  }
  anim->mDuration /= tps;
  anim->mTicksPerSecond = 1.0;
  auto* root = new aiNode("Scene");
  root->mNumChildren = 1;
  root->mChildren = new aiNode* [1] { scene->mRootNode };
  scene->mRootNode->mParent = root;
  scene->mRootNode = root;
  Assimp::Exporter exporter;
  ASSERT_EQ(exporter.Export(scene.get(), "collada", dae.string()), AI_SUCCESS)
      << exporter.GetErrorString();
}

// Runs `f`, expecting a MotionError whose message contains every one of `parts`.
template <class F>
void expect_motion_error(F&& f, const std::vector<std::string>& parts) {
  try {
    f();
    ADD_FAILURE() << "expected a MotionError mentioning " << parts.front();
  } catch (const MotionError& e) {
    const std::string what = e.what();
    for (const std::string& p : parts)
      EXPECT_NE(what.find(p), std::string::npos) << "'" << p << "' not in: " << what;
  }
}

}  // namespace

TEST(Motion, RealBvhJointAndFrameCountsMatchTheHeader) {
  for (const RealFile& rf : kRealFiles) {
    SCOPED_TRACE(rf.path);
    const fs::path file = testmodel(rf.path);
    const BvhText bvh = read_bvh(file);
    const LoadedMotion m = load_at_source_rate(file, rf.scale);
    EXPECT_EQ(m.skeleton.joint_count(), count_joint_lines(file));
    ASSERT_EQ(m.skeleton.joint_count(), static_cast<int>(bvh.joints.size()));
    for (size_t j = 0; j < bvh.joints.size(); ++j) {
      EXPECT_EQ(m.skeleton.names[j], bvh.joints[j].name);
      EXPECT_EQ(m.skeleton.parents[j], bvh.joints[j].parent);
    }
    EXPECT_EQ(m.clip.source_frame_count, bvh.declared_frames);
    EXPECT_EQ(m.clip.frame_count, bvh.declared_frames);
    // Boxing_Toes.bvh holds one motion line more than its header declares (3070 for 3069);
    // readers, assimp included, take the header's count.
    EXPECT_GE(static_cast<int>(bvh.frames.size()), bvh.declared_frames);
    EXPECT_NEAR(m.clip.rate, 1.0 / bvh.frame_time, 1e-3 * m.clip.rate);
    EXPECT_EQ(m.clip.rate, std::round(m.clip.rate)) << "BVH rates are snapped to whole Hz";
    EXPECT_NEAR(m.clip.duration(), (bvh.declared_frames - 1) * bvh.frame_time,
                1e-3 * m.clip.duration());
  }
}

TEST(Motion, CmuAndBoxingCountsAndRates) {
  // The numbers this project's manifests rely on (also checked against the text above).
  const LoadedMotion a = load_at_source_rate(testmodel("BVH/01_01.bvh"), kCmuScale);
  const LoadedMotion b = load_at_source_rate(testmodel("BVH/01_03.bvh"), kCmuScale);
  const LoadedMotion c = load_at_source_rate(testmodel("BVH/Boxing_Toes.bvh"), 0.01);
  EXPECT_EQ(a.skeleton.joint_count(), 31);
  EXPECT_EQ(a.clip.frame_count, 2752);
  EXPECT_EQ(a.clip.rate, 120.0);
  EXPECT_EQ(b.skeleton.joint_count(), 31);
  EXPECT_EQ(b.clip.frame_count, 4511);
  EXPECT_EQ(c.skeleton.joint_count(), 21);
  EXPECT_EQ(c.clip.frame_count, 3069);
  EXPECT_EQ(c.clip.rate, 100.0);
  // Standing hip height in metres with the manifests' scales: about 1 m (CMU) and 0.92 m.
  EXPECT_NEAR(a.clip.position(1, 0).y(), 1.0, 0.1);
  EXPECT_NEAR(c.clip.position(0, 0).y(), 0.92, 0.05);
}

TEST(Motion, HipTrajectoryMatchesTheChannelsTimesScale) {
  for (const RealFile& rf : kRealFiles) {
    SCOPED_TRACE(rf.path);
    const fs::path file = testmodel(rf.path);
    const BvhText bvh = read_bvh(file);
    ASSERT_EQ(bvh.joints[0].channels[0], "Xposition");
    const LoadedMotion y_up = load_at_source_rate(file, rf.scale, UpAxis::Y);
    const LoadedMotion z_up = load_at_source_rate(file, rf.scale, UpAxis::Z);
    const int n = bvh.declared_frames;
    for (int f : {0, 1, 2, 100, n / 3, n / 2, n - 2, n - 1}) {
      const std::vector<double>& line = bvh.frames[f];
      const Eigen::Vector3d file_pos(line[0], line[1], line[2]);
      const Eigen::Vector3d expect_y = rf.scale * file_pos;
      // z-up source: (x, y, z) -> (x, z, -y) brings its up axis to +y.
      const Eigen::Vector3d expect_z = rf.scale * Eigen::Vector3d(line[0], line[2], -line[1]);
      // assimp keeps keys in single precision: 1e-6 relative of a few metres.
      EXPECT_LT((y_up.clip.position(f, 0) - expect_y).norm(), 1e-5) << "frame " << f;
      EXPECT_LT((z_up.clip.position(f, 0) - expect_z).norm(), 1e-5) << "frame " << f;
      EXPECT_LT((y_up.clip.root_trajectory()[f] - expect_y).norm(), 1e-5);
    }
  }
}

TEST(Motion, EveryJointFollowsTheFilesForwardKinematics) {
  // A bone moves as the file says: all joints' world positions and orientations equal forward
  // kinematics of the motion line computed here from the text.
  for (const RealFile& rf : kRealFiles) {
    SCOPED_TRACE(rf.path);
    const fs::path file = testmodel(rf.path);
    const BvhText bvh = read_bvh(file);
    const LoadedMotion m = load_at_source_rate(file, rf.scale);
    for (int f : {rf.first_frame, 500, bvh.declared_frames - 1}) {
      const std::vector<Eigen::Affine3d> world = bvh_world(bvh, f);
      for (size_t j = 0; j < world.size(); ++j) {
        const Eigen::Vector3d p = rf.scale * world[j].translation();
        EXPECT_LT((m.clip.position(f, j) - p).norm(), 2e-5) << bvh.joints[j].name << " frame " << f;
        const Eigen::Quaterniond q(world[j].linear());
        EXPECT_LT(angle_between(m.clip.rotation(f, j), q), 1e-5) << bvh.joints[j].name;
      }
    }
  }
}

TEST(Motion, ResampleTo30FpsPicksEveryFourthFrame) {
  const fs::path file = testmodel("BVH/01_01.bvh");
  const LoadedMotion src = load_at_source_rate(file, kCmuScale);
  MotionLoadOptions o;
  o.scale = kCmuScale;
  o.output_rate = 30.0;
  o.first_frame = 1;
  const LoadedMotion out = load_motion(file, o);
  EXPECT_EQ(out.clip.rate, 30.0);
  EXPECT_EQ(out.clip.frame_count, (2751 - 1) / 4 + 1);
  for (int k : {0, 1, 2, 50, 333, out.clip.frame_count - 1}) {
    const int f = 1 + 4 * k;
    for (int j = 0; j < src.clip.joint_count; ++j) {
      // Exact multiples land on source keys: the same pose, not an approximation of it.
      EXPECT_EQ(out.clip.position(k, j), src.clip.position(f, j)) << "k " << k << " joint " << j;
      EXPECT_EQ(out.clip.rotation(k, j).coeffs(), src.clip.rotation(f, j).coeffs());
    }
  }
}

TEST(Motion, ResampleBetweenFramesBlendsNeighbours) {
  // 120 Hz -> 48 Hz: output frame 1 is source frame 2.5, halfway between frames 2 and 3.
  const fs::path file = testmodel("BVH/01_03.bvh");
  const LoadedMotion src = load_at_source_rate(file, kCmuScale);
  MotionLoadOptions o;
  o.scale = kCmuScale;
  o.output_rate = 48.0;
  const LoadedMotion out = load_motion(file, o);
  EXPECT_EQ(out.clip.frame_count, static_cast<int>(std::floor(4510 / 2.5)) + 1);
  for (int k : {1, 3, 101}) {
    const double u = 2.5 * k;
    const int f0 = static_cast<int>(std::floor(u));
    const double s = u - f0;
    // The root's local transform is its world transform (up to the fixed unit/axis conversion),
    // so its position is exactly the lerp of the neighbouring frames and its rotation the slerp.
    const Eigen::Vector3d p = (1 - s) * src.clip.position(f0, 0) + s * src.clip.position(f0 + 1, 0);
    EXPECT_LT((out.clip.position(k, 0) - p).norm(), 1e-12);
    const Eigen::Quaterniond q = src.clip.rotation(f0, 0).slerp(s, src.clip.rotation(f0 + 1, 0));
    EXPECT_LT(angle_between(out.clip.rotation(k, 0), q), 1e-9);
    // Deeper joints blend their local rotations: world positions lie near, not on, the lerp.
    for (int j = 1; j < src.clip.joint_count; ++j) {
      const double span = (src.clip.position(f0 + 1, j) - src.clip.position(f0, j)).norm();
      const Eigen::Vector3d mid =
          (1 - s) * src.clip.position(f0, j) + s * src.clip.position(f0 + 1, j);
      EXPECT_LE((out.clip.position(k, j) - mid).norm(), span + 1e-9) << src.skeleton.names[j];
    }
  }
}

TEST(Motion, SlerpHalfwayIsUnitAndBetween) {
  const LoadedMotion m = load_at_source_rate(testmodel("BVH/Boxing_Toes.bvh"), 0.01);
  for (int f : {10, 1000, 2500}) {
    const double t = (f + 0.5) / m.clip.rate;
    const std::vector<JointPose> pose = sample_pose(m.clip, t);
    for (int j = 0; j < m.clip.joint_count; ++j) {
      const Eigen::Quaterniond& q0 = m.clip.rotation(f, j);
      const Eigen::Quaterniond& q1 = m.clip.rotation(f + 1, j);
      const Eigen::Quaterniond& q = pose[j].rotation;
      EXPECT_NEAR(q.norm(), 1.0, 1e-12);
      const double whole = angle_between(q0, q1);
      EXPECT_NEAR(angle_between(q, q0), 0.5 * whole, 1e-9);
      EXPECT_NEAR(angle_between(q, q1), 0.5 * whole, 1e-9);
      EXPECT_LT(
          (pose[j].position - 0.5 * (m.clip.position(f, j) + m.clip.position(f + 1, j))).norm(),
          1e-12);
    }
    // On a frame's own time the sample is that frame.
    const std::vector<JointPose> on = sample_pose(m.clip, f / m.clip.rate);
    EXPECT_EQ(on[3].position, m.clip.position(f, 3));
  }
}

TEST(Motion, OtherFormatsLoad) {
  // FBX (Blender rig, 24 fps, centimetre UnitScaleFactor) and glTF 2 (skinned, keys in ms).
  const LoadedMotion fbx = load_motion(testmodel("FBX/animation_with_skeleton.fbx"));
  EXPECT_EQ(fbx.clip.rate, 24.0);
  EXPECT_EQ(fbx.clip.frame_count, 21);
  EXPECT_DOUBLE_EQ(fbx.clip.scale, 0.01);
  EXPECT_GE(fbx.skeleton.find("Bone.013"), 0);
  EXPECT_LT(fbx.skeleton.find("Cube"), 0) << "mesh nodes are not joints";
  const int bone = fbx.skeleton.require("Bone.006");
  EXPECT_GT((fbx.clip.position(20, bone) - fbx.clip.position(0, bone)).norm(), 1e-3)
      << "the animation moves the chain";

  const LoadedMotion gltf = load_motion(testmodel("glTF2/simple_skin/simple_skin.gltf"));
  EXPECT_EQ(gltf.skeleton.joint_count(), 2);  // the skin's two joints, not the mesh node
  EXPECT_EQ(gltf.clip.frame_count, 12);       // keys every 0.5 s over 5.5 s
  EXPECT_GT(angle_between(gltf.clip.rotation(0, 1), gltf.clip.rotation(3, 1)), 0.1);
}

TEST(Motion, ColladaExportedFromRealBvhLoadsTheSameMotion) {
  // assimp-testmodels has no animated Collada skeleton: make one from 01_01.bvh with assimp's
  // Collada exporter (see export_collada for the two exporter defects worked around).
  const test::TempDir scratch("clothdb_test_character_collada");
  const fs::path dir = scratch.path();
  const fs::path bvh = testmodel("BVH/01_01.bvh");
  const fs::path dae = dir / "01_01.dae";
  export_collada(bvh, dae);
  ASSERT_TRUE(fs::exists(dae));
  // Same settings for both, as a manifest gives them (motions/cmu_walk.json): CMU units to
  // metres, +y up (the exporter writes <unit meter="1"/> and <up_axis>Y_UP</up_axis>, so the
  // Collada importer neither scales nor rotates), and source_rate 120. The rate matters: the
  // BVH says "Frame Time: .0083333", so the exported keys are 0.0083333 s apart (120.0005 Hz);
  // the BVH reader snaps that to 120 Hz, and a Collada file read at its keys' own times drifts
  // from it by 1/120 - 0.0083333 s per frame (0.07 ms by frame 2000: 0.1 mm of hip travel).
  MotionLoadOptions options;
  options.scale = kCmuScale;
  options.up_axis = UpAxis::Y;
  options.source_rate = 120.0;
  const LoadedMotion a = load_motion(bvh, options);
  const LoadedMotion b = load_motion(dae, options);
  EXPECT_EQ(b.skeleton.joint_count(), 31);
  ASSERT_EQ(b.skeleton.names, a.skeleton.names);
  EXPECT_EQ(b.skeleton.parents, a.skeleton.parents);
  EXPECT_EQ(b.clip.rate, 120.0);
  EXPECT_EQ(b.clip.frame_count, 2752);
  ASSERT_EQ(b.clip.frame_count, a.clip.frame_count);
  // Every frame: the hip root follows the BVH load, and so does every joint. The exporter writes
  // each joint's local 4x4 matrix in single precision and the importer decomposes it again:
  // measured 3.7e-6 m (hip), 6.1e-6 m and 4.8e-5 rad (worst joint, at the end of a chain), so
  // 1e-5 m and 1e-4 rad.
  double worst_hip = 0, worst_joint = 0, worst_angle = 0;
  for (int f = 0; f < a.clip.frame_count; ++f) {
    worst_hip = std::max(worst_hip, (b.clip.position(f, 0) - a.clip.position(f, 0)).norm());
    for (int j = 0; j < a.clip.joint_count; ++j) {
      worst_joint = std::max(worst_joint, (b.clip.position(f, j) - a.clip.position(f, j)).norm());
      worst_angle =
          std::max(worst_angle, angle_between(b.clip.rotation(f, j), a.clip.rotation(f, j)));
    }
  }
  std::printf("Collada against BVH: hip %.2g m, joints %.2g m, %.2g rad\n", worst_hip, worst_joint,
              worst_angle);
  EXPECT_LT(worst_hip, 1e-5);
  EXPECT_LT(worst_joint, 1e-5);
  EXPECT_LT(worst_angle, 1e-4);
  // The hip really travels in this clip (so the comparison above is not of two still poses).
  EXPECT_GT((a.clip.position(a.clip.frame_count - 1, 0) - a.clip.position(0, 0)).norm(), 1.0);
  // Without source_rate the rate comes from the keys' spacing and snaps to 120 Hz too; and a
  // z-up setting turns both formats the same way.
  const LoadedMotion bz = load_at_source_rate(dae, kCmuScale, UpAxis::Z);
  EXPECT_EQ(bz.clip.rate, 120.0);
  EXPECT_EQ(bz.clip.frame_count, 2752);
  for (int f : {1, 500, 2751}) {
    const Vec3 p = a.clip.position(f, 0);
    EXPECT_LT((bz.clip.position(f, 0) - Vec3(p.x(), p.z(), -p.y())).norm(), 1e-5) << "frame " << f;
  }
}

TEST(Motion, BadFilesFailWithNamedErrors) {
  const test::TempDir scratch("clothdb_test_character_bad");
  const fs::path dir = scratch.path();
  const fs::path good = testmodel("BVH/01_01.bvh");

  const fs::path missing = dir / "missing.bvh";
  expect_motion_error([&] { load_motion(missing); }, {missing.string(), "file not found"});

  // Truncated in the motion data, at a line boundary (assimp reads as many frames as the header
  // declares and meets the end of the file) and in the middle of a number.
  std::string text;
  {
    std::ifstream in(good, std::ios::binary);
    text.assign(std::istreambuf_iterator<char>(in), {});
  }
  size_t cut = text.find('\n', text.size() / 2);
  const fs::path lines = dir / "truncated_lines.bvh";
  write_text(lines, text.substr(0, cut + 1));
  expect_motion_error([&] { load_motion(lines); }, {lines.string(), "end of file"});
  const fs::path mid = dir / "truncated_mid.bvh";
  write_text(mid, text.substr(0, text.size() - 1000));
  expect_motion_error([&] { load_motion(mid); }, {mid.string(), "truncated"});
  const fs::path hierarchy = dir / "truncated_hierarchy.bvh";
  write_text(hierarchy, text.substr(0, 1500));
  expect_motion_error([&] { load_motion(hierarchy); }, {hierarchy.string(), "truncated"});
  const fs::path empty = dir / "empty.bvh";
  write_text(empty, "");
  expect_motion_error([&] { load_motion(empty); }, {empty.string(), "empty file"});

  // A header that declares fewer frames than the data holds is caught by the frame-count check.
  const size_t frames_at = text.find("Frames: 2752");
  ASSERT_NE(frames_at, std::string::npos);
  std::string fewer = text;
  fewer.replace(frames_at, 12, "Frames: 2000");
  const fs::path extra = dir / "extra_lines.bvh";
  write_text(extra, fewer);
  // assimp reads the declared 2000 frames and ignores the rest: a consistent 2000-frame file.
  EXPECT_EQ(load_motion(extra).clip.source_frame_count, 2000);

  // No skeleton / no animation.
  const fs::path obj = testmodel("OBJ/box.obj");
  expect_motion_error([&] { load_motion(obj); },
                      {obj.string(), "no skeleton and no animation as read by assimp ",
                       "this assimp cannot read it from this format"});
  const fs::path spider = testmodel("FBX/spider.fbx");
  expect_motion_error([&] { load_motion(spider); }, {spider.string(), "no animation"});
  const fs::path morph =
      testmodel("glTF2/glTF-Sample-Models/AnimatedMorphCube-glTF/AnimatedMorphCube.gltf");
  expect_motion_error([&] { load_motion(morph); }, {morph.string(), "no skeleton"});

  // A bone the scene asks for that is not there.
  const LoadedMotion m = load_motion(good);
  expect_motion_error([&] { m.skeleton.require("LeftWing"); },
                      {good.string(), "bone 'LeftWing' not found", "LeftUpLeg"});
  BodySpec spec;
  spec.bones = {"LeftUpLeg", "Tail"};
  expect_motion_error([&] { make_body(m.skeleton, spec); }, {good.string(), "bone 'Tail'"});

  // Options that do not fit the file.
  MotionLoadOptions range;
  range.first_frame = 10;
  range.last_frame = 5000;
  expect_motion_error([&] { load_motion(good, range); },
                      {good.string(), "frame range 10..5000", "2752 frames"});
  MotionLoadOptions named;
  named.animation = "Dance";
  expect_motion_error([&] { load_motion(good, named); },
                      {good.string(), "no animation named 'Dance'", "'Motion'"});
}

TEST(Manifest, ProjectManifestsLoad) {
  const MotionManifest walk = load_manifest(fs::path(CLOTHDB_SOURCE_DIR) / "motions/cmu_walk.json");
  ASSERT_EQ(walk.clips.size(), 3u);
  EXPECT_EQ(walk.output_rate, 30.0);
  const LoadedMotion a = load_clip(walk, walk.require("01_01"));
  EXPECT_EQ(a.clip.rate, 30.0);
  EXPECT_EQ(a.clip.first_source_frame, 1);
  EXPECT_EQ(a.clip.frame_count, (2751 - 1) / 4 + 1);
  EXPECT_EQ(a.skeleton.joint_count(), 31);
  const LoadedMotion level = load_clip(walk, walk.require("01_03_level_walk"));
  EXPECT_EQ(level.clip.frame_count, 76);
  EXPECT_NEAR(level.clip.duration(), 2.5, 1e-12);

  const MotionManifest boxing = load_manifest(fs::path(CLOTHDB_SOURCE_DIR) / "motions/boxing.json");
  ASSERT_EQ(boxing.clips.size(), 2u);
  const LoadedMotion b = load_clip(boxing, boxing.require("boxing_knockdown"));
  EXPECT_EQ(b.skeleton.joint_count(), 21);
  EXPECT_EQ(b.clip.first_source_frame, 2200);
  EXPECT_EQ(b.clip.frame_count, static_cast<int>(std::floor((3068 - 2200) * 0.3 + 1e-9)) + 1);
}

TEST(Manifest, ErrorsNameTheFileAndField) {
  const test::TempDir scratch("clothdb_test_character_manifest");
  const fs::path dir = scratch.path();
  const fs::path bvh = testmodel("BVH/01_01.bvh");
  auto manifest_with = [&](const std::string& name, const std::string& second_clip) {
    const fs::path file = dir / name;
    write_text(file, "{\"clips\": [{\"file\": \"" + bvh.string() + "\"}, " + second_clip + "]}");
    return file;
  };
  const fs::path scale = manifest_with(
      "scale.json", "{\"file\": \"${ASSIMP_TESTMODELS}/BVH/01_03.bvh\", \"scale\": -1}");
  expect_motion_error([&] { load_manifest(scale); },
                      {scale.string() + ": clips[1].scale: expected a positive number"});
  const fs::path up = manifest_with("up.json", "{\"file\": \"x.bvh\", \"up_axis\": \"w\"}");
  expect_motion_error([&] { load_manifest(up); }, {up.string() + ": clips[1].up_axis:", "'w'"});
  const fs::path no_file = manifest_with("nofile.json", "{\"name\": \"b\"}");
  expect_motion_error([&] { load_manifest(no_file); }, {no_file.string() + ": clips[1].file:"});
  const fs::path typo = manifest_with("typo.json", "{\"file\": \"x.bvh\", \"frist_frame\": 3}");
  expect_motion_error([&] { load_manifest(typo); },
                      {typo.string() + ": clips[1].frist_frame: unknown field"});
  const fs::path frame = manifest_with("frame.json", "{\"file\": \"x.bvh\", \"last_frame\": 1.5}");
  expect_motion_error([&] { load_manifest(frame); }, {frame.string() + ": clips[1].last_frame:"});
  const fs::path dup = manifest_with("dup.json", "{\"file\": \"" + bvh.string() + "\"}");
  expect_motion_error([&] { load_manifest(dup); }, {dup.string() + ": clips[1].name: duplicate"});
  const fs::path json = dir / "broken.json";
  write_text(json, "{\"clips\": [");
  expect_motion_error([&] { load_manifest(json); }, {json.string() + ": not valid JSON"});
  expect_motion_error([&] { load_manifest(dir / "none.json"); }, {"none.json: file not found"});
  // A scene where a manifest is asked for (`graph build SCENE`): the mix-up and the scene's
  // manifest are named (it said "air_drag: unknown field (typo?)").
  const fs::path scene = dir / "a_scene.json";
  write_text(scene,
             "{\"manifest\": \"cmu_walk.json\", \"air_drag\": 1, \"garment\": {\"type\": "
             "\"skirt\"}}");
  expect_motion_error([&] { load_manifest(scene); },
                      {scene.string() + ": (top level): a scene file, not a motion manifest; its "
                                        "manifest is \"cmu_walk.json\""});

  // Valid manifest, bad referenced file or range: the load names file, clip and manifest.
  const fs::path relative =
      manifest_with("relative.json", "{\"name\": \"b\", \"file\": \"gone.bvh\"}");
  const MotionManifest rel = load_manifest(relative);
  EXPECT_EQ(rel.clips[1].file, dir / "gone.bvh") << "relative paths are relative to the manifest";
  expect_motion_error([&] { load_clip(rel, 1); }, {(dir / "gone.bvh").string(), "file not found",
                                                   "clip 'b'", relative.string()});
  const fs::path range =
      manifest_with("range.json", "{\"name\": \"b\", \"file\": \"" + bvh.string() +
                                      "\", \"first_frame\": 100, \"last_frame\": 9000}");
  expect_motion_error([&] { load_clip(load_manifest(range), 1); },
                      {bvh.string(), "frame range 100..9000", range.string()});
}

TEST(Body, CapsuleEndpointsAreJointPositions) {
  const LoadedMotion m = load_at_source_rate(testmodel("BVH/01_01.bvh"), kCmuScale);
  const Body body = make_body(m.skeleton, {});
  ASSERT_FALSE(body.capsules.empty());
  for (int f : {0, 1, 700}) {
    const std::vector<CapsuleCollider> caps = body_capsules_at_frame(body, m.skeleton, m.clip, f);
    ASSERT_EQ(caps.size(), body.capsules.size());
    const int prev = std::max(f - 1, 0);
    for (size_t i = 0; i < caps.size(); ++i) {
      const BoneCapsule& bc = body.capsules[i];
      EXPECT_EQ(caps[i].bone, bc.joint);
      EXPECT_EQ(caps[i].a, m.clip.position(f, bc.joint));
      EXPECT_EQ(caps[i].a_start, m.clip.position(prev, bc.joint));
      if (bc.child >= 0) {
        EXPECT_EQ(caps[i].b, m.clip.position(f, bc.child));
        EXPECT_EQ(caps[i].b_start, m.clip.position(prev, bc.child));
      } else {
        // End site: the same offset from the joint in every frame, carried by its rotation.
        const Eigen::Vector3d tip = m.clip.position(f, bc.joint) +
                                    m.clip.rotation(f, bc.joint) * *m.skeleton.end_site[bc.joint];
        EXPECT_LT((caps[i].b - tip).norm(), 1e-12);
        EXPECT_NEAR((caps[i].b - caps[i].a).norm(), (caps[i].b_start - caps[i].a_start).norm(),
                    1e-9);
      }
    }
  }
  // Between frames: the interpolated pose's joints.
  const double t0 = 10.25 / m.clip.rate, t1 = 10.75 / m.clip.rate;
  const std::vector<CapsuleCollider> between =
      body_capsules_between(body, m.skeleton, m.clip, t0, t1);
  const std::vector<JointPose> p0 = sample_pose(m.clip, t0), p1 = sample_pose(m.clip, t1);
  for (size_t i = 0; i < between.size(); ++i) {
    EXPECT_EQ(between[i].a, p1[body.capsules[i].joint].position);
    EXPECT_EQ(between[i].a_start, p0[body.capsules[i].joint].position);
  }
}

// The span against a brute force over every pair of joints (each pair's path through its lowest
// common ancestor); the size against the extent it stands in for on CMU's rig.
TEST(Body, SpanIsTheLongestPathAlongTheBones) {
  for (const RealFile& rf : kRealFiles) {
    SCOPED_TRACE(rf.path);
    const LoadedMotion m = load_at_source_rate(testmodel(rf.path), rf.scale);
    const Skeleton& sk = m.skeleton;
    const std::vector<JointPose> rest = rest_pose(sk);
    std::vector<double> from_root(sk.joint_count(), 0.0);
    for (int j = 0; j < sk.joint_count(); ++j)
      if (sk.parents[j] >= 0)
        from_root[j] =
            from_root[sk.parents[j]] + (rest[j].position - rest[sk.parents[j]].position).norm();
    auto ancestors = [&](int j) {
      std::vector<int> chain;
      for (; j >= 0; j = sk.parents[j]) chain.push_back(j);
      return chain;
    };
    double longest = 0.0;
    for (int a = 0; a < sk.joint_count(); ++a)
      for (int b = a + 1; b < sk.joint_count(); ++b) {
        const std::vector<int> up_a = ancestors(a), up_b = ancestors(b);
        int common = -1;
        for (int x : up_a)
          if (std::find(up_b.begin(), up_b.end(), x) != up_b.end()) {
            common = x;
            break;
          }
        if (common < 0) continue;  // different roots
        longest = std::max(longest, from_root[a] + from_root[b] - 2 * from_root[common]);
      }
    EXPECT_NEAR(skeleton_span(sk), longest, 1e-9);
    EXPECT_DOUBLE_EQ(skeleton_size(sk), kStatureOverSpan * skeleton_span(sk));
  }
  // On CMU's rig the size is the rest pose's extent with its end sites (what the default radii
  // were tuned on) within 0.1 %.
  const LoadedMotion cmu = load_at_source_rate(testmodel("BVH/01_01.bvh"), kCmuScale);
  const std::vector<JointPose> rest = rest_pose(cmu.skeleton);
  Eigen::Vector3d lo = rest[0].position, hi = lo;
  for (int j = 0; j < cmu.skeleton.joint_count(); ++j) {
    lo = lo.cwiseMin(rest[j].position);
    hi = hi.cwiseMax(rest[j].position);
    if (cmu.skeleton.end_site[j]) {
      const Eigen::Vector3d tip = point_in_joint(rest[j], *cmu.skeleton.end_site[j]);
      lo = lo.cwiseMin(tip);
      hi = hi.cwiseMax(tip);
    }
  }
  EXPECT_NEAR(skeleton_size(cmu.skeleton) / (hi - lo).maxCoeff(), 1.0, 1e-3);
}

TEST(Body, RadiiFollowProportionsAndOverrides) {
  for (const RealFile& rf : kRealFiles) {
    SCOPED_TRACE(rf.path);
    const LoadedMotion m = load_at_source_rate(testmodel(rf.path), rf.scale);
    const double size = skeleton_size(m.skeleton);
    EXPECT_GT(size, 1.3);  // a human in metres: the scale is right
    EXPECT_LT(size, 2.0);
    std::map<BodyRegion, double> radius;
    for (const BoneCapsule& c : all_bone_capsules(m.skeleton)) {
      EXPECT_NE(c.region, BodyRegion::Other) << m.skeleton.names[c.joint];
      EXPECT_GT(c.radius, 0.01);
      EXPECT_LT(c.radius, 0.16);
      radius[c.region] = c.radius;
    }
    EXPECT_GT(radius[BodyRegion::Torso], radius[BodyRegion::Thigh]);
    EXPECT_GT(radius[BodyRegion::Thigh], radius[BodyRegion::Shin]);
    EXPECT_GT(radius[BodyRegion::UpperArm], radius[BodyRegion::Forearm]);
    EXPECT_GT(radius[BodyRegion::Forearm], radius[BodyRegion::Hand]);
  }
  // The upper arm is "LeftArm" in CMU and "LeftShoulder" in Boxing_Toes.
  const LoadedMotion cmu = load_at_source_rate(testmodel("BVH/01_01.bvh"), kCmuScale);
  const LoadedMotion box = load_at_source_rate(testmodel("BVH/Boxing_Toes.bvh"), 0.01);
  EXPECT_EQ(classify_bone(cmu.skeleton, cmu.skeleton.require("LeftShoulder")),
            BodyRegion::Clavicle);
  EXPECT_EQ(classify_bone(cmu.skeleton, cmu.skeleton.require("LeftArm")), BodyRegion::UpperArm);
  EXPECT_EQ(classify_bone(box.skeleton, box.skeleton.require("LeftShoulder")),
            BodyRegion::UpperArm);
  EXPECT_EQ(classify_bone(box.skeleton, box.skeleton.require("LeftHip")), BodyRegion::Thigh);

  BodySpec spec;
  spec.bones = {"LeftUpLeg", "LeftLeg", "LeftUpLeg"};
  spec.radius = {{"LeftLeg", 0.061}};
  const Body body = make_body(cmu.skeleton, spec);
  ASSERT_EQ(body.capsules.size(), 2u) << "listed bones only, each once";
  EXPECT_EQ(body.capsules[0].joint, cmu.skeleton.require("LeftUpLeg"));
  EXPECT_EQ(body.capsules[1].radius, 0.061);
  EXPECT_EQ(body_capsules_at_frame(body, cmu.skeleton, cmu.clip, 5).size(), 2u);

  BodySpec bad_radius;
  bad_radius.radius = {{"Head", -0.1}};
  expect_motion_error([&] { make_body(cmu.skeleton, bad_radius); }, {"radius of bone 'Head'"});
  BodySpec pelvis;
  pelvis.bones = {"LHipJoint"};  // on Hips; its segment to LeftUpLeg is the pelvis side
  EXPECT_EQ(make_body(cmu.skeleton, pelvis).capsules.size(), 1u);
  BodySpec no_segment;
  no_segment.bones = {"LeftHand"};  // CMU's hand joint coincides with its finger and thumb joints
  expect_motion_error([&] { make_body(cmu.skeleton, no_segment); },
                      {"bone 'LeftHand' has no segment"});
}

TEST(Body, AutomaticSelectionByDistanceToTheGarment) {
  const LoadedMotion m = load_at_source_rate(testmodel("BVH/01_03.bvh"), kCmuScale);
  const Body all = make_body(m.skeleton, {});
  const int frame = 1;
  const std::vector<CapsuleCollider> caps = body_capsules_at_frame(all, m.skeleton, m.clip, frame);
  // A "skirt" ring of points 3 cm outside the left thigh capsule, around its middle.
  const int thigh = m.skeleton.require("LeftUpLeg");
  size_t index = 0;
  while (all.capsules[index].joint != thigh) ++index;
  const CapsuleCollider& c = caps[index];
  const Eigen::Vector3d axis = (c.b - c.a).normalized();
  const Eigen::Vector3d side = axis.unitOrthogonal(), other = axis.cross(side);
  Eigen::Matrix3Xd garment(3, 8);
  for (int i = 0; i < 8; ++i) {
    const double angle = 2 * kPi * i / 8;
    garment.col(i) =
        0.5 * (c.a + c.b) + (c.radius + 0.03) * (std::cos(angle) * side + std::sin(angle) * other);
  }
  const Body near = make_body_near(m.skeleton, m.clip, garment, 0.05, {}, frame);
  ASSERT_FALSE(near.capsules.empty());
  bool has_thigh = false;
  for (const BoneCapsule& b : near.capsules) {
    has_thigh = has_thigh || b.joint == thigh;
    EXPECT_NE(m.skeleton.names[b.joint], "Head");
    EXPECT_NE(m.skeleton.names[b.joint], "RightFoot");
  }
  EXPECT_TRUE(has_thigh);
  EXPECT_LT(near.capsules.size(), all.capsules.size());
  // The ring is 3 cm from the left thigh: a 1 cm distance leaves it out (the ring may still
  // touch the other thigh); a huge distance selects every bone.
  for (const BoneCapsule& b : make_body_near(m.skeleton, m.clip, garment, 0.01, {}, frame).capsules)
    EXPECT_NE(b.joint, thigh);
  EXPECT_EQ(make_body_near(m.skeleton, m.clip, garment, 10.0, {}, frame).capsules.size(),
            all.capsules.size());
}

// A manifest without the CMU scale makes a skeleton 18 times too tall; one with the wrong up axis
// lays it down. Both load (it may be a creature) with a warning naming the manifest field.
TEST(Character, ImplausibleSkeletonIsWarnedNamingTheManifestField) {
  const fs::path dir = fs::path(testing::TempDir());
  const fs::path manifest = dir / "no_scale.json";
  auto write_manifest = [&](const std::string& extra) {
    write_text(manifest, R"({"clips": [{"name": "walk", "file": ")" +
                             testmodel("BVH/01_01.bvh").string() +
                             R"(", "first_frame": 1, "last_frame": 40)" + extra + "}]}");
    testing::internal::CaptureStderr();
    load_clip(load_manifest(manifest), 0);
    return testing::internal::GetCapturedStderr();
  };
  const std::string tall = write_manifest("");
  EXPECT_NE(
      tall.find("m tall (a person is 0.5 to 3 m): set " + manifest.string() + ": clips[0].scale"),
      std::string::npos)
      << tall;
  const std::string lying = write_manifest(R"(, "scale": 0.0564444, "up_axis": "z")");
  EXPECT_NE(lying.find("as if lying down: set " + manifest.string() + ": clips[0].up_axis"),
            std::string::npos)
      << lying;
  const std::string fine = write_manifest(R"(, "scale": 0.0564444, "up_axis": "y")");
  EXPECT_EQ(fine.find("warning"), std::string::npos) << fine;
}

// FBX and glTF written by Blender 3.4 from the first 2 s of 01_01.bvh with the exporters' defaults
// (scripts/make_blender_fixtures.py, docs/guide/garment_placement.md#motion-from-blender): the
// same joints, rate, frames and motion as the BVH's frames 0..240. Blender's quirks are in them:
// the FBX's armature object is a static node above Hips, keyed with the bones; the glTF's keys
// start at 1/120 s (Blender frame 1).
TEST(Motion, BlenderFbxAndGltfMatchTheBvh) {
  const fs::path dir = fs::path(CLOTHDB_SOURCE_DIR) / "tests/data/blender";
  MotionLoadOptions bvh_options;
  bvh_options.scale = kCmuScale;
  bvh_options.last_frame = 240;  // 2 s at 120 Hz: Blender frames 1..241
  const LoadedMotion bvh = load_motion(testmodel("BVH/01_01.bvh"), bvh_options);
  ASSERT_EQ(bvh.clip.frame_count, 241);
  std::map<std::pair<std::string, int>, double> bvh_radius;
  for (const BoneCapsule& c : all_bone_capsules(bvh.skeleton))
    bvh_radius[{bvh.skeleton.names[c.joint], c.child}] = c.radius;
  // Tolerances: the glTF holds every frame in single precision (measured 1.3e-6 m); Blender's FBX
  // exporter drops keys its default "Simplify" (1.0) finds redundant (LeftForeArm keeps 186 of 241)
  // and the curves between them miss by up to 4.4 mm (measured, a finger).
  const std::pair<const char*, double> files[] = {{"01_01_blender.fbx", 1e-2},
                                                  {"01_01_blender.glb", 1e-5}};
  for (const auto& [name, tolerance] : files) {
    SCOPED_TRACE(name);
    const LoadedMotion m = load_motion(dir / name);  // the file's own units, axis and rate
    EXPECT_EQ(m.skeleton.names.front(), "Hips") << "the armature object is not a joint";
    ASSERT_EQ(m.skeleton.names, bvh.skeleton.names);
    EXPECT_EQ(m.skeleton.parents, bvh.skeleton.parents);
    EXPECT_NEAR(m.clip.rate, 120.0, 0.01);
    EXPECT_EQ(m.clip.frame_count, bvh.clip.frame_count);
    ASSERT_EQ(m.clip.joint_count, bvh.clip.joint_count);
    // Every joint of every frame where the BVH puts it; a one-frame shift is 0.68 m off (frame 0
    // is CMU's calibration T-pose).
    double worst = 0, worst_shifted = 0;
    for (int f = 0; f < m.clip.frame_count; ++f)
      for (int j = 0; j < m.clip.joint_count; ++j) {
        worst = std::max(worst, (m.clip.position(f, j) - bvh.clip.position(f, j)).norm());
        if (f + 1 < m.clip.frame_count)
          worst_shifted =
              std::max(worst_shifted, (m.clip.position(f, j) - bvh.clip.position(f + 1, j)).norm());
      }
    std::printf("%s against the BVH: worst joint %.3g m (one frame off: %.3g m)\n", name, worst,
                worst_shifted);
    EXPECT_LT(worst, tolerance);
    EXPECT_GT(worst_shifted, 5e-2) << "the comparison can tell a one-frame shift";
    // End sites: the FBX's leaf bones are the BVH's End Sites (Blender's bone tails), from the
    // file; the glTF has none, and each leaf's made-up end points where the BVH's does (along
    // the leaf's own bone axis: Blender's frames follow its bones), with its parent bone's length.
    const std::vector<JointPose> rest = rest_pose(m.skeleton), bvh_rest = rest_pose(bvh.skeleton);
    const bool gltf = fs::path(name).extension() == ".glb";
    int leaves = 0;
    for (int j = 0; j < m.skeleton.joint_count(); ++j) {
      if (!bvh.skeleton.end_site[j]) continue;
      EXPECT_TRUE(bvh.skeleton.end_site_from_file[j]) << bvh.skeleton.names[j];
      if (!m.skeleton.end_site[j]) {
        // Only a leaf on its parent (CMU's thumbs) has no bone to take a length from.
        EXPECT_TRUE(gltf && (rest[j].position - rest[m.skeleton.parents[j]].position).norm() < 1e-6)
            << m.skeleton.names[j];
        continue;
      }
      ++leaves;
      EXPECT_EQ(m.skeleton.end_site_from_file[j], !gltf) << m.skeleton.names[j];
      if (!gltf) continue;  // the FBX's rest pose is its first frame's pose, not the BVH's rest
      const Eigen::Vector3d want = bvh_rest[j].rotation * *bvh.skeleton.end_site[j];
      const Eigen::Vector3d got = rest[j].rotation * *m.skeleton.end_site[j];
      EXPECT_GT(want.normalized().dot(got.normalized()), std::cos(1e-3)) << m.skeleton.names[j];
    }
    EXPECT_GE(leaves, 5);
    // Capsules: the BVH's radius for every bone, and a head. The radii's reference is the
    // skeleton's span along the bones, which every format stores (glTF has no end sites, the FBX's
    // rest pose is the pose of its export frame); single precision leaves 1e-7.
    const double size_ratio = skeleton_size(m.skeleton) / skeleton_size(bvh.skeleton);
    EXPECT_NEAR(size_ratio, 1.0, 1e-6);
    bool head = false;
    int compared = 0;
    for (const BoneCapsule& c : all_bone_capsules(m.skeleton)) {
      head = head || m.skeleton.names[c.joint] == "Head";
      const auto it = bvh_radius.find({m.skeleton.names[c.joint], c.child});
      if (it == bvh_radius.end()) continue;
      EXPECT_NEAR(c.radius, it->second, 1e-6 * it->second) << m.skeleton.names[c.joint];
      ++compared;
    }
    EXPECT_TRUE(head) << "the head has a capsule";
    EXPECT_TRUE(bvh_radius.count({"Head", -1})) << "the BVH's head has a capsule";
    EXPECT_GE(compared, 20);
  }
}
