#include "character_scene/character_scene.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>

#include "solvers/upsampled.hpp"

namespace clothdb {

namespace {

using nlohmann::json;

// Bounds of the scene's integers: far beyond any real scene, small enough that nothing sized by
// them can exhaust memory (settle_frames sizes a pose array; vertices a generated mesh).
constexpr int kMaxSettleFrames = 100000;
constexpr int kMaxGeneratedVertices = 1000000;

// Field access with errors that name the file and the field path.
struct Fields {
  std::string file;
  [[noreturn]] void fail(const std::string& field, const std::string& what) const {
    throw SceneError(file + ": " + field + ": " + what);
  }
  double number(const json& obj, const std::string& key, const std::string& path, double fallback,
                bool positive = false, bool non_negative = false) const {
    if (!obj.contains(key)) return fallback;
    const json& v = obj.at(key);
    if (!v.is_number()) fail(path + key, "expected a number");
    const double d = v.get<double>();
    if (positive && !(d > 0)) fail(path + key, "expected a positive number, got " + v.dump());
    if (non_negative && !(d >= 0)) fail(path + key, "expected a number >= 0, got " + v.dump());
    return d;
  }
  // An integer in [minimum, maximum]; compared before narrowing, so 2^40 is "too large", not a
  // wrapped value.
  int integer(const json& obj, const std::string& key, const std::string& path, int fallback,
              int minimum, int maximum) const {
    if (!obj.contains(key)) return fallback;
    const json& v = obj.at(key);
    const bool in_range =
        v.is_number_unsigned() ? v.get<uint64_t>() <= uint64_t(std::max(maximum, 0)) &&
                                     int64_t(v.get<uint64_t>()) >= minimum
        : v.is_number_integer() ? v.get<int64_t>() >= minimum && v.get<int64_t>() <= maximum
                                : false;
    if (!in_range)
      fail(path + key, "expected an integer in [" + std::to_string(minimum) + ", " +
                           std::to_string(maximum) + "], got " + v.dump());
    return int(v.get<int64_t>());
  }
  std::string string(const json& obj, const std::string& key, const std::string& path,
                     const std::string& fallback) const {
    if (!obj.contains(key)) return fallback;
    if (!obj.at(key).is_string()) fail(path + key, "expected a string");
    return obj.at(key).get<std::string>();
  }
  const json& object(const json& obj, const std::string& key, const std::string& path) const {
    static const json empty = json::object();
    if (!obj.contains(key)) return empty;
    if (!obj.at(key).is_object()) fail(path + key, "expected an object");
    return obj.at(key);
  }
  void only(const json& obj, const std::vector<std::string>& keys, const std::string& path) const {
    for (auto it = obj.begin(); it != obj.end(); ++it)
      if (std::find(keys.begin(), keys.end(), it.key()) == keys.end()) {
        std::string list;
        for (const auto& k : keys) list += (list.empty() ? "" : ", ") + k;
        fail(path + it.key(), "unknown field (known: " + list + ")");
      }
  }
};

// Why solver.coarse_vertices cannot drive this solver and garment ("" if it can). One owner for the
// scene file's check (load_scene_file) and for a count given elsewhere (make_scene_solver, from
// `bench character --coarse-vertices`).
std::string coarse_drive_refusal(SolverKind solver, GarmentKind garment) {
  if (solver != SolverKind::Xpbd)
    return std::string("a coarse garment drives xpbd only, not ") + solver_name(solver);
  if (garment == GarmentKind::Mesh)
    return "needs a procedural garment (skirt or cape): a mesh garment has no coarser copy";
  return "";
}

}  // namespace

SceneFile load_scene_file(const std::filesystem::path& file) {
  SceneFile s;
  s.path = file;
  std::error_code ec;
  if (std::filesystem::is_directory(file, ec))
    throw SceneError(file.string() + ": is a directory, not a scene file (JSON)");
  std::ifstream in(file);
  if (!in) throw SceneError(file.string() + ": cannot open the scene file");
  std::stringstream buf;
  buf << in.rdbuf();
  s.text = buf.str();
  json j;
  try {
    j = json::parse(s.text);
  } catch (const json::parse_error& e) {
    throw SceneError(file.string() + ": not valid JSON: " + e.what());
  }
  const Fields f{file.string()};
  if (!j.is_object()) f.fail("(top level)", "expected an object");
  // A manifest given where a scene is asked for (`simulate motions/cmu_walk.json`): name the
  // mix-up, not the manifest's first field as unknown.
  if (!j.contains("garment") && !j.contains("manifest") && j.contains("clips") &&
      j["clips"].is_array() && !j["clips"].empty() && j["clips"][0].is_object())
    f.fail("(top level)",
           "a motion manifest, not a scene file; a scene names a manifest, the garment, the "
           "material and the solver (motions/README.md; e.g. motions/skirt_walk.json)");
  f.only(j,
         {"name", "manifest", "clips", "garment", "material", "solver", "colliders", "air_drag",
          "settle_frames", "steering", "graph"},
         "");
  s.name = f.string(j, "name", "", file.stem().string());
  const std::string manifest = f.string(j, "manifest", "", "");
  if (manifest.empty()) f.fail("manifest", "required: the motion manifest (JSON) this scene uses");
  std::filesystem::path manifest_path = manifest;
  if (manifest_path.is_relative()) manifest_path = file.parent_path() / manifest_path;
  // The manifest's own errors name the manifest; the scene and its field say where it was named.
  try {
    s.manifest = load_manifest(manifest_path);
  } catch (const MotionError& e) {
    f.fail("manifest", e.what());
  }
  if (j.contains("clips")) {
    if (!j["clips"].is_array() || j["clips"].empty())
      f.fail("clips", "expected a non-empty array of clip names");
    for (size_t i = 0; i < j["clips"].size(); ++i) {
      if (!j["clips"][i].is_string())
        f.fail("clips[" + std::to_string(i) + "]", "expected a string");
      const std::string name = j["clips"][i].get<std::string>();
      try {
        s.manifest.require(name);
      } catch (const MotionError& e) {
        f.fail("clips[" + std::to_string(i) + "]", e.what());
      }
      s.clips.push_back(name);
    }
  } else {
    for (const auto& c : s.manifest.clips) s.clips.push_back(c.name);
  }

  if (!j.contains("garment"))
    f.fail("garment", "required: {\"type\": \"skirt\" | \"cape\" | \"mesh\", ...}");
  const json& g = f.object(j, "garment", "");
  const std::string type = f.string(g, "type", "garment.", "");
  if (type == "skirt") {
    f.only(g, {"type", "bone", "waist_radius", "flare", "length", "raise", "vertices"}, "garment.");
    s.garment_kind = GarmentKind::Skirt;
    s.skirt.bone = f.string(g, "bone", "garment.", s.skirt.bone);
    s.skirt.waist_radius = f.number(g, "waist_radius", "garment.", 0.0, false, true);
    s.skirt.flare = f.number(g, "flare", "garment.", s.skirt.flare, true);
    s.skirt.length = f.number(g, "length", "garment.", s.skirt.length, true);
    s.skirt.raise = f.number(g, "raise", "garment.", s.skirt.raise);
    s.skirt.vertices =
        f.integer(g, "vertices", "garment.", s.skirt.vertices, 16, kMaxGeneratedVertices);
  } else if (type == "cape") {
    f.only(g, {"type", "bone", "width", "length", "back_offset", "vertices"}, "garment.");
    s.garment_kind = GarmentKind::Cape;
    s.cape.bone = f.string(g, "bone", "garment.", "");
    s.cape.width = f.number(g, "width", "garment.", 0.0, false, true);
    s.cape.length = f.number(g, "length", "garment.", s.cape.length, true);
    s.cape.back_offset = f.number(g, "back_offset", "garment.", 0.0, false, true);
    s.cape.vertices =
        f.integer(g, "vertices", "garment.", s.cape.vertices, 16, kMaxGeneratedVertices);
  } else if (type == "mesh") {
    f.only(g, {"type", "file", "scale", "weld_tolerance", "pins", "bone"}, "garment.");
    s.garment_kind = GarmentKind::Mesh;
    std::filesystem::path mesh_file = f.string(g, "file", "garment.", "");
    if (mesh_file.empty()) f.fail("garment.file", "required for a mesh garment");
    if (mesh_file.is_relative()) mesh_file = file.parent_path() / mesh_file;
    s.mesh.file = mesh_file.string();
    s.mesh.scale = f.number(g, "scale", "garment.", 1.0, true);
    s.mesh.weld_tolerance =
        f.number(g, "weld_tolerance", "garment.", s.mesh.weld_tolerance, false, true);
    s.mesh.bone = f.string(g, "bone", "garment.", "");
    const json& p = f.object(g, "pins", "garment.");
    if (p.contains("vertex_group")) {
      s.mesh.pins.kind = PinRuleKind::VertexGroup;
      s.mesh.pins.group = f.string(p, "vertex_group", "garment.pins.", "");
    } else if (p.contains("height_band")) {
      const json& band = p["height_band"];
      if (!band.is_array() || band.size() != 2 || !band[0].is_number() || !band[1].is_number() ||
          band[0].get<double>() > band[1].get<double>())
        f.fail("garment.pins.height_band", "expected [low, high] in metres with low <= high");
      s.mesh.pins.kind = PinRuleKind::HeightBand;
      s.mesh.pins.y_min = band[0].get<double>();
      s.mesh.pins.y_max = band[1].get<double>();
    } else if (p.contains("bone")) {
      s.mesh.pins.kind = PinRuleKind::BoneDistance;
      s.mesh.pins.bone = f.string(p, "bone", "garment.pins.", "");
      s.mesh.pins.distance = f.number(p, "distance", "garment.pins.", s.mesh.pins.distance, true);
    } else {
      f.fail("garment.pins",
             "required: {\"vertex_group\": NAME} | {\"height_band\": [lo, hi]} | {\"bone\": NAME, "
             "\"distance\": M}");
    }
  } else {
    f.fail("garment.type", "expected \"skirt\", \"cape\" or \"mesh\", got \"" + type + "\"");
  }

  const json& m = f.object(j, "material", "");
  f.only(m, {"density", "youngs_modulus", "poisson", "thickness", "bending_stiffness", "damping"},
         "material.");
  s.material.density = f.number(m, "density", "material.", s.material.density, true);
  s.material.youngs_modulus =
      f.number(m, "youngs_modulus", "material.", s.material.youngs_modulus, true);
  s.material.poisson = f.number(m, "poisson", "material.", s.material.poisson, false, true);
  if (s.material.poisson >= 0.5) f.fail("material.poisson", "expected a value in [0, 0.5)");
  s.material.thickness = f.number(m, "thickness", "material.", s.material.thickness, true);
  s.material.bending_stiffness =
      f.number(m, "bending_stiffness", "material.", s.material.bending_stiffness);
  s.material.damping = f.number(m, "damping", "material.", s.material.damping, false, true);

  const json& so = f.object(j, "solver", "");
  // The scene's defaults where the block is silent; parsed and checked by the one serialiser of
  // solver settings (database/run_settings.hpp), so every field a database records may be set here.
  s.solver = SolverKind::Xpbd;
  s.settings.substeps = 10;
  s.settings.iterations = 1;
  s.settings.threads = 1;
  try {
    parse_solver_settings_json(so.dump(), file.string(), &s.solver, &s.settings, "solver.");
  } catch (const SettingsError& e) {
    throw SceneError(e.what());
  }
  if (s.settings.self_collision_thickness_mm > 0.0 && s.solver != SolverKind::Xpbd)
    f.fail("solver.self_collision.thickness_mm",
           std::string("self-collision is implemented for xpbd only, not for ") +
               solver_name(s.solver));
  // The coarse copy drives the garment (docs/guide/resolution.md): one as fine or finer only costs
  // more and gives the garment nothing it would not get solved itself.
  if (s.settings.coarse_vertices > 0) {
    const std::string refusal = coarse_drive_refusal(s.solver, s.garment_kind);
    if (!refusal.empty()) f.fail("solver.coarse_vertices", refusal);
    const int fine = s.garment_kind == GarmentKind::Cape ? s.cape.vertices : s.skirt.vertices;
    if (s.settings.coarse_vertices >= fine)
      f.fail("solver.coarse_vertices", "must be fewer than garment.vertices (got " +
                                           std::to_string(s.settings.coarse_vertices) +
                                           ", garment.vertices " + std::to_string(fine) +
                                           "); 0 or absent solves the garment itself");
  }

  const json& c = f.object(j, "colliders", "");
  f.only(c,
         {"bones", "auto_distance", "radius", "margin", "friction_static", "friction_kinetic",
          "motion"},
         "colliders.");
  if (c.contains("bones")) {
    if (!c["bones"].is_array()) f.fail("colliders.bones", "expected an array of bone names");
    for (size_t i = 0; i < c["bones"].size(); ++i) {
      if (!c["bones"][i].is_string())
        f.fail("colliders.bones[" + std::to_string(i) + "]", "expected a string");
      s.body.bones.push_back(c["bones"][i].get<std::string>());
    }
  }
  s.auto_distance = f.number(c, "auto_distance", "colliders.", 0.0, false, true);
  const json& r = f.object(c, "radius", "colliders.");
  for (auto it = r.begin(); it != r.end(); ++it) {
    if (!it.value().is_number() || it.value().get<double>() <= 0)
      f.fail("colliders.radius." + it.key(), "expected a positive number of metres");
    s.body.radius[it.key()] = it.value().get<double>();
  }
  s.margin = f.number(c, "margin", "colliders.", s.margin, true);
  s.friction_static = f.number(c, "friction_static", "colliders.", s.friction_static, false, true);
  s.friction_kinetic =
      f.number(c, "friction_kinetic", "colliders.", s.friction_kinetic, false, true);
  try {
    s.collider_motion = parse_collider_motion(
        f.string(c, "motion", "colliders.", collider_motion_name(s.collider_motion)));
  } catch (const std::invalid_argument& e) {
    f.fail("colliders.motion", e.what());
  }
  s.air_drag = f.number(j, "air_drag", "", s.air_drag, false, true);
  s.settle_frames = f.integer(j, "settle_frames", "", s.settle_frames, 0, kMaxSettleFrames);
  const json& st = f.object(j, "steering", "");
  f.only(st, {"frames", "max_mm"}, "steering.");
  s.steering.frames = f.integer(st, "frames", "steering.", s.steering.frames, 0, 1000);
  s.steering.max_distance =
      1e-3 * f.number(st, "max_mm", "steering.", 1e3 * s.steering.max_distance, true);
  if (j.contains("graph")) s.graph = f.object(j, "graph", "");
  return s;
}

int CharacterScene::clip_index(const std::string& name) const {
  for (size_t i = 0; i < clips.size(); ++i)
    if (clips[i].name == name) return static_cast<int>(i);
  std::string list;
  for (const auto& c : clips) list += (list.empty() ? "" : ", ") + c.name;
  throw SceneError(file.path.string() + ": no clip '" + name + "' in this scene (clips: " + list +
                   ")");
}

CharacterScene build_character_scene(const SceneFile& file) {
  CharacterScene scene;
  scene.file = file;
  for (const auto& name : file.clips) {
    LoadedMotion motion = load_clip(file.manifest, file.manifest.require(name));
    if (scene.clips.empty()) {
      scene.skeleton = std::move(motion.skeleton);
    } else if (motion.skeleton.names != scene.skeleton.names) {
      throw SceneError(file.path.string() + ": clip '" + name + "' (" + motion.clip.source +
                       ") has a different skeleton from clip '" + scene.clips.front().name + "'");
    }
    motion.clip.name = name;
    scene.clips.push_back(std::move(motion.clip));
  }
  scene.bind = rest_pose(scene.skeleton);
  switch (file.garment_kind) {
    case GarmentKind::Skirt:
      scene.garment = make_skirt(scene.skeleton, file.skirt);
      break;
    case GarmentKind::Cape:
      scene.garment = make_cape(scene.skeleton, file.cape);
      break;
    case GarmentKind::Mesh:
      // The mesh's errors name the mesh file; the scene and its field say where it was named.
      try {
        scene.garment = import_garment(scene.skeleton, file.mesh);
      } catch (const GarmentError& e) {
        throw GarmentError(file.path.string() + ": garment.file: " + e.what());
      }
      break;
  }
  scene.model = make_model(scene.garment.mesh, file.material, scene.garment.pins);
  if (file.auto_distance > 0) {
    // Bones near the garment over the first clip's frames (sampled), so a limb that only swings
    // close later is still found.
    Body merged;
    const MotionClip& clip = scene.clips.front();
    for (int f = 0; f < clip.frame_count; f += std::max(1, clip.frame_count / 8)) {
      const Eigen::Matrix3Xd x = carry_garment(scene.garment, scene.bind, clip_pose(clip, f));
      for (const auto& cap :
           make_body_near(scene.skeleton, clip, x, file.auto_distance, file.body, f).capsules) {
        bool have = false;
        for (const auto& m : merged.capsules)
          have |= (m.joint == cap.joint && m.child == cap.child);
        if (!have) merged.capsules.push_back(cap);
      }
    }
    scene.body = merged;
  } else {
    scene.body = make_body(scene.skeleton, file.body);
  }
  // Where the garment sits (docs/guide/garment_placement.md). A mesh garment is judged on it; the
  // procedural skirt and cape are built from the skeleton (the skirt's waist is loose by design:
  // its radius adds the thigh's and 2 cm), so their pins are only reported.
  if (file.garment_kind == GarmentKind::Mesh) {
    scene.placement = check_placement(scene.skeleton, scene.bind, scene.garment, file.body.radius,
                                      scene.body.capsules, file.auto_distance > 0,
                                      file.path.string(), "garment.file (" + file.mesh.file + ")");
  } else {
    BodySpec every_bone;
    every_bone.radius = file.body.radius;
    scene.placement =
        measure_placement(scene.skeleton, scene.bind, scene.garment,
                          make_body(scene.skeleton, every_bone).capsules, scene.body.capsules);
    scene.placement.auto_colliders = file.auto_distance > 0;
    const double never = std::numeric_limits<double>::infinity();
    for (const std::string& w :
         placement_warnings(scene.placement, file.path.string(), "garment", {never, never}))
      std::fprintf(stderr, "%s\n", w.c_str());
  }
  scene.env.air_drag = file.air_drag;
  scene.env.collision_margin = file.margin;
  scene.env.friction_static = file.friction_static;
  scene.env.friction_kinetic = file.friction_kinetic;
  scene.env.collider_motion = file.collider_motion;
  return scene;
}

std::vector<JointPose> clip_pose(const MotionClip& clip, int frame) {
  std::vector<JointPose> pose(clip.joint_count);
  for (int j = 0; j < clip.joint_count; ++j) {
    pose[j].position = clip.position(frame, j);
    pose[j].rotation = clip.rotation(frame, j);
  }
  return pose;
}

namespace {

// `pose` blended toward `target` by weight w in [0, 1]: joint positions linearly, orientations by
// slerp (both world transforms).
std::vector<JointPose> blend_pose(const std::vector<JointPose>& pose,
                                  const std::vector<JointPose>& target, double w) {
  std::vector<JointPose> out(pose.size());
  for (size_t j = 0; j < pose.size(); ++j) {
    out[j].position = (1.0 - w) * pose[j].position + w * target[j].position;
    out[j].rotation = pose[j].rotation.slerp(w, target[j].rotation).normalized();
  }
  return out;
}

}  // namespace

std::unique_ptr<Solver> make_scene_solver(const CharacterScene& scene, SolverKind kind,
                                          const SolverSettings& settings) {
  if (settings.coarse_vertices <= 0) return make_solver(kind, scene.model, settings);
  const std::string refusal = coarse_drive_refusal(kind, scene.file.garment_kind);
  if (!refusal.empty())
    throw SceneError(scene.file.path.string() + ": solver.coarse_vertices: " + refusal);
  // The same garment from the same parameters at the coarse count: the same rest surface.
  Garment coarse;
  switch (scene.file.garment_kind) {
    case GarmentKind::Skirt: {
      SkirtSpec spec = scene.file.skirt;
      spec.vertices = settings.coarse_vertices;
      coarse = make_skirt(scene.skeleton, spec);
      break;
    }
    case GarmentKind::Cape: {
      CapeSpec spec = scene.file.cape;
      spec.vertices = settings.coarse_vertices;
      coarse = make_cape(scene.skeleton, spec);
      break;
    }
    case GarmentKind::Mesh:  // refused above
      throw std::logic_error("make_scene_solver: a mesh garment passed coarse_drive_refusal");
  }
  // The same rule as the scene file's (load_scene_file), for a count given elsewhere (`bench
  // character --coarse-vertices`), on the meshes as made.
  if (coarse.mesh.vertex_count() >= scene.model.vertex_count())
    throw SceneError(scene.file.path.string() + ": solver.coarse_vertices " +
                     std::to_string(settings.coarse_vertices) + " makes " +
                     std::to_string(coarse.mesh.vertex_count()) +
                     " vertices, not fewer than the garment's " +
                     std::to_string(scene.model.vertex_count()) + ": nothing to drive");
  return make_upsampled_solver(scene.model,
                               make_model(coarse.mesh, scene.file.material, coarse.pins), settings);
}

ClothState settle_garment(const CharacterScene& scene, Solver& solver,
                          const std::vector<JointPose>& pose) {
  // Settle in the bind pose, where the garment was made and fits the body (no leg through the
  // skirt, whatever the target pose), moved rigidly onto the target's anchor bone so the garment
  // is already where and how it will hang; then blend the limbs into the target pose and hold it
  // (docs/notebook/BENCHMARKS.md, "Settling from any start frame": a skirt put straight into a pose
  // with the legs apart and projected out of the capsules was caught around a leg, over 600 %
  // strain). A third of the settle frames each.
  const int frames = scene.file.settle_frames;
  std::vector<JointPose> start = pose;
  if (frames > 0) {
    const int anchor = scene.garment.anchor_joint;
    const Eigen::Quaterniond turn = pose[anchor].rotation * scene.bind[anchor].rotation.inverse();
    for (size_t j = 0; j < start.size(); ++j) {
      start[j].rotation = (turn * scene.bind[j].rotation).normalized();
      start[j].position =
          pose[anchor].position + turn * (scene.bind[j].position - scene.bind[anchor].position);
    }
  }
  ClothState state;
  state.x = carry_garment(scene.garment, scene.bind, start);
  state.v = Eigen::Matrix3Xd::Zero(3, state.x.cols());
  // Push anything that starts inside the body out first, then let it hang.
  Environment env = scene.env;
  env.capsules = body_capsules(scene.body, scene.skeleton, start, start);
  resolve_collisions(state.x, state.x, scene.model.inv_mass, env, 1.0);
  if (frames > 0) {
    const int hold = frames / 3, blend = std::max(1, frames / 3);
    std::vector<std::vector<JointPose>> poses;
    poses.reserve(static_cast<size_t>(frames) + 1);
    for (int f = 0; f <= frames; ++f) {
      // Smoothstep weight: the limbs start and stop moving gently.
      const double t = std::clamp(static_cast<double>(f - hold) / blend, 0.0, 1.0);
      poses.push_back(blend_pose(start, pose, t * t * (3.0 - 2.0 * t)));
    }
    const PoseRun run = simulate_poses(scene, solver, poses, 30.0, state);
    if (!run.stable)
      throw SceneError(scene.file.path.string() + ": the garment does not settle: " + run.message);
  }
  state.v.setZero();
  return state;
}

PoseRun simulate_poses(const CharacterScene& scene, Solver& solver,
                       const std::vector<std::vector<JointPose>>& poses, double rate,
                       ClothState& state,
                       const std::function<void(size_t, ClothState&)>& before_step) {
  PoseRun run;
  Environment env = scene.env;
  StepInputs inputs;
  inputs.env = &env;
  const double dt = 1.0 / rate;
  for (size_t f = 1; f < poses.size(); ++f) {
    env.capsules = body_capsules(scene.body, scene.skeleton, poses[f - 1], poses[f]);
    inputs.kinematic_targets = skin_pins(scene.garment, scene.bind, poses[f]);
    if (before_step) before_step(f, state);
    const auto start = std::chrono::steady_clock::now();
    const StepReport report = solver.step(state, dt, inputs);
    run.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (!report.stable) {
      run.stable = false;
      run.message = "step " + std::to_string(f) + ": " + report.message;
      break;
    }
    run.step_halvings += report.step_halvings;
    FrameMetrics m;
    m.max_strain = max_edge_strain(scene.model, state.x);
    m.max_penetration = max_penetration(state.x, scene.model.inv_mass, env);
    m.mean_penetration = mean_penetration(state.x, scene.model.inv_mass, env);
    m.kinetic_energy = kinetic_energy(scene.model, state.v);
    m.step_halvings = report.step_halvings;
    m.iterations = report.iterations;
    m.factorizations = report.factorizations;
    m.strain_limit_passes = report.strain_limit_passes;
    m.strain_limit_capped = report.strain_limit_capped;
    run.metrics.push_back(m);
    run.frames.push_back(state.x);
  }
  run.end_velocity = state.v;
  return run;
}

Eigen::Isometry3d character_frame(const CharacterScene& scene, const std::vector<JointPose>& pose) {
  // Heading: the root's bind-pose +z carried by its rotation, projected onto the floor.
  const Eigen::Quaterniond motion = pose[0].rotation * scene.bind[0].rotation.inverse();
  Vec3 forward = motion * Vec3(0, 0, 1);
  forward.y() = 0;
  if (forward.norm() < 1e-6) {  // root pitched straight up or down: use its x axis instead
    forward = motion * Vec3(1, 0, 0);
    forward = Vec3(-forward.z(), 0, forward.x());
  }
  const double yaw = std::atan2(forward.x(), forward.z());
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = Eigen::AngleAxisd(yaw, Vec3::UnitY()).toRotationMatrix();
  t.translation() = Vec3(pose[0].position.x(), 0.0, pose[0].position.z());
  return t;
}

}  // namespace clothdb
