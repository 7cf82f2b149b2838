#include "explore/job_wire.hpp"

#include <bit>
#include <cstring>

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
// encode_job refuses a job with a basis.) The target source, 16 bytes, travels as `targets`
// (encode_job reads them).
static_assert(sizeof(JobInput) - sizeof(SolverSettings) - sizeof(db::CodecSettings) ==
                  96 + 40 + 16 + 24,
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

std::vector<uint8_t> encode_job(uint64_t seq, const JobInput& job) {
  // A basis is a few MB; MPI workers would need it sent once per basis, not once per job.
  if (job.basis)
    throw std::invalid_argument(
        "job_wire: codec v2 or v3 during precompute (--codec v2, v3) runs in one process only; "
        "precompute with MPI writes codec v1 (convert afterwards with `clothdb db recode`)");
  Out o("CDBJ");
  o.u64(seq);
  o.i32(job.edge);
  o.floats(job.x);
  o.floats(job.v);
  db::RunSettings run;
  run.solver = job.solver;
  run.settings = job.settings;
  run.codec = job.codec;
  o.str(db::run_settings_json(run));
  o.f64(job.epsilon);
  // Targets an in-process explorer reads on demand (JobInput::target_source) travel as copies: a
  // worker rank has no database to read them from (docs/notebook/explorer.md, "MPI").
  if (job.target_source) {
    const SteerTargetSource& source = *job.target_source;
    o.u32(static_cast<uint32_t>(source.ids.size()));
    for (int64_t id : source.ids) {
      const ExactStatePtr t = source.exact->get(id);
      o.i64(id);
      o.floats(t->x);
      o.floats(t->v);
    }
  } else {
    o.u32(static_cast<uint32_t>(job.targets.size()));
    for (const SteerTarget& t : job.targets) {
      o.i64(t.state);
      o.floats(t.x);
      o.floats(t.v);
    }
  }
  return o.take();
}

JobInput decode_job(const uint8_t* data, size_t size, uint64_t* seq) {
  In in(data, size, "CDBJ", "job");
  JobInput job;
  *seq = in.u64("seq");
  job.edge = in.i32("edge");
  job.x = in.floats("x");
  job.v = in.floats("v");
  if (job.x.size() != job.v.size() || job.x.size() % 3 != 0)
    in.fail("v", std::to_string(job.x.size()) + " position and " + std::to_string(job.v.size()) +
                     " velocity floats: must be equal multiples of 3");
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
  const uint32_t targets = in.u32("targets");
  for (uint32_t k = 0; k < targets; ++k) {
    SteerTarget t;
    t.state = in.i64("target state");
    t.x = in.floats("target x");
    t.v = in.floats("target v");
    if (t.x.size() != job.x.size() || t.v.size() != job.x.size())
      in.fail("targets", "target " + std::to_string(k) + " has " + std::to_string(t.x.size()) +
                             " position and " + std::to_string(t.v.size()) +
                             " velocity floats, the job's state " + std::to_string(job.x.size()));
    job.targets.push_back(std::move(t));
  }
  in.finish();
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
