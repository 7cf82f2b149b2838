// Garments on a character: procedural skirt and cape on the real CMU and boxing motions, pins
// that follow their bones exactly, collisions with the body capsules, and bad scenes refused.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <utility>
#include <vector>

#include "bench/character_bench.hpp"
#include "character_scene/character_scene.hpp"
#include "database/format/artist_mesh.hpp"
#include "database/store/writer.hpp"
#include "edit/clip_edit.hpp"
#include "exchange/point_cache.hpp"
#include "garment/garment.hpp"
#include "support/cli.hpp"
#include "support/temp_dir.hpp"

using namespace clothdb;

namespace {

const std::string kMotions = std::string(CLOTHDB_SOURCE_DIR) + "/motions/";

std::string write_temp(const std::string& name, const std::string& text) {
  const std::string path = testing::TempDir() + "/" + name;
  std::ofstream(path) << text;
  return path;
}

// A scene file in the temp dir that points at the bundled manifest.
std::string temp_scene(const std::string& name, const std::string& body) {
  return write_temp(name, "{\"manifest\": \"" + kMotions + "cmu_walk.json\", " + body + "}");
}

// Runs `frames` frames of the scene's first clip from the settled state; checks every frame.
void expect_clean_run(const CharacterScene& scene, int frames, double strain_limit) {
  auto solver = make_solver(scene.file.solver, scene.model, scene.file.settings);
  const MotionClip& clip = scene.clips.front();
  ClothState state = settle_garment(scene, *solver, clip_pose(clip, 0));
  const double thickness = scene.file.material.thickness;
  for (int f = 1; f < frames; ++f) {
    const PoseRun run = simulate_poses(scene, *solver, {clip_pose(clip, f - 1), clip_pose(clip, f)},
                                       clip.rate, state);
    ASSERT_TRUE(run.stable) << run.message;
    ASSERT_TRUE(state.x.allFinite()) << "frame " << f;
    EXPECT_LE(run.metrics[0].max_penetration, thickness) << "frame " << f;
    EXPECT_LE(run.metrics[0].max_strain, strain_limit) << "frame " << f;
  }
}

}  // namespace

TEST(Garment, SkirtPinsFollowTheHipsExactly) {
  const SceneFile file = load_scene_file(kMotions + "skirt_walk.json");
  const CharacterScene scene = build_character_scene(file);
  ASSERT_GE(scene.model.vertex_count(), 1500);
  const int hips = scene.skeleton.require("Hips");
  const MotionClip& clip = scene.clips.front();
  for (int f : {0, 17, 100}) {
    const auto pose = clip_pose(clip, f);
    const Eigen::Matrix3Xd pins = skin_pins(scene.garment, scene.bind, pose);
    // Each pin keeps its offset in the hips' frame: R_bind^T (p_rest - t_bind) = R^T (p - t).
    for (size_t k = 0; k < scene.garment.pins.size(); ++k) {
      const Vec3 rest = scene.garment.mesh.rest.col(scene.garment.pins[k]);
      const Vec3 local_bind =
          scene.bind[hips].rotation.inverse() * (rest - scene.bind[hips].position);
      const Vec3 local_now =
          pose[hips].rotation.inverse() * (Vec3(pins.col(k)) - pose[hips].position);
      EXPECT_LT((local_bind - local_now).norm(), 1e-9);
    }
  }
}

// The strain bound (docs/RESULTS.md#strain-how-much-the-cloth-stretches) on the demo skirt
// (flare 1.5) over 01_01's first 125 frames, where the legs lift into the hem. Without the contact
// round the collision pass has the last word: the thigh pushes the hem ring outward and its edges
// stretch to about 9-11 % (the worst edge lies at the collision margin of a leg). With the scene's
// round (the strain limit once more after the collision pass) the hem slides and stays within 6 %,
// with no vertex below the body's surface.
TEST(Garment, SkirtOnWalkStaysWithinTheStrainBoundWhereTheBodyPushesOnIt) {
  const SceneFile file = load_scene_file(kMotions + "skirt_walk.json");
  ASSERT_GE(file.settings.strain_limit_contact_rounds, 1);
  CharacterBenchOptions options;
  options.clip = "01_01";
  options.frames = 125;
  const auto with_rounds = run_character_bench(file, options);
  options.contact_rounds = 0;
  const auto without = run_character_bench(file, options);
  ASSERT_EQ(with_rounds.size(), 1u);
  ASSERT_EQ(without.size(), 1u);
  for (const auto* r : {&with_rounds[0], &without[0]}) {
    ASSERT_TRUE(r->stable) << r->message;
    EXPECT_EQ(r->frames, 124);
    EXPECT_LE(r->max_penetration, file.material.thickness) << r->solver;
  }
  EXPECT_GT(without[0].max_strain, 0.08);
  EXPECT_LE(without[0].worst_edge_gap, file.margin + 1e-3) << without[0].worst_edge_bone;
  EXPECT_LE(with_rounds[0].max_strain, 0.06) << "frame " << with_rounds[0].worst_frame;
  EXPECT_LE(with_rounds[0].p99_strain, 0.03);
}

// `bench character --reference --strain-targets`: each run is compared with the same setting at
// 8x the sub-steps (scene_reference), over the same frames; a strain target that every run meets
// marks exactly one run, one that none meets marks none.
TEST(Garment, BenchCharacterComparesEachRunWithItsSettingAtEightTimesTheSubsteps) {
  SceneFile file = load_scene_file(kMotions + "skirt_walk.json");
  file.settle_frames = 3;
  CharacterBenchOptions options;
  options.clip = "01_01";
  options.frames = 5;
  options.substeps = {4, 6};
  options.reference = true;
  options.strain_targets = {1.0, 1e-6};
  const auto rows = run_character_bench(file, options);
  ASSERT_EQ(rows.size(), 2u);
  int marked_all = 0, marked_none = 0;
  for (const CharacterBenchRow& r : rows) {
    ASSERT_TRUE(r.stable) << r.message;
    const int substeps = r.solver.find("substeps=4 ") != std::string::npos ? 4 : 6;
    EXPECT_NE(r.reference.find("substeps=" + std::to_string(8 * substeps) + " "), std::string::npos)
        << r.reference;
    // A run is not its own reference: a coarser step leaves the cloth somewhere else.
    EXPECT_GT(r.reference_rms_mm, 0.0) << r.solver;
    EXPECT_GE(r.reference_max_mm, r.reference_rms_mm) << r.solver;
    for (double t : r.cheapest_for) (t == 1.0 ? marked_all : marked_none)++;
  }
  EXPECT_EQ(marked_all, 1);
  EXPECT_EQ(marked_none, 0);
}

