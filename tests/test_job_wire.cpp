// The messages between MPI ranks (explore/job_wire.hpp): every field survives the trip, and a
// truncated, padded, mislabelled or inconsistent message is refused with the field named.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>

#include "database/codec/codec.hpp"
#include "explore/job_wire.hpp"

using namespace clothdb;

namespace {

std::vector<float> ramp(size_t n, float scale) {
  std::vector<float> v(n);
  for (size_t i = 0; i < n; ++i) v[i] = scale * std::sin(0.37f * static_cast<float>(i));
  return v;
}

std::vector<uint8_t> blob(uint32_t frames, uint32_t vertices, double bound) {
  codec::EncodeSettings s;
  s.bound = bound;
  const std::vector<float> data = ramp(size_t(frames) * vertices * 3, 0.3f);
  return codec::encode(data.data(), frames, vertices, s);
}

JobInput sample_job() {
  JobInput j;
  j.edge = 7;
  j.x = ramp(30, 0.5f);
  j.v = ramp(30, -2.0f);
  j.solver = SolverKind::Newton;
  j.settings.substeps = 13;
  j.settings.iterations = 4;
  j.settings.pbd_stretch_stiffness = 0.25;
  j.settings.pbd_bend_stiffness = 0.125;
  j.settings.provot_critical_rate = 0.07;
  j.settings.newton_tolerance = 3e-7;
  j.settings.newton_max_iterations = 17;
  j.settings.newton_max_halvings = 3;
  j.settings.newton_guess = SolverSettings::Guess::Extrapolate;
  j.settings.newton_reuse_contraction = 0.25;
  j.settings.newton_exact_hessian = false;
  j.settings.linear_solver = LinearSolverKind::ConjugateGradientIC;
  j.settings.threads = 5;
  j.settings.tethers = false;
  j.codec.position_bound = 2e-4;
  j.codec.velocity_bound = 3e-3;
  j.codec.key_interval = 9;
  j.codec.zstd_level = 7;
  return j;
}

JobResult sample_result() {
  JobResult r;
  r.stable = true;
  r.message = "fine";
  r.frame_count = 6;
  r.vertex_count = 10;
  r.clip_blob = blob(6, 10, 1e-4);
  r.clip_max_error = 9.5e-5;
  r.end_x_blob = blob(1, 10, 1e-4);
  r.end_v_blob = blob(1, 10, 1e-3);
  r.last = ramp(30, 0.25f);
  r.quality.max_strain = 0.031;
  r.quality.max_penetration = 0.0007;
  r.quality.mean_penetration = 0.0003;
  r.quality.jitter = 0.0011;
  r.quality.halved_steps = 2;
  r.quality.worst_frame = 4;
  r.cpu_seconds = 1.25;
  return r;
}

}  // namespace

TEST(JobWire, JobKeepsEveryField) {
  const JobInput a = sample_job();
  const std::vector<uint8_t> bytes = encode_job(42, a);
  uint64_t seq = 0;
  const JobInput b = decode_job(bytes.data(), bytes.size(), &seq);
  EXPECT_EQ(seq, 42u);
  EXPECT_EQ(b.edge, a.edge);
  EXPECT_EQ(b.x, a.x);
  EXPECT_EQ(b.v, a.v);
  EXPECT_EQ(b.solver, a.solver);
  EXPECT_EQ(b.settings.substeps, a.settings.substeps);
  EXPECT_EQ(b.settings.iterations, a.settings.iterations);
  EXPECT_EQ(b.settings.pbd_stretch_stiffness, a.settings.pbd_stretch_stiffness);
  EXPECT_EQ(b.settings.pbd_bend_stiffness, a.settings.pbd_bend_stiffness);
  EXPECT_EQ(b.settings.provot_critical_rate, a.settings.provot_critical_rate);
  EXPECT_EQ(b.settings.newton_tolerance, a.settings.newton_tolerance);
  EXPECT_EQ(b.settings.newton_max_iterations, a.settings.newton_max_iterations);
  EXPECT_EQ(b.settings.newton_max_halvings, a.settings.newton_max_halvings);
  EXPECT_EQ(b.settings.newton_guess, a.settings.newton_guess);
  EXPECT_EQ(b.settings.newton_reuse_contraction, a.settings.newton_reuse_contraction);
  EXPECT_EQ(b.settings.newton_exact_hessian, a.settings.newton_exact_hessian);
  EXPECT_EQ(b.settings.linear_solver, a.settings.linear_solver);
  EXPECT_EQ(b.settings.threads, a.settings.threads);
  EXPECT_EQ(b.settings.tethers, a.settings.tethers);
  EXPECT_EQ(b.codec.position_bound, a.codec.position_bound);
  EXPECT_EQ(b.codec.velocity_bound, a.codec.velocity_bound);
  EXPECT_EQ(b.codec.key_interval, a.codec.key_interval);
  EXPECT_EQ(b.codec.zstd_level, a.codec.zstd_level);
}

