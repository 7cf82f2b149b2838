// Internals of clothrt shared by the database handle (db.cpp), the player (player.cpp) and the C
// entry points (api.cpp). Not installed; games use clothrt.h.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "clothrt.h"
#include "database/codec/codec.hpp"
#include "database/format/reader.hpp"
#include "database/format/status.hpp"

namespace clothrt {

using clothdb::Error;
using clothdb::Status;

int to_code(Status status);

// A contiguous allocation for one decoded clip, kept when the clip is evicted so the next decode
// can reuse it instead of allocating.
struct Buffer {
  void* data = nullptr;
  size_t capacity = 0;  // bytes
};
bool allocate_buffer(Buffer* buffer, size_t bytes);  // false: out of memory
void free_buffer(Buffer* buffer);

// How a decoded clip is laid out in memory. Positions whose quantised range fits 16 bits (any
// garment: 65,536 steps of about 1 mm) are kept as the codec's integers, x = origin + step * q,
// which halves the cache's memory and the bytes a frame of playback reads; others as floats.
struct ClipView {
  const void* data = nullptr;
  bool quantised = false;
  float origin[3] = {0, 0, 0};
  float step = 0;
  uint32_t frames = 0;
};

struct PrimaryInfo {
  int64_t id = 0;
  std::string name;
  int32_t frames = 0;
  double rate = 30;
  int src_node = 0, tgt_node = 0;
  uint32_t succ_begin = 0, succ_end = 0;  // into Db::successors
  uint32_t cand_begin = 0, cand_end = 0;  // into Db::candidates: clips along it, by state id
};

struct StateInfo {
  int64_t id = 0;
  int primary = -1;  // index of the primary clip it is stored with
};

struct ClipInfo {
  int64_t id = 0;
  int state = -1;    // start state index
  int primary = -1;  // primary clip index
  int32_t frames = 0;
  int to_state = -1;  // cloth edge target, -1: none (a dead end)
  double blend_error = 0;
  uint32_t slot_begin = 0;  // one slot per successor of its primary clip
};

// A slot caches where the cloth goes when clip C is followed by successor k of its primary clip:
// a clip index (shifted left by one, low bit set when it is a fallback), or one of these.
constexpr int32_t kSlotNone = -1;        // no cloth anywhere along that successor
constexpr int32_t kSlotUnresolved = -2;  // needs a nearest-state search
constexpr int32_t kSlotResolving = -3;   // queued or being searched

enum class EntryState : uint8_t { Absent, Queued, Loading, Ready, Failed };

// The cache entry of one cloth clip (one per clip, created at open, so the cache never allocates
// bookkeeping at run time).
struct Entry {
  EntryState state = EntryState::Absent;
  int pins = 0;
  int lru_prev = -1, lru_next = -1;  // list of Ready entries, most recently used first
  bool in_lru = false;
  Buffer buffer;
  size_t bytes = 0;  // bytes of decoded frames in the buffer
  ClipView view;
  Status failure = Status::Ok;
};

// What a decoding thread needs: a SQLite connection and codec buffers, reused for every clip.
struct Loader {
  clothdb::db::Reader* reader = nullptr;
  clothdb::codec::DecodeScratch scratch;
  std::vector<uint8_t> blob, pos_blob, vel_blob;
  std::vector<float> chunk;  // one chunk of decoded frames before repacking to 16 bits
  std::vector<float> x, v, sx, sv;
};

struct Player;

struct Db {
  ~Db();

  Status open(const std::string& path, const clothrt_db_options& options, Error* err);

  // Cache, all thread-safe. pin() keeps a clip from eviction and queues it for decoding if absent.
  void pin(int clip);
  void unpin(int clip);
  // Pins and waits until the clip is decoded (decoding it on this thread if nobody else is).
  // On failure the pin is released and err says why.
  Status acquire(int clip, ClipView* view, bool* stalled, Error* err);
  // Reads the slot of (clip, successor k), searching for the nearest state now if needed.
  int32_t resolve_now(int clip, uint32_t k);
  // Queues a nearest-state search for the slot unless one is resolved or under way.
  void request_resolve(int clip, uint32_t k);
  // With no prefetch threads: does one queued job on the calling thread.
  void service_one();

