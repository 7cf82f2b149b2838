// The precompute across many machines with MPI (compiled only when CMake finds MPI: CLOTHDB_MPI).
//
// Rank 0 owns the database and the exploration queue and is the only rank that opens SQLite; it
// runs explore() with a BatchRunner that hands each job of a batch to the next free worker rank
// (dynamic hand-out, longest edge first) and collects the results. explore() integrates them in
// the batch's order, so the database is the one a single process writes with the same --batch.
// Every rank loads the scene and builds the graph itself from the same command line; a worker's
// first message carries the hashes of both, and rank 0 refuses a worker that differs.
//
// Rank 0 only coordinates (it simulates only when every worker is lost): its per-job work is
// microseconds to milliseconds against seconds of simulation, and a coordinator that never blocks
// in a solver answers every worker at once (docs/notebook/BENCHMARKS.md measures both).
//
// A job names its states by id; a worker keeps a replica of those it has been sent and rank 0 an
// account of each replica, so a job message carries whole only the states that worker lacks
// (explore/job_wire.hpp, ReplicaLedger).
//
// Fault tolerance (OpenMPI 4.1 has no ULFM): run with `mpirun --enable-recovery`, so the job
// survives a dead process; rank 0 sets MPI_ERRORS_RETURN and polls with MPI_Iprobe, and a job not
// back within its timeout (see OwnerOptions) goes back to the front of the queue for another rank;
// the silent rank gets no more jobs unless its result turns up after all. Results are
// deterministic, so a job run twice gives the same bytes and either copy may be integrated.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "explore/explorer.hpp"

namespace clothdb::mpi {

// True when this process was started by mpirun / srun (OpenMPI, PMI or PMIx variables set).
bool launched_by_mpi();

// MPI_Init_thread (funneled: only the main thread calls MPI; OpenMP threads simulate) when
// launched_by_mpi(), MPI_Finalize at the end. A plain `clothdb` run never initialises MPI.
class Session {
 public:
  Session(int* argc, char*** argv);
  ~Session();
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;
};

int rank();  // 0 when MPI is not active
int size();  // 1 when MPI is not active
// Ends every rank (MPI_Abort) when more than one runs: an error on one rank must not leave the
// others waiting for it.
void abort_all(int code);

// Rank 0's `text` on every rank (a collective call: every rank must make it). Workers get what
// rank 0 decided from files only it may read, e.g. the motion graph the database holds. Polls
// (MPI_Ibcast + MPI_Test with a sleep) instead of spinning a core while rank 0 works.
std::string share_from_owner(const std::string& text);

struct OwnerOptions {
  // A job is lost when its result has not come back after max(job_timeout, 4 x the slowest
  // seconds per frame seen so far x its frames); before the first result, 10 x job_timeout.
  double job_timeout = 60.0;
  bool verbose = false;  // one line per hand-out, loss and late result on stderr
  int threads = 1;       // rank 0's threads when it must simulate itself (every worker lost)
  // Each worker's replica of the states it has been sent (explore/job_wire.hpp ReplicaLedger):
  // at most this many bytes of exact states (24 B a vertex each) beyond those one job names.
  size_t replica_bytes = size_t(256) << 20;
};

// What rank 0 measured (for docs/notebook/BENCHMARKS.md and the summary line).
struct OwnerStats {
  long jobs_sent = 0, results = 0, lost = 0, late = 0, duplicates = 0, local_jobs = 0;
  double bytes_out = 0, bytes_back = 0;  // job and result messages
  // The states the job messages named: sent whole (as blobs or floats), by id only, and dropped
  // from a worker's replica (explore/job_wire.hpp).
  long states_sent = 0, states_named = 0, states_dropped = 0, sent_as_blobs = 0;
  double encode_seconds = 0;  // wall, encoding job messages
  double decode_seconds = 0;  // wall, decoding (and checking) result messages
  double idle_seconds = 0;    // wall, rank 0 waiting with nothing to do
  int workers = 0, workers_lost = 0;
};

// Rank 0's side. runner() is what explore() calls; finish() tells every worker to stop.
class Owner {
 public:
  Owner(const CharacterScene& scene, const ExploreGraph& graph, const OwnerOptions& options);
  ~Owner();
  Owner(const Owner&) = delete;
  Owner& operator=(const Owner&) = delete;
  BatchRunner runner();
  void finish();
  const OwnerStats& stats() const;
  std::string summary() const;  // a few lines for stderr

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// A worker's side: says hello, then simulates every job it receives with `threads` OpenMP threads
// inside the solver until rank 0 says stop.
void run_worker(const CharacterScene& scene, const ExploreGraph& graph, int threads);

}  // namespace clothdb::mpi