// The demo skirt at 3,000 and 12,000 vertices (motions/skirt_walk_12k.json) with the setting
// docs/guide/resolution.md gives for 12k (strain-limit over-relaxation 1.8, Chebyshev rho 0.8 on
// 4 stretch sweeps): over 01_01's first 30 frames after a short settle, within 0.5 % of the strain
// limit at both resolutions. The 12k skirt goes above it later in the clip
// (frames 45-73, docs/notebook/resolution.md); this pins the short window only.
TEST(Garment, DemoSkirtStaysWithinTheStrainBoundAtThreeAndTwelveThousandVertices) {
  for (const char* name : {"skirt_walk.json", "skirt_walk_12k.json"}) {
    SceneFile file = load_scene_file(kMotions + name);
    file.settle_frames = 10;
    CharacterBenchOptions options;
    options.clip = "01_01";
    options.frames = 30;
    options.strain_limit_relaxation = 1.8;
    options.chebyshev_rho = 0.8;
    options.stretch_iterations = 4;
    const auto rows = run_character_bench(file, options);
    ASSERT_EQ(rows.size(), 1u);
    const CharacterBenchRow& r = rows[0];
    ASSERT_TRUE(r.stable) << name << ": " << r.message;
    EXPECT_EQ(r.frames, 29) << name;
    // Measured: p99 2.47 % and 2.49 %, max 2.50 % at both (the limit holds).
    EXPECT_LE(r.max_strain, 0.03) << name << ", frame " << r.worst_frame;
    EXPECT_LE(r.p99_strain, 0.026) << name;
    EXPECT_LE(r.max_penetration, file.material.thickness) << name;
  }
}

// Settling (docs/notebook/BENCHMARKS.md, "Settling from any start frame"): settled from 01_01
// frames where the legs are apart, the skirt used to be put straight into the pose and caught
// around a leg (over 600 % strain). Settled in the bind pose and blended into the pose, it hangs
// within the strain bound, outside the body, and its pins are where skinning puts them.
TEST(Garment, SettleFromLegsApartStaysWithinTheStrainBound) {
  const CharacterScene scene =
      build_character_scene(load_scene_file(kMotions + "skirt_walk_flared.json"));
  auto solver = make_solver(scene.file.solver, scene.model, scene.file.settings);
  const MotionClip& clip = scene.clips[static_cast<size_t>(scene.clip_index("01_01"))];
  for (int frame : {100, 380}) {
    const auto pose = clip_pose(clip, frame);
    const ClothState state = settle_garment(scene, *solver, pose);
    ASSERT_TRUE(state.x.allFinite()) << "frame " << frame;
    EXPECT_LE(max_edge_strain(scene.model, state.x), 0.06) << "frame " << frame;
    Environment env = scene.env;
    env.capsules = body_capsules(scene.body, scene.skeleton, pose, pose);
    EXPECT_LE(max_penetration(state.x, scene.model.inv_mass, env), scene.file.material.thickness)
        << "frame " << frame;
    const Eigen::Matrix3Xd pins = skin_pins(scene.garment, scene.bind, pose);
    for (size_t k = 0; k < scene.garment.pins.size(); ++k)
      EXPECT_LT(
          (Vec3(state.x.col(scene.garment.pins[k])) - Vec3(pins.col(static_cast<Eigen::Index>(k))))
              .norm(),
          1e-9)
          << "frame " << frame << " pin " << k;
  }
}

TEST(Garment, CapeOnBoxingDoesNotPenetrateOrOverstretch) {
  SceneFile file = load_scene_file(kMotions + "cape_boxing.json");
  const CharacterScene scene = build_character_scene(file);
  // auto_distance selects only the bones near the cape: fewer than all of the skeleton's.
  EXPECT_LT(scene.body.capsules.size(), all_bone_capsules(scene.skeleton).size());
  EXPECT_GT(scene.body.capsules.size(), 0u);
  // The cape's target (docs/RESULTS.md#strain-how-much-the-cloth-stretches) is 8 % (66 % before it;
  // 17 % with the strain limit capped at 16 passes and no contact round).
  expect_clean_run(scene, 45, 0.08);
}

TEST(Garment, EverySolverRunsTheSkirtAndTheCape) {
  // The bundled scenes with each of the four solvers (few vertices, so this stays quick): every
  // frame is finite, no vertex is deeper in a capsule than the cloth's thickness, and the pinned
  // vertices of the simulated cloth sit exactly where linear blend skinning puts them.
  for (const char* name : {"skirt_walk.json", "cape_boxing.json"}) {
    SceneFile file = load_scene_file(kMotions + name);
    // Few vertices: explicit mass-spring needs about 20,000 sub-steps per frame at 300.
    file.skirt.vertices = file.cape.vertices = 150;
    file.settle_frames = 3;
    for (SolverKind kind :
         {SolverKind::MassSpring, SolverKind::Pbd, SolverKind::Xpbd, SolverKind::Newton}) {
      SCOPED_TRACE(std::string(name) + " " + solver_name(kind));
      file.solver = kind;
      // The cape's self-collision is XPBD's alone; the others refuse it (test_self_collision).
      if (kind != SolverKind::Xpbd) file.settings.self_collision_thickness_mm = 0.0;
      file.settings.substeps = kind == SolverKind::Newton ? 1 : 10;
      file.settings.iterations = kind == SolverKind::Pbd ? 20 : 2;
      const CharacterScene scene = build_character_scene(file);
      SolverSettings settings = file.settings;
      // Explicit mass-spring needs the sub-step its own stability limit asks for.
      if (kind == SolverKind::MassSpring)
        settings.substeps =
            static_cast<int>(std::ceil((1.0 / 30.0) / mass_spring_critical_dt(scene.model)));
      auto solver = make_solver(kind, scene.model, settings);
      const MotionClip& clip = scene.clips.front();
      ClothState state = settle_garment(scene, *solver, clip_pose(clip, 0));
      for (int f = 1; f < 5; ++f) {
        const PoseRun run = simulate_poses(
            scene, *solver, {clip_pose(clip, f - 1), clip_pose(clip, f)}, clip.rate, state);
        ASSERT_TRUE(run.stable) << run.message;
        ASSERT_TRUE(state.x.allFinite()) << "frame " << f;
        EXPECT_LE(run.metrics[0].max_penetration, file.material.thickness) << "frame " << f;
        const Eigen::Matrix3Xd pins = skin_pins(scene.garment, scene.bind, clip_pose(clip, f));
        double worst = 0;
        for (size_t k = 0; k < scene.garment.pins.size(); ++k)
          worst = std::max(worst, (Vec3(state.x.col(scene.garment.pins[k])) -
                                   Vec3(pins.col(static_cast<Eigen::Index>(k))))
                                      .norm());
        EXPECT_LT(worst, 1e-9) << "frame " << f << ": a pin is off its skinned position";
      }
    }
  }
}

