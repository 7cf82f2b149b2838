// `precompute --auto` on a tiny garment: the calibration measures every candidate against the
// reference, and the choice is the cheapest candidate within the bound: its measured error is
// within fraction x epsilon, and a cheaper candidate lost for its error (it was stable).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "explore/auto_solver.hpp"
#include "explore/precompute.hpp"

using namespace clothdb;

namespace {

CharacterScene tiny_scene() {
  SceneFile file = load_scene_file(std::string(CLOTHDB_SOURCE_DIR) + "/motions/skirt_walk.json");
  file.clips = {"01_03_level_walk"};
  file.skirt.vertices = 60;
  file.settle_frames = 5;
  return build_character_scene(file);
}

}  // namespace

TEST(AutoSolver, ChoosesTheCheapestSettingWithinTheBound) {
  const CharacterScene scene = tiny_scene();
  const MotionClip& clip = scene.clips.front();
  std::vector<std::vector<JointPose>> poses;
  for (int f = 0; f < 12; ++f) poses.push_back(clip_pose(clip, f));
  AutoSolverOptions options;
  options.kinds = {SolverKind::Pbd, SolverKind::Xpbd};
  options.quick = true;
  options.frames = 8;
  const AutoCalibration cal = calibrate_solvers(scene, poses, clip.rate, options);
  ASSERT_EQ(cal.frames, 8);
  // PBD: the benchmark's table; XPBD, the scene's own solver: variations of its setting.
  ASSERT_EQ(cal.candidates.size(),
            solver_candidates(SolverKind::Pbd, true).size() +
                scene_variations(SolverKind::Xpbd, scene.file.settings, true).size());
  for (const AutoCandidate& c : cal.candidates) {
    if (!c.stable) continue;
    EXPECT_TRUE(std::isfinite(c.error)) << c.config.label;
    EXPECT_GT(c.error, 0.0) << c.config.label;  // none of them is the reference
    EXPECT_GT(c.cpu_ms_per_frame, 0.0);
  }
  // A bound between a cheap inaccurate candidate and a costlier accurate one, so the choice is
  // not simply the cheapest.
  std::vector<size_t> by_cost(cal.candidates.size());
  for (size_t i = 0; i < by_cost.size(); ++i) by_cost[i] = i;
  std::sort(by_cost.begin(), by_cost.end(), [&](size_t a, size_t b) {
    return cal.candidates[a].cpu_ms_per_frame < cal.candidates[b].cpu_ms_per_frame;
  });
  double bound = -1;
  for (size_t a = 0; a < by_cost.size() && bound < 0; ++a)
    for (size_t b = a + 1; b < by_cost.size() && bound < 0; ++b) {
      const AutoCandidate &cheap = cal.candidates[by_cost[a]], &dear = cal.candidates[by_cost[b]];
      if (cheap.stable && dear.stable && dear.error < cheap.error)
        bound = 0.5 * (cheap.error + dear.error);
    }
  ASSERT_GT(bound, 0) << auto_table(cal, -1, 1, 1);
  const double fraction = 0.5, epsilon = bound / fraction;
  const int chosen = pick_solver(cal, epsilon, fraction);
  ASSERT_GE(chosen, 0) << auto_table(cal, chosen, epsilon, fraction);
  const AutoCandidate& pick = cal.candidates[chosen];
  EXPECT_TRUE(pick.stable);
  EXPECT_LE(pick.error, fraction * epsilon);
  int cheaper = 0, rejected_for_error = 0;
  for (const AutoCandidate& c : cal.candidates) {
    if (c.cpu_ms_per_frame >= pick.cpu_ms_per_frame) continue;
    ++cheaper;
    EXPECT_FALSE(c.stable && c.error <= fraction * epsilon)
        << c.config.label << " is cheaper and within the bound";
    rejected_for_error += c.stable && c.error > fraction * epsilon;
  }
  EXPECT_GE(cheaper, 1);
  EXPECT_GE(rejected_for_error, 1);
  // The table says so.
  const std::string table = auto_table(cal, chosen, epsilon, fraction);
  EXPECT_NE(table.find("**chosen**"), std::string::npos);
  EXPECT_NE(table.find("error above the bound"), std::string::npos);
  // The setting round-trips through its database form.
  SolverKind kind;
  SolverSettings settings;
  parse_solver_settings_json(solver_settings_json(pick.config.kind, pick.config.settings), "test",
                             &kind, &settings);
  EXPECT_EQ(kind, pick.config.kind);
  EXPECT_EQ(settings.substeps, pick.config.settings.substeps);
  EXPECT_EQ(settings.iterations, pick.config.settings.iterations);
}

