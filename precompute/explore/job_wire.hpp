// Plain-bytes messages between the rank that owns the database and the ranks that simulate
// (explore/explore_mpi.hpp), kept free of MPI so they are tested in every build.
//
// Every message starts with a 4-byte kind ("CDBJ" job, "CDBR" result, "CDBH" hello) and a u32
// format version; numbers are little-endian, arrays and blobs carry their length. Decoding checks
// every length against the bytes received and against the counts the message declares (a clip
// blob's own header must agree with the result's frame and vertex counts), and throws WireError
// naming the message and the field. A changed JobInput or JobResult must bump kWireVersion: ranks
// built from different sources then refuse each other instead of misreading.
#pragma once

#include <cstdint>
#include <list>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <vector>

#include "explore/explorer.hpp"

namespace clothdb {

constexpr uint32_t kWireVersion = 7;  // 2: clip quality metrics and the last frame; 3: Newton
                                      // options; 4: solver and codec settings as RunSettings JSON;
                                      // 5: steering (targets, epsilon, what the pull did);
                                      // 6: clip self-intersections (docs/guide/self_collision.md);
                                      // 7: states by id, a worker's replica (ReplicaLedger below)

class WireError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A worker's first message: who it is, and what it loaded (checked against the owner's).
struct WorkerHello {
  std::string host;         // for messages
  int64_t pid = 0;          // for messages (and for killing it in tests)
  uint64_t scene_hash = 0;  // xxh64 of the scene file's text
  uint64_t graph_hash = 0;  // graph_hash() of the explore graph it built
  uint32_t vertices = 0;    // garment vertex count
  int32_t threads = 1;      // OpenMP threads it runs inside one simulation
};

std::vector<uint8_t> encode_hello(const WorkerHello& hello);
WorkerHello decode_hello(const uint8_t* data, size_t size);

// A job names its states (the start state, the steering targets) by id. Each worker keeps a
// replica of the states it has been sent (StateReplica), and rank 0 keeps, per worker, the
// account of what that replica holds (ReplicaLedger): a job message carries whole only the states
// the worker lacks (as the file stores them, two codec blobs, or as floats when the job has no
// store or a blob is not codec version 1), and the ids the worker must drop first. Rank 0 alone
// decides what is dropped (its least recently used ids once the replica would exceed the
// ledger's capacity, never one the job needs), and MPI delivers one rank's messages in order, so
// ledger and replica hold the same ids without any reply. A state sent whole decodes on the
// worker to the floats rank 0 holds (the file's blobs, decoded as a resumed run reads them), so
// the database stays the single process's.
struct ReplicaLedger {
  size_t capacity_bytes = size_t(256) << 20;  // exact states (exact_state_bytes each)
  size_t bytes = 0;
  std::list<int64_t> lru;  // ids held, most recently used first
  std::unordered_map<int64_t, std::list<int64_t>::iterator> where;
};

// A worker's copies, by id: the exact states (a cache that never evicts by itself: rank 0's
// messages say what to drop) and their reduced forms, for the steering's pruned search.
struct StateReplica {
  uint32_t vertices = 0;  // the garment's: every state sent must have this many
  StateReducer reducer;
  std::shared_ptr<StateCache> exact;
  std::unordered_map<int64_t, std::vector<double>> reduced;
};
StateReplica make_replica(uint32_t vertices, double tau);

// What the job messages carried (rank 0's statistics), summed over calls.
struct JobWireCounts {
  long states_sent = 0;     // whole: the worker lacked them
  long states_named = 0;    // by id only: the worker held them
  long states_dropped = 0;  // told to drop (the ledger's capacity)
  long sent_as_blobs = 0;   // of states_sent, as the file's blobs (the rest as floats)
};

// Writes the job for the worker `ledger` accounts for, and updates the ledger. Throws
// std::invalid_argument for a job that cannot travel (a codec basis, no start state id, a
// target whose state the job does not have).
std::vector<uint8_t> encode_job(uint64_t seq, const JobInput& job, ReplicaLedger& ledger,
                                JobWireCounts* counts = nullptr);
// Reads a job into the worker's replica (drops, then the states sent) and returns it with its
// start state and its targets (JobInput::target_source over the replica) resolved. Every check
// (lengths, blobs, that every named id is held) is made before the replica changes.
JobInput decode_job(const uint8_t* data, size_t size, uint64_t* seq, StateReplica& replica);

std::vector<uint8_t> encode_result(uint64_t seq, const JobResult& result);
JobResult decode_result(const uint8_t* data, size_t size, uint64_t* seq);

// xxh64 over what a job's meaning depends on: node count, start node, rate, and every edge's
// nodes, name and poses (bit for bit). Two ranks with equal hashes simulate identical jobs.
uint64_t graph_hash(const ExploreGraph& graph);

}  // namespace clothdb