TEST(Garment, BadScenesNameFileAndField) {
  auto expect_error = [](const std::string& path, const std::string& needle) {
    try {
      load_scene_file(path);
      FAIL() << "expected an error mentioning " << needle;
    } catch (const std::exception& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(needle), std::string::npos) << what;
      EXPECT_NE(what.find(std::filesystem::path(path).filename().string()), std::string::npos)
          << what;
    }
  };
  expect_error(temp_scene("bad_type.json", "\"garment\": {\"type\": \"hat\"}"), "garment.type");
  expect_error(
      temp_scene("bad_vertices.json", "\"garment\": {\"type\": \"skirt\", \"vertices\": -3}"),
      "garment.vertices");
  expect_error(temp_scene("bad_material.json",
                          "\"garment\": {\"type\": \"skirt\"}, \"material\": {\"density\": 0}"),
               "material.density");
  expect_error(temp_scene("bad_solver.json",
                          "\"garment\": {\"type\": \"skirt\"}, \"solver\": {\"name\": \"magic\"}"),
               "solver");
  expect_error(temp_scene("bad_field.json", "\"garment\": {\"type\": \"skirt\"}, \"colour\": 3"),
               "colour");
  expect_error(
      temp_scene("bad_clip.json", "\"garment\": {\"type\": \"skirt\"}, \"clips\": [\"nope\"]"),
      "clips[0]");
  expect_error(
      temp_scene("bad_motion.json",
                 "\"garment\": {\"type\": \"skirt\"}, \"colliders\": {\"motion\": \"teleport\"}"),
      "colliders.motion");
  expect_error(write_temp("not_json.json", "{ garment: "), "not valid JSON");
  expect_error(write_temp("no_manifest.json", "{\"garment\": {\"type\": \"skirt\"}}"), "manifest");
  // A motion manifest where a scene is asked for: the mix-up is named (it said "output_rate:
  // unknown field").
  expect_error(
      write_temp("a_manifest.json",
                 "{\"output_rate\": 30, \"clips\": [{\"name\": \"a\", \"file\": \"a.bvh\"}]}"),
      "a_manifest.json: (top level): a motion manifest, not a scene file");
  // A manifest that is not there: the scene and its field, then the path.
  expect_error(write_temp("lost_manifest.json",
                          "{\"manifest\": \"no_such_manifest.json\", \"garment\": {\"type\": "
                          "\"skirt\"}}"),
               "lost_manifest.json: manifest: ");
  // A coarse copy as fine as the garment (or finer) drives nothing (docs/guide/resolution.md).
  expect_error(temp_scene("coarse_finer.json",
                          "\"garment\": {\"type\": \"skirt\", \"vertices\": 200}, \"solver\": "
                          "{\"name\": \"xpbd\", \"coarse_vertices\": 3000}"),
               "solver.coarse_vertices: must be fewer than garment.vertices (got 3000, "
               "garment.vertices 200)");
  expect_error(temp_scene("coarse_same.json",
                          "\"garment\": {\"type\": \"cape\", \"vertices\": 300}, \"solver\": "
                          "{\"name\": \"xpbd\", \"coarse_vertices\": 300}"),
               "solver.coarse_vertices: must be fewer");
  // A bone the scene asks for that the skeleton does not have: named at build time.
  const SceneFile bad_bone = load_scene_file(
      temp_scene("bad_bone.json",
                 "\"garment\": {\"type\": \"skirt\", \"bone\": \"Tail\"}, \"clips\": [\"01_01\"]"));
  try {
    build_character_scene(bad_bone);
    FAIL();
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("Tail"), std::string::npos) << e.what();
  }
  // An empty mesh garment: the scene, its field and the mesh file, at build time.
  const std::string empty_obj = write_temp("empty_garment.obj", "");
  try {
    build_character_scene(load_scene_file(temp_scene(
        "empty_garment.json",
        "\"clips\": [\"01_01\"], \"garment\": {\"type\": \"mesh\", "
        "\"file\": \"" +
            empty_obj + "\", \"bone\": \"Hips\", \"pins\": {\"height_band\": [0.9, 1]}}")));
    FAIL() << "an empty OBJ garment was accepted";
  } catch (const GarmentError& e) {
    EXPECT_NE(std::string(e.what()).find("empty_garment.json: garment.file: "), std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("empty_garment.obj: no vertices"), std::string::npos)
        << e.what();
  }
  // A coarse count given beside the scene (`bench character --coarse-vertices`) that is not
  // coarser: refused when the solver is made.
  const CharacterScene small = build_character_scene(load_scene_file(
      temp_scene("coarse_override.json",
                 "\"clips\": [\"01_01\"], \"garment\": {\"type\": \"skirt\", \"vertices\": 200}")));
  SolverSettings finer = small.file.settings;
  finer.coarse_vertices = 5000;
  try {
    make_scene_solver(small, SolverKind::Xpbd, finer);
    FAIL() << "a coarse copy finer than the garment was accepted";
  } catch (const SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("not fewer than the garment's"), std::string::npos)
        << e.what();
  }
}

