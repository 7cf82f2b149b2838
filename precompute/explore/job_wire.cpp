#include "explore/job_wire.hpp"

#include <algorithm>
#include <bit>
#include <cstring>
#include <limits>
#include <unordered_set>

#include "database/codec/codec.hpp"
#include "database/format/checksum.hpp"

namespace clothdb {

static_assert(std::endian::native == std::endian::little, "the wire format is little-endian");

// A new field in one of these structs must go into its encoder and decoder below (and bump
// kWireVersion); the sizes catch a field added without that on the platform we build on. The
// solver and codec settings travel as their one serialiser's JSON (database/run_settings.hpp), so
// a new solver option needs nothing here.
#if defined(__x86_64__) && defined(__GLIBCXX__)
// (The settings inside JobInput travel as JSON: their own size does not matter here.)
// (The codec v2/v3 basis, body anchors and flag, 40 bytes, and the v3 contract, 24, do not travel:
// encode_job refuses a job with a basis.) The target source, 16 bytes, travels as its ids, and the
// store, 16, is where encode_job reads the states a worker lacks; the start state's id, 8, travels.
static_assert(sizeof(JobInput) - sizeof(SolverSettings) - sizeof(db::CodecSettings) ==
                  96 + 40 + 16 + 24 + 8 + 16,
              "JobInput changed: update encode_job/decode_job");
static_assert(sizeof(ClipQuality) == 56, "ClipQuality changed: update encode_result/decode_result");
// (A version 3 clip's contract figures, 32 bytes, do not travel: they come only with a basis.)
static_assert(sizeof(JobResult) == 248 + 32,
              "JobResult changed: update encode_result/decode_result");
static_assert(sizeof(WorkerHello) == 64, "WorkerHello changed: update encode_hello/decode_hello");
#endif

namespace {

class Out {
 public:
  explicit Out(const char kind[4]) {
    raw(kind, 4);
    u32(kWireVersion);
  }
  void raw(const void* p, size_t n) {
    if (n == 0) return;
    const size_t at = bytes_.size();
    bytes_.resize(at + n);
    std::memcpy(bytes_.data() + at, p, n);
  }
  void u32(uint32_t v) { raw(&v, 4); }
  void i32(int32_t v) { raw(&v, 4); }
  void u64(uint64_t v) { raw(&v, 8); }
  void i64(int64_t v) { raw(&v, 8); }
  void f64(double v) { raw(&v, 8); }
  void str(const std::string& s) {
    u64(s.size());
    raw(s.data(), s.size());
  }
  void bytes(const std::vector<uint8_t>& b) {
    u64(b.size());
    raw(b.data(), b.size());
  }
  void floats(const std::vector<float>& f) {
    u64(f.size());
    raw(f.data(), f.size() * sizeof(float));
  }
  std::vector<uint8_t> take() { return std::move(bytes_); }

