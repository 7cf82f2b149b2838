// `clothdb bench character`: a character scene's clip run with several solvers, sub-step counts,
// thread counts and collider motions (docs/GUIDE.md#the-pipeline-command-by-command): time per
// frame, edge strain, penetration into the body capsules, and tunnelling (vertices whose path
// crossed a capsule during a frame). On request, each run's distance to a converged run of the same
// model (the same setting at 8x the sub-steps) and, per strain target, the cheapest run that meets
// it (as `bench solvers --strain-study` does for the cloth-only scenes).
#pragma once

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "character_scene/character_scene.hpp"
#include "cloth/collision.hpp"

namespace clothdb {

struct CharacterBenchOptions {
  std::string clip;                 // empty: the scene's first clip
  int frames = 90;                  // frames of the clip simulated after settling (from frame 0)
  std::vector<SolverKind> solvers;  // empty: the scene's solver
  // Sub-steps per frame; 0 is each solver's default: the scene's for PBD and XPBD, 1 for Newton,
  // and for mass-spring the count its stability limit asks for (mass_spring_critical_dt).
  // Mass-spring is never run below that count (it would blow up; the row says so).
  std::vector<int> substeps{0};
  int iterations = 0;                    // constraint iterations (PBD, XPBD); 0: the scene's
  int stretch_iterations = -1;           // XPBD stretch sweeps; -1: the scene's (0: as iterations)
  double strain_limit = -1.0;            // XPBD strain limit; negative: the scene's (0: off)
  int strain_limit_iterations = 0;       // XPBD strain-limit passes; 0: the scene's
  int contact_rounds = -1;               // XPBD strain_limit_contact_rounds; negative: the scene's
  double strain_limit_relaxation = 0.0;  // XPBD strain_limit_relaxation; 0: the scene's
  double chebyshev_rho = -1.0;           // XPBD chebyshev_rho; negative: the scene's (0: off)
  int tethers = -1;                      // XPBD tethers: 0 off, 1 on; negative: the scene's
  std::vector<int> threads{1};
  std::vector<ColliderMotion> collider_motions;  // empty: the scene's
  // XPBD self-collision thicknesses (mm) to run, 0 for off. Empty: the scene's, and when that is
  // on also a run without it, so its cost is shown beside the same run without
  // (docs/guide/self_collision.md).
  std::vector<double> self_collision_mm;
  // Also run each setting at 8x the sub-steps (scene_reference, solvers/solver_candidates.hpp)
  // over the same frames and report the distance to it.
  bool reference = false;
  // Largest-strain targets, (l - l0) / l0: the cheapest stable run (CPU per frame) whose largest
  // strain meets each (meets_strain_target, bench/strain_study.hpp) is marked.
  std::vector<double> strain_targets;
  // SolverSettings::coarse_vertices to run (0: the garment solved itself; N: the garment made with
  // N vertices solved and driving it). Empty: the scene's. With `reference`, every run of a
  // setting is compared with the garment's own run at 8x the sub-steps (scene_reference).
  std::vector<int> coarse_vertices;
};

struct CharacterBenchRow {
  std::string solver;  // Solver::describe()
  int threads = 1;
  ColliderMotion collider_motion = ColliderMotion::Interpolated;
  int vertices = 0, capsules = 0, frames = 0;
  double ms_per_frame = 0;      // wall time of the solver steps per frame
  double cpu_ms_per_frame = 0;  // process CPU time (all threads) per frame
  double max_strain = 0;        // largest edge strain over all frames
  // 99th percentile of (l - l0) / l0 over every edge at every frame's end (the p99 of
  // docs/RESULTS.md#strain-how-much-the-cloth-stretches).
  double p99_strain = 0;
  int step_halvings = 0;  // Newton: sub-step halvings over the run
  // Per frame: the solver's iterations (Newton's, or constraint iterations) and Newton's
  // factorisations, which tell a cheaper factorisation from fewer of them.
  double iterations_per_frame = 0, factorizations_per_frame = 0;
  // XPBD strain limit: passes per sub-step (mean over the run, StepReport::strain_limit_passes)
  // and the runs of it that stopped at the cap with an edge still being shortened.
  double strain_limit_passes_per_substep = 0;
  long strain_limit_capped = 0;
  double max_penetration = 0;   // deepest vertex below a capsule surface at a frame's end, m
  double mean_penetration = 0;  // largest per-frame mean over penetrating vertices, m
  // Vertex-frames whose straight path over the frame, relative to a capsule moving with the body,
  // reaches deeper than half the capsule's radius: the vertex passed through the limb.
  int tunnelled = 0;
  // Self-collision thickness of the run (mm, 0: off), and edge-triangle crossings
  // (cloth/self_intersection.hpp): the most in one frame, that frame, and how many frames have any.
  double self_collision_mm = 0;
  int self_intersections = 0;
  int self_intersection_frame = -1;
  int self_intersection_frames = 0;
  double deepest_path = 0;  // largest path_depth_fraction over vertices, capsules and frames
  // Where the largest strain was, to tell a collision pushing on the cloth from the solver not
  // converging: the frame, how far down the garment the edge sits at rest (0 at its highest rest
  // vertex, 1 at its lowest), and the gap from its nearer end to the nearest body capsule's
  // surface at that frame (at or below the collision margin: the body is pushing on it).
  int worst_frame = -1;
  double worst_edge_depth = 0;
  double worst_edge_gap = 0;  // m
  std::string worst_edge_bone;
  bool stable = true;
  std::string message;
  // CharacterBenchOptions::reference: the reference's label, the RMS and the largest vertex
  // distance to it over frames 1..frames (compare_frames, mm), and its CPU per frame. NaN when
  // not run or unstable.
  std::string reference;
  double reference_rms_mm = NAN, reference_max_mm = NAN, reference_cpu_ms_per_frame = NAN;
  std::vector<double> cheapest_for;  // the strain targets this run is the cheapest to meet
};

// The fastest point of any body capsule (its end points) over clip frames [0, frames).
struct CapsuleSpeed {
  double speed = 0;   // m/s
  double radius = 0;  // of that capsule, m
  int frame = 0;      // the frame the end point arrives at
  std::string bone;
};
CapsuleSpeed fastest_capsule(const CharacterScene& scene, const MotionClip& clip, int frames);

// Runs every combination of options.solvers x substeps x threads x collider_motions on the scene
// (built once per solver); `progress` gets one line per finished run.
std::vector<CharacterBenchRow> run_character_bench(
    const SceneFile& file, const CharacterBenchOptions& options,
    const std::function<void(const std::string&)>& progress = {});

std::string character_rows_markdown(const std::vector<CharacterBenchRow>& rows);

// The garment settled (settle_garment, with the scene's solver and settings) from every `every`-th
// frame of a clip: per start frame, the largest edge strain and the deepest penetration of the
// settled state (docs/RESULTS.md#strain-how-much-the-cloth-stretches: every 50th start frame of
// 01_01 within 6 %).
struct SettleRow {
  int frame = 0;
  double max_strain = 0;
  double max_penetration = 0;  // m
};
std::vector<SettleRow> run_settle_bench(
    const SceneFile& file, const std::string& clip, int every,
    const std::function<void(const std::string&)>& progress = {});

}  // namespace clothdb
