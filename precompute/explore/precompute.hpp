// `clothdb precompute` as a library function: which motion graph, the resume rules, --auto and the
// MPI roles, so that they can be unit-tested and the CLI only parses arguments and prints.
//
//   motion graph: --graph FILE, else the one the database holds (`clothdb graph build --db`, or an
//                 earlier precompute), else one built from the scene's clips and its manifest
//                 (Kovar et al. 2002) with the manifest's weights and declared transitions and
//                 the settings of the scene's "graph" block (a stored graph made with other
//                 settings than the block's is refused, and so is --percentile beside it);
//   resume:       an existing database must have been made from the same scene file (hash), the
//                 same motion graph and the same solver setting (or --auto's recorded choice);
//   --auto:       calibrates the solvers on the start edge and takes the cheapest within
//                 auto_fraction x epsilon (explore/auto_solver.hpp); a resumed run reuses the
//                 choice the database records;
//   MPI:          under mpirun only rank 0 opens the database and chooses the graph; workers get
//                 its JSON and simulate jobs;
//   error floor:  a database without a floor in meta (a new one) first has the garment's error
//                 floor on the graph measured (explore/error_floor.hpp) and stored in meta; an
//                 epsilon below the floor (measured now or stored) is refused before anything is
//                 written, unless --force.
// The run settings are validated (database/run_settings.hpp) before any file is created.
#pragma once

#include <cstdio>
#include <string>

#include "explore/error_floor.hpp"
#include "explore/explorer.hpp"
#include "graph/motion_graph.hpp"

namespace clothdb {

struct PrecomputeRequest {
  std::string scene;       // scene file
  std::string db;          // database file (created, or resumed)
  std::string graph;       // --graph: a motion graph file ("" : the database's, else built)
  std::string curve;       // prefix of the error curve's .csv/.svg ("": beside the database)
  double percentile = -1;  // motion graph transition threshold percentile (<= 0: default)
  // m; > 0: the codec's position bound for a new database (an existing one must have it)
  double position_bound = 0;
  ExploreOptions explore;  // epsilon, budgets, threads (<= 0: all cores), batch, progress
  // --auto
  bool automatic = false;
  std::string auto_solvers;  // comma-separated ("" : the scene's)
  double auto_fraction = 0.5;
  int auto_frames = 15;
  bool auto_quick = false;
  bool auto_newton_reference = false;
  // the error floor
  bool measure_floor = true;  // --no-floor: false (a floor already in meta is still checked)
  ErrorFloorOptions floor;    // threads <= 0: the exploration's
  bool force = false;         // --force: explore with an epsilon below the floor
  // under mpirun
  double job_timeout = 60.0;
  bool mpi_verbose = false;
  double mpi_replica_mb =
      256;  // each worker's replica of the states it was sent (mpi::OwnerOptions)
};

struct PrecomputeOutcome {
  bool worker = false;  // this rank was an MPI worker: nothing else below is set
  bool resumed = false;
  std::string summary;      // one line: garment, colliders, solver, graph, epsilon, threads
  std::string auto_table;   // --auto's table ("" when not chosen now)
  std::string mpi_summary;  // rank 0's MPI summary ("" without MPI)
  std::string curve_prefix;
  // The floor the epsilon was checked against (m; < 0: none, --no-floor on a database without
  // one), and whether it was measured in this run (else read from meta).
  double error_floor = -1;
  bool floor_measured = false;
  std::string floor_line;  // what was printed about it
  ExploreReport report;
};

struct ChosenGraph {
  MotionGraph graph;
  std::string json;   // what the database stores (meta motion_graph)
  std::string where;  // where it came from, for messages
};

// The motion graph rule above. stored_json: the database's meta motion_graph ("" if none).
ChosenGraph choose_motion_graph(const CharacterScene& scene, const std::string& graph_file,
                                const std::string& stored_json, double percentile);

// The resume and --auto rules above: may change scene.file.solver / settings; returns --auto's
// table ("" when nothing was calibrated now). Throws naming the database when the stored solver
// setting differs from the scene's without --auto.
std::string choose_solver(const PrecomputeRequest& request, CharacterScene& scene,
                          const ExploreGraph& graph);

// The whole job. Progress and notes go to `log` (stderr in the CLI). Throws std::runtime_error /
// db::SettingsError naming the file, field or argument; an invalid setting is refused before the
// database is created.
PrecomputeOutcome run_precompute(const PrecomputeRequest& request, std::FILE* log);

}  // namespace clothdb
