// The error floor of a garment on a motion (explore/error_floor.hpp,
// docs/GUIDE.md#choosing-epsilon-the-error-floor): a multi-stable garment (a strongly flared skirt
// with soft bending) measures above a well-posed one on the same motion, the measurement does not
// depend on the run or the thread count, walks that cannot meet fall back to different start
// frames, and `precompute` refuses an epsilon below the floor without --force, writing nothing, and
// stores the floor in meta with it.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "database/format/cloth_graph.hpp"
#include "database/store/check.hpp"
#include "explore/error_floor.hpp"
#include "explore/precompute.hpp"
#include "support/explore_fixture.hpp"

using namespace clothdb;
using namespace clothdb::test;

namespace {

// The fixture's small skirt with the bundled scene's light air drag (the fixture's heavy drag
// makes every garment forget its history) and the flare and bending given.
CharacterScene skirt(double flare, double bending_stiffness) {
  SceneFile file = load_scene_file(kMotions + "skirt_walk.json");
  file.clips = {"01_03_level_walk"};
  file.skirt.vertices = 200;
  file.skirt.length = 0.5;
  file.skirt.flare = flare;
  file.material.bending_stiffness = bending_stiffness;
  file.settle_frames = 10;
  file.settings.substeps = 6;
  file.settings.iterations = 1;
  file.settings.tethers = false;
  file.settings.stretch_iterations = 0;
  file.settings.strain_limit = 0.0;
  file.air_drag = 0.3;
  return build_character_scene(file);
}

// 3 s walked together: on this swaying graph 1 s leaves every skirt still swinging with its
// history (the transient, tens of mm), 3 s leaves the well-posed ones within a few mm and the
// flared soft one about 40 mm apart.
ErrorFloorOptions quick(int threads = 1) {
  ErrorFloorOptions o;
  o.histories = 4;
  o.history_seconds = 0.5;
  o.continuation_seconds = 3.0;
  o.hold_seconds = 1.0;
  o.threads = threads;
  return o;
}

std::string temp_path(const std::string& name) {
  return testing::TempDir() + "/clothdb_error_floor_" + name;
}

void remove_db(const std::string& path) {
  for (const char* suffix : {"", "-wal", "-shm", ".lock"}) std::filesystem::remove(path + suffix);
}

}  // namespace

TEST(ErrorFloor, MultiStableSkirtMeasuresAboveAWellPosedOne) {
  const CharacterScene flared = skirt(2.0, 1e-5);
  const CharacterScene straight = skirt(1.0, 1e-5);
  const CharacterScene stiff = skirt(2.0, 1e-2);
  const ErrorFloor f_flared = measure_error_floor(flared, small_graph(flared), quick());
  const ErrorFloor f_straight = measure_error_floor(straight, small_graph(straight), quick());
  const ErrorFloor f_stiff = measure_error_floor(stiff, small_graph(stiff), quick());
  for (const ErrorFloor* f : {&f_flared, &f_straight, &f_stiff}) {
    EXPECT_FALSE(f->fallback) << f->note;  // the fixture graph has a choice at its one node
    EXPECT_EQ(f->histories(), 4);
    EXPECT_EQ(f->walked.size(), 6u);
    EXPECT_EQ(f->held.size(), 6u);
    EXPECT_EQ(f->halfway.size(), 6u);
  }
  // Measured: about 43, 7 and 1 mm walked; 38, 6 and 0.2 mm held still.
  EXPECT_GT(f_flared.floor, 3 * f_straight.floor)
      << "flared " << error_floor_summary(f_flared) << "\nstraight "
      << error_floor_summary(f_straight);
  EXPECT_GT(f_flared.floor, 3 * f_stiff.floor)
      << "flared " << error_floor_summary(f_flared) << "\nstiff " << error_floor_summary(f_stiff);
  EXPECT_GT(f_flared.held_median, 3 * std::max(f_straight.held_median, f_stiff.held_median));
}