TEST(Garment, ImportedMeshIsWeldedAndPinned) {
  // Two quads exported as separate objects (seam vertices duplicated), pinned by height band.
  const std::string obj =
      write_temp("apron.obj",
                 "o left\nv -0.2 1.0 0.2\nv 0 1.0 0.2\nv 0 0.6 0.2\nv -0.2 0.6 0.2\nf 1 4 3 2\n"
                 "o right\nv 0 1.0 0.2\nv 0.2 1.0 0.2\nv 0.2 0.6 0.2\nv 0 0.6 0.2\nf 5 8 7 6\n");
  const SceneFile file = load_scene_file(temp_scene(
      "apron.json",
      "\"clips\": [\"01_01\"], \"garment\": {\"type\": \"mesh\", \"file\": \"" + obj +
          "\", \"scale\": 1, \"bone\": \"Hips\", \"pins\": {\"height_band\": [0.95, 1.05]}}"));
  const LoadedMotion motion = load_clip(file.manifest, 0);
  const Garment g = import_garment(motion.skeleton, file.mesh);
  EXPECT_EQ(g.mesh.vertex_count(), 6);  // 8 vertices, 2 welded along the seam
  EXPECT_EQ(g.pins.size(), 3u);         // the top row
  MeshGarmentSpec none = file.mesh;
  none.pins.y_min = 5.0;
  none.pins.y_max = 6.0;
  EXPECT_THROW(import_garment(motion.skeleton, none), GarmentError);
  // A non-manifold garment (three triangles on one edge) is refused.
  const std::string fan = write_temp(
      "fan.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n");
  MeshGarmentSpec bad = file.mesh;
  bad.file = fan;
  bad.pins.y_min = -10;
  bad.pins.y_max = 10;
  try {
    import_garment(motion.skeleton, bad);
    FAIL();
  } catch (const GarmentError& e) {
    EXPECT_NE(std::string(e.what()).find("manifold"), std::string::npos) << e.what();
  }
}

namespace {

// Imports an OBJ text as a mesh garment pinned by a height band around y = 1; returns the error
// message ("" when it loads) and what it printed on stderr.
std::pair<std::string, std::string> import_obj(const std::string& name, const std::string& obj,
                                               double weld = 1e-5) {
  const std::string path = write_temp(name, obj);
  const SceneFile file = load_scene_file(temp_scene(
      name + ".json", "\"clips\": [\"01_01\"], \"garment\": {\"type\": \"mesh\", \"file\": \"" +
                          path + "\", \"bone\": \"Hips\", \"weld_tolerance\": " +
                          std::to_string(weld) + ", \"pins\": {\"height_band\": [0.95, 1.05]}}"));
  static const LoadedMotion motion = load_clip(file.manifest, 0);
  testing::internal::CaptureStderr();
  std::string error;
  try {
    import_garment(motion.skeleton, file.mesh);
  } catch (const GarmentError& e) {
    error = e.what();
  }
  return {error, testing::internal::GetCapturedStderr()};
}

// A 0.4 x 0.4 m sheet from two quads, the right one's left edge `gap` metres from the left one's.
std::string two_quads(double gap) {
  const std::string x = std::to_string(gap);
  return "o left\nv -0.2 1.0 0.2\nv 0 1.0 0.2\nv 0 0.6 0.2\nv -0.2 0.6 0.2\nf 1 4 3 2\n"
         "o right\nv " +
         x + " 1.0 0.2\nv 0.2 1.0 0.2\nv 0.2 0.6 0.2\nv " + x + " 0.6 0.2\nf 5 8 7 6\n";
}

}  // namespace

TEST(Garment, ImportRefusesDamagedAndImplausibleGeometry) {
  auto [far, far_log] = import_obj("far.obj",
                                   "v 0 1 0\nv 0.2 1 0\nv 0 0.8 0\nv 1e30 0.8 0\n"
                                   "f 1 3 2\nf 2 3 4\n");
  EXPECT_NE(far.find("far.obj: the garment is 1e+30 m across"), std::string::npos) << far;
  EXPECT_NE(far.find("a vertex is at (1e+30, 0.8, 0)"), std::string::npos) << far;
  EXPECT_NE(far.find("garment.scale"), std::string::npos) << far;
  // NaN in the file: blamed on the file, not later on the solver.
  auto [nan, nan_log] = import_obj("nan.obj", "v 0 1 0\nv 0.2 1 0\nv nan 0.8 0\nf 1 3 2\n");
  EXPECT_NE(nan.find("nan.obj: a vertex has a non-finite coordinate (nan, 0.8, 0)"),
            std::string::npos)
      << nan;
  // A 20 um needle: refused with its id before it shows up as 18,000 % strain.
  auto [needle, needle_log] = import_obj("needle.obj",
                                         "v 0 1 0\nv 0.2 1 0\nv 0.1 1.00002 0\nv 0.1 0.8 0\n"
                                         "f 1 3 2\nf 1 2 4\n");
  EXPECT_NE(needle.find("needle triangles 0 "), std::string::npos) << needle;
  EXPECT_NE(needle.find("garment.weld_tolerance"), std::string::npos) << needle;
  // Collinear points: a zero-area triangle.
  auto [flat, flat_log] = import_obj("flat.obj",
                                     "v 0 1 0\nv 0.1 1 0\nv 0.2 1 0\nv 0.1 0.8 0\n"
                                     "f 1 2 3\nf 1 4 2\n");
  EXPECT_NE(flat.find("degenerate (zero-area) triangles 0"), std::string::npos) << flat;
  // A weld tolerance that merges most of the garment.
  auto [weld, weld_log] = import_obj("weld.obj", two_quads(0.0), 0.3);
  EXPECT_NE(weld.find("garment.weld_tolerance 0.3 m merges over"), std::string::npos) << weld;
  EXPECT_NE(weld.find("lower it"), std::string::npos) << weld;
  // A face naming a vertex the file does not have: its line and the count, in plain English.
  auto [index, index_log] = import_obj("index.obj", "v 0 1 0\nv 0.2 1 0\nv 0 0.8 0\nf 1 2 9\n");
  EXPECT_NE(index.find("index.obj:4: face vertex index 9 outside the 3 vertices so far"),
            std::string::npos)
      << index;
}

