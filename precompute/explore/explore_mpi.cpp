#include "explore/explore_mpi.hpp"

#include <mpi.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <limits>
#include <map>
#include <thread>

#include "database/format/checksum.hpp"
#include "explore/job_wire.hpp"

namespace clothdb::mpi {

namespace {

enum Tag : int { kHello = 1, kJob = 2, kResult = 3, kStop = 4 };

using Clock = std::chrono::steady_clock;

bool g_active = false;
// Set when a rank was lost: MPI_Finalize's closing fence (PMIx) can wait for the dead process
// forever on OpenMPI 4.1, so the survivors end without it (everything is committed by then).
bool g_skip_finalize = false;
int g_rank = 0, g_size = 1;

double since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

void check(int rc, const char* what) {
  if (rc == MPI_SUCCESS) return;
  char text[MPI_MAX_ERROR_STRING];
  int len = 0;
  MPI_Error_string(rc, text, &len);
  throw std::runtime_error(std::string("MPI: ") + what + ": " + std::string(text, len));
}

std::string host_name() {
  char name[256] = {0};
  gethostname(name, sizeof name - 1);
  return name;
}

// Sleeps a little longer each time nothing happens (0.1 ms up to 5 ms): MPI's blocking calls spin
// on a core, which on a shared or oversubscribed node takes it from the simulations.
class Backoff {
 public:
  void idle() {
    std::this_thread::sleep_for(std::chrono::microseconds(us_));
    us_ = std::min(us_ * 2, 5000);
  }
  void reset() { us_ = 100; }

 private:
  int us_ = 100;
};

// Receives the message MPI_Iprobe found.
std::vector<uint8_t> receive(const MPI_Status& probed) {
  int count = 0;
  check(MPI_Get_count(&probed, MPI_BYTE, &count), "MPI_Get_count");
  std::vector<uint8_t> bytes(static_cast<size_t>(count));
  check(MPI_Recv(bytes.data(), count, MPI_BYTE, probed.MPI_SOURCE, probed.MPI_TAG, MPI_COMM_WORLD,
                 MPI_STATUS_IGNORE),
        "MPI_Recv");
  return bytes;
}

uint64_t scene_hash(const CharacterScene& scene) {
  return db::xxh64(scene.file.text.data(), scene.file.text.size());
}

}  // namespace

bool launched_by_mpi() {
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK", "PMI_SIZE"})
    if (std::getenv(v)) return true;
  return false;
}

Session::Session(int* argc, char*** argv) {
  if (!launched_by_mpi()) return;
  int provided = 0;
  if (MPI_Init_thread(argc, argv, MPI_THREAD_FUNNELED, &provided) != MPI_SUCCESS) return;
  g_active = true;
  // Errors come back as codes (and become exceptions) instead of killing every rank, so a worker
  // that disappears does not take rank 0 with it.
  MPI_Comm_set_errhandler(MPI_COMM_WORLD, MPI_ERRORS_RETURN);
  MPI_Comm_rank(MPI_COMM_WORLD, &g_rank);
  MPI_Comm_size(MPI_COMM_WORLD, &g_size);
}

Session::~Session() {
  if (g_active && !g_skip_finalize) MPI_Finalize();
  g_active = false;
}

int rank() {
  return g_rank;
}
int size() {
  return g_size;
}

void abort_all(int code) {
  if (g_active && g_size > 1) MPI_Abort(MPI_COMM_WORLD, code);
}

namespace {

void broadcast_polling(void* data, int count) {
  MPI_Request request = MPI_REQUEST_NULL;
  check(MPI_Ibcast(data, count, MPI_BYTE, 0, MPI_COMM_WORLD, &request), "MPI_Ibcast");
  Backoff backoff;
  while (true) {
    int done = 0;
    check(MPI_Test(&request, &done, MPI_STATUS_IGNORE), "MPI_Test");
    if (done) return;
    backoff.idle();
  }
}

}  // namespace

std::string share_from_owner(const std::string& text) {
  if (!g_active || g_size < 2) return text;
  uint64_t length = g_rank == 0 ? text.size() : 0;
  broadcast_polling(&length, sizeof length);
  std::string out = g_rank == 0 ? text : std::string(length, '\0');
  if (length > static_cast<uint64_t>(std::numeric_limits<int>::max()))
    throw std::runtime_error("MPI: a shared text of " + std::to_string(length) + " bytes");
  if (length > 0) broadcast_polling(out.data(), static_cast<int>(length));
  return out;
}

// ---- rank 0 ----

struct Owner::Impl {
  enum class State { Loading, Idle, Busy, Lost };
  struct Worker {
    State state = State::Loading;
    // What its replica holds. Every job message sent to it updates both, in the order MPI
    // delivers them; a rank declared lost that answers after all received every message it was
    // sent, so its account is still right.
    ReplicaLedger ledger;
    std::string host;
    int64_t pid = 0;
    uint64_t seq = 0;  // the job it is running
    Clock::time_point start;
    long jobs = 0;
  };
  struct Handed {
    uint64_t batch = 0;  // which batch (results of an earlier batch are late copies)
    size_t index = 0;
    uint32_t frames = 0;
  };
  struct Send {
    MPI_Request request = MPI_REQUEST_NULL;
    std::vector<uint8_t> bytes;
  };