TEST(ErrorFloor, SameResultTwiceAndForOneAndTwoThreads) {
  const CharacterScene scene = skirt(2.0, 1e-5);
  const ExploreGraph graph = small_graph(scene);
  const ErrorFloor a = measure_error_floor(scene, graph, quick(1));
  ErrorFloorOptions talking = quick(1);
  talking.progress = true;
  testing::internal::CaptureStderr();
  const ErrorFloor b = measure_error_floor(scene, graph, talking);
  const std::string progress = testing::internal::GetCapturedStderr();
  const ErrorFloor c = measure_error_floor(scene, graph, quick(2));
  EXPECT_GT(a.floor, 0.0);
  // A line per history, each but the last with the time left (the measurement can take minutes).
  EXPECT_NE(progress.find("history 1 of 4 simulated ("), std::string::npos) << progress;
  EXPECT_NE(progress.find("s left\nerror floor: history 2 of 4"), std::string::npos) << progress;
  EXPECT_NE(progress.find("history 4 of 4 simulated ("), std::string::npos) << progress;
  EXPECT_EQ(progress.substr(progress.find("history 4 of 4")).find("left"), std::string::npos)
      << progress;
  EXPECT_EQ(a.walked, b.walked);
  EXPECT_EQ(a.held, b.held);
  EXPECT_EQ(a.walked, c.walked);
  EXPECT_EQ(a.held, c.held);
  EXPECT_EQ(a.met, c.met);
  EXPECT_EQ(a.history_edges, c.history_edges);
  EXPECT_EQ(error_floor_json(a, graph, quick(1), false),
            error_floor_json(c, graph, quick(1), false));
  // The histories are different walks that meet at one node.
  for (size_t i = 0; i < a.history_edges.size(); ++i)
    for (size_t j = i + 1; j < a.history_edges.size(); ++j)
      EXPECT_NE(a.history_edges[i], a.history_edges[j]);
}

TEST(ErrorFloor, WalksThatCannotMeetFallBackToDifferentStartFrames) {
  const CharacterScene scene = skirt(2.0, 1e-5);
  ExploreGraph graph = small_graph(scene);
  graph.edges.erase(graph.edges.begin());  // only the sway loop: every walk is the same
  const ErrorFloor f = measure_error_floor(scene, graph, quick());
  EXPECT_TRUE(f.fallback);
  EXPECT_NE(f.note.find("one way out"), std::string::npos) << f.note;
  EXPECT_EQ(f.start_frames, (std::vector<int>{0, 3, 7, 11}));  // 15 frames, 4 histories
  EXPECT_EQ(f.walked.size(), 6u);
  EXPECT_GT(f.floor, 0.0);
}

TEST(ErrorFloor, RefusesBadOptions) {
  const CharacterScene scene = skirt(1.0, 1e-5);
  ErrorFloorOptions o = quick();
  o.histories = 1;
  EXPECT_THROW(measure_error_floor(scene, small_graph(scene), o), std::invalid_argument);
  o = quick();
  o.hold_seconds = -1;
  EXPECT_THROW(measure_error_floor(scene, small_graph(scene), o), std::invalid_argument);
}

TEST(ErrorFloor, SuggestedEpsilonIsOneAndAHalfFloorsRoundedUpToAMillimetre) {
  EXPECT_DOUBLE_EQ(suggested_epsilon(0.0123), 0.019);  // 18.45 mm -> 19 mm
  EXPECT_DOUBLE_EQ(suggested_epsilon(0.002), 0.003);
  EXPECT_DOUBLE_EQ(suggested_epsilon(0.00001), 0.001);  // at least 1 mm
}

