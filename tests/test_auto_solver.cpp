// `precompute --auto` on a tiny garment: the calibration measures every candidate against the
// reference, and the choice is the cheapest candidate within the bound: its measured error is
// within fraction x epsilon, and a cheaper candidate lost for its error (it was stable).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "explore/auto_solver.hpp"

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
  ASSERT_EQ(cal.candidates.size(), solver_candidates(SolverKind::Pbd, true).size() +
                                       solver_candidates(SolverKind::Xpbd, true).size());
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