  const CharacterScene& scene;
  const ExploreGraph& graph;
  OwnerOptions options;
  uint64_t scene_hash_ = 0, graph_hash_ = 0;
  std::vector<Worker> workers;  // by rank (0 unused)
  std::map<uint64_t, Handed> handed;
  std::deque<Send> sends;
  uint64_t next_seq = 1, batch = 0;
  double slowest_per_frame = 0;  // wall seconds per frame, hand-out to result
  OwnerStats stats;
  Clock::time_point created = Clock::now();
  // The batch being run.
  const std::vector<JobInput>* jobs = nullptr;
  std::vector<JobResult>* results = nullptr;
  std::vector<bool> filled;
  std::deque<size_t> pending;
  size_t remaining = 0;

  Impl(const CharacterScene& s, const ExploreGraph& g, const OwnerOptions& o)
      : scene(s), graph(g), options(o) {
    scene_hash_ = scene_hash(scene);
    graph_hash_ = graph_hash(graph);
    workers.resize(static_cast<size_t>(size()));
    for (Worker& w : workers) w.ledger.capacity_bytes = options.replica_bytes;
    workers[0].state = State::Lost;  // rank 0 is not a worker
    stats.workers = size() - 1;
  }

  std::string who(int r) const {
    return "rank " + std::to_string(r) + " (" + workers[r].host + " pid " +
           std::to_string(workers[r].pid) + ")";
  }

  double timeout(uint32_t frames) const {
    if (slowest_per_frame <= 0) return 10 * options.job_timeout;
    return std::max(options.job_timeout, 4 * slowest_per_frame * frames);
  }

  void send(int to, int tag, std::vector<uint8_t> bytes) {
    sends.push_back({MPI_REQUEST_NULL, std::move(bytes)});
    Send& s = sends.back();
    check(MPI_Isend(s.bytes.data(), static_cast<int>(s.bytes.size()), MPI_BYTE, to, tag,
                    MPI_COMM_WORLD, &s.request),
          "MPI_Isend");
  }

  // Frees the buffers of sends that completed (in order: the oldest first).
  void reap_sends() {
    while (!sends.empty()) {
      int done = 0;
      if (MPI_Test(&sends.front().request, &done, MPI_STATUS_IGNORE) != MPI_SUCCESS || !done) break;
      sends.pop_front();
    }
  }

