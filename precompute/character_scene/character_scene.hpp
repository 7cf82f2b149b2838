// A character scene: the scene file (JSON) that names the motion manifest and clips, the garment,
// the material, the solver and its settings, and the colliding bones; and the simulation of the
// garment along a sequence of poses (one clip, or a transition of the motion graph).
//
// Scene file format (paths relative to the scene file):
//   {
//     "name": "skirt-walk",
//     "manifest": "cmu_walk.json",
//     "clips": ["walk"],                           // optional: default all of the manifest's
//     "garment": {"type": "skirt", "bone": "Hips", "vertices": 2000, "length": 0.55},
//        // or {"type": "cape", "vertices": 1500, "length": 0.8}
//        // or {"type": "mesh", "file": "dress.obj", "scale": 1, "pins": {"height_band":
//        [1.0, 1.1]}}, modelled on the skeleton's rest pose (docs/guide/garment_placement.md)
//        //    pins: {"vertex_group": "waist"} | {"height_band": [lo, hi]} | {"bone": "Hips",
//        "distance": 0.05}
//     "material": {"density": 0.15, "youngs_modulus": 1e8, "poisson": 0.3, "thickness": 5e-4,
//                  "bending_stiffness": 1e-5, "damping": 1e-3},
//     "solver": {"name": "xpbd", "substeps": 10, "iterations": 1, "tolerance": 1e-6,
//                "linear_solver": "ldlt", "threads": 1, "tethers": true,
//                "stretch_iterations": 2, "strain_limit": 0.025,
//                "strain_limit_iterations": 64, "strain_limit_contact_rounds": 1,
//                "coarse_vertices": 3000},
//        // coarse_vertices (skirt or cape, xpbd; default 0, off): the garment made with this many
//        // vertices is solved and drives the scene's garment (docs/guide/resolution.md)
//        // any field of SolverSettings, read and checked by its one serialiser
//        // (database/run_settings.hpp: solver_settings_json); defaults as above
//     "colliders": {"bones": ["Hips", "LeftUpLeg"], "auto_distance": 0.2,
//                   "radius": {"Hips": 0.12}, "margin": 0.004,
//                   "friction_static": 0.4, "friction_kinetic": 0.3,
//                   "motion": "interpolated"},   // or "swept", "end-pose": cloth/collision.hpp
//     "air_drag": 0.3,
//     "settle_frames": 30,
//     "graph": {"percentile": 0.5, "min_segment_s": 0.35}
//        // the motion graph `clothdb precompute` and `clothdb floor` build from the scene's clips;
//        // fields and defaults: graph/motion_graph.hpp, graph_settings_from_scene
//   }
// Every field but "manifest" and "garment" has a default. Errors name the scene file and field.
#pragma once

#include <filesystem>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "character/body.hpp"
#include "character/manifest.hpp"
#include "cloth/model.hpp"
#include "garment/garment.hpp"
#include "garment/placement.hpp"
#include "hard_cases/hard_cases.hpp"
#include "solvers/solver.hpp"