TEST(JobWire, ResultKeepsEveryField) {
  const JobResult a = sample_result();
  const std::vector<uint8_t> bytes = encode_result(9, a);
  uint64_t seq = 0;
  const JobResult b = decode_result(bytes.data(), bytes.size(), &seq);
  EXPECT_EQ(seq, 9u);
  EXPECT_EQ(b.stable, a.stable);
  EXPECT_EQ(b.message, a.message);
  EXPECT_EQ(b.frame_count, a.frame_count);
  EXPECT_EQ(b.vertex_count, a.vertex_count);
  EXPECT_EQ(b.clip_blob, a.clip_blob);
  EXPECT_EQ(b.clip_max_error, a.clip_max_error);
  EXPECT_EQ(b.end_x_blob, a.end_x_blob);
  EXPECT_EQ(b.end_v_blob, a.end_v_blob);
  EXPECT_EQ(b.last, a.last);
  EXPECT_EQ(b.quality.max_strain, a.quality.max_strain);
  EXPECT_EQ(b.quality.max_penetration, a.quality.max_penetration);
  EXPECT_EQ(b.quality.mean_penetration, a.quality.mean_penetration);
  EXPECT_EQ(b.quality.jitter, a.quality.jitter);
  EXPECT_EQ(b.quality.halved_steps, a.quality.halved_steps);
  EXPECT_EQ(b.quality.worst_frame, a.quality.worst_frame);
  EXPECT_EQ(b.cpu_seconds, a.cpu_seconds);
}

TEST(JobWire, HelloKeepsEveryField) {
  WorkerHello a;
  a.host = "node17";
  a.pid = 123456;
  a.scene_hash = 0x0123456789abcdefull;
  a.graph_hash = 0xfedcba9876543210ull;
  a.vertices = 3000;
  a.threads = 8;
  const std::vector<uint8_t> bytes = encode_hello(a);
  const WorkerHello b = decode_hello(bytes.data(), bytes.size());
  EXPECT_EQ(b.host, a.host);
  EXPECT_EQ(b.pid, a.pid);
  EXPECT_EQ(b.scene_hash, a.scene_hash);
  EXPECT_EQ(b.graph_hash, a.graph_hash);
  EXPECT_EQ(b.vertices, a.vertices);
  EXPECT_EQ(b.threads, a.threads);
}

TEST(JobWire, EveryTruncationAndPaddingIsRefused) {
  const std::vector<uint8_t> job = encode_job(1, sample_job());
  const std::vector<uint8_t> result = encode_result(1, sample_result());
  uint64_t seq = 0;
  for (size_t n = 0; n < job.size(); ++n)
    EXPECT_THROW(decode_job(job.data(), n, &seq), WireError) << n;
  for (size_t n = 0; n < result.size(); ++n)
    EXPECT_THROW(decode_result(result.data(), n, &seq), WireError) << n;
  std::vector<uint8_t> padded = job;
  padded.push_back(0);
  EXPECT_THROW(decode_job(padded.data(), padded.size(), &seq), WireError);
}

TEST(JobWire, WrongKindOrVersionIsRefusedByName) {
  const std::vector<uint8_t> job = encode_job(1, sample_job());
  uint64_t seq = 0;
  EXPECT_THROW(decode_result(job.data(), job.size(), &seq), WireError);  // a job is not a result
  std::vector<uint8_t> newer = job;
  newer[4] = static_cast<uint8_t>(kWireVersion + 1);
  try {
    decode_job(newer.data(), newer.size(), &seq);
    ADD_FAILURE() << "a newer format was accepted";
  } catch (const WireError& e) {
    EXPECT_NE(std::string(e.what()).find("version"), std::string::npos) << e.what();
  }
}

TEST(JobWire, HugeLengthIsRefusedBeforeAllocating) {
  std::vector<uint8_t> job = encode_job(1, sample_job());
  // x's element count sits after kind, version, seq and edge.
  const uint64_t huge = uint64_t(1) << 60;
  std::memcpy(job.data() + 4 + 4 + 8 + 4, &huge, 8);
  uint64_t seq = 0;
  try {
    decode_job(job.data(), job.size(), &seq);
    ADD_FAILURE() << "a huge length was accepted";
  } catch (const WireError& e) {
    EXPECT_NE(std::string(e.what()).find(": x:"), std::string::npos) << e.what();
  }
}

TEST(JobWire, BlobsMustMatchTheDeclaredCounts) {
  uint64_t seq = 0;
  JobResult r = sample_result();
  r.frame_count = 5;  // the clip blob holds 6
  std::vector<uint8_t> bytes = encode_result(1, r);
  try {
    decode_result(bytes.data(), bytes.size(), &seq);
    ADD_FAILURE() << "a clip of the wrong length was accepted";
  } catch (const WireError& e) {
    EXPECT_NE(std::string(e.what()).find("clip_blob"), std::string::npos) << e.what();
  }
  r = sample_result();
  r.end_v_blob = blob(1, 11, 1e-3);  // one vertex too many
  bytes = encode_result(1, r);
  EXPECT_THROW(decode_result(bytes.data(), bytes.size(), &seq), WireError);
}

TEST(JobWire, GraphHashSeesOneBitOfOnePose) {
  ExploreGraph g;
  g.node_count = 1;
  std::vector<JointPose> pose(3);
  g.edges.push_back({0, 0, "hold", std::vector<std::vector<JointPose>>(4, pose), 0});
  const uint64_t h = graph_hash(g);
  EXPECT_EQ(h, graph_hash(g));
  ExploreGraph changed = g;
  changed.edges[0].poses[2][1].position.x() = std::nextafter(0.0, 1.0);
  EXPECT_NE(h, graph_hash(changed));
  changed = g;
  changed.edges[0].db_clip = 5;  // the database id is rank 0's business, not the job's
  EXPECT_EQ(h, graph_hash(changed));
}