  void on_hello(int from, const std::vector<uint8_t>& bytes) {
    const WorkerHello h = decode_hello(bytes.data(), bytes.size());
    Worker& w = workers[from];
    w.host = h.host;
    w.pid = h.pid;
    if (h.scene_hash != scene_hash_ || h.graph_hash != graph_hash_ ||
        h.vertices != static_cast<uint32_t>(scene.model.vertex_count()))
      throw std::runtime_error(
          who(from) + " loaded a different " +
          (h.scene_hash != scene_hash_ ? "scene file" : "motion graph or garment") +
          " than rank 0: every rank must read the same SCENE, motion files and --graph");
    w.state = State::Idle;
    if (options.verbose)
      std::fprintf(stderr, "mpi: %s ready, %d threads\n", who(from).c_str(), h.threads);
  }

  void on_result(int from, const std::vector<uint8_t>& bytes) {
    const auto t0 = Clock::now();
    uint64_t seq = 0;
    JobResult r = decode_result(bytes.data(), bytes.size(), &seq);
    stats.decode_seconds += since(t0);
    stats.bytes_back += static_cast<double>(bytes.size());
    ++stats.results;
    Worker& w = workers[from];
    const bool was_lost = w.state == State::Lost;
    if (w.state == State::Busy && w.seq == seq) {
      const auto it = handed.find(seq);
      if (it != handed.end() && it->second.frames > 0)
        slowest_per_frame = std::max(slowest_per_frame, since(w.start) / it->second.frames);
    }
    w.state = State::Idle;
    ++w.jobs;
    if (was_lost) {
      ++stats.late;
      --stats.workers_lost;
      std::fprintf(stderr, "\nmpi: %s answered after all; it gets jobs again\n", who(from).c_str());
    }
    const auto it = handed.find(seq);
    if (it == handed.end())
      throw std::runtime_error(who(from) + " sent a result for job " + std::to_string(seq) +
                               " that was never handed out");
    const Handed h = it->second;
    handed.erase(it);
    if (h.batch != batch || filled[h.index]) {  // a second copy of a re-handed job
      ++stats.duplicates;
      return;
    }
    (*results)[h.index] = std::move(r);
    filled[h.index] = true;
    --remaining;
  }

  // Handles every message waiting; true if there was one.
  bool poll() {
    bool any = false;
    while (true) {
      int flag = 0;
      MPI_Status st;
      check(MPI_Iprobe(MPI_ANY_SOURCE, MPI_ANY_TAG, MPI_COMM_WORLD, &flag, &st), "MPI_Iprobe");
      if (!flag) break;
      any = true;
      const std::vector<uint8_t> bytes = receive(st);
      if (st.MPI_TAG == kHello)
        on_hello(st.MPI_SOURCE, bytes);
      else if (st.MPI_TAG == kResult)
        on_result(st.MPI_SOURCE, bytes);
      else
        throw std::runtime_error("rank " + std::to_string(st.MPI_SOURCE) +
                                 " sent an unknown message (tag " + std::to_string(st.MPI_TAG) +
                                 ")");
    }
    reap_sends();
    return any;
  }

  void hand_out(int to, size_t index) {
    const JobInput& job = (*jobs)[index];
    const uint64_t seq = next_seq++;
    const auto t0 = Clock::now();
    Worker& w = workers[to];
    JobWireCounts counts;
    std::vector<uint8_t> bytes = encode_job(seq, job, w.ledger, &counts);
    stats.encode_seconds += since(t0);
    stats.states_sent += counts.states_sent;
    stats.states_named += counts.states_named;
    stats.states_dropped += counts.states_dropped;
    stats.sent_as_blobs += counts.sent_as_blobs;
    stats.bytes_out += static_cast<double>(bytes.size());
    ++stats.jobs_sent;
    handed[seq] = {batch, index, static_cast<uint32_t>(graph.edges[job.edge].poses.size())};
    w.state = State::Busy;
    w.seq = seq;
    w.start = Clock::now();
    if (options.verbose)
      std::fprintf(stderr, "mpi: job %llu (batch %llu #%zu, '%s') -> %s\n",
                   static_cast<unsigned long long>(seq), static_cast<unsigned long long>(batch),
                   index, graph.edges[job.edge].name.c_str(), who(to).c_str());
    send(to, kJob, std::move(bytes));
  }