TEST(Garment, ImportWarnsOfAnOpenSeamJustAboveTheWeldTolerance) {
  // Welded: no warning.
  auto [ok, ok_log] = import_obj("closed.obj", two_quads(0.0));
  EXPECT_EQ(ok, "");
  EXPECT_EQ(ok_log.find("open seam"), std::string::npos) << ok_log;
  // A 30 um gap with a 10 um tolerance: loads, with a warning naming the gap and the seam length.
  auto [open, open_log] = import_obj("open.obj", two_quads(3e-5));
  EXPECT_EQ(open, "");
  EXPECT_NE(open_log.find("an open seam: 4 boundary vertices"), std::string::npos) << open_log;
  EXPECT_NE(open_log.find("closest gap 0.03 mm, seam length 0.4 m"), std::string::npos) << open_log;
  EXPECT_NE(open_log.find("raise garment.weld_tolerance"), std::string::npos) << open_log;
}

namespace {

test::CliResult run_clothdb(const std::string& arguments) {
  return test::run_clothdb(arguments, testing::TempDir() + "/clothdb_garment_cli.log");
}

}  // namespace

TEST(Garment, CommandLineRefusesBadScenesAndFilesAndWritesNothing) {
  // The user's view of "bad files and bad scenes fail with the named error": `clothdb simulate`
  // exits non-zero, names the file and what is wrong, and leaves no output directory behind.
  const std::string out = testing::TempDir() + "/cli_bad_out";
  std::filesystem::remove_all(out);
  auto expect_refused = [&](const std::string& scene, const std::vector<std::string>& needles) {
    const test::CliResult r =
        run_clothdb("simulate " + scene + " --frames 3 --preview-every 0 --out " + out);
    EXPECT_EQ(r.code, 1) << r.output;
    EXPECT_NE(r.output.find("clothdb: error:"), std::string::npos) << r.output;
    for (const auto& n : needles)
      EXPECT_NE(r.output.find(n), std::string::npos) << "'" << n << "' not in: " << r.output;
    EXPECT_FALSE(std::filesystem::exists(out)) << "output written for a refused scene: " << scene;
  };
  // A bad scene field.
  const std::string bad_type = temp_scene("cli_bad_type.json", "\"garment\": {\"type\": \"hat\"}");
  expect_refused(bad_type, {"cli_bad_type.json", "garment.type"});
  // A colliding bone the skeleton does not have.
  const std::string bad_bone =
      temp_scene("cli_bad_bone.json",
                 "\"clips\": [\"01_01\"], \"garment\": {\"type\": \"skirt\", \"vertices\": 200}, "
                 "\"colliders\": {\"bones\": [\"LeftUpLeg\", \"Tail\"]}");
  expect_refused(bad_bone, {"01_01.bvh", "bone 'Tail'"});
  // A truncated motion file behind a manifest.
  std::string bvh;
  {
    std::ifstream in(assimp_testmodels_dir() / "BVH/01_01.bvh", std::ios::binary);
    bvh.assign(std::istreambuf_iterator<char>(in), {});
  }
  ASSERT_GT(bvh.size(), 10000u);
  const std::string cut = write_temp("cli_cut.bvh", bvh.substr(0, bvh.size() / 2 + 7));
  const std::string manifest =
      write_temp("cli_cut_manifest.json",
                 "{\"output_rate\": 30, \"clips\": [{\"name\": \"cut\", \"file\": \"" + cut +
                     "\", \"scale\": 0.0564444}]}");
  const std::string scene = write_temp(
      "cli_cut_scene.json", "{\"manifest\": \"" + manifest +
                                "\", \"garment\": {\"type\": \"skirt\", \"vertices\": 200}}");
  expect_refused(scene, {"cli_cut.bvh"});
  // A scene file that is not there.
  expect_refused(testing::TempDir() + "/no_such_scene.json", {"no_such_scene.json", "cannot open"});
}

TEST(Garment, FastLimbsOnBoxingDoNotTunnel) {
  // The cape on the first 10 s of Boxing_Toes.bvh. Its fastest capsule moves several radii per
  // frame; with one projection per frame some vertices end on the far side of a limb (their path
  // crosses it), while swept capsules, or the scene's 15 sub-steps with interpolated capsules,
  // keep every vertex on its side and out of every capsule at every frame.
  const SceneFile file = load_scene_file(kMotions + "cape_boxing.json");
  ASSERT_EQ(file.collider_motion, ColliderMotion::Interpolated);
  ASSERT_EQ(file.settings.substeps, 15);
  const CharacterScene scene = build_character_scene(file);
  const MotionClip& clip = scene.clips[static_cast<size_t>(scene.clip_index("boxing"))];
  const CapsuleSpeed fast = fastest_capsule(scene, clip, 300);
  EXPECT_GT(fast.speed / clip.rate, 2 * fast.radius) << fast.bone << " " << fast.speed << " m/s";

  CharacterBenchOptions options;
  options.clip = "boxing";
  options.frames = 300;
  options.substeps = {1};
  // The collider motions are compared as they move the cloth; the contact round (the strain
  // limit after the collision pass) is for the scene's sub-steps: at one sub-step per frame the
  // limit chases strains of several hundred per cent and can drag a vertex across a limb.
  options.contact_rounds = 0;
  options.collider_motions = {ColliderMotion::Interpolated, ColliderMotion::Swept};
  // Without self-collision here: at one sub-step per frame its contacts, resolved after the
  // collision pass, can push a vertex 15 mm into a limb; the scene's 15 sub-steps run it below.
  options.self_collision_mm = {0.0};
  const auto one_step = run_character_bench(file, options);
  ASSERT_EQ(one_step.size(), 2u);
  // One projection per frame let vertices through a limb before the changes in
  // docs/notebook/BENCHMARKS.md, "Cloth that does not stretch"; its collision pass (contacts
  // resolved per vertex, also before the strain limit) no longer does on this clip, so only the
  // swept motion's guarantee is asserted here (the limb speed above shows the case is still hard).
  // `clothdb bench character motions/cape_boxing.json` reports both.
  EXPECT_EQ(one_step[1].tunnelled, 0) << "swept";
  options.substeps = {0};       // the scene's 15
  options.contact_rounds = -1;  // and its contact round
  options.collider_motions = {ColliderMotion::Interpolated};
  options.self_collision_mm = {file.settings.self_collision_thickness_mm};
  const auto chosen = run_character_bench(file, options);
  ASSERT_EQ(chosen.size(), 1u);
  EXPECT_EQ(chosen[0].tunnelled, 0);
  for (const auto* r : {&one_step[1], &chosen[0]}) {
    EXPECT_TRUE(r->stable) << r->message;
    EXPECT_EQ(r->frames, 299);
    EXPECT_LE(r->max_penetration, file.material.thickness) << r->solver;  // worst over all frames
  }
}