 private:
  std::vector<uint8_t> bytes_;
};

class In {
 public:
  In(const uint8_t* data, size_t size, const char kind[4], const char* what)
      : p_(data), end_(data + size), what_(what) {
    if (size < 8 || std::memcmp(data, kind, 4) != 0)
      fail("header",
           "not a " + std::string(what) + " message (" + std::to_string(size) + " bytes)");
    p_ += 4;
    const uint32_t version = u32("version");
    if (version != kWireVersion)
      fail("version", "format " + std::to_string(version) + ", this build speaks " +
                          std::to_string(kWireVersion) +
                          ": every rank must run the same clothdb build");
  }
  [[noreturn]] void fail(const char* field, const std::string& problem) const {
    throw WireError(std::string(what_) + " message: " + field + ": " + problem);
  }
  void raw(void* out, size_t n, const char* field) {
    if (static_cast<size_t>(end_ - p_) < n)
      fail(field, "needs " + std::to_string(n) + " bytes, " + std::to_string(end_ - p_) +
                      " left (truncated)");
    std::memcpy(out, p_, n);
    p_ += n;
  }
  template <typename T>
  T num(const char* field) {
    T v;
    raw(&v, sizeof v, field);
    return v;
  }
  uint32_t u32(const char* field) { return num<uint32_t>(field); }
  int32_t i32(const char* field) { return num<int32_t>(field); }
  uint64_t u64(const char* field) { return num<uint64_t>(field); }
  int64_t i64(const char* field) { return num<int64_t>(field); }
  double f64(const char* field) { return num<double>(field); }
  // A length checked against what is left before anything is allocated for it.
  size_t length(const char* field, size_t element) {
    const uint64_t n = u64(field);
    if (n > static_cast<size_t>(end_ - p_) / element)
      fail(field, "declares " + std::to_string(n) + " elements, only " + std::to_string(end_ - p_) +
                      " bytes left");
    return static_cast<size_t>(n);
  }
  // A u32 element count checked against what is left (each element at least `element` bytes).
  size_t count(const char* field, size_t element) {
    const uint32_t n = u32(field);
    if (n > static_cast<size_t>(end_ - p_) / element)
      fail(field, "declares " + std::to_string(n) + " elements, only " + std::to_string(end_ - p_) +
                      " bytes left");
    return n;
  }
  std::string str(const char* field) {
    std::string s(length(field, 1), '\0');
    raw(s.data(), s.size(), field);
    return s;
  }
  std::vector<uint8_t> bytes(const char* field) {
    std::vector<uint8_t> b(length(field, 1));
    raw(b.data(), b.size(), field);
    return b;
  }
  std::vector<float> floats(const char* field) {
    std::vector<float> f(length(field, sizeof(float)));
    raw(f.data(), f.size() * sizeof(float), field);
    return f;
  }
  void finish() const {
    if (p_ != end_) fail("end", std::to_string(end_ - p_) + " bytes after the last field");
  }

