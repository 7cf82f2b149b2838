// A small cloth graph shared by the explorer's and the played benchmark's tests: a 200-vertex
// skirt with heavy air drag (contractive: it forgets its history within about two edges) on a
// one-node graph of two loops, holding still and swaying, or on a two-node graph.
#pragma once

#include <cmath>
#include <string>
#include <vector>

#include "explore/explorer.hpp"

namespace clothdb::test {

inline const std::string kMotions = std::string(CLOTHDB_SOURCE_DIR) + "/motions/";

inline CharacterScene small_scene() {
  SceneFile file = load_scene_file(kMotions + "skirt_walk.json");
  file.clips = {"01_03_level_walk"};
  file.skirt.vertices = 200;
  file.settle_frames = 10;
  file.settings.substeps = 6;
  file.settings.iterations = 1;
  // Fixed here rather than inherited from the bundled scene, so tuning the demo cannot change
  // how fast this small graph converges.
  file.skirt.flare = 1.5;
  file.skirt.length = 0.5;
  file.material.bending_stiffness = 1e-5;  // the demo's is 1e-4 since 2026-12-02
  file.settings.tethers = false;
  // The bundled scene's strain limit (docs/GUIDE.md#the-solvers) is not what these tests
  // measure, and costs 64 passes a step.
  file.settings.stretch_iterations = 0;
  file.settings.strain_limit = 0.0;
  // Heavy air drag: the cloth forgets its history within about two edges, so the explorer
  // converges in a few dozen clips (a light fabric needs Kim et al.'s CPU-hours). At 3.0 how long
  // these tests ran to convergence was a lottery on the capsule radii: moving every radius by
  // 2e-4 turned seconds into minutes (docs/notebook/blender_motion.md); at 6.0 every scaling of
  // the radii from -1 % to +1 % converged in 730-1,710 frames.
  file.air_drag = 6.0;
  file.steering = {};  // off unless a test turns it on (the demo scene steers)
  return build_character_scene(file);
}

// The character turning about its root by `angle` (radians) and back: a loop at one node.
inline std::vector<std::vector<JointPose>> sway(const std::vector<JointPose>& pose, double angle,
                                                int frames) {
  std::vector<std::vector<JointPose>> out;
  for (int k = 0; k < frames; ++k) {
    const double a = angle * std::sin(2 * 3.14159265358979 * k / (frames - 1));
    const Eigen::Quaterniond q(Eigen::AngleAxisd(a, Vec3::UnitY()));
    std::vector<JointPose> p = pose;
    for (auto& j : p) {
      j.position = pose[0].position + q * (j.position - pose[0].position);
      j.rotation = q * j.rotation;
    }
    out.push_back(std::move(p));
  }
  return out;
}

inline ExploreGraph small_graph(const CharacterScene& scene) {
  const auto pose = clip_pose(scene.clips.front(), 0);
  ExploreGraph g;
  g.node_count = 1;
  g.rate = 30;
  g.edges.push_back({0, 0, "hold", std::vector<std::vector<JointPose>>(12, pose), 0});
  g.edges.push_back({0, 0, "sway", sway(pose, 0.6, 16), 0});
  return g;
}

// The character turning about its root from angle a0 to a1 (radians), eased in and out.
inline std::vector<std::vector<JointPose>> turn(const std::vector<JointPose>& pose, double a0,
                                                double a1, int frames) {
  std::vector<std::vector<JointPose>> out;
  for (int k = 0; k < frames; ++k) {
    const double s = double(k) / (frames - 1), h = s * s * (3 - 2 * s);
    const Eigen::Quaterniond q(Eigen::AngleAxisd(a0 + (a1 - a0) * h, Vec3::UnitY()));
    std::vector<JointPose> p = pose;
    for (auto& j : p) {
      j.position = pose[0].position + q * (j.position - pose[0].position);
      j.rotation = q * j.rotation;
    }
    out.push_back(std::move(p));
  }
  return out;
}

// A graph of two nodes (standing, and standing turned by 0.5 rad): turn there, turn back, a sway
// at node 0 and a hold at node 1. Every edge's end node has states the explorer must find among
// those of its own node, not the other's.
inline ExploreGraph two_node_graph(const CharacterScene& scene) {
  const auto pose = clip_pose(scene.clips.front(), 0);
  ExploreGraph g;
  g.node_count = 2;
  g.rate = 30;
  g.edges.push_back({0, 1, "turn", turn(pose, 0, 0.5, 14), 0});
  g.edges.push_back({1, 0, "back", turn(pose, 0.5, 0, 14), 0});
  g.edges.push_back({0, 0, "sway", sway(pose, 0.6, 16), 0});
  g.edges.push_back({1, 1, "hold", turn(pose, 0.5, 0.5, 12), 0});
  return g;
}

// The state store's scale test (tests/test_state_store.cpp, support/explore_run_main.cpp): a
// skirt of a few dozen vertices with light drag on tiny_graph, and an epsilon of 1 um,
// so that nearly every clip end is a new state and thousands of states come within seconds.
inline CharacterScene tiny_scene() {
  SceneFile file = small_scene().file;
  file.skirt.vertices = 40;
  file.air_drag = 0.5;
  file.settings.substeps = 3;
  return build_character_scene(file);
}

// Four nodes, the character standing turned by 0, 0.4, 0.8 and 1.2 rad: at each node a hold of 5
// frames (a loop) and a turn of 7 frames to the next node (the last back to the first). Cheap
// clips, many of them, and the states spread over four nodes (the nearest-state search is
// per node).
inline ExploreGraph tiny_graph(const CharacterScene& scene) {
  const auto pose = clip_pose(scene.clips.front(), 0);
  ExploreGraph g;
  g.node_count = 4;
  g.rate = 30;
  for (int k = 0; k < 4; ++k) {
    const double a = 0.4 * k, next = 0.4 * ((k + 1) % 4);
    g.edges.push_back({k, k, "hold" + std::to_string(k), turn(pose, a, a, 5), 0});
    g.edges.push_back({k, (k + 1) % 4, "turn" + std::to_string(k), turn(pose, a, next, 7), 0});
  }
  return g;
}

inline ExploreOptions many_states_options(int threads, long total_frames, size_t cache_bytes) {
  ExploreOptions options;
  options.epsilon = 1e-6;
  options.batch = 64;
  options.threads = threads;
  options.max_frames = total_frames;
  options.progress = false;
  options.state_cache_bytes = cache_bytes;
  return options;
}

}  // namespace clothdb::test
