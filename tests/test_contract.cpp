// The clothdb contract (database/cloth_graph.hpp, database/run_settings.hpp): the one state
// distance on hand-computed cases, the node-anchor / start rules, typed meta, and the run settings
// record through each path it travels (database run row, scene file, MPI wire), with invalid
// values refused by field name.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>

#include "clothrt.h"
#include "database/format/cloth_graph.hpp"
#include "database/store/check.hpp"
#include "database/store/run_settings.hpp"
#include "database/store/writer.hpp"
#include "explore/job_wire.hpp"

using namespace clothdb;

namespace {

std::string temp_file(const std::string& name) {
  const std::string path = testing::TempDir() + "/clothdb_contract_" + name;
  for (const char* suffix : {"", "-wal", "-shm"}) std::filesystem::remove(path + suffix);
  return path;
}

// Every field different from its default, so a field dropped on any path shows.
db::RunSettings unusual_settings() {
  db::RunSettings r;
  r.epsilon = 0.0037;
  r.solver = SolverKind::Newton;
  SolverSettings& s = r.settings;
  s.substeps = 7;
  s.iterations = 3;
  s.pbd_stretch_stiffness = 0.75;
  s.pbd_bend_stiffness = 0.125;
  s.provot_critical_rate = 0.07;
  s.newton_tolerance = 3e-7;
  s.newton_max_iterations = 17;
  s.newton_max_halvings = 4;
  s.newton_guess = SolverSettings::Guess::Extrapolate;
  s.newton_reuse_contraction = 0.25;
  s.newton_exact_hessian = false;
  s.linear_solver = LinearSolverKind::ConjugateGradientIC;
  s.threads = 3;
  s.tethers = false;
  s.newton_velocity_tolerance = 2e-3;
  s.newton_accept_decrease = false;
  s.newton_projected_first = false;
  s.stretch_iterations = 4;
  s.strain_limit = 0.05;
  s.strain_limit_iterations = 6;
  r.codec.position_bound = 0.00025;
  r.codec.velocity_bound = 0.002;
  r.codec.key_interval = 6;
  r.codec.zstd_level = 5;
  r.cpu_hours = 0.25;
  r.max_frames = 1234;
  r.threads = 2;
  r.batch = 12;
  r.auto_solver = true;
  r.resim_clip = 42;
  return r;
}

void expect_same_solver(SolverKind ka, const SolverSettings& a, SolverKind kb,
                        const SolverSettings& b, bool threads) {
  EXPECT_EQ(ka, kb);
  EXPECT_EQ(a.substeps, b.substeps);
  EXPECT_EQ(a.iterations, b.iterations);
  EXPECT_EQ(a.pbd_stretch_stiffness, b.pbd_stretch_stiffness);
  EXPECT_EQ(a.pbd_bend_stiffness, b.pbd_bend_stiffness);
  EXPECT_EQ(a.provot_critical_rate, b.provot_critical_rate);
  EXPECT_EQ(a.newton_tolerance, b.newton_tolerance);
  EXPECT_EQ(a.newton_max_iterations, b.newton_max_iterations);
  EXPECT_EQ(a.newton_max_halvings, b.newton_max_halvings);
  EXPECT_EQ(a.newton_guess, b.newton_guess);
  EXPECT_EQ(a.newton_reuse_contraction, b.newton_reuse_contraction);
  EXPECT_EQ(a.newton_exact_hessian, b.newton_exact_hessian);
  EXPECT_EQ(a.linear_solver, b.linear_solver);
  if (threads) {
    EXPECT_EQ(a.threads, b.threads);
  }
  EXPECT_EQ(a.tethers, b.tethers);
  EXPECT_EQ(a.newton_velocity_tolerance, b.newton_velocity_tolerance);
  EXPECT_EQ(a.newton_accept_decrease, b.newton_accept_decrease);
  EXPECT_EQ(a.newton_projected_first, b.newton_projected_first);
  EXPECT_EQ(a.stretch_iterations, b.stretch_iterations);
  EXPECT_EQ(a.strain_limit, b.strain_limit);
  EXPECT_EQ(a.strain_limit_iterations, b.strain_limit_iterations);
}

void expect_same_codec(const db::CodecSettings& a, const db::CodecSettings& b) {
  EXPECT_EQ(a.position_bound, b.position_bound);
  EXPECT_EQ(a.velocity_bound, b.velocity_bound);
  EXPECT_EQ(a.key_interval, b.key_interval);
  EXPECT_EQ(a.zstd_level, b.zstd_level);
}

void expect_same_run(const db::RunSettings& a, const db::RunSettings& b) {
  EXPECT_EQ(a.epsilon, b.epsilon);
  expect_same_solver(a.solver, a.settings, b.solver, b.settings, true);
  expect_same_codec(a.codec, b.codec);
  EXPECT_EQ(a.cpu_hours, b.cpu_hours);
  EXPECT_EQ(a.max_frames, b.max_frames);
  EXPECT_EQ(a.threads, b.threads);
  EXPECT_EQ(a.batch, b.batch);
  EXPECT_EQ(a.auto_solver, b.auto_solver);
  EXPECT_EQ(a.resim_clip, b.resim_clip);
}

// The message of the SettingsError `f` throws ("" if none).
template <class F>
std::string refusal(F&& f) {
  try {
    f();
  } catch (const db::SettingsError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(StateDistance, HandComputedCases) {
  // Two vertices. dx = (3, 4, 0) at vertex 0 and 0 at vertex 1; dv = (0, 0, 10) at vertex 1.
  const std::vector<float> xa = {3, 4, 0, 1, 1, 1}, xb = {0, 0, 0, 1, 1, 1};
  const std::vector<float> va = {0, 0, 0, 0, 0, 10}, vb = {0, 0, 0, 0, 0, 0};
  // tau = 0: positions only, sqrt((25 + 0) / 2).
  EXPECT_DOUBLE_EQ(db::state_distance(xa, va, xb, vb, 0.0), std::sqrt(12.5));
  // tau = 0.1: sqrt((25 + (0.1 * 10)^2) / 2) = sqrt(13).
  EXPECT_NEAR(db::state_distance(xa, va, xb, vb, 0.1), std::sqrt(13.0), 1e-12);
  // Symmetric, and zero against itself.
  EXPECT_DOUBLE_EQ(db::state_distance(xb, vb, xa, va, 0.1),
                   db::state_distance(xa, va, xb, vb, 0.1));
  EXPECT_EQ(db::state_distance(xa, va, xa, va, 0.1), 0.0);
  // Differences in double precision: 1 + 2^-23 and 1 differ by one float ulp, which a float
  // subtraction of the squares would lose entirely.
  const float one_up = std::nextafter(1.0f, 2.0f);
  const std::vector<float> p = {one_up, 0, 0}, q = {1, 0, 0}, z = {0, 0, 0};
  EXPECT_DOUBLE_EQ(db::state_distance(p, z, q, z, 0.0), double(one_up) - 1.0);
  // States of different garments have no distance.
  EXPECT_THROW(db::state_distance(xa, va, p, z, 0.1), std::invalid_argument);
}

TEST(ClothGraphRules, NodeAnchorStartClipAndStartState) {
  // Node 0 -> 1 by clips 10 and 11, node 1 -> 0 by clip 12.
  const std::vector<db::NodeEdge> edges = {{0, 1, 10}, {0, 1, 11}, {1, 0, 12}};
  EXPECT_EQ(db::node_anchor_clip(edges, 0), 10);  // the first edge leaving the node
  EXPECT_EQ(db::node_anchor_clip(edges, 1), 12);
  EXPECT_EQ(db::node_anchor_clip(edges, 2), 0);  // none leaves it
  EXPECT_EQ(db::start_clip(edges, 1), 12);
  EXPECT_EQ(db::node_of_primary_clip(edges, 11), 0);
  EXPECT_EQ(db::node_of_primary_clip(edges, 99), -1);
  std::vector<db::StoredState> states(3);
  states[0].id = 5, states[0].primary_clip = 12;  // node 1
  states[1].id = 7, states[1].primary_clip = 10;  // node 0
  states[2].id = 6, states[2].primary_clip = 10;  // node 0, older
  EXPECT_EQ(db::start_state(states, edges, 0), 6);
  EXPECT_EQ(db::start_state(states, edges, 1), 5);
  EXPECT_EQ(db::start_state(states, edges, 2), 0);
  std::vector<db::PrimaryClip> clips(2);
  clips[0].id = 10, clips[0].name = "walk[0-30]";
  clips[1].id = 12, clips[1].name = "walk[30-60]";
  EXPECT_EQ(db::parse_start_clip("12", clips), 1);
  EXPECT_EQ(db::parse_start_clip("walk[0-30]", clips), 0);  // older tools stored the name
  EXPECT_EQ(db::parse_start_clip("13", clips), -1);
}

TEST(ClothGraphMeta, TypedAccessorsRefuseWrongTypes) {
  const std::string path = temp_file("meta.db");
  db::Writer w = db::Writer::create(path);
  db::set_meta_integer(w, db::meta::kStartClip, 17);
  db::set_meta_text(w, db::meta::kMotionGraph, "{}");
  w.set_meta(db::meta::kSceneHash, "12abc");
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok) << err.message;
  EXPECT_EQ(db::meta_integer(r, db::meta::kStartClip), 17);
  EXPECT_EQ(db::meta_text(r, db::meta::kMotionGraph), "{}");
  EXPECT_FALSE(db::meta_text(r, db::meta::kAutoSolver).has_value());
  EXPECT_EQ(db::meta_integer(r, db::meta::kFormatVersion), db::kSchemaVersion);
  try {
    db::meta_integer(r, db::meta::kSceneHash);
    ADD_FAILURE() << "a text read as an integer";
  } catch (const ClothdbError& e) {
    EXPECT_NE(std::string(e.what()).find("scene_hash"), std::string::npos) << e.what();
  }
  // Every key the writer stores on creation is a known key.
  std::vector<std::pair<std::string, std::string>> all;
  ASSERT_EQ(r.all_meta(&all, &err), db::Status::Ok);
  const auto& known = db::meta::known_keys();
  for (const auto& [key, value] : all)
    EXPECT_NE(std::find(known.begin(), known.end(), key), known.end()) << key;
}

TEST(RunSettings, EveryFieldSurvivesTheDatabaseRow) {
  const db::RunSettings given = unusual_settings();
  const std::string path = temp_file("run.db");
  db::Writer w = db::Writer::create(path);
  const int64_t run = w.begin_run(db::run_settings_json(given));
  std::vector<db::Run> runs;
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  ASSERT_EQ(r.runs(&runs, &err), db::Status::Ok);
  ASSERT_EQ(runs.size(), 1u);
  EXPECT_EQ(runs[0].id, run);
  expect_same_run(db::parse_run_settings_json(runs[0].settings, "run row"), given);
}

TEST(RunSettings, EveryFieldSurvivesTheMpiWire) {
  const db::RunSettings given = unusual_settings();
  JobInput job;
  job.edge = 3;
  job.x = {1, 2, 3};
  job.v = {4, 5, 6};
  job.solver = given.solver;
  job.settings = given.settings;
  job.codec = given.codec;
  job.epsilon = 0.0125;
  job.state = 12;
  job.targets = {{77, {0.5f, -1, 2}, {3, 0.25f, -4}}};
  ReplicaLedger ledger;
  const std::vector<uint8_t> bytes = encode_job(9, job, ledger);
  uint64_t seq = 0;
  StateReplica worker = make_replica(1, 1.0 / 30);
  const JobInput back = decode_job(bytes.data(), bytes.size(), &seq, worker);
  EXPECT_EQ(seq, 9u);
  expect_same_solver(back.solver, back.settings, given.solver, given.settings, true);
  expect_same_codec(back.codec, given.codec);
  EXPECT_EQ(back.epsilon, job.epsilon);
  EXPECT_EQ(back.state, 12);
  EXPECT_EQ(back.x, job.x);
  ASSERT_TRUE(back.target_source);
  ASSERT_EQ(back.target_source->ids, std::vector<int64_t>{77});
  EXPECT_EQ(back.target_source->exact->get(77)->x, job.targets[0].x);
  EXPECT_EQ(back.target_source->exact->get(77)->v, job.targets[0].v);
}

TEST(RunSettings, EveryFieldSurvivesTheSceneFile) {
  const db::RunSettings given = unusual_settings();
  // The bundled scene with its solver block replaced by the serialiser's output.
  const std::string motions = std::string(CLOTHDB_SOURCE_DIR) + "/motions/";
  std::ifstream in(motions + "skirt_walk.json");
  nlohmann::json scene = nlohmann::json::parse(in);
  scene["manifest"] = motions + "cmu_walk.json";
  scene["solver"] = nlohmann::json::parse(solver_settings_json(given.solver, given.settings, true));
  const std::string path = temp_file("scene.json");
  std::ofstream(path) << scene.dump(2);
  const SceneFile file = load_scene_file(path);
  expect_same_solver(file.solver, file.settings, given.solver, given.settings, true);

  // A bad value in the scene names the file and the field, and a typo is not ignored.
  scene["solver"]["substeps"] = 1099511627776;  // 2^40 must not wrap to a small number
  std::ofstream(path) << scene.dump(2);
  try {
    load_scene_file(path);
    ADD_FAILURE() << "2^40 sub-steps accepted";
  } catch (const std::exception& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find(path), std::string::npos) << m;
    EXPECT_NE(m.find("solver.substeps"), std::string::npos) << m;
  }
  scene["solver"].erase("substeps");
  scene["solver"]["substep"] = 10;
  std::ofstream(path) << scene.dump(2);
  EXPECT_THROW(load_scene_file(path), std::exception);
}

TEST(RunSettings, InvalidValuesAreRefusedByName) {
  struct Case {
    const char* field;
    void (*set)(db::RunSettings&);
  };
  const Case cases[] = {
      {"epsilon_m",
       [](db::RunSettings& r) { r.epsilon = std::numeric_limits<double>::quiet_NaN(); }},
      {"epsilon_m", [](db::RunSettings& r) { r.epsilon = -0.005; }},
      {"epsilon_m", [](db::RunSettings& r) { r.epsilon = 0; }},
      {"cpu_hours", [](db::RunSettings& r) { r.cpu_hours = -1; }},
      {"cpu_hours",
       [](db::RunSettings& r) { r.cpu_hours = std::numeric_limits<double>::quiet_NaN(); }},
      {"max_frames", [](db::RunSettings& r) { r.max_frames = -5; }},
      {"threads", [](db::RunSettings& r) { r.threads = 100000; }},
      {"solver.substeps", [](db::RunSettings& r) { r.settings.substeps = 0; }},
      {"solver.threads", [](db::RunSettings& r) { r.settings.threads = 100000; }},
      {"codec.position_bound", [](db::RunSettings& r) { r.codec.position_bound = -1; }},
  };
  for (const Case& c : cases) {
    db::RunSettings r;
    c.set(r);
    const std::string m = refusal([&] { db::validate_run_settings(r, "run settings"); });
    EXPECT_NE(m.find(std::string(": ") + c.field + ":"), std::string::npos)
        << c.field << " -> '" << m << "'";
    // The serialiser refuses to write it, too.
    EXPECT_FALSE(refusal([&] { db::run_settings_json(r); }).empty()) << c.field;
  }
  // Text with a NaN is not even JSON; a negative epsilon in text is refused by name.
  EXPECT_NE(refusal([] { db::parse_run_settings_json("{\"epsilon_m\": nan}", "t"); }), "");
  EXPECT_NE(
      refusal([] { db::parse_run_settings_json("{\"epsilon_m\": -1}", "t"); }).find("epsilon_m"),
      std::string::npos);
  EXPECT_NE(
      refusal([] { db::parse_run_settings_json("{\"epsilom_m\": 1e-3}", "t"); }).find("epsilom_m"),
      std::string::npos);
  // A misspelt solver field names the field it is likely meant to be; one far from every field
  // lists them (it said only "expected one of the documented fields").
  SolverKind kind = SolverKind::Xpbd;
  SolverSettings s;
  EXPECT_NE(refusal([&] {
              parse_solver_settings_json(R"({"substep": 6})", "scene.json", &kind, &s, "solver.");
            }).find("scene.json: solver.substep: unknown field; did you mean 'substeps'?"),
            std::string::npos);
  EXPECT_NE(refusal([&] {
              parse_solver_settings_json(R"({"self_collision": {"thicknes_mm": 4}})", "scene.json",
                                         &kind, &s, "solver.");
            })
                .find("solver.self_collision.thicknes_mm: unknown field; did you mean "
                      "'thickness_mm'?"),
            std::string::npos);
  const std::string far = refusal(
      [&] { parse_solver_settings_json(R"({"colour": 3})", "scene.json", &kind, &s, "solver."); });
  EXPECT_NE(far.find("solver.colour: unknown field (known: "), std::string::npos) << far;
  EXPECT_NE(far.find("substeps"), std::string::npos) << far;
}

TEST(RunSettings, ReadsTheRowsOlderBuildsWrote) {
  // A schema-3 run row as the explorer wrote it before the record existed.
  const std::string legacy =
      "{\"epsilon_m\": 0.005000, \"threads\": 2, \"batch\": 16, \"solver\": \"xpbd\", "
      "\"solver_settings\": {\"iterations\":1,\"linear_solver\":\"ldlt\",\"name\":\"xpbd\","
      "\"substeps\":30,\"tethers\":true,\"tolerance\":1e-06}, \"auto_solver\": true}";
  const db::RunSettings r = db::parse_run_settings_json(legacy, "legacy");
  EXPECT_EQ(r.epsilon, 0.005);
  EXPECT_EQ(r.solver, SolverKind::Xpbd);
  EXPECT_EQ(r.settings.substeps, 30);
  EXPECT_EQ(r.settings.iterations, 1);
  EXPECT_EQ(r.threads, 2);
  EXPECT_EQ(r.batch, 16);
  EXPECT_TRUE(r.auto_solver);
  const db::RunSettings resim = db::parse_run_settings_json(
      "{\"epsilon_m\": 0.005, \"carried_forward_from_clip\": 56}", "legacy resim");
  EXPECT_EQ(resim.resim_clip, 56);
}

// A file written by the build before this contract existed (schema 3: run rows with the old
// free-form settings, the garment's short solver record, an edit with a changeset): made by
// `clothdb precompute tests/data/mpi_small.json --db v3_small.clothdb --epsilon 10 --frames 120
// --threads 1` and `clothdb clip flag v3_small.clothdb 3` at commit 5bc4d0a.
TEST(OldFiles, SchemaThreeOpensChecksPlaysAndReadsItsSettings) {
  const std::string path = temp_file("v3.clothdb");
  std::filesystem::copy_file(std::string(CLOTHDB_SOURCE_DIR) + "/tests/data/v3_small.clothdb",
                             path);
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok) << err.message;
  EXPECT_EQ(r.schema_version(), 3);
  const db::CheckReport check = db::check_database(path);
  for (const auto& p : check.problems) ADD_FAILURE() << p;
  // Its run row and garment record read through the one serialiser.
  std::vector<db::Run> runs;
  ASSERT_EQ(r.runs(&runs, &err), db::Status::Ok);
  ASSERT_FALSE(runs.empty());
  const db::RunSettings run = db::parse_run_settings_json(runs[0].settings, "v3 run");
  EXPECT_DOUBLE_EQ(run.epsilon, 0.01);
  EXPECT_EQ(run.settings.substeps, 6);
  db::Garment g;
  ASSERT_EQ(r.garment(&g, &err), db::Status::Ok);
  SolverKind kind = SolverKind::Pbd;
  SolverSettings settings;
  parse_solver_settings_json(g.solver, "v3 garment", &kind, &settings);
  EXPECT_EQ(kind, SolverKind::Xpbd);
  EXPECT_EQ(settings.substeps, 6);
  EXPECT_EQ(db::meta_integer(r, db::meta::kStartClip).value_or(0) > 0, true);
  r.close();

  // It plays: a random walk of 300 frames, no error, positions finite.
  clothrt_db* rt = nullptr;
  ASSERT_EQ(clothrt_db_open(path.c_str(), nullptr, &rt), CLOTHRT_OK) << clothrt_last_open_errmsg();
  clothrt_player* p = nullptr;
  ASSERT_EQ(clothrt_player_create(rt, &p), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_set_random(p, 1, 7), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_start(p, 0), CLOTHRT_OK) << clothrt_player_errmsg(p);
  std::vector<float> x(3 * clothrt_db_vertex_count(rt));
  for (int f = 0; f < 300; ++f) {
    ASSERT_EQ(clothrt_player_advance(p, 1.0 / 30), CLOTHRT_OK) << clothrt_player_errmsg(p);
    ASSERT_EQ(clothrt_player_get_positions(p, x.data(), 12, nullptr), CLOTHRT_OK);
    for (float c : x) ASSERT_TRUE(std::isfinite(c));
  }
  clothrt_player_destroy(p);
  clothrt_db_close(rt);

  // A writer opens it (no migration needed) and undo reverts its edit exactly.
  db::Writer w = db::Writer::open(path);
  EXPECT_EQ(w.undo_last("test").action, "flag");
}
