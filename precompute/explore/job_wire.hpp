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
#include <stdexcept>
#include <string>
#include <vector>

#include "explore/explorer.hpp"

namespace clothdb {

constexpr uint32_t kWireVersion = 6;  // 2: clip quality metrics and the last frame; 3: Newton
                                      // options; 4: solver and codec settings as RunSettings JSON;
                                      // 5: steering (targets, epsilon, what the pull did);
                                      // 6: clip self-intersections (docs/guide/self_collision.md)

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

std::vector<uint8_t> encode_job(uint64_t seq, const JobInput& job);
JobInput decode_job(const uint8_t* data, size_t size, uint64_t* seq);

std::vector<uint8_t> encode_result(uint64_t seq, const JobResult& result);
JobResult decode_result(const uint8_t* data, size_t size, uint64_t* seq);

// xxh64 over what a job's meaning depends on: node count, start node, rate, and every edge's
// nodes, name and poses (bit for bit). Two ranks with equal hashes simulate identical jobs.
uint64_t graph_hash(const ExploreGraph& graph);

}  // namespace clothdb