// ---- the artist's topology kept (docs/guide/mesh_garments.md) ----------------------------------

namespace {

// The committed test garment: quads, a pentagon, two triangles, a UV seam, per-vertex normals
// and two groups without materials (scripts/make_quad_skirt.py).
const std::string kQuadSkirt = kMotions + "garments/quad_skirt.obj";

// The faces of an OBJ as (vertex, UV, normal) per corner, face by face.
std::vector<std::array<uint32_t, 3>> obj_corners(const ObjMesh& m) {
  std::vector<std::array<uint32_t, 3>> out;
  for (size_t c = 0; c < m.corners.size(); ++c)
    out.push_back({m.corners[c], m.corner_uvs.empty() ? kObjNone : m.corner_uvs[c],
                   m.corner_normals.empty() ? kObjNone : m.corner_normals[c]});
  return out;
}

}  // namespace

namespace {

// A skirt-like tube of 16 x 6 vertices around the rest pose's Hips (at the origin in CMU's rest
// pose): radius 0.14 m at the top, growing by `flare` per row (so the thighs stay inside), rows
// 0.1 m apart from y = 0 down, moved by `offset` and multiplied by `scale` (file units). The top
// row is pinned to Hips by a height band.
std::string tube_scene(const std::string& name, const Eigen::Vector3d& offset, double scale = 1.0,
                       double flare = 0.032) {
  std::string obj;
  const int columns = 16, rows = 6;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < columns; ++c) {
      const double a = 2 * 3.14159265358979 * c / columns;
      const Eigen::Vector3d p = scale * (Eigen::Vector3d((0.14 + flare * r) * std::cos(a), -0.1 * r,
                                                         (0.14 + flare * r) * std::sin(a)) +
                                         offset);
      obj += "v " + std::to_string(p.x()) + " " + std::to_string(p.y()) + " " +
             std::to_string(p.z()) + "\n";
    }
  for (int r = 0; r + 1 < rows; ++r)
    for (int c = 0; c < columns; ++c) {
      const int a = r * columns + c + 1, b = r * columns + (c + 1) % columns + 1;
      obj += "f " + std::to_string(a) + " " + std::to_string(a + columns) + " " +
             std::to_string(b + columns) + " " + std::to_string(b) + "\n";
    }
  const std::string path = write_temp(name + ".obj", obj);
  const Eigen::Vector3d pin_centre = scale * offset;
  // Pins: the vertices within 0.16 m of the Hips joint's bone as placed (the top row only).
  return temp_scene(name + ".json",
                    "\"clips\": [\"01_01\"], \"garment\": {\"type\": \"mesh\", \"file\": \"" +
                        path + "\", \"scale\": " + std::to_string(1.0 / scale) +
                        ", \"bone\": \"Hips\", \"pins\": {\"height_band\": [" +
                        std::to_string(pin_centre.y() - 0.01) + ", " +
                        std::to_string(pin_centre.y() + 0.01) + "]}}");
}

// build_character_scene's error ("" when it loads) and what it printed on stderr.
std::pair<std::string, std::string> build_scene(const std::string& scene_file,
                                                PlacementReport* report = nullptr) {
  testing::internal::CaptureStderr();
  std::string error;
  try {
    const CharacterScene scene = build_character_scene(load_scene_file(scene_file));
    if (report) *report = scene.placement;
  } catch (const std::exception& e) {
    error = e.what();
  }
  return {error, testing::internal::GetCapturedStderr()};
}

}  // namespace

TEST(Garment, MeshGarmentKeepsTheArtistsTopologyAndGroups) {
  const SceneFile file = load_scene_file(kMotions + "quad_skirt_walk.json");
  const LoadedMotion motion = load_clip(file.manifest, 0);
  const Garment g = import_garment(motion.skeleton, file.mesh);
  const ObjMesh obj = read_obj(kQuadSkirt);
  const db::ArtistMesh& a = g.artist;
  // As given: the file's vertex order, faces (quads, a pentagon, triangles), UVs and normals.
  ASSERT_EQ(a.vertex_count(), obj.positions.size() / 3);
  EXPECT_EQ(a.face_sizes, obj.face_sizes);
  EXPECT_EQ(a.corners, obj.corners);
  EXPECT_EQ(a.uvs, obj.uvs);
  EXPECT_EQ(a.corner_uvs, obj.corner_uvs);
  EXPECT_EQ(a.normals, obj.normals);
  EXPECT_EQ(a.corner_normals, obj.corner_normals);
  EXPECT_EQ(std::count(a.face_sizes.begin(), a.face_sizes.end(), 5u), 1);
  EXPECT_EQ(std::count(a.face_sizes.begin(), a.face_sizes.end(), 3u), 2);
  // The UV seam splits the 10 vertices of the ring's first column: one render vertex more each.
  EXPECT_EQ(a.render_vertex_count(), a.vertex_count() + 10);
  // Faces fanned: a quad gives 2 triangles, the pentagon 3.
  EXPECT_EQ(a.render_triangle_count(), 214u * 2 + 3 + 2);
  // Nothing to weld: the map is the identity and the simulation mesh has the artist's vertices.
  EXPECT_EQ(g.mesh.vertex_count(), int(a.vertex_count()));
  for (uint32_t v = 0; v < a.vertex_count(); ++v) {
    EXPECT_EQ(a.map_vertices[3 * v], v);
    EXPECT_EQ(a.map_weights[3 * v], 1.0f);
  }
  // OBJ groups without materials are vertex groups: `waist` is the top two rings.
  EXPECT_EQ(g.pins.size(), 48u);
  ASSERT_EQ(a.groups.size(), 2u);
  EXPECT_EQ(a.groups[0].name, "waist");
  EXPECT_EQ(a.groups[0].faces.size(), 24u);
  EXPECT_EQ(a.groups[0].material, "");
}