  void check_timeouts() {
    for (size_t r = 1; r < workers.size(); ++r) {
      Worker& w = workers[r];
      if (w.state == State::Loading && since(created) > 10 * options.job_timeout) {
        w.state = State::Lost;
        ++stats.workers_lost;
        std::fprintf(stderr, "\nmpi: rank %zu never said hello in %.0f s; running without it\n", r,
                     since(created));
      }
      if (w.state != State::Busy) continue;
      const auto it = handed.find(w.seq);
      const uint32_t frames = it == handed.end() ? 0 : it->second.frames;
      const double limit = timeout(frames);
      if (since(w.start) <= limit) continue;
      w.state = State::Lost;
      ++stats.lost;
      ++stats.workers_lost;
      if (it != handed.end() && it->second.batch == batch && !filled[it->second.index]) {
        pending.push_front(it->second.index);
        std::fprintf(stderr,
                     "\nmpi: %s: no result for job %llu after %.0f s; lost, its job goes back to "
                     "the queue\n",
                     who(static_cast<int>(r)).c_str(), static_cast<unsigned long long>(w.seq),
                     limit);
      }
    }
  }

  bool any_worker(std::initializer_list<State> states) const {
    for (size_t r = 1; r < workers.size(); ++r)
      if (std::find(states.begin(), states.end(), workers[r].state) != states.end()) return true;
    return false;
  }

  void run(const std::vector<JobInput>& batch_jobs, std::vector<JobResult>& batch_results) {
    ++batch;
    jobs = &batch_jobs;
    results = &batch_results;
    filled.assign(batch_jobs.size(), false);
    const std::vector<size_t> order = longest_first(graph, batch_jobs);
    pending.assign(order.begin(), order.end());
    remaining = batch_jobs.size();
    Backoff backoff;
    while (remaining > 0) {
      bool progress = poll();
      for (size_t r = 1; r < workers.size() && !pending.empty(); ++r)
        if (workers[r].state == State::Idle) {
          hand_out(static_cast<int>(r), pending.front());
          pending.pop_front();
          progress = true;
        }
      check_timeouts();
      if (!pending.empty() && !any_worker({State::Loading, State::Idle, State::Busy})) {
        // Every worker is lost: rank 0 finishes the work itself rather than stall.
        const size_t index = pending.front();
        pending.pop_front();
        JobInput job = batch_jobs[index];
        job.settings.threads = std::max(1, options.threads);
        batch_results[index] = run_job(scene, graph, job);
        filled[index] = true;
        --remaining;
        ++stats.local_jobs;
        progress = true;
      }
      if (progress) {
        backoff.reset();
      } else {
        const auto t0 = Clock::now();
        backoff.idle();
        stats.idle_seconds += since(t0);
      }
    }
    jobs = nullptr;
    results = nullptr;
  }