// The precompute's rule (explore/precompute.hpp): measured before the database exists, refused
// below it without --force (no file), stored in meta with --force, and read back on resume.
TEST(Precompute, RefusesAnEpsilonBelowTheErrorFloorWithoutForce) {
  const std::string scene_file = temp_path("scene.json");
  std::ofstream(scene_file) << R"({"name": "floor", "manifest": ")" << kMotions
                            << R"(cmu_walk.json",
    "clips": ["01_03_level_walk"],
    "garment": {"type": "skirt", "bone": "Hips", "vertices": 200, "length": 0.5, "flare": 2.0},
    "material": {"density": 0.15, "youngs_modulus": 1e8, "thickness": 0.0005, "bending_stiffness": 1e-5, "damping": 0.001},
    "solver": {"name": "xpbd", "substeps": 6, "iterations": 1, "tethers": false},
    "colliders": {"bones": ["LowerBack", "LHipJoint", "RHipJoint", "LeftUpLeg", "LeftLeg", "RightUpLeg", "RightLeg"]},
    "air_drag": 0.3, "settle_frames": 10})";
  const std::string path = temp_path("refused.db");
  remove_db(path);

  PrecomputeRequest request;
  request.scene = scene_file;
  request.db = path;
  request.floor = quick(2);
  request.explore.threads = 2;
  request.explore.max_frames = 20;
  request.explore.progress = false;

  // What the precompute will measure: the same scene, graph and options.
  const CharacterScene scene = build_character_scene(load_scene_file(scene_file));
  const ChosenGraph chosen = choose_motion_graph(scene, "", "", -1);
  const ErrorFloor expected =
      measure_error_floor(scene, explore_graph(scene, chosen.graph, "test"), quick(1));
  ASSERT_GT(expected.floor, 0.0);

  request.explore.epsilon = 0.5 * expected.floor;
  try {
    run_precompute(request, nullptr);
    ADD_FAILURE() << "an epsilon below the floor was accepted";
  } catch (const std::runtime_error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("below the error floor"), std::string::npos) << m;
    EXPECT_NE(m.find("--force"), std::string::npos) << m;
    EXPECT_NE(m.find("--epsilon"), std::string::npos) << m;
  }
  EXPECT_FALSE(std::filesystem::exists(path));

  request.force = true;
  const PrecomputeOutcome forced = run_precompute(request, nullptr);
  EXPECT_TRUE(forced.floor_measured);
  EXPECT_EQ(forced.error_floor, expected.floor);
  {
    db::Reader r;
    db::Error err;
    ASSERT_EQ(r.open(path, &err), db::Status::Ok) << err.message;
    EXPECT_EQ(db::meta_number(r, db::meta::kErrorFloor), expected.floor);
    const std::optional<std::string> detail = db::meta_text(r, db::meta::kErrorFloorDetail);
    ASSERT_TRUE(detail.has_value());
    const nlohmann::json j = nlohmann::json::parse(*detail);
    EXPECT_EQ(j["walked_mm"].size(), expected.walked.size());
    EXPECT_FALSE(j.contains("cpu_seconds"));  // meta is the same whoever measured it
  }
  {
    // `db check` accepts the stored floor and names a damaged one.
    const db::CheckReport ok = db::check_database(path);
    for (const auto& problem : ok.problems) ADD_FAILURE() << problem;
    const std::string damaged = temp_path("damaged.db");
    remove_db(damaged);
    for (const char* suffix : {"", "-wal"})
      if (std::filesystem::exists(path + suffix))
        std::filesystem::copy_file(path + suffix, damaged + suffix);
    {
      db::Writer w = db::Writer::open(damaged);
      db::set_meta_text(w, db::meta::kErrorFloor, "-0.01");
    }
    bool named = false;
    for (const auto& problem : db::check_database(damaged).problems)
      named |= problem.find("error_floor") != std::string::npos;
    EXPECT_TRUE(named);
  }

  // Resumed: the stored floor is checked, not measured again.
  request.force = false;
  EXPECT_THROW(run_precompute(request, nullptr), std::runtime_error);
  request.force = true;
  const PrecomputeOutcome resumed = run_precompute(request, nullptr);
  EXPECT_TRUE(resumed.resumed);
  EXPECT_FALSE(resumed.floor_measured);
  EXPECT_EQ(resumed.error_floor, expected.floor);

  // An epsilon above the floor needs no --force; --no-floor measures nothing.
  const std::string above = temp_path("above.db");
  remove_db(above);
  request.db = above;
  request.force = false;
  request.explore.epsilon = suggested_epsilon(expected.floor);
  EXPECT_TRUE(run_precompute(request, nullptr).floor_measured);
  const std::string none = temp_path("none.db");
  remove_db(none);
  request.db = none;
  request.measure_floor = false;
  request.explore.epsilon = 0.5 * expected.floor;
  const PrecomputeOutcome unmeasured = run_precompute(request, nullptr);
  EXPECT_LT(unmeasured.error_floor, 0);
  {
    db::Reader r;
    db::Error err;
    ASSERT_EQ(r.open(none, &err), db::Status::Ok) << err.message;
    EXPECT_FALSE(db::meta_number(r, db::meta::kErrorFloor).has_value());
  }
  // A database without a floor (made with --no-floor, or before floors) has it measured when it
  // is resumed: the same refusal, and with --force the same stored value as a new database.
  request.measure_floor = true;
  EXPECT_THROW(run_precompute(request, nullptr), std::runtime_error);
  request.force = true;
  const PrecomputeOutcome late = run_precompute(request, nullptr);
  EXPECT_TRUE(late.resumed);
  EXPECT_TRUE(late.floor_measured);
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(none, &err), db::Status::Ok) << err.message;
  EXPECT_EQ(db::meta_number(r, db::meta::kErrorFloor), expected.floor);
}
