// `clothdb precompute SCENE --db FILE`: the main job. Takes the motion graph the database holds
// (`clothdb graph build --db`), or --graph, or builds one (Kovar et al. 2002), then explores the
// secondary cloth graph (Kim et al. 2013) into the database until no dead end is above epsilon or a
// budget runs out. Rerunning the same command resumes.
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <thread>

#include "cli_util.hpp"
#include "commands.hpp"
#include "explore/forecast.hpp"
#include "explore/precompute.hpp"

namespace clothdb::cli {

namespace {

// "12.34 mm", or "unknown" when every dead end is unexplored (CurvePoint::worst_error is NaN).
std::string mm(double metres) {
  if (std::isnan(metres)) return "unknown";
  char text[32];
  std::snprintf(text, sizeof text, "%.2f mm", 1e3 * metres);
  return text;
}

std::string floor_text(const PrecomputeOutcome& out) {
  if (out.error_floor < 0) return "not measured (--no-floor)";
  char text[96];
  std::snprintf(text, sizeof text, "%.2f mm (%s)", 1e3 * out.error_floor,
                out.floor_measured ? "measured in this run" : "the database's meta");
  return text;
}

}  // namespace

void register_precompute(CLI::App& app) {
  auto args = std::make_shared<PrecomputeRequest>();
  auto epsilon_mm = std::make_shared<double>(5.0);
  auto position_bound_mm = std::make_shared<double>(0.0);  // 0: the codec's default
  args->explore.threads = 0;
  args->explore.batch = 16;
  auto quiet = std::make_shared<bool>(false);
  auto floor_seconds = std::make_shared<double>(args->floor.continuation_seconds);
  CLI::App* cmd = app.add_subcommand(
      "precompute",
      "Builds the scene's motion graph and explores the secondary cloth graph into the database "
      "(Kim et al. 2013) until every dead end is within --epsilon or a budget (--frames, "
      "--cpu-hours) runs out. Killed at any moment, the same command resumes from the database. "
      "Before a new database is explored, the garment's error floor on the graph is measured "
      "(`clothdb floor`; stored in meta error_floor) and an --epsilon below it is refused "
      "unless --force: no clip end could link within it.");
  cmd->add_option("SCENE", args->scene, "Scene file (JSON), e.g. motions/skirt_walk.json")
      ->required();
  cmd->add_option("--db", args->db, "Database file (created, or resumed if it exists)")->required();
  cmd->add_option("--epsilon", *epsilon_mm,
                  "Error bound in mm: RMS over vertices of sqrt(|dx|^2 + (|dv|/rate)^2)")
      ->capture_default_str()
      ->check(positive_number(1e3));
  cmd->add_option("--position-bound", *position_bound_mm,
                  "Codec bound per coordinate in mm for a new --db (default 0.5; a file's codec is "
                  "fixed when it is made: an existing file with another bound is refused)")
      ->check(number_in(1e-6, 1e3));
  auto codec_name = std::make_shared<std::string>("v1");
  auto contract = std::make_shared<ContractOptions>();
  cmd->add_option("--codec", *codec_name,
                  "Frame codec of the clips this run stores: v1, v2 (a garment subspace built "
                  "from the clips stored so far, from --basis-first-frames on and again each time "
                  "the frames double; each clip keeps the smaller of v1 and v2; docs/DATABASE.md, "
                  "\"clothdb precompute ... --codec v2\"), or v3 (the same bases, each clip coded "
                  "within --rms-mm, --max-mm and --jitter-mm against its simulated frames and "
                  "kept where smaller than v1)")
      ->check(CLI::IsMember({"v1", "v2", "v3"}))
      ->capture_default_str();
  contract->add_to(*cmd);
  cmd->add_flag("--always", args->explore.subspace_always,
                "--codec v2, v3: keep the subspace blob even where the clip's v1 blob is smaller "
                "(to measure the codec on the simulated frames; `db recode --always` likewise)");
  cmd->add_option("--modes", args->explore.subspace_modes, "--codec v2, v3: modes of each basis")
      ->check(number_in(1, 1024));
  cmd->add_flag("--body-frame", args->explore.subspace_body_frame,
                "--codec v2: code the cloth relative to a rigid body frame fitted to the "
                "garment's highest 5 % (its pinned band) in every frame");
  cmd->add_option("--basis-first-frames", args->explore.subspace_first_frames,
                  "--codec v2: stored clip frames before the first basis is built")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_option("--frames", args->explore.max_frames,
                  "Budget: cloth frames to simulate in this run (0: none)")
      ->capture_default_str();
  cmd->add_option("--cpu-hours", args->explore.cpu_hours,
                  "Budget: CPU hours of everything this run does (0: none): the set-up, the "
                  "error floor's measurement and every simulation, all threads; checked before "
                  "each batch, so a run overshoots it by at most one batch (`budget` in the "
                  "summary shows what was counted and the largest batch)")
      ->capture_default_str();
  cmd->add_option(
         "--threads", args->explore.threads,
         "OpenMP threads (0: all cores). Under mpirun: each worker rank's threads inside one "
         "simulation (0: 1)")
      ->capture_default_str()
      ->check(number_in(0, max_solver_threads()));
  cmd->add_option("--batch", args->explore.batch,
                  "Dead ends simulated per batch; fixed so the result does not depend on --threads")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_option_function<double>(
         "--state-cache-mb",
         [args](double mb) { args->explore.state_cache_bytes = static_cast<size_t>(mb * 1048576); },
         "Memory for exact cloth states read back from the database (an LRU cache; default 256). "
         "Every other state is held as a reduced form of at most 16 x 6 doubles "
         "(docs/notebook/explorer.md#memory-per-state); changes the speed only, never the file")
      ->check(number_in(0.0, 1e6));
  cmd->add_option("--graph", args->graph,
                  "Use this motion graph (from `clothdb graph build --out`); default: the one the "
                  "database holds "
                  "(`clothdb graph build --db`), else one built from the scene's clips");
  cmd->add_option("--percentile", args->percentile,
                  "Motion graph: transition threshold percentile (default: the scene's graph "
                  "block, else graph build's; refused beside a graph block)")
      ->check(number_in(0.0, 100.0, true));
  cmd->add_option("--curve", args->curve,
                  "Write the error-against-CPU-time curve to PREFIX.csv and PREFIX.svg (default: "
                  "beside the database)");
  cmd->add_flag("--quiet", *quiet, "No progress bar");
  cmd->add_flag("--force", args->force,
                "Explore even with an --epsilon below the garment's error floor (which cannot "
                "link clip ends: `clothdb floor --help`)");
  cmd->add_flag("!--no-floor", args->measure_floor,
                "Do not measure the error floor of a database that has none (a floor already "
                "in its meta is still checked)");
  cmd->add_option("--floor-seconds", *floor_seconds,
                  "Error floor: seconds of the common continuation and of holding still (each)")
      ->capture_default_str()
      ->check(number_in(0.0, 600.0));
  cmd->add_option("--floor-histories", args->floor.histories,
                  "Error floor: different histories that meet at a common node")
      ->capture_default_str()
      ->check(CLI::Range(2, 64));
  cmd->add_flag(
      "--auto", args->automatic,
      "Choose the solver setting: simulate the garment along the first --auto-frames frames of the "
      "start edge with the scene's own solver setting and variations of it (fewer and more "
      "sub-steps and iterations, every other field kept) and with a reference (the scene's setting "
      "at 8x the sub-steps); compare over the frames where the reference's own chaos floor stays "
      "within a quarter of the bound; take the cheapest (CPU time) whose error is within "
      "--auto-fraction x epsilon, or, when none is, the cheapest whose error is at most the "
      "scene's "
      "own setting's. Prints the table; the database records the choice and a resumed run reuses "
      "it");
  cmd->add_option("--auto-solvers", args->auto_solvers,
                  "--auto: comma-separated solvers to try (default: the scene's), e.g. xpbd,pbd");
  cmd->add_option("--auto-fraction", args->auto_fraction,
                  "--auto: accept an error up to this fraction of epsilon")
      ->capture_default_str()
      ->check(number_in(0.0, 1.0));
  cmd->add_option("--auto-frames", args->auto_frames, "--auto: frames of the calibration clip")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_flag("--auto-quick", args->auto_quick, "--auto: fewer candidate settings");
  cmd->add_flag("--auto-newton-reference", args->auto_newton_reference,
                "--auto: measure against the benchmark's Newton reference instead (also counts the "
                "difference between the solvers' material models)");
#ifdef CLOTHDB_MPI
  cmd->add_option(
         "--job-timeout", args->job_timeout,
         "Under mpirun: seconds after which a job whose result has not come back is lost and "
         "handed to another rank (grows to 4x the slowest time per frame seen x the job's frames; "
         "10x this before the first result). Run mpirun with --enable-recovery so a dead rank "
         "does not end the job")
      ->capture_default_str()
      ->check(positive_number());
  cmd->add_flag("--mpi-verbose", args->mpi_verbose,
                "Under mpirun: one line per job handed out, lost or late");
  cmd->add_option(
         "--mpi-replica-mb", args->mpi_replica_mb,
         "Under mpirun: each worker keeps the states it has been sent, up to this many MB of "
         "positions and velocities (24 B a vertex a state; the least recently used are dropped), "
         "so that a job names the states a worker holds by id instead of sending them again. "
         "Changes the bytes sent, never the result")
      ->capture_default_str()
      ->check(number_in(0.0, 1e7));
#endif
  cmd->callback([args, epsilon_mm, position_bound_mm, quiet, floor_seconds, codec_name, contract] {
    PrecomputeRequest request = *args;
    if (*codec_name == "v2" || *codec_name == "v3") {
      if (request.explore.subspace_modes == 0) request.explore.subspace_modes = 64;
    } else if (request.explore.subspace_modes != 0 || request.explore.subspace_body_frame ||
               request.explore.subspace_always) {
      throw std::runtime_error("--modes, --body-frame, --always: only with --codec v2 or v3");
    }
    if (*codec_name == "v3" && request.explore.subspace_body_frame)
      throw std::runtime_error("--body-frame: only with --codec v2");
    request.explore.subspace_contract = contract->resolved(*codec_name == "v3");
    request.explore.epsilon = 1e-3 * *epsilon_mm;
    request.position_bound = 1e-3 * *position_bound_mm;
    request.floor.continuation_seconds = request.floor.hold_seconds = *floor_seconds;
    request.explore.progress = !*quiet;
    PrecomputeOutcome out;
    try {
      out = run_precompute(request, stderr);
    } catch (const db::SettingsError& e) {
      // Name the argument the user typed next to the record's field.
      const std::string m = e.what();
      const std::pair<const char*, const char*> flags[] = {{": epsilon_m:", "--epsilon (mm)"},
                                                           {": cpu_hours:", "--cpu-hours"},
                                                           {": max_frames:", "--frames"},
                                                           {": threads:", "--threads"},
                                                           {": batch:", "--batch"}};
      for (const auto& [field, flag] : flags)
        if (m.find(field) != std::string::npos && m.find("solver.") == std::string::npos)
          throw std::runtime_error(std::string(flag) + ": " + m);
      throw;
    }
    if (out.worker) return;
    if (!out.mpi_summary.empty()) std::fputs(out.mpi_summary.c_str(), stderr);
    const ExploreReport& report = out.report;
    std::printf(
        "database     %s\n"
        "states       %d\nclips        %d\ndead ends    %d (%s)\nframes       %ld stored, %ld this "
        "run\n"
        "cpu          %.1f s this run (%.3f CPU-s per stored frame)\n"
        "budget       %.3f CPU s counted (everything the run did: set-up, error floor, "
        "simulations; --cpu-hours %g), largest batch %.3f CPU s\n"
        "worst error  %s unresolved (%s weighted by reach; %d unexplored ways out: state alone "
        "at its node, error unknown), %.2f mm largest blend on an edge (epsilon %.1f mm)\n"
        "linked       %.1f %% of clip ends linked back within epsilon\n"
        "dead ends    %d closed with a link to the nearest state's clip (blend error mean %.2f "
        "mm, worst %.2f mm): the runtime needs no fallback\n"
        "steering     %d clip ends steered onto a state this run (largest pull %.2f mm in a "
        "frame)\n"
        "error floor  %s\n"
        "curve        %s.csv, %s.svg\n"
        "forecast     %s\n",
        request.db.c_str(), report.states, report.clips, report.dead_ends,
        report.converged ? "converged" : "budget reached", report.frames, report.frames_this_run,
        report.cpu_seconds,
        report.frames_this_run > 0 ? report.cpu_seconds / report.frames_this_run : 0.0,
        report.budget_cpu_seconds, request.explore.cpu_hours, report.largest_batch_cpu_seconds,
        mm(report.worst_error).c_str(), mm(report.weighted_worst_error).c_str(),
        report.curve.empty() ? 0 : report.curve.back().unexplored, 1e3 * report.worst_blend_error,
        *epsilon_mm, 100 * report.linked_fraction, report.links, 1e3 * report.mean_link_error,
        1e3 * report.worst_link_error, report.steered, 1e3 * report.worst_steering,
        floor_text(out).c_str(), out.curve_prefix.c_str(), out.curve_prefix.c_str(),
        forecast_text(report.forecast).c_str());
    std::printf(
        "memory       %zu B a state held (reduced form), exact states read back through a "
        "cache of %.0f MB (peak %.1f MB alive, %ld read from the file, %ld hits); %ld state "
        "distances measured\n",
        report.bytes_per_state, report.state_cache.capacity / 1048576.0,
        report.state_cache.peak_alive_bytes / 1048576.0, report.state_cache.reads,
        report.state_cache.hits, report.exact_evaluations);
    if (request.explore.subspace_modes > 0 && request.explore.subspace_contract.jitter > 0)
      std::printf(
          "codec        v3 (%u modes, contract RMS %g / max %g / jitter %g mm): %d bases built "
          "this run, %d removed (no clip chose them), %d of this run's clips stored as v3\n",
          request.explore.subspace_modes, 1e3 * request.explore.subspace_contract.rms,
          1e3 * request.explore.subspace_contract.max,
          1e3 * request.explore.subspace_contract.jitter, report.bases_built, report.bases_removed,
          report.clips_v3);
    else if (request.explore.subspace_modes > 0)
      std::printf(
          "codec        v2 (%u modes): %d bases built this run, %d removed (no clip chose "
          "them), %d of this run's clips stored as v2\n",
          request.explore.subspace_modes, report.bases_built, report.bases_removed,
          report.clips_v2);
  });
}

}  // namespace clothdb::cli