  void finish() {
    // Not to lost ranks: over TCP a send to a dead process tries to reconnect to it. The stop
    // says whether to skip MPI_Finalize (a rank was lost in this run).
    bool lost = stats.lost > 0;
    for (size_t r = 1; r < workers.size(); ++r) lost = lost || workers[r].state == State::Lost;
    g_skip_finalize = lost;
    for (size_t r = 1; r < workers.size(); ++r)
      if (workers[r].state != State::Lost)
        send(static_cast<int>(r), kStop, {static_cast<uint8_t>(lost ? 1 : 0)});
    // Wait (briefly) for the stops to leave; a send to a dead rank may never complete.
    const auto t0 = Clock::now();
    Backoff backoff;
    while (!sends.empty() && since(t0) < 10) {
      reap_sends();
      backoff.idle();
    }
    for (Send& s : sends)
      if (s.request != MPI_REQUEST_NULL) MPI_Request_free(&s.request);
    // MPI may still read these buffers until MPI_Finalize: keep them to the end of the process.
    static std::deque<Send> kept;
    for (Send& s : sends) kept.push_back(std::move(s));
    sends.clear();
  }
};

Owner::Owner(const CharacterScene& scene, const ExploreGraph& graph, const OwnerOptions& options)
    : impl_(std::make_unique<Impl>(scene, graph, options)) {}
Owner::~Owner() = default;

BatchRunner Owner::runner() {
  return [this](const std::vector<JobInput>& jobs, std::vector<JobResult>& results) {
    impl_->run(jobs, results);
  };
}

void Owner::finish() {
  impl_->finish();
}
const OwnerStats& Owner::stats() const {
  return impl_->stats;
}

std::string Owner::summary() const {
  const OwnerStats& s = impl_->stats;
  const double jobs = std::max<long>(1, s.jobs_sent), results = std::max<long>(1, s.results);
  char text[1024];
  std::snprintf(
      text, sizeof text,
      "mpi: %d workers, %ld jobs sent, %ld results (%ld lost, %ld late, %ld duplicates, %ld run on "
      "rank 0)\n"
      "mpi: %.0f bytes per job out, %.0f bytes per result back; rank 0 per job: encode %.1f us, "
      "decode %.1f us; rank 0 idle %.1f s\n"
      "mpi: states named by the jobs: %ld sent whole (%ld as the file's blobs), %ld by id (held "
      "by the worker), %ld dropped from replicas\n",
      s.workers, s.jobs_sent, s.results, s.lost, s.late, s.duplicates, s.local_jobs,
      s.bytes_out / jobs, s.bytes_back / results, 1e6 * s.encode_seconds / jobs,
      1e6 * s.decode_seconds / results, s.idle_seconds, s.states_sent, s.sent_as_blobs,
      s.states_named, s.states_dropped);
  return text;
}

// ---- workers ----

void run_worker(const CharacterScene& scene, const ExploreGraph& graph, int threads) {
  WorkerHello h;
  h.host = host_name();
  h.pid = getpid();
  h.scene_hash = scene_hash(scene);
  h.graph_hash = graph_hash(graph);
  h.vertices = static_cast<uint32_t>(scene.model.vertex_count());
  h.threads = std::max(1, threads);
  const std::vector<uint8_t> hello = encode_hello(h);
  check(MPI_Send(hello.data(), static_cast<int>(hello.size()), MPI_BYTE, 0, kHello, MPI_COMM_WORLD),
        "MPI_Send hello");
  // The states rank 0 has sent (its ledger of this rank says which).
  StateReplica replica = make_replica(h.vertices, 1.0 / graph.rate);
  Backoff backoff;
  while (true) {
    int flag = 0;
    MPI_Status st;
    check(MPI_Iprobe(0, MPI_ANY_TAG, MPI_COMM_WORLD, &flag, &st), "MPI_Iprobe");
    if (!flag) {
      backoff.idle();
      continue;
    }
    backoff.reset();
    const std::vector<uint8_t> bytes = receive(st);
    if (st.MPI_TAG == kStop) {
      g_skip_finalize = !bytes.empty() && bytes[0] != 0;
      return;
    }
    if (st.MPI_TAG != kJob)
      throw std::runtime_error("rank 0 sent an unknown message (tag " + std::to_string(st.MPI_TAG) +
                               ")");
    uint64_t seq = 0;
    JobInput job = decode_job(bytes.data(), bytes.size(), &seq, replica);
    job.settings.threads = h.threads;
    JobResult result;
    try {
      result = run_job(scene, graph, job);
    } catch (const std::exception& e) {
      // Reported as an unstable job: rank 0 leaves the dead end and says why.
      result = JobResult{};
      result.stable = false;
      result.message = "rank " + std::to_string(rank()) + " (" + h.host + "): " + e.what();
    }
    const std::vector<uint8_t> out = encode_result(seq, result);
    check(MPI_Send(out.data(), static_cast<int>(out.size()), MPI_BYTE, 0, kResult, MPI_COMM_WORLD),
          "MPI_Send result");
  }
}

}  // namespace clothdb::mpi