namespace clothdb {

struct SceneError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

enum class GarmentKind { Skirt, Cape, Mesh };

// Steered clip ends (docs/GUIDE.md#the-precompute-kim-et-al-2013, beyond Kim et al. 2013): over the
// last `frames` frames of a clip, the cloth is pulled toward the nearest state at the clip's end
// node, ramped in, so that the clip ends on that state and links to it instead of making a new
// state. Only ends within `max_distance` (m, db::state_distance) of a state are steered; farther
// ones make new states as without steering. frames 0: off (the scene file's
// "steering": {"frames": K, "max_mm": D}).
struct SteeringSpec {
  int frames = 0;
  double max_distance = 0.03;
};

struct SceneFile {
  std::filesystem::path path;
  std::string text;  // the file as given (stored in the database)
  std::string name;
  MotionManifest manifest;
  std::vector<std::string> clips;  // names of the manifest clips the scene uses
  GarmentKind garment_kind = GarmentKind::Skirt;
  SkirtSpec skirt;
  CapeSpec cape;
  MeshGarmentSpec mesh;
  Material material;
  SolverKind solver = SolverKind::Xpbd;
  SolverSettings settings;
  BodySpec body;
  double auto_distance = 0.0;  // > 0: collide only bones within this distance of the garment
  double margin = 0.004;
  double friction_static = 0.4, friction_kinetic = 0.3;
  ColliderMotion collider_motion = ColliderMotion::Interpolated;
  double air_drag = 0.3;
  int settle_frames = 30;
  SteeringSpec steering;
  // The "graph" block as given (an object; null when absent). The graph layer reads and checks it
  // (graph_settings_from_scene), the one owner of the graph settings and their defaults.
  nlohmann::json graph;
};

// Reads and validates a scene file. Throws SceneError "<file>: <field>: <problem>" (and passes on
// the manifest's MotionError).
SceneFile load_scene_file(const std::filesystem::path& file);

struct CharacterScene {
  SceneFile file;
  Skeleton skeleton;
  std::vector<MotionClip> clips;  // in file.clips order, at the manifest's output rate
  std::vector<JointPose> bind;    // the skeleton's rest pose the garment is built in
  Garment garment;
  ClothModel model;
  Body body;
  PlacementReport placement;  // where the garment sits at rest (garment/placement.hpp)
  Environment env;            // gravity, drag, margin, friction (capsules are set per step)

  int clip_index(const std::string& name) const;  // throws SceneError listing the clips
};

// Loads the motions, builds the garment, the cloth model and the body colliders. Throws
// SceneError / MotionError / GarmentError naming the file and what is wrong.
CharacterScene build_character_scene(const SceneFile& file);

// The scene's solver with `settings`: make_solver on the scene's model, or with
// settings.coarse_vertices > 0 the same garment made with that many vertices solved and driving
// this one (make_upsampled_solver). Throws SceneError for a mesh garment or a solver other than
// XPBD with coarse_vertices.
std::unique_ptr<Solver> make_scene_solver(const CharacterScene& scene, SolverKind kind,
                                          const SolverSettings& settings);

// Joint poses of one clip frame.
std::vector<JointPose> clip_pose(const MotionClip& clip, int frame);

// The garment settled for scene.file.settle_frames frames and brought into `pose`: a third in the
// bind pose moved rigidly onto the pose's anchor bone, a third blending the limbs into `pose`, a
// third holding it (with 0 settle frames: carried straight into `pose`). The rest state every
// exploration starts from.
ClothState settle_garment(const CharacterScene& scene, Solver& solver,
                          const std::vector<JointPose>& pose);

struct PoseRun {
  std::vector<Eigen::Matrix3Xd> frames;  // one per pose after the first (the state after each step)
  std::vector<FrameMetrics> metrics;
  Eigen::Matrix3Xd end_velocity;  // velocities after the last step
  bool stable = true;
  std::string message;
  double seconds = 0;  // solver time
  int step_halvings = 0;
};

// Simulates from `state` (at poses[0]) through poses[1..] at `rate` Hz, one solver step per pose;
// `state` ends at the last pose. Pins follow by skinning; capsules sweep between poses.
// before_step (optional): called before each step with the frame index it steps to (1 ..
// poses.size() - 1) and the state, which it may change (steering sets velocities here, so that the
// step's constraints and collisions act on what it did).
PoseRun simulate_poses(const CharacterScene& scene, Solver& solver,
                       const std::vector<std::vector<JointPose>>& poses, double rate,
                       ClothState& state,
                       const std::function<void(size_t, ClothState&)>& before_step = {});

// Character space (docs/SECONDARY_GRAPH.md), where a clothdb file stores cloth: the root
// projected to the floor, facing +z (its bind-pose +z carried by its rotation).
Eigen::Isometry3d character_frame(const CharacterScene& scene, const std::vector<JointPose>& pose);

}  // namespace clothdb
