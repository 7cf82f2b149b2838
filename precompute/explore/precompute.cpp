#include "explore/precompute.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <thread>

#include "database/format/cloth_graph.hpp"
#include "database/store/writer_lock.hpp"
#include "explore/auto_solver.hpp"
#include "explore/primary_graph.hpp"
#include "report/output.hpp"
#ifdef CLOTHDB_MPI
#include "explore/explore_mpi.hpp"
#endif

namespace clothdb {

namespace {

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

std::vector<std::string> split_names(const std::string& list) {
  std::vector<std::string> out;
  std::stringstream in(list);
  std::string item;
  while (std::getline(in, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

ErrorFloorOptions floor_options_for(const PrecomputeRequest& request,
                                    const ExploreOptions& options) {
  ErrorFloorOptions o = request.floor;
  if (o.threads <= 0) o.threads = options.threads;
  o.progress = options.progress;
  return o;
}

std::string millimetres(double metres) {
  char text[32];
  std::snprintf(text, sizeof text, "%.2f mm", 1e3 * metres);
  return text;
}

// The error floor rule of precompute.hpp: the floor stored in the database's meta, else (unless
// --no-floor) measured now, and the epsilon checked against it. Runs before the database is
// created or changed, so a refusal writes nothing. Returns the measurement made now, if any.
std::optional<ErrorFloor> check_error_floor(const PrecomputeRequest& request,
                                            const CharacterScene& scene, const ExploreGraph& eg,
                                            const std::string& graph_json, double epsilon,
                                            bool exists, const ErrorFloorOptions& floor_options,
                                            PrecomputeOutcome& out, std::FILE* log) {
  std::optional<ErrorFloor> measured;
  if (exists) {
    db::Reader reader;
    db::Error err;
    if (reader.open(request.db, &err) != db::Status::Ok)
      throw std::runtime_error(err.message);  // names the file
    // A database holding another motion graph is refused for that (by prepare_database's own
    // check, read-only here) before a floor is measured on the wrong graph.
    ExploreGraph copy = eg;
    attach_primary_graph(reader, copy, graph_json);
    if (const std::optional<double> stored = db::meta_number(reader, db::meta::kErrorFloor))
      out.error_floor = *stored;
  }
  std::string floor_text, details;  // "26.81 mm (median of ...)", then indented lines
  if (out.error_floor >= 0) {
    floor_text = millimetres(out.error_floor) + " (measured when " + request.db +
                 " was made: meta error_floor)";
  } else if (request.measure_floor) {
    if (log)
      std::fprintf(log,
                   "measuring the error floor of this garment on this motion: %d histories, %g s "
                   "walked together, %g s held still (--no-floor to skip)...\n",
                   floor_options.histories, floor_options.continuation_seconds,
                   floor_options.hold_seconds);
    measured = measure_error_floor(scene, eg, floor_options);
    out.error_floor = measured->floor;
    out.floor_measured = true;
    floor_text = error_floor_summary(*measured);
    if (measured->fallback) details += "\n  note: " + measured->note;
    char cpu[96];
    std::snprintf(cpu, sizeof cpu, "\n  measured in %.1f CPU s (%ld solver steps)",
                  measured->cpu_seconds, measured->frames);
    details += cpu;
  } else {
    return measured;
  }
  const bool below = epsilon < out.error_floor;
  char verdict[160];
  std::snprintf(verdict, sizeof verdict, "; epsilon %.1f mm is %s it%s", 1e3 * epsilon,
                below ? "below" : "not below",
                below && request.force ? " (--force: exploring anyway)" : "");
  out.floor_line = "error floor of this garment on this motion: " + floor_text + verdict + details;
  if (below && !request.force) {
    char advice[320];
    std::snprintf(advice, sizeof advice,
                  "States that reach the same node by different histories stay about that far "
                  "apart, so clip ends cannot link within epsilon %.1f mm and every clip would "
                  "make a new state. Use --epsilon %.0f (1.5 x the floor, rounded up to a mm), "
                  "or --force to explore with %.1f mm anyway; nothing was written.",
                  1e3 * epsilon, 1e3 * suggested_epsilon(out.error_floor), 1e3 * epsilon);
    throw std::runtime_error(request.db + ": epsilon " + millimetres(epsilon) +
                             " is below the error floor of this garment on this motion, " +
                             floor_text + details + "\n" + advice);
  }
  if (log) std::fprintf(log, "%s\n", out.floor_line.c_str());
  return measured;
}

}  // namespace

ChosenGraph choose_motion_graph(const CharacterScene& scene, const std::string& graph_file,
                                const std::string& stored_json, double percentile) {
  ChosenGraph out;
  if (!graph_file.empty()) {
    out.graph = load_motion_graph(graph_file);
    out.where = graph_file;
  } else if (!stored_json.empty()) {
    out.where = "the database's meta motion_graph";
    const nlohmann::json j = nlohmann::json::parse(stored_json, nullptr, false);
    if (j.is_discarded()) throw std::runtime_error(out.where + ": not valid JSON");
    out.graph = motion_graph_from_json(j, out.where);
    out.json = stored_json;
    // A scene that fixes its graph settings must get a graph made with them (one made by `graph
    // build --db` with other settings would otherwise be explored silently).
    if (!scene.file.graph.is_null()) {
      const GraphSettings wanted =
          graph_settings_from_scene(scene.file.graph, scene.file.path.string());
      MotionGraph probe;
      probe.settings = wanted;
      if (motion_graph_to_json(probe)["settings"] != j["settings"])
        throw std::runtime_error(out.where + ": was built with other graph settings (" +
                                 j["settings"].dump() + ") than the graph block of " +
                                 scene.file.path.string() + " (" +
                                 motion_graph_to_json(probe)["settings"].dump() +
                                 "); use a new --db, or build the graph from the scene");
    }
  } else {
    GraphSettings settings = graph_settings_from_scene(scene.file.graph, scene.file.path.string());
    if (percentile > 0) {
      if (!scene.file.graph.is_null())
        throw std::runtime_error(scene.file.path.string() +
                                 ": graph: the scene's graph block fixes the motion graph's "
                                 "settings; set percentile there, not with --percentile");
      settings.threshold = percentile;
    }
    const MotionManifest& manifest = scene.file.manifest;
    std::vector<double> weights;
    std::vector<ManifestTransition> declared;
    for (const auto& name : scene.file.clips)
      weights.push_back(manifest.clips[manifest.require(name)].weight);
    for (const auto& t : manifest.transitions)
      if (std::count(scene.file.clips.begin(), scene.file.clips.end(), t.from) &&
          std::count(scene.file.clips.begin(), scene.file.clips.end(), t.to))
        declared.push_back(t);
    out.graph = build_motion_graph(scene.clips, scene.skeleton, settings, declared);
    set_edge_weights(out.graph, weights, declared);
    out.where = scene.file.path.string();
  }
  if (out.json.empty()) out.json = motion_graph_to_json(out.graph).dump();
  return out;
}

std::string choose_solver(const PrecomputeRequest& request, CharacterScene& scene,
                          const ExploreGraph& eg) {
  const std::string stored = stored_solver(request.db);
  SolverKind kind = scene.file.solver;
  SolverSettings settings = scene.file.settings;
  if (!stored.empty()) {
    try {
      parse_solver_settings_json(stored, request.db + ": garment solver", &kind, &settings);
    } catch (const std::exception&) {
      if (request.automatic) throw;
      return "";  // recorded before the full settings were: nothing to compare
    }
    // Threads never change a result, so they are not part of the comparison.
    const std::string now = solver_settings_json(scene.file.solver, scene.file.settings);
    if (request.automatic) {
      const int threads = scene.file.settings.threads;
      scene.file.solver = kind;
      scene.file.settings = settings;
      scene.file.settings.threads = threads;
    } else if (solver_settings_json(kind, settings) != now) {
      throw std::runtime_error(request.db + ": was made with the solver setting " + stored +
                               ", the scene gives " + now +
                               " (if --auto chose it, rerun with --auto)");
    }
    return "";
  }
  if (!request.automatic) return "";
  AutoSolverOptions o;
  for (const std::string& name : split_names(request.auto_solvers))
    o.kinds.push_back(parse_solver_kind(name));
  o.quick = request.auto_quick;
  o.frames = request.auto_frames;
  o.epsilon = request.explore.epsilon;
  o.fraction = request.auto_fraction;
  o.newton_reference = request.auto_newton_reference;
  // The calibration clip: the start of the first edge out of the start node (where the
  // exploration itself starts).
  const ExploreEdge* first = nullptr;
  for (const ExploreEdge& e : eg.edges)
    if (!first && e.from_node == eg.start_node) first = &e;
  if (!first) throw std::runtime_error("--auto: no edge leaves the motion graph's start node");
  const AutoCalibration cal = calibrate_solvers(scene, first->poses, eg.rate, o);
  const int chosen = pick_solver(cal, o.epsilon, o.fraction);
  const std::string table = auto_table(cal, chosen, o.epsilon, o.fraction);
  if (chosen < 0) {
    char bound[160];
    std::snprintf(bound, sizeof bound, "%.3g mm (--auto-fraction %.3g x --epsilon %.3g mm)",
                  1e3 * o.fraction * o.epsilon, o.fraction, 1e3 * o.epsilon);
    throw std::runtime_error("--auto: no candidate is stable with an error within " +
                             std::string(bound) + " on " + scene.file.path.string() +
                             "; raise --epsilon or --auto-fraction, or add solvers with "
                             "--auto-solvers\n" +
                             table);
  }
  scene.file.solver = cal.candidates[chosen].config.kind;
  scene.file.settings = cal.candidates[chosen].config.settings;
  scene.file.settings.threads = 1;
  return table;
}

PrecomputeOutcome run_precompute(const PrecomputeRequest& request, std::FILE* log) {
  PrecomputeOutcome out;
  // --cpu-hours counts everything from here: the scene, --auto's calibration, the error floor.
  const double process_cpu_start = process_cpu_seconds();
  const SceneFile file = load_scene_file(request.scene);
  CharacterScene scene = build_character_scene(file);
  if (log)
    for (const std::string& line : placement_lines(scene.placement))
      std::fprintf(log, "%s: %s\n", request.scene.c_str(), line.c_str());
  ExploreOptions options = request.explore;
  options.process_cpu_start = process_cpu_start;
  options.auto_solver = request.automatic;
  options.threads = options.threads > 0
                        ? options.threads
                        : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  // Refused here, before a file exists: NaN or negative epsilon or budget, a thread count no
  // machine has, ... (the explorer validates the same record again with the database's codec).
  make_run_settings(scene, options, db::CodecSettings{});
  if (request.automatic && !(request.auto_fraction > 0 && request.auto_fraction <= 1))
    throw db::SettingsError("--auto-fraction: must be in (0, 1]");

  bool worker = false;
#ifdef CLOTHDB_MPI
  worker = mpi::size() > 1 && mpi::rank() != 0;
  if (mpi::size() > 1 && options.subspace_modes > 0)
    throw db::SettingsError(
        "--codec v2, v3: runs in one process only (MPI workers would each need the basis); "
        "precompute with codec v1 and convert with `clothdb db recode`");
#endif
  // One writer per database (database/writer_lock.hpp): a second run is refused here, naming the
  // holder, before the graph set-up.
  const auto lock = worker ? nullptr : db::WriterLock::acquire(request.db);
  const bool exists = !worker && std::filesystem::exists(request.db);
  if (exists && std::filesystem::is_directory(request.db))
    throw std::runtime_error(request.db + ": is a directory, not a database file");
  std::string stored;
  if (exists) {
    db::Reader reader;
    db::Error err;
    if (reader.open(request.db, &err) != db::Status::Ok)
      throw std::runtime_error(err.message);  // names the file
    stored = stored_motion_graph(reader);
  }
  ChosenGraph chosen;
  if (!worker) chosen = choose_motion_graph(scene, request.graph, stored, request.percentile);
  if (!stored.empty() && request.graph.empty()) chosen.where = request.db + ": meta motion_graph";
#ifdef CLOTHDB_MPI
  // Only rank 0 reads the database, so the graph it chose (the database's, --graph, or built)
  // goes to the workers as JSON, and every rank explores the graph parsed from that same text.
  if (mpi::size() > 1) {
    chosen.json = mpi::share_from_owner(chosen.json);
    chosen.where = "the motion graph rank 0 sent";
    chosen.graph = motion_graph_from_json(nlohmann::json::parse(chosen.json), chosen.where);
  }
#endif
  if (chosen.graph.edges.empty())
    throw std::runtime_error(chosen.where + ": the motion graph has no edges");
  ExploreGraph eg = explore_graph(scene, chosen.graph, chosen.where);
#ifdef CLOTHDB_MPI
  // Every rank has the same scene and graph now; only rank 0 goes on to the database. The
  // solver setting (the scene's, or --auto's choice on rank 0) travels with each job.
  if (worker) {
    mpi::run_worker(scene, eg, std::max(1, request.explore.threads));
    out.worker = true;
    return out;
  }
#endif
  out.resumed = !stored_solver(request.db).empty();  // a garment: an earlier precompute
  if (request.automatic && log)
    std::fprintf(log, "--auto: calibrating on %d frames of the start edge...\n",
                 request.auto_frames);
  out.auto_table = choose_solver(request, scene, eg);
  if (!out.auto_table.empty() && log) std::fputs(out.auto_table.c_str(), log);
  if (request.automatic && out.auto_table.empty() && log)
    std::fprintf(log, "--auto: resuming with the setting chosen when %s was made: %s\n",
                 request.db.c_str(),
                 solver_settings_json(scene.file.solver, scene.file.settings).c_str());
  // A codec bound the existing file does not have is refused before the floor is measured.
  if (exists && request.position_bound > 0)
    db::Writer::open_or_create(request.db, request.position_bound);
  const ErrorFloorOptions floor_options = floor_options_for(request, options);
  const std::optional<ErrorFloor> measured = check_error_floor(
      request, scene, eg, chosen.json, options.epsilon, exists, floor_options, out, log);
  if (measured) options.cpu_seconds_spent = measured->cpu_seconds;
  db::Writer writer = db::Writer::open_or_create(request.db, request.position_bound);
  prepare_database(writer, scene, eg, chosen.json);
  if (!out.auto_table.empty()) db::set_meta_text(writer, db::meta::kAutoSolver, out.auto_table);
  if (measured) {
    // Without timings: the meta of two runs of the same command must be the same (a killed and
    // resumed precompute gives the uninterrupted one's database).
    db::Writer::Transaction tx(writer);
    db::set_meta_number(writer, db::meta::kErrorFloor, measured->floor);
    db::set_meta_text(writer, db::meta::kErrorFloorDetail,
                      error_floor_json(*measured, eg, floor_options, false));
    tx.commit();
  }
  char line[512];
  std::snprintf(line, sizeof line,
                "%s: %s of %d vertices, %zu capsules, %s; motion graph %d nodes, %d edges (%d "
                "transitions); epsilon %.1f mm, %d threads%s",
                request.db.c_str(), scene.garment.name.c_str(), scene.model.vertex_count(),
                scene.body.capsules.size(), solver_name(scene.file.solver),
                chosen.graph.node_count(), chosen.graph.edge_count(),
                chosen.graph.transition_count(), 1e3 * options.epsilon, options.threads,
                out.resumed ? " (resuming)" : "");
  out.summary = line;
  if (log) std::fprintf(log, "%s\n", line);
#ifdef CLOTHDB_MPI
  std::unique_ptr<mpi::Owner> owner;
  if (mpi::size() > 1) {
    mpi::OwnerOptions mo;
    mo.job_timeout = request.job_timeout;
    mo.verbose = request.mpi_verbose;
    mo.replica_bytes = static_cast<size_t>(request.mpi_replica_mb * double(1 << 20));
    mo.threads = options.threads;
    owner = std::make_unique<mpi::Owner>(scene, eg, mo);
    if (log)
      std::fprintf(log, "%s: MPI: rank 0 owns the database, %d worker ranks simulate\n",
                   request.db.c_str(), mpi::size() - 1);
  }
  out.report = explore(scene, eg, writer, options, owner ? owner->runner() : BatchRunner{});
  if (owner) {
    char buf[160];
    std::snprintf(
        buf, sizeof buf,
        "mpi: rank 0 integrating: %.1f us per job (decode end state, nearest state, SQLite)\n",
        1e6 * out.report.integrate_seconds / std::max(1L, out.report.jobs_this_run));
    out.mpi_summary = owner->summary() + buf;
  }
#else
  out.report = explore(scene, eg, writer, options);
#endif
  out.curve_prefix = request.curve.empty() ? request.db + ".curve" : request.curve;
  write_file_atomic(out.curve_prefix + ".csv", curve_csv(out.report.curve));
  write_file_atomic(out.curve_prefix + ".svg", curve_svg(out.report.curve, options.epsilon));
#ifdef CLOTHDB_MPI
  // Workers stop only now: everything rank 0 writes is written, whatever happens to them.
  if (owner) owner->finish();
#endif
  return out;
}

}  // namespace clothdb