// The scene's own solver: the candidates are variations of its setting, the first being the
// setting itself, and the reference is a converged run of the same model (8x the sub-steps).
// Whatever the bound, the choice is within it, and its error, measured here again from the same
// settled start against the reference, is within the bound too.
TEST(AutoSolver, ChoosesAmongVariationsOfTheScenesSettingWithinTheBound) {
  const CharacterScene scene = tiny_scene();
  const MotionClip& clip = scene.clips.front();
  std::vector<std::vector<JointPose>> poses;
  for (int f = 0; f < 8; ++f) poses.push_back(clip_pose(clip, f));
  AutoSolverOptions options;
  options.quick = true;
  options.frames = 6;
  options.epsilon = 0.02;
  options.fraction = 0.5;
  const AutoCalibration cal = calibrate_solvers(scene, poses, clip.rate, options);
  ASSERT_FALSE(cal.candidates.empty());
  EXPECT_EQ(cal.reference.settings.substeps, 8 * scene.file.settings.substeps);
  EXPECT_EQ(cal.reference.settings.strain_limit, scene.file.settings.strain_limit);
  // The scene's own setting is the first candidate, field for field (threads aside).
  SolverSettings own = scene.file.settings;
  own.threads = 1;
  EXPECT_EQ(solver_settings_json(cal.candidates.front().config.kind,
                                 cal.candidates.front().config.settings),
            solver_settings_json(scene.file.solver, own));
  EXPECT_NE(cal.candidates.front().config.label.find("(scene)"), std::string::npos);
  bool cheaper = false, costlier = false;
  for (const AutoCandidate& c : cal.candidates) {
    EXPECT_EQ(c.config.settings.strain_limit, scene.file.settings.strain_limit);
    EXPECT_EQ(c.config.settings.tethers, scene.file.settings.tethers);
    cheaper |= c.config.settings.substeps < scene.file.settings.substeps;
    costlier |= c.config.settings.substeps > scene.file.settings.substeps;
  }
  EXPECT_TRUE(cheaper);
  EXPECT_TRUE(costlier);
  ASSERT_GE(cal.window, 1);
  ASSERT_LE(cal.window, cal.frames);
  ASSERT_EQ(cal.floor.size(), static_cast<size_t>(cal.frames));

  // A bound at the median candidate error, so some qualify and (usually) some do not.
  std::vector<double> errors;
  for (const AutoCandidate& c : cal.candidates)
    if (c.stable) errors.push_back(c.error);
  ASSERT_FALSE(errors.empty());
  std::sort(errors.begin(), errors.end());
  const double bound = errors[errors.size() / 2] * (1 + 1e-9);
  const double fraction = 0.5, epsilon = bound / fraction;
  const int chosen = pick_solver(cal, epsilon, fraction);
  ASSERT_GE(chosen, 0) << auto_table(cal, chosen, epsilon, fraction);
  const AutoCandidate& pick = cal.candidates[chosen];
  EXPECT_LE(pick.error, bound);
  for (const AutoCandidate& c : cal.candidates)
    if (c.stable && c.error <= bound) {
      EXPECT_GE(c.cpu_ms_per_frame, pick.cpu_ms_per_frame);
    }

  // Measured again: the chosen setting and the reference from the reference's settled start, over
  // the calibration window, positions frame by frame.
  auto settler = make_solver(cal.reference.kind, scene.model, cal.reference.settings);
  const std::vector<std::vector<JointPose>> window(poses.begin(), poses.begin() + cal.window + 1);
  const ClothState start = settle_garment(scene, *settler, window.front());
  auto again = [&](const SolverCandidate& c) {
    auto solver = make_solver(c.kind, scene.model, c.settings);
    ClothState state = start;
    return simulate_poses(scene, *solver, window, clip.rate, state);
  };
  const PoseRun ref = again(cal.reference), run = again(pick.config);
  ASSERT_TRUE(ref.stable && run.stable);
  EXPECT_LE(compare_frames(run.frames, ref.frames, 0).worst_frame_rms, bound);

  const std::string table = auto_table(cal, chosen, epsilon, fraction);
  EXPECT_NE(table.find("chaos floor"), std::string::npos) << table;
  EXPECT_NE(table.find("within bound"), std::string::npos) << table;

  // A bound nothing meets: the choice is the cheapest at most the scene's own error, so never
  // costlier than the scene's setting, and the table says why.
  ASSERT_EQ(scene_index(cal), 0);
  const AutoCandidate& own_run = cal.candidates.front();
  ASSERT_TRUE(own_run.stable);
  const double tiny = 0.1 * errors.front() / fraction;
  const int fallback = pick_solver(cal, tiny, fraction);
  ASSERT_GE(fallback, 0);
  EXPECT_LE(cal.candidates[fallback].error, own_run.error);
  EXPECT_LE(cal.candidates[fallback].cpu_ms_per_frame, own_run.cpu_ms_per_frame);
  EXPECT_NE(auto_table(cal, fallback, tiny, fraction).find("at most that error"),
            std::string::npos);
}

// No candidate within the bound and the scene's own setting not among them (another solver was
// asked for): precompute --auto refuses, naming the epsilon.
TEST(AutoSolver, RefusesNamingTheEpsilonWhenNoCandidateQualifies) {
  CharacterScene scene = tiny_scene();
  const ChosenGraph graph = choose_motion_graph(scene, "", "", -1);
  const ExploreGraph eg = explore_graph(scene, graph.graph, "test");
  PrecomputeRequest request;
  request.db = testing::TempDir() + "/clothdb_auto_refuses.db";
  std::filesystem::remove(request.db);
  request.automatic = true;
  request.auto_solvers = "pbd";  // not the scene's solver: its own setting is no candidate
  request.auto_quick = true;
  request.auto_frames = 4;
  request.explore.epsilon = 1e-9;  // 1 nm: no candidate is that close to the reference
  try {
    choose_solver(request, scene, eg);
    ADD_FAILURE() << "a candidate was accepted within 1 nm";
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("--epsilon 1e-06 mm"), std::string::npos) << what;
    EXPECT_NE(what.find("error above the bound"), std::string::npos) << what;
  }
  EXPECT_FALSE(std::filesystem::exists(request.db));
}