TEST(Garment, WeldedSeamMapsBothCopiesToOneSimulationVertex) {
  // The apron of ImportedMeshIsWeldedAndPinned: two objects whose shared edge is duplicated.
  const std::string obj =
      write_temp("apron_map.obj",
                 "o left\nv -0.2 1.0 0.2\nv 0 1.0 0.2\nv 0 0.6 0.2\nv -0.2 0.6 0.2\nf 1 4 3 2\n"
                 "o right\nv 0 1.0 0.2\nv 0.2 1.0 0.2\nv 0.2 0.6 0.2\nv 0 0.6 0.2\nf 5 8 7 6\n");
  const SceneFile file = load_scene_file(temp_scene(
      "apron_map.json", "\"clips\": [\"01_01\"], \"garment\": {\"type\": \"mesh\", \"file\": \"" +
                            obj +
                            "\", \"bone\": \"Hips\", \"pins\": {\"vertex_group\": \"right\"}}"));
  const LoadedMotion motion = load_clip(file.manifest, 0);
  const Garment g = import_garment(motion.skeleton, file.mesh);
  ASSERT_EQ(g.artist.vertex_count(), 8u);
  EXPECT_EQ(g.mesh.vertex_count(), 6);
  EXPECT_EQ(g.pins.size(), 4u);  // the group `right`, which has no material of its own
  EXPECT_EQ(g.artist.map_vertices[3 * 1], g.artist.map_vertices[3 * 4]);  // (0, 1.0) twice
  EXPECT_EQ(g.artist.map_vertices[3 * 2], g.artist.map_vertices[3 * 7]);  // (0, 0.6) twice
  // Frames in artist order map back to the same simulation positions.
  std::vector<float> sim(18), artist(24), back(18);
  for (size_t i = 0; i < sim.size(); ++i) sim[i] = float(i) * 0.25f;
  db::to_artist_order(g.artist, sim.data(), artist.data());
  std::string why;
  ASSERT_TRUE(db::to_simulation_order(g.artist, 6, artist.data(), back.data(), &why)) << why;
  EXPECT_EQ(back, sim);
}

TEST(Garment, ArtistsMeshRoundTripsThroughTheDatabaseAndClipExport) {
  const SceneFile file = load_scene_file(kMotions + "quad_skirt_walk.json");
  const LoadedMotion motion = load_clip(file.manifest, 0);
  const Garment g = import_garment(motion.skeleton, file.mesh);
  const uint32_t n = uint32_t(g.mesh.vertex_count());
  test::TempDir dir;
  const std::string path = dir.file("quad.clothdb");
  constexpr int kFrames = 4;
  std::vector<float> frames;  // the rest shape, swung a little more each frame
  for (int f = 0; f < kFrames; ++f)
    for (uint32_t v = 0; v < n; ++v) {
      const Vec3 p = g.mesh.rest.col(v);
      frames.insert(frames.end(), {float(p.x() + 0.01 * f * (0.1 - p.y())), float(p.y()),
                                   float(p.z() + 0.003 * f)});
    }
  int64_t clip = 0;
  {
    db::Writer w = db::Writer::create(path);
    db::Garment row;
    for (const auto& t : g.mesh.triangles)
      for (int k = 0; k < 3; ++k) row.triangles.push_back(uint32_t(t[size_t(k)]));
    for (uint32_t v = 0; v < n; ++v)
      for (int k = 0; k < 3; ++k) row.rest_positions.push_back(float(g.mesh.rest(k, v)));
    row.material = row.solver = "{}";
    w.put_garment(row);
    w.put_artist_mesh(g.artist);
    db::PrimaryClip p;
    p.name = "walk";
    p.frame_count = kFrames;
    const int64_t primary = w.add_primary_clip(p);
    const std::vector<float> zero(size_t(n) * 3, 0.0f);
    db::NewClothClip c;
    c.start_state = w.add_cloth_state(primary, 0, frames.data(), zero.data(), n);
    c.primary_clip = primary;
    clip = w.add_cloth_clip(c, frames.data(), kFrames, n);
  }
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok) << err.message;
  db::ArtistMesh stored;
  ASSERT_EQ(r.artist_mesh(&stored, &err), db::Status::Ok) << err.message;
  EXPECT_EQ(stored.positions, g.artist.positions);
  EXPECT_EQ(stored.face_sizes, g.artist.face_sizes);
  EXPECT_EQ(stored.corners, g.artist.corners);
  EXPECT_EQ(stored.uvs, g.artist.uvs);
  EXPECT_EQ(stored.corner_uvs, g.artist.corner_uvs);
  EXPECT_EQ(stored.normals, g.artist.normals);
  EXPECT_EQ(stored.corner_normals, g.artist.corner_normals);
  EXPECT_EQ(stored.render_triangles, g.artist.render_triangles);
  EXPECT_EQ(stored.map_vertices, g.artist.map_vertices);
  ASSERT_EQ(stored.groups.size(), g.artist.groups.size());
  EXPECT_EQ(stored.groups[1].faces, g.artist.groups[1].faces);

  // clip export: the artist's OBJ (same faces, UVs, normals as the file) and an artist-order PC2.
  testing::internal::CaptureStderr();  // it says it writes no body (no scene in this file)
  // No scene in this file (made by the Writer, not the precompute): the cloth alone.
  const ExportedClip out = export_clip(r, clip, dir.file("export"), "", "", false);
  testing::internal::GetCapturedStderr();
  const ObjMesh original = read_obj(kQuadSkirt), exported = read_obj(out.cloth_obj);
  EXPECT_EQ(exported.face_sizes, original.face_sizes);
  EXPECT_EQ(obj_corners(exported), obj_corners(original));
  EXPECT_EQ(exported.uvs, original.uvs);
  EXPECT_EQ(exported.normals, original.normals);
  EXPECT_EQ(exported.face_groups.size(), original.face_groups.size());
  const PointCache pc = read_pc2(out.cloth_pc2);
  ASSERT_EQ(pc.vertex_count, int(stored.vertex_count()));
  ASSERT_EQ(pc.frame_count, kFrames);
  // Import of the artist-order PC2 reaches the same simulation positions.
  const std::vector<float> back = read_edited_frames(out.cloth_pc2, stored, n, kFrames);
  std::vector<float> decoded;
  codec::DecodeScratch scratch;
  std::vector<uint8_t> blob;
  ASSERT_EQ(r.clip_blob(clip, &blob, &err), db::Status::Ok);
  ASSERT_EQ(r.decode_all(blob, &decoded, scratch, &err), db::Status::Ok);
  ASSERT_EQ(back.size(), decoded.size());
  for (size_t i = 0; i < back.size(); ++i) ASSERT_EQ(back[i], decoded[i]) << i;
  // A cache of neither topology is refused, naming both counts.
  PointCache wrong = pc;
  wrong.vertex_count = 7;
  wrong.positions.resize(size_t(kFrames) * 7 * 3);
  write_pc2(dir.file("wrong.pc2"), wrong);
  try {
    read_edited_frames(dir.file("wrong.pc2"), stored, n, kFrames);
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("7 vertices"), std::string::npos) << e.what();
  }
}