  void fill_stats(clothrt_stats* out);
  void reset_stats();
  void set_error(const Error& e);

  // Graph, immutable after open.
  std::string path;
  clothdb::db::Reader reader;
  uint32_t vertex_count = 0;
  std::vector<uint32_t> triangles;
  // The render mesh (clothrt_db_render_*, db::ArtistMesh): per render vertex its simulation
  // vertices and weights; all_indexed when every weight is (1, 0, 0), so sampling copies.
  uint32_t render_vertex_count = 0;
  std::vector<uint32_t> render_triangles;
  std::vector<uint32_t> render_sim;     // 3 per render vertex
  std::vector<float> render_weights;    // 3 per render vertex
  std::vector<uint32_t> render_source;  // artist vertex per render vertex
  std::vector<float> render_uvs;        // 2 per render vertex; empty: no UVs
  bool all_indexed = true;
  // Built at open for the per-frame normals and tangents (Player::render): the triangles around
  // each vertex in ascending order, as compressed rows (vertex v's are faces[begin[v] ..
  // begin[v + 1]), padded to an even count with a zero row; db.cpp, adjacency), so a vertex sums
  // its triangles' vectors by reading them in the order a scatter over the triangles would add
  // them (the same float sums, bit for bit). Entries are offsets into the player's rows (4 floats
  // per simulation triangle, 8 per render triangle). vertex_faces* cover the simulation mesh;
  // render_faces* the render triangles whose UV triangle is not degenerate (only when the mesh
  // has UVs), with per render triangle its UV edges and 1 / det (Lengyel 2001): du1, dv1, du2,
  // dv2, 1 / det.
  std::vector<uint32_t> vertex_faces_begin, vertex_faces;
  std::vector<uint32_t> render_faces_begin, render_faces;
  std::vector<float> render_uv_edges;
  std::vector<PrimaryInfo> primaries;
  std::vector<int> successors;  // primary indices
  std::vector<int> candidates;  // clip indices, grouped by primary clip, by state id
  std::vector<StateInfo> states;
  std::vector<ClipInfo> clips;
  std::unique_ptr<std::atomic<int32_t>[]> slots;
  // Per slot: the blend error (m) of a precomputed link (ClothLink) the slot follows, 0 otherwise.
  std::vector<float> slot_blend;
  size_t slot_count = 0;
  std::unordered_map<int64_t, int> primary_by_id, clip_by_id;
  int start_primary = 0;
  uint32_t max_successors = 0;
  clothrt_db_options options{};
  size_t metadata_bytes = 0;  // including the codec bases
  // Codec version 2 bases (docs/DATABASE.md, "version 2"), loaded once at open and shared by every
  // decoding thread.
  std::vector<clothdb::codec::Basis> bases;
  const clothdb::codec::Basis* basis_for(const clothdb::codec::BlobInfo& info) const;
  // A cloth state decoded through the loader's connection with the database's bases.
  Status read_state(Loader& loader, int64_t state, std::vector<float>* x, std::vector<float>* v,
                    Error* err);

  // Cache and job queue, guarded by mu.
  std::mutex mu;
  std::condition_variable loaded_cv, work_cv;
  std::vector<Entry> entries;
  int lru_head = -1, lru_tail = -1;
  std::vector<Buffer> pool;    // buffers of evicted clips, reused by the next decodes
  size_t cache_bytes = 0;      // capacity of all buffers held (entries and pool)
  std::vector<int64_t> queue;  // ring of jobs: clip index, or ~slot for a nearest-state search
  size_t queue_head = 0, queue_size = 0;
  std::vector<uint8_t> queue_seen;  // per clip, for dropping stale and duplicate jobs
  std::atomic<size_t> queued{0};    // mirrors queue_size for a lock-free "anything to do?"
  bool stopping = false;
  std::vector<Player*> players;

  std::vector<std::thread> workers;
  std::vector<std::unique_ptr<clothdb::db::Reader>> worker_readers;
  std::vector<std::unique_ptr<Loader>> worker_loaders;
  std::mutex io_mu;  // guards `reader` and sync_loader for loads on callers' threads
  Loader sync_loader;