 private:
  const uint8_t* p_;
  const uint8_t* end_;
  const char* what_;
};

// A blob must be a frame blob of exactly the frames and vertices the message says.
void check_blob(const In& in, const std::vector<uint8_t>& blob, uint32_t frames, uint32_t vertices,
                const char* field) {
  codec::BlobInfo info;
  db::Error err;
  if (codec::read_info(blob.data(), blob.size(), &info, &err) != db::Status::Ok)
    in.fail(field, std::string("not a valid frame blob: ") + err.message);
  if (info.frame_count != frames || info.vertex_count != vertices || info.size != blob.size())
    in.fail(field, "holds " + std::to_string(info.frame_count) + " frames of " +
                       std::to_string(info.vertex_count) + " vertices in " +
                       std::to_string(info.size) + " bytes; the message says " +
                       std::to_string(frames) + " of " + std::to_string(vertices) + " in " +
                       std::to_string(blob.size()));
}

}  // namespace

std::vector<uint8_t> encode_hello(const WorkerHello& h) {
  Out o("CDBH");
  o.str(h.host);
  o.i64(h.pid);
  o.u64(h.scene_hash);
  o.u64(h.graph_hash);
  o.u32(h.vertices);
  o.i32(h.threads);
  return o.take();
}

WorkerHello decode_hello(const uint8_t* data, size_t size) {
  In in(data, size, "CDBH", "hello");
  WorkerHello h;
  h.host = in.str("host");
  h.pid = in.i64("pid");
  h.scene_hash = in.u64("scene_hash");
  h.graph_hash = in.u64("graph_hash");
  h.vertices = in.u32("vertices");
  h.threads = in.i32("threads");
  in.finish();
  return h;
}

StateReplica make_replica(uint32_t vertices, double tau) {
  if (vertices == 0) throw std::invalid_argument("job_wire: a replica of a garment of 0 vertices");
  StateReplica r;
  r.vertices = vertices;
  r.reducer = make_reducer(vertices, tau);
  r.exact = std::make_shared<StateCache>(
      std::numeric_limits<size_t>::max(), [](int64_t id) -> ExactState {
        // decode_job checks every id a job names before the job runs: this is a bug.
        throw std::logic_error("job_wire: state " + std::to_string(id) +
                               " is not in this worker's replica");
      });
  return r;
}

namespace {

// A state rank 0 sends a worker whole: as the file's blobs when the job's store has them and they
// are codec version 1 (a worker has no basis), else as floats.
void write_state(Out& o, const JobInput& job, int64_t id, JobWireCounts* counts) {
  const std::shared_ptr<StateCache> store =
      job.store ? job.store : (job.target_source ? job.target_source->exact : nullptr);
  if (store) {
    const StateBlobs b = store->blobs(id);
    auto version_1 = [](const std::vector<uint8_t>& blob) {
      codec::BlobInfo info;
      db::Error err;
      return !blob.empty() &&
             codec::read_info(blob.data(), blob.size(), &info, &err) == db::Status::Ok &&
             info.version == codec::kFormatVersion && info.frame_count == 1;
    };
    if (version_1(b.x) && version_1(b.v)) {
      o.i64(id);
      o.u32(1);
      o.bytes(b.x);
      o.bytes(b.v);
      if (counts) ++counts->sent_as_blobs;
      return;
    }
  }
  auto floats = [&](const std::vector<float>& x, const std::vector<float>& v) {
    o.i64(id);
    o.u32(0);
    o.floats(x);
    o.floats(v);
  };
  if (id == job.state) return floats(job.x, job.v);
  for (const SteerTarget& t : job.targets)
    if (t.state == id) return floats(t.x, t.v);
  if (job.target_source) {
    const ExactStatePtr e = job.target_source->exact->get(id);
    return floats(e->x, e->v);
  }
  throw std::invalid_argument("job_wire: the job names state " + std::to_string(id) +
                              " but holds no copy of it");
}

}  // namespace

std::vector<uint8_t> encode_job(uint64_t seq, const JobInput& job, ReplicaLedger& ledger,
                                JobWireCounts* counts) {
  // A basis is a few MB; MPI workers would need it sent once per basis, not once per job.
  if (job.basis)
    throw std::invalid_argument(
        "job_wire: codec v2 or v3 during precompute (--codec v2, v3) runs in one process only; "
        "precompute with MPI writes codec v1 (convert afterwards with `clothdb db recode`)");
  if (job.state == 0)
    throw std::invalid_argument("job_wire: a job's start state travels by id: set JobInput::state");
  // The states the job names: its start state, then its targets in their order.
  std::vector<int64_t> targets;
  if (job.target_source)
    targets = job.target_source->ids;
  else
    for (const SteerTarget& t : job.targets) targets.push_back(t.state);
  std::vector<int64_t> needed = {job.state};
  std::unordered_set<int64_t> named = {job.state};
  for (int64_t id : targets)
    if (named.insert(id).second) needed.push_back(id);
  // What the worker lacks, and what it drops to stay within the ledger's capacity once it holds
  // them: its least recently used ids that this job does not name.
  const size_t state_bytes = exact_state_bytes(static_cast<uint32_t>(job.x.size() / 3));
  std::vector<int64_t> send, drop;
  for (int64_t id : needed)
    if (!ledger.where.count(id)) send.push_back(id);
  size_t bytes = ledger.bytes + send.size() * state_bytes;
  for (auto it = ledger.lru.rbegin(); it != ledger.lru.rend() && bytes > ledger.capacity_bytes;
       ++it)
    if (!named.count(*it)) {
      drop.push_back(*it);
      bytes -= state_bytes;
    }
  Out o("CDBJ");
  o.u64(seq);
  o.i32(job.edge);
  o.u32(static_cast<uint32_t>(drop.size()));
  for (int64_t id : drop) o.i64(id);
  o.u32(static_cast<uint32_t>(send.size()));
  JobWireCounts local;
  for (int64_t id : send) write_state(o, job, id, &local);
  o.i64(job.state);
  db::RunSettings run;
  run.solver = job.solver;
  run.settings = job.settings;
  run.codec = job.codec;
  o.str(db::run_settings_json(run));
  o.f64(job.epsilon);
  o.u32(static_cast<uint32_t>(targets.size()));
  for (int64_t id : targets) o.i64(id);
  // The message is made: the ledger follows it as the worker's replica will.
  for (int64_t id : drop) {
    ledger.lru.erase(ledger.where.at(id));
    ledger.where.erase(id);
  }
  for (int64_t id : needed) {
    const auto found = ledger.where.find(id);
    if (found != ledger.where.end()) ledger.lru.erase(found->second);
    ledger.lru.push_front(id);
    ledger.where[id] = ledger.lru.begin();
  }
  ledger.bytes = bytes;
  if (counts) {
    counts->states_sent += static_cast<long>(send.size());
    counts->states_named += static_cast<long>(needed.size() - send.size());
    counts->states_dropped += static_cast<long>(drop.size());
    counts->sent_as_blobs += local.sent_as_blobs;
  }
  return o.take();
}

JobInput decode_job(const uint8_t* data, size_t size, uint64_t* seq, StateReplica& replica) {
  In in(data, size, "CDBJ", "job");
  JobInput job;
  *seq = in.u64("seq");
  job.edge = in.i32("edge");
  std::vector<int64_t> drop(in.count("drop", 8));
  for (int64_t& id : drop) id = in.i64("drop");
  std::vector<std::pair<int64_t, ExactState>> sent(in.count("states", 8 + 4 + 16));
  codec::DecodeScratch scratch;
  for (auto& [id, state] : sent) {
    id = in.i64("state id");
    const uint32_t form = in.u32("state form");
    const std::string which = "state " + std::to_string(id);
    if (form == 0) {
      state.x = in.floats("state x");
      state.v = in.floats("state v");
    } else if (form == 1) {
      const std::vector<uint8_t> bx = in.bytes("state x blob"), bv = in.bytes("state v blob");
      for (const auto* b : {&bx, &bv}) {
        codec::BlobInfo info;
        db::Error err;
        if (codec::read_info(b->data(), b->size(), &info, &err) != db::Status::Ok)
          in.fail("state blob", which + ": not a valid frame blob: " + err.message);
        if (info.frame_count != 1 || info.version != codec::kFormatVersion ||
            info.size != b->size())
          in.fail("state blob", which + ": " + std::to_string(info.frame_count) +
                                    " frames of codec version " + std::to_string(info.version) +
                                    " in " + std::to_string(info.size) + " of " +
                                    std::to_string(b->size()) + " bytes; must be one frame of 1");
        std::vector<float>& out = b == &bx ? state.x : state.v;
        if (codec::decode_all(b->data(), b->size(), out, scratch, &err) != db::Status::Ok)
          in.fail("state blob", which + " does not decode: " + err.message);
      }
    } else {
      in.fail("state form", which + ": form " + std::to_string(form) + " (0 floats, 1 blobs)");
    }
    const size_t floats = 3 * size_t(replica.vertices);
    if (state.x.size() != floats || state.v.size() != floats)
      in.fail("state v", which + " has " + std::to_string(state.x.size()) + " position and " +
                             std::to_string(state.v.size()) + " velocity floats, the garment's " +
                             std::to_string(replica.vertices) + " vertices " +
                             std::to_string(floats));
  }
  job.state = in.i64("start state");
  const std::string settings = in.str("settings");
  try {
    const db::RunSettings run = db::parse_run_settings_json(settings, "job message: settings");
    job.solver = run.solver;
    job.settings = run.settings;
    job.codec = run.codec;
  } catch (const db::SettingsError& e) {
    in.fail("settings", e.what());
  }
  job.epsilon = in.f64("epsilon");
  std::vector<int64_t> targets(in.count("targets", 8));
  for (int64_t& id : targets) id = in.i64("target");
  in.finish();
  // Every state the job names must be held once the drops and the states sent are applied.
  std::unordered_set<int64_t> arriving, dropped(drop.begin(), drop.end());
  for (const auto& s : sent) arriving.insert(s.first);
  auto held = [&](int64_t id) {
    return arriving.count(id) || (replica.reduced.count(id) && !dropped.count(id));
  };
  if (!held(job.state))
    in.fail("start state",
            "state " + std::to_string(job.state) + " is neither held by this worker nor sent");
  for (int64_t id : targets)
    if (!held(id))
      in.fail("targets",
              "state " + std::to_string(id) + " is neither held by this worker nor sent");
  // Applied: the replica now holds what rank 0's ledger says it holds.
  for (int64_t id : drop) {
    replica.exact->erase(id);
    replica.reduced.erase(id);
  }
  for (auto& [id, state] : sent) {
    replica.reduced[id] = reduce(replica.reducer, state.x.data(), state.v.data());
    replica.exact->put(id, std::move(state));
  }
  const ExactStatePtr start = replica.exact->get(job.state);
  job.x = start->x;
  job.v = start->v;
  if (!targets.empty()) {
    auto source = std::make_shared<SteerTargetSource>();
    source->reducer = replica.reducer;
    source->exact = replica.exact;
    source->ids = targets;
    for (int64_t id : targets) source->reduced.push_back(replica.reduced.at(id));
    job.target_source = std::move(source);
  }
  return job;
}

std::vector<uint8_t> encode_result(uint64_t seq, const JobResult& r) {
  Out o("CDBR");
  o.u64(seq);
  o.u32(r.stable ? 1 : 0);
  o.str(r.message);
  o.u32(r.frame_count);
  o.u32(r.vertex_count);
  o.bytes(r.clip_blob);
  o.f64(r.clip_max_error);
  o.floats(r.last);
  o.bytes(r.end_x_blob);
  o.bytes(r.end_v_blob);
  const ClipQuality& q = r.quality;
  o.f64(q.max_strain);
  o.f64(q.max_penetration);
  o.f64(q.mean_penetration);
  o.f64(q.jitter);
  o.i32(q.halved_steps);
  o.i32(q.worst_frame);
  o.i32(q.self_intersections);
  o.i32(q.self_intersection_frame);
  o.i32(q.self_intersection_frames);
  o.f64(r.cpu_seconds);
  o.i64(r.steer_target);
  o.f64(r.steer_distance);
  o.f64(r.steer_displacement);
  o.f64(r.steer_acceleration);
  return o.take();
}

JobResult decode_result(const uint8_t* data, size_t size, uint64_t* seq) {
  In in(data, size, "CDBR", "result");
  JobResult r;
  *seq = in.u64("seq");
  r.stable = in.u32("stable") != 0;
  r.message = in.str("message");
  r.frame_count = in.u32("frame_count");
  r.vertex_count = in.u32("vertex_count");
  r.clip_blob = in.bytes("clip_blob");
  r.clip_max_error = in.f64("clip_max_error");
  r.last = in.floats("last");
  r.end_x_blob = in.bytes("end_x_blob");
  r.end_v_blob = in.bytes("end_v_blob");
  ClipQuality& q = r.quality;
  q.max_strain = in.f64("max_strain");
  q.max_penetration = in.f64("max_penetration");
  q.mean_penetration = in.f64("mean_penetration");
  q.jitter = in.f64("jitter");
  q.halved_steps = in.i32("halved_steps");
  q.worst_frame = in.i32("worst_frame");
  q.self_intersections = in.i32("self_intersections");
  q.self_intersection_frame = in.i32("self_intersection_frame");
  q.self_intersection_frames = in.i32("self_intersection_frames");
  r.cpu_seconds = in.f64("cpu_seconds");
  r.steer_target = in.i64("steer_target");
  r.steer_distance = in.f64("steer_distance");
  r.steer_displacement = in.f64("steer_displacement");
  r.steer_acceleration = in.f64("steer_acceleration");
  in.finish();
  if (r.stable) {  // an unstable job carries no frames
    check_blob(in, r.clip_blob, r.frame_count, r.vertex_count, "clip_blob");
    if (r.last.size() != size_t(r.vertex_count) * 3)
      in.fail("last", std::to_string(r.last.size()) + " floats for " +
                          std::to_string(r.vertex_count) + " vertices");
    check_blob(in, r.end_x_blob, 1, r.vertex_count, "end_x_blob");
    check_blob(in, r.end_v_blob, 1, r.vertex_count, "end_v_blob");
  }
  return r;
}

uint64_t graph_hash(const ExploreGraph& graph) {
  Out o("CDBG");
  o.i32(graph.node_count);
  o.i32(graph.start_node);
  o.f64(graph.rate);
  for (const ExploreEdge& e : graph.edges) {
    o.i32(e.from_node);
    o.i32(e.to_node);
    o.str(e.name);
    o.u64(e.poses.size());
    for (const auto& pose : e.poses) {
      o.u64(pose.size());
      for (const JointPose& j : pose) {
        o.raw(j.position.data(), 3 * sizeof(double));
        o.raw(j.rotation.coeffs().data(), 4 * sizeof(double));
      }
    }
  }
  const std::vector<uint8_t> bytes = o.take();
  return db::xxh64(bytes.data(), bytes.size());
}

}  // namespace clothdb
