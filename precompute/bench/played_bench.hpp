// `clothdb bench played DB`: how far the cloth a player sees is from the cloth a simulation of the
// same path would have produced (docs/GUIDE.md#is-the-database-good). For seeded random walks
// through the primary graph (the game's view: at each node a way out with probability proportional
// to the manifest's weights), it plays the walk with the runtime library (clothrt, as a game links
// it) and simulates the SAME walk continuously with the database's scene and solver settings from
// the same start state. Per frame it reports the RMS and largest vertex distance between played and
// simulated cloth, and whether the frame was blending, fell back to a nearest state, or followed a
// linked cloth edge.
//
// Next to it, the chaos floor: the same continuous simulation from a start perturbed by 1 um,
// against the unperturbed one. Where the played error is near the floor, the database is as good
// as any simulation could be told apart from another; where it is far above, the database
// (epsilon, blends, fallbacks, the codec) is the cause.
//
// Deterministic for a given seed (the walks, the simulations, the perturbation).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "explore/explorer.hpp"

namespace clothdb {

struct PlayedOptions {
  int paths = 4;
  double seconds = 60;  // per path
  uint64_t seed = 1;
  double perturbation = 1e-6;  // m: the chaos floor's start perturbation
  int threads = 0;             // simulations in parallel (0: all cores)
  bool progress = true;        // a progress bar with ETA on stderr
};

struct PlayedFrame {
  double time = 0;  // s
  int64_t primary_clip = 0, cloth_clip = 0;
  double rms_mm = 0, max_mm = 0;  // played against simulated
  double chaos_rms_mm = 0;        // simulated against simulated from the perturbed start
  bool transition = false;        // a node was passed on the way to this frame
  bool blending = false, fallback = false, linked = false;
};

struct PlayedPath {
  std::vector<std::string> edges;  // primary clips in the order played
  std::vector<PlayedFrame> frames;
  // Nodes where a way out without any cloth was left out of the choice (its weight given to the
  // others): a database missing cloth for a whole primary clip.
  int ways_without_cloth = 0;
};

struct PlayedReport {
  std::vector<PlayedPath> paths;
  long frames = 0;
  double played_rms_mm_p50 = 0, played_rms_mm_p95 = 0, played_max_mm = 0;
  double chaos_floor_rms_mm_p50 = 0, chaos_floor_rms_mm_p95 = 0;
  double max_pop_mm = 0, jitter_mm = 0;  // pops_and_jitter over every path
  double fallback_fraction = 0, blending_fraction = 0, linked_fraction = 0;
  double simulated_seconds = 0;  // CPU time of the reference simulations
};

// What the RMS hides, per vertex over frames (played p, simulated s, both `frames` frames of
// `vertices` vertices; the played as 3 floats a vertex, frame after frame):
// - max_pop_mm: the largest frame-to-frame jump |p(f+1) - p(f)| of a vertex beyond the same jump
//   |s(f+1) - s(f)| in the simulation (0 when the played cloth never jumps more than it);
// - jitter_mm: the largest second difference over frames |e(f+1) - 2 e(f) + e(f-1)| of the
//   played-minus-simulated distance e(f) = |p(f) - s(f)|: an error that flickers, where a steady
//   error has none.
struct PopsAndJitter {
  double max_pop_mm = 0, jitter_mm = 0;
};
PopsAndJitter pops_and_jitter(const float* played, const std::vector<Eigen::Matrix3Xd>& simulated,
                              size_t frames, size_t vertices);

// db_path: the database to play; scene, graph: what it was made from (load_database_scene);
// solver/settings: the settings the database records (garment row). Throws naming the database
// when it cannot be played.
PlayedReport bench_played(const std::string& db_path, const CharacterScene& scene,
                          const ExploreGraph& graph, SolverKind solver,
                          const SolverSettings& settings, const PlayedOptions& options);

// The summary as JSON (keys played_rms_mm_p50, played_rms_mm_p95, played_max_mm,
// chaos_floor_rms_mm_p50, chaos_floor_rms_mm_p95, max_pop_mm, jitter_mm, fallback_fraction,
// blending_fraction, linked_fraction, frames, paths, seconds, seed, database).
std::string played_json(const PlayedReport& report, const PlayedOptions& options,
                        const std::string& db_path);
// One path, one row per frame.
std::string played_path_csv(const PlayedPath& path);
// Error against time, with transitions, blends and fallbacks marked.
std::string played_path_svg(const PlayedPath& path, const std::string& title);

}  // namespace clothdb