  Error error;
  std::mutex error_mu;

  std::atomic<bool> timing{false};
  std::atomic<uint64_t> loads{0}, evictions{0}, failures{0}, stalls{0}, fallbacks{0};
  std::atomic<uint64_t> sqlite_ns{0}, decode_ns{0}, repack_ns{0};
  std::atomic<uint64_t> retired_sample_ns{0}, retired_transition_ns{0}, retired_frames{0};

 private:
  void worker_main(Loader* loader);
  void push_job(int64_t job);  // mu held
  bool pop_job(int64_t* job);  // mu held
  void run_job(int64_t job, Loader& loader);
  // Decodes clip into the entry's buffer (mu not held; the entry is Loading and owned by us).
  Status load(int clip, Loader& loader, Error* err);
  Status load_impl(int clip, Loader& loader, Error* err);
  int32_t search_nearest(int clip, uint32_t k, Loader& loader);
  int32_t search_impl(int clip, uint32_t k, Loader& loader);
  void lru_remove(int clip);  // mu held
  void lru_push_front(int clip);
  void trim_to_cap();  // mu held: frees pooled buffers while over the cap
  // mu held: records how a load of `clip` ended (Ready and in the LRU, or Failed with its buffer
  // back in the pool). Callers notify loaded_cv.
  void finish_load(int clip, Status st);
  bool take_buffer(size_t bytes, Buffer* out);  // mu held
};

struct Player {
  explicit Player(Db* d);
  ~Player();

  int start_clip(int clip);
  int set_next(int primary);
  void set_random(bool enabled, uint64_t seed);
  int advance(double dt);
  int positions(float* out, size_t stride, const float* m);
  int render(const clothrt_render_output& out, const float* m);
  void info(clothrt_frame_info* out) const;
  size_t memory() const;

  Db* db;
  Error error;
  double blend_frames = 8;

 private:
  int choose_next();  // successor position k for the node ahead
  void issue_prefetch();
  void poll_prefetch();
  void release_prefetch();
  void request(uint32_t k);
  int transition();
  bool pass_node();
  int load_current();
  template <typename Out>
  void sample(Out&& out) const;
  // The current pose in character space into dst (vertex_count * 3 floats).
  void sample_into(float* dst);

  bool started_ = false;
  int primary_ = -1;
  int clip_ = -1;  // -1 while holding
  // clip_ was reached by pass_node() and is neither pinned nor in view_ yet (only inside advance).
  bool unloaded_ = false;
  ClipView view_;
  double t_ = 0;  // frames into the primary clip
  // The pose shown is clip(t) + max(0, r0 - t / blend_span) * offset_. When holding it is offset_.
  std::vector<float> offset_;
  std::vector<float> local_;  // character-space pose before a transform or a strided copy
  // Render-mesh scratch, sized at creation (Player::render): face normals (4 floats per
  // simulation triangle, and a zero row after them), simulation-vertex normals (as x, y, z planes
  // of vertex_count floats), their world-space turn and the world-space positions (3 floats per
  // vertex); with UVs, per render triangle its tangent and bitangent directions (8 floats; a zero
  // row after them) and per render vertex 9 planes (the normal, the tangent sum, the bitangent
  // sum; overwritten in place by the tangent and its sign).
  std::vector<float> face_normals_, normals_, world_normals_, world_, face_tangents_, tangents_;
  double r0_ = 0, blend_span_ = 1;
  bool fallback_ = false, holding_ = false;
  int next_k_ = -1;  // successor chosen for the node ahead (-1: not yet)
  bool next_named_ = false;
  bool random_ = false;
  uint64_t rng_ = 0;
  bool prefetch_issued_ = false;
  std::vector<int> pinned_;       // per successor k: the clip pinned for it, -1: none
  std::vector<uint8_t> pending_;  // per successor k: waiting for a nearest-state search
  uint64_t transitions_ = 0, fallbacks_ = 0, interrupted_ = 0;

 public:
  std::atomic<uint64_t> sample_ns{0}, transition_ns{0}, frames{0};
};

}  // namespace clothrt