// A garment lives in the skeleton's rest pose (docs/guide/garment_placement.md): one placed there
// loads quietly and reports its pins; one a little off is warned about; one modelled on a posed
// frame or standing on the floor, or in centimetres, is refused naming the distance and the cause.
TEST(Garment, PlacementIsReportedWarnedAndRefused) {
  PlacementReport r;
  const std::string good = tube_scene("placed", {0, 0, 0});
  const auto [good_error, good_log] = build_scene(good, &r);
  ASSERT_EQ(good_error, "");
  EXPECT_EQ(good_log.find("warning"), std::string::npos) << good_log;
  EXPECT_EQ(r.pin_count, 16);
  ASSERT_EQ(r.bands.size(), 1u);
  EXPECT_EQ(r.bands[0].bone, "Hips");
  EXPECT_LT(r.worst_pin, 0.05);
  EXPECT_NEAR(r.lo.y(), -0.5, 1e-6);
  EXPECT_NEAR(r.hi.y(), 0.0, 1e-6);
  const std::vector<std::string> lines = placement_lines(r);
  ASSERT_FALSE(lines.empty());
  EXPECT_NE(lines[0].find("16 pins: 16 on 'Hips'"), std::string::npos) << lines[0];
  EXPECT_NE(lines[1].find("the body (nearest: '"), std::string::npos) << lines[1];
  EXPECT_NE(lines[2].find("colliders: "), std::string::npos) << lines[2];

  // Without the flare the thighs leave the tube at rest: their colliders cross it, and are named.
  const auto [straight_error, straight_log] =
      build_scene(tube_scene("straight", {0, 0, 0}, 1.0, 0.0));
  EXPECT_EQ(straight_error, "");
  EXPECT_NE(straight_log.find("the collider of bone 'LeftUpLeg' crosses the garment at rest"),
            std::string::npos)
      << straight_log;

  // 10 cm forward: loads, with a warning naming the scene file, the field and the distance.
  const std::string near = tube_scene("forward", {0, 0, 0.10});
  const auto [near_error, near_log] = build_scene(near, &r);
  EXPECT_EQ(near_error, "");
  EXPECT_GT(r.worst_pin, 0.05);
  EXPECT_LT(r.worst_pin, 0.20);
  EXPECT_NE(near_log.find(near + ": warning: garment.file"), std::string::npos) << near_log;
  EXPECT_NE(near_log.find("from their bone's capsule"), std::string::npos) << near_log;

  // Modelled on the character standing on the floor (the hips 0.95 m up): refused, naming the
  // distance, the limit, the scene file and field, and the likely cause.
  const std::string posed = tube_scene("posed", {0, 0.95, 0});
  const auto [posed_error, posed_log] = build_scene(posed);
  ASSERT_NE(posed_error, "");
  EXPECT_NE(posed_error.find(posed + ": garment.file"), std::string::npos) << posed_error;
  EXPECT_NE(posed_error.find("16 pins on 'Hips' up to 0."), std::string::npos) << posed_error;
  EXPECT_NE(posed_error.find("refused over 0.200 m"), std::string::npos) << posed_error;
  EXPECT_NE(posed_error.find("modelled on a posed frame"), std::string::npos) << posed_error;

  // The right shape in decimetres read as metres (6 m across: under the 20 m the importer refuses
  // outright, centimetres among them): refused as a wrong scale.
  const std::string cm = tube_scene("decimetres", {0, 0, 0}, 10.0);
  std::ifstream cm_in(cm);
  std::string cm_scene((std::istreambuf_iterator<char>(cm_in)), std::istreambuf_iterator<char>());
  const std::string scale_field = "\"scale\": 0.100000";
  ASSERT_NE(cm_scene.find(scale_field), std::string::npos) << cm_scene;
  cm_scene.replace(cm_scene.find(scale_field), scale_field.size(), "\"scale\": 1");
  std::ofstream(cm) << cm_scene;
  const auto [cm_error, cm_log] = build_scene(cm);
  EXPECT_NE(cm_error.find("wrong scale"), std::string::npos) << cm_error;
}

// A pin rule that matches nothing says so with the garment's extent and its nearest vertex.
TEST(Garment, UnmatchedPinsNameTheExtentAndTheNearestVertex) {
  const std::string scene = tube_scene("unmatched", {0, 0, 0});
  SceneFile file = load_scene_file(scene);
  file.mesh.pins.y_min = 0.5;
  file.mesh.pins.y_max = 0.6;
  const LoadedMotion motion = load_clip(file.manifest, 0);
  try {
    import_garment(motion.skeleton, file.mesh);
    FAIL() << "no pins, yet it loaded";
  } catch (const GarmentError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("matches no vertex (0 pins)"), std::string::npos) << m;
    EXPECT_NE(m.find("the garment spans (-0.300, -0.500, -0.300) .. (0.300, 0.000, 0.300) m"),
              std::string::npos)
        << m;
    EXPECT_NE(m.find("its nearest vertex is 0.500 m below the band"), std::string::npos) << m;
  }
}
