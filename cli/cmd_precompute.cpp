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
#include "database/writer_lock.hpp"
#include "explore/auto_solver.hpp"
#include "explore/explorer.hpp"
#include "explore/primary_graph.hpp"
#include "graph/motion_graph.hpp"
#include "report/output.hpp"
#ifdef CLOTHDB_MPI
#include "explore/explore_mpi.hpp"
#endif

namespace clothdb::cli {

namespace {

struct Args {
  std::string scene, db, graph, curve;
  double epsilon_mm = 5.0, cpu_hours = 0.0, percentile = -1.0;
  long frames = 0;
  int threads = 0, batch = 16;
  bool quiet = false;
  bool automatic = false, auto_quick = false, auto_newton = false;
  std::string auto_solvers;
  double auto_fraction = 0.5;
  int auto_frames = 15;
  double job_timeout = 60.0;  // under mpirun (--job-timeout)
  bool mpi_verbose = false;
};

// The solver setting an existing database was made with ("" for none or a database older than
// the recorded settings).
std::string stored_solver(const std::string& path) {
  db::Reader reader;
  db::Error err;
  db::Garment g;
  if (!std::filesystem::exists(path) || reader.open(path, &err) != db::Status::Ok ||
      reader.garment(&g, &err) != db::Status::Ok)
    return "";
  return g.solver;
}

// --auto: sets the scene's solver and settings (explore/auto_solver.hpp) and returns the table it
// chose from ("" when reusing the database's choice). Without --auto, refuses to resume a
// database made with other solver settings (e.g. chosen by --auto).
std::string choose_solver(const Args& args, CharacterScene& scene, const ExploreGraph& eg) {
  const std::string stored = stored_solver(args.db);
  SolverKind kind = scene.file.solver;
  SolverSettings settings = scene.file.settings;
  if (!stored.empty()) {
    try {
      parse_solver_settings_json(stored, args.db + ": garment solver", &kind, &settings);
    } catch (const std::exception&) {
      if (args.automatic) throw;
      return "";  // recorded before the full settings were: nothing to compare
    }
    const std::string now = solver_settings_json(scene.file.solver, scene.file.settings);
    if (args.automatic) {
      scene.file.solver = kind;
      scene.file.settings.substeps = settings.substeps;
      scene.file.settings.iterations = settings.iterations;
      scene.file.settings.newton_tolerance = settings.newton_tolerance;
      scene.file.settings.linear_solver = settings.linear_solver;
      std::fprintf(stderr, "--auto: resuming with the setting chosen when %s was made: %s\n",
                   args.db.c_str(), stored.c_str());
    } else if (solver_settings_json(kind, settings) != now) {
      throw std::runtime_error(args.db + ": was made with the solver setting " + stored +
                               ", the scene gives " + now +
                               " (if --auto chose it, rerun with --auto)");
    }
    return "";
  }
  if (!args.automatic) return "";
  AutoSolverOptions o;
  for (const std::string& name : split_list(args.auto_solvers))
    o.kinds.push_back(parse_solver_kind(name));
  o.quick = args.auto_quick;
  o.frames = args.auto_frames;
  o.epsilon = 1e-3 * args.epsilon_mm;
  o.fraction = args.auto_fraction;
  o.newton_reference = args.auto_newton;
  // The calibration clip: the start of the first edge out of the start node (where the
  // exploration itself starts).
  const ExploreEdge* first = nullptr;
  for (const ExploreEdge& e : eg.edges)
    if (!first && e.from_node == eg.start_node) first = &e;
  std::fprintf(stderr, "--auto: calibrating on %d frames of %s...\n", o.frames,
               first->name.c_str());
  const AutoCalibration cal = calibrate_solvers(scene, first->poses, eg.rate, o);
  const int chosen = pick_solver(cal, o.epsilon, o.fraction);
  const std::string table = auto_table(cal, chosen, o.epsilon, o.fraction);
  std::fputs(table.c_str(), stderr);
  if (chosen < 0)
    throw std::runtime_error(
        "--auto: no candidate is stable with an error within " +
        std::to_string(std::lround(1e6 * o.fraction * o.epsilon)) + " um on " +
        scene.file.path.string() +
        "; raise --epsilon or --auto-fraction, or add solvers with --auto-solvers");
  scene.file.solver = cal.candidates[chosen].config.kind;
  scene.file.settings = cal.candidates[chosen].config.settings;
  scene.file.settings.threads = 1;
  return table;
}

}  // namespace

void register_precompute(CLI::App& app) {
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "precompute",
      "Builds the scene's motion graph and explores the secondary cloth graph into the database "
      "(Kim et al. 2013) until every dead end is within --epsilon or a budget (--frames, "
      "--cpu-hours) runs out. Killed at any moment, the same command resumes from the database.");
  cmd->add_option("SCENE", args->scene, "Scene file (JSON), e.g. motions/skirt_walk.json")
      ->required();
  cmd->add_option("--db", args->db, "Database file (created, or resumed if it exists)")->required();
  cmd->add_option("--epsilon", args->epsilon_mm,
                  "Error bound in mm: RMS over vertices of sqrt(|dx|^2 + (|dv|/rate)^2)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_option("--frames", args->frames,
                  "Budget: cloth frames to simulate in this run (0: none)")
      ->capture_default_str();
  cmd->add_option("--cpu-hours", args->cpu_hours,
                  "Budget: CPU hours of simulation in this run (0: none)")
      ->capture_default_str();
  cmd->add_option(
         "--threads", args->threads,
         "OpenMP threads (0: all cores). Under mpirun: each worker rank's threads inside one "
         "simulation (0: 1)")
      ->capture_default_str()
      ->check(number_in(0, max_solver_threads()));
  cmd->add_option("--batch", args->batch,
                  "Dead ends simulated per batch; fixed so the result does not depend on --threads")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_option("--graph", args->graph,
                  "Use this motion graph (from `clothdb graph build --out`); default: the one the "
                  "database holds "
                  "(`clothdb graph build --db`), else one built from the scene's clips");
  cmd->add_option("--percentile", args->percentile,
                  "Motion graph: transition threshold percentile (default: graph build's)");
  cmd->add_option("--curve", args->curve,
                  "Write the error-against-CPU-time curve to PREFIX.csv and PREFIX.svg (default: "
                  "beside the database)");
  cmd->add_flag("--quiet", args->quiet, "No progress bar");
  cmd->add_flag(
      "--auto", args->automatic,
      "Choose the solver setting: simulate the garment along the first --auto-frames frames of the "
      "start edge with each setting of the solver benchmark's sweep and with a reference (the "
      "first solver's finest setting with 4x the sub-steps); take the cheapest (CPU time) whose "
      "error is within "
      "--auto-fraction x epsilon. Prints the table; the database records the choice and a resumed "
      "run reuses it");
  cmd->add_option("--auto-solvers", args->auto_solvers,
                  "--auto: comma-separated solvers to try (default: the scene's), e.g. xpbd,pbd");
  cmd->add_option("--auto-fraction", args->auto_fraction,
                  "--auto: accept an error up to this fraction of epsilon")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  cmd->add_option("--auto-frames", args->auto_frames, "--auto: frames of the calibration clip")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_flag("--auto-quick", args->auto_quick,
                "--auto: the benchmark's quick sweep (fewer settings)");
  cmd->add_flag("--auto-newton-reference", args->auto_newton,
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
      ->check(CLI::PositiveNumber);
  cmd->add_flag("--mpi-verbose", args->mpi_verbose,
                "Under mpirun: one line per job handed out, lost or late");
#endif
  cmd->callback([args] {
#ifdef CLOTHDB_MPI
    const bool owner_rank = mpi::size() <= 1 || mpi::rank() == 0;
#else
    const bool owner_rank = true;
#endif
    // One writer per database: a second run is refused here, before the scene and graph set-up.
    const auto lock = owner_rank ? db::WriterLock::acquire(args->db) : nullptr;
    const SceneFile file = load_scene_file(args->scene);
    CharacterScene scene = build_character_scene(file);
    // Under mpirun only rank 0 touches the database (and chooses the graph); workers are given
    // the graph below.
    bool worker = false;
#ifdef CLOTHDB_MPI
    worker = mpi::size() > 1 && mpi::rank() != 0;
#endif
    const bool exists = !worker && std::filesystem::exists(args->db);
    // The motion graph: --graph, else the one the database holds (`graph build --db`, or an
    // earlier precompute), else built here from the scene's clips and the manifest.
    std::string stored;
    if (exists) {
      db::Reader reader;
      db::Error err;
      if (reader.open(args->db, &err) != db::Status::Ok)
        throw std::runtime_error(args->db + ": " + std::string(err.message));
      stored = stored_motion_graph(reader);
    }
    MotionGraph graph;
    std::string graph_json, where;
    if (worker) {
      // filled in from rank 0's graph below
    } else if (!args->graph.empty()) {
      graph = load_motion_graph(args->graph);
      where = args->graph;
    } else if (!stored.empty()) {
      where = args->db + ": meta motion_graph";
      graph = motion_graph_from_json(nlohmann::json::parse(stored), where);
      graph_json = stored;
    } else {
      GraphSettings settings;
      if (args->percentile > 0) settings.threshold = args->percentile;
      const MotionManifest& manifest = scene.file.manifest;
      std::vector<double> weights;
      std::vector<ManifestTransition> declared;
      for (const auto& name : file.clips)
        weights.push_back(manifest.clips[manifest.require(name)].weight);
      for (const auto& t : manifest.transitions)
        if (std::count(file.clips.begin(), file.clips.end(), t.from) &&
            std::count(file.clips.begin(), file.clips.end(), t.to))
          declared.push_back(t);
      graph = build_motion_graph(scene.clips, scene.skeleton, settings, declared);
      set_edge_weights(graph, weights, declared);
      where = args->scene;
    }
    if (graph_json.empty() && !worker) graph_json = motion_graph_to_json(graph).dump();
#ifdef CLOTHDB_MPI
    // Only rank 0 reads the database, so the graph it chose (the database's, --graph, or built)
    // goes to the workers as JSON, and every rank explores the graph parsed from that same text.
    if (mpi::size() > 1) {
      graph_json = mpi::share_from_owner(graph_json);
      where = "the motion graph rank 0 sent";
      graph = motion_graph_from_json(nlohmann::json::parse(graph_json), where);
    }
#endif
    if (graph.edges.empty()) throw std::runtime_error(where + ": the motion graph has no edges");
    ExploreGraph eg = explore_graph(scene, graph, where);
#ifdef CLOTHDB_MPI
    // Every rank has the same scene and graph now; only rank 0 goes on to the database. The
    // solver setting (the scene's, or --auto's choice on rank 0) travels with each job.
    if (worker) {
      mpi::run_worker(scene, eg, std::max(1, args->threads));
      return;
    }
#endif
    const bool resuming = !stored_solver(args->db).empty();  // a garment: an earlier precompute
    const std::string auto_table_text = choose_solver(*args, scene, eg);
    db::Writer writer = exists ? db::Writer::open(args->db) : db::Writer::create(args->db);
    prepare_database(writer, scene, eg, graph_json);
    if (!auto_table_text.empty()) writer.set_meta("auto_solver", auto_table_text);
    ExploreOptions options;
    if (args->automatic) options.run_settings = "\"auto_solver\": true";
    options.epsilon = 1e-3 * args->epsilon_mm;
    options.cpu_hours = args->cpu_hours;
    options.max_frames = args->frames;
    options.threads = args->threads > 0
                          ? args->threads
                          : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    options.batch = args->batch;
    options.progress = !args->quiet;
    std::fprintf(stderr,
                 "%s: %s of %d vertices, %zu capsules, %s; motion graph %d nodes, %d edges (%d "
                 "transitions); "
                 "epsilon %.1f mm, %d threads%s\n",
                 args->db.c_str(), scene.garment.name.c_str(), scene.model.vertex_count(),
                 scene.body.capsules.size(), solver_name(scene.file.solver), graph.node_count(),
                 graph.edge_count(), graph.transition_count(), args->epsilon_mm, options.threads,
                 resuming ? " (resuming)" : "");
#ifdef CLOTHDB_MPI
    std::unique_ptr<mpi::Owner> owner;
    if (mpi::size() > 1) {
      mpi::OwnerOptions mo;
      mo.job_timeout = args->job_timeout;
      mo.verbose = args->mpi_verbose;
      mo.threads = options.threads;
      owner = std::make_unique<mpi::Owner>(scene, eg, mo);
      std::fprintf(stderr, "%s: MPI: rank 0 owns the database, %d worker ranks simulate\n",
                   args->db.c_str(), mpi::size() - 1);
    }
    const ExploreReport report =
        explore(scene, eg, writer, options, owner ? owner->runner() : BatchRunner{});
    if (owner) {
      std::fprintf(stderr, "%s", owner->summary().c_str());
      std::fprintf(
          stderr,
          "mpi: rank 0 integrating: %.1f us per job (decode end state, nearest state, SQLite)\n",
          1e6 * report.integrate_seconds / std::max(1L, report.jobs_this_run));
    }
#else
    const ExploreReport report = explore(scene, eg, writer, options);
#endif
    const std::string prefix = args->curve.empty() ? args->db + ".curve" : args->curve;
    write_file_atomic(prefix + ".csv", curve_csv(report.curve));
    write_file_atomic(prefix + ".svg", curve_svg(report.curve, options.epsilon));
    std::printf(
        "database     %s\n"
        "states       %d\nclips        %d\ndead ends    %d (%s)\nframes       %ld stored, %ld this "
        "run\n"
        "cpu          %.1f s this run (%.3f CPU-s per stored frame)\n"
        "worst error  %.2f mm unresolved, %.2f mm largest blend on an edge (epsilon %.1f mm)\n"
        "curve        %s.csv, %s.svg\n",
        args->db.c_str(), report.states, report.clips, report.dead_ends,
        report.converged ? "converged" : "budget reached", report.frames, report.frames_this_run,
        report.cpu_seconds,
        report.frames_this_run > 0 ? report.cpu_seconds / report.frames_this_run : 0.0,
        1e3 * report.worst_error, 1e3 * report.worst_blend_error, args->epsilon_mm, prefix.c_str(),
        prefix.c_str());
#ifdef CLOTHDB_MPI
    // Workers stop only now: everything rank 0 writes is written, whatever happens to them.
    if (owner) owner->finish();
#endif
  });
}

}  // namespace clothdb::cli
