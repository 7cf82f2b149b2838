// The messages between MPI ranks (explore/job_wire.hpp): every field survives the trip, and a
// truncated, padded, mislabelled or inconsistent message is refused with the field named.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>

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
  // Steering (the demo scene steers): the explorer's epsilon and the states at the end node.
  j.epsilon = 0.0037;
  j.state = 3;
  j.targets = {{11, ramp(30, 0.75f), ramp(30, -1.5f)}, {-4, ramp(30, 0.125f), ramp(30, 3.0f)}};
  return j;
}

// A worker's replica for sample_job's 10-vertex states.
StateReplica replica() {
  return make_replica(10, 1.0 / 30);
}

// Encoded for a worker that holds nothing yet, and decoded by one.
JobInput round_trip(const JobInput& job, uint64_t* seq, std::vector<uint8_t>* bytes = nullptr) {
  ReplicaLedger ledger;
  const std::vector<uint8_t> b = encode_job(*seq, job, ledger);
  StateReplica r = replica();
  if (bytes) *bytes = b;
  return decode_job(b.data(), b.size(), seq, r);
}

std::vector<uint8_t> fresh_job(uint64_t seq, const JobInput& job) {
  ReplicaLedger ledger;
  return encode_job(seq, job, ledger);
}

// The ids a replica holds, sorted, and the ids a ledger accounts for, sorted.
std::vector<int64_t> held(const StateReplica& r) {
  std::vector<int64_t> ids;
  for (const auto& [id, reduced] : r.reduced) ids.push_back(id);
  std::sort(ids.begin(), ids.end());
  return ids;
}
std::vector<int64_t> held(const ReplicaLedger& l) {
  std::vector<int64_t> ids(l.lru.begin(), l.lru.end());
  std::sort(ids.begin(), ids.end());
  return ids;
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
  uint64_t seq = 42;
  const JobInput b = round_trip(a, &seq);
  EXPECT_EQ(seq, 42u);
  EXPECT_EQ(b.edge, a.edge);
  EXPECT_EQ(b.state, a.state);
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
  EXPECT_EQ(b.epsilon, a.epsilon);
  // The targets arrive as ids over the worker's replica, in their order, with their reduced forms.
  EXPECT_TRUE(b.targets.empty());
  ASSERT_TRUE(b.target_source);
  const SteerTargetSource& t = *b.target_source;
  ASSERT_EQ(t.ids.size(), a.targets.size());
  ASSERT_EQ(t.reduced.size(), a.targets.size());
  for (size_t k = 0; k < a.targets.size(); ++k) {
    EXPECT_EQ(t.ids[k], a.targets[k].state) << "target " << k;
    EXPECT_EQ(t.exact->get(t.ids[k])->x, a.targets[k].x) << "target " << k;
    EXPECT_EQ(t.exact->get(t.ids[k])->v, a.targets[k].v) << "target " << k;
    EXPECT_EQ(t.reduced[k], reduce(t.reducer, a.targets[k].x.data(), a.targets[k].v.data()));
  }
  // Without steering targets the job names its start state alone.
  JobInput plain = a;
  plain.targets.clear();
  seq = 5;
  EXPECT_FALSE(round_trip(plain, &seq).target_source);
}

// The replica follows rank 0's ledger: each state crosses once while the worker holds it, the
// least recently used are dropped beyond the capacity (never one the job names), and the two
// always hold the same ids.
TEST(JobWire, ReplicaHoldsWhatTheLedgerSaysAndStatesCrossOnce) {
  const uint32_t vertices = 10;
  auto state = [&](int64_t id) {
    return SteerTarget{id, ramp(3 * vertices, 0.01f * float(id)), ramp(3 * vertices, -0.5f)};
  };
  ReplicaLedger ledger;
  ledger.capacity_bytes = 4 * exact_state_bytes(vertices);  // four states
  StateReplica worker = replica();
  // Jobs starting at state s with targets t: (start, targets) per job.
  const std::vector<std::pair<int64_t, std::vector<int64_t>>> jobs = {
      {1, {2, 3}}, {2, {1, 3}}, {4, {5, 6}}, {1, {2, 3}}, {7, {}}, {5, {4, 6, 7, 8}}, {2, {}}};
  size_t first_bytes = 0;
  for (size_t j = 0; j < jobs.size(); ++j) {
    SCOPED_TRACE("job " + std::to_string(j));
    JobInput job = sample_job();
    const SteerTarget start = state(jobs[j].first);
    job.state = start.state;
    job.x = start.x;
    job.v = start.v;
    job.targets.clear();
    for (int64_t id : jobs[j].second) job.targets.push_back(state(id));
    const std::vector<int64_t> before = held(ledger);
    JobWireCounts counts;
    const std::vector<uint8_t> bytes = encode_job(j, job, ledger, &counts);
    uint64_t seq = 0;
    const JobInput got = decode_job(bytes.data(), bytes.size(), &seq, worker);
    EXPECT_EQ(held(worker), held(ledger));
    EXPECT_LE(ledger.bytes, std::max<size_t>(ledger.capacity_bytes,
                                             (1 + jobs[j].second.size()) * exact_state_bytes(10)));
    EXPECT_EQ(ledger.bytes, held(ledger).size() * exact_state_bytes(vertices));
    // Sent whole exactly the named states the worker did not hold.
    long lacked = !std::binary_search(before.begin(), before.end(), job.state);
    for (int64_t id : jobs[j].second)
      lacked += !std::binary_search(before.begin(), before.end(), id);
    EXPECT_EQ(counts.states_sent, lacked);
    EXPECT_EQ(counts.states_named, long(1 + jobs[j].second.size()) - lacked);
    EXPECT_EQ(got.x, start.x);
    EXPECT_EQ(got.v, start.v);
    for (size_t k = 0; k < jobs[j].second.size(); ++k) {
      const SteerTarget t = state(jobs[j].second[k]);
      ASSERT_TRUE(got.target_source);
      EXPECT_EQ(got.target_source->ids[k], t.state);
      EXPECT_EQ(got.target_source->exact->get(t.state)->x, t.x);
    }
    if (j == 0) first_bytes = bytes.size();
    if (j == 1) {  // the same three states: all held, ids only
      EXPECT_EQ(counts.states_sent, 0);
      EXPECT_LE(bytes.size() + 3 * exact_state_bytes(vertices), first_bytes);
    }
    if (j == 2) {  // six held, four fit: 1 and 2 go
      EXPECT_EQ(counts.states_dropped, 2);
    }
  }
}

// A message that names a state the worker does not hold (a ledger that is not this worker's) is
// refused by name, and the replica is left as it was.
TEST(JobWire, AStateTheWorkerLacksIsRefusedAndTheReplicaUnchanged) {
  const JobInput job = sample_job();
  ReplicaLedger ledger;
  const std::vector<uint8_t> first = encode_job(1, job, ledger);
  const std::vector<uint8_t> second = encode_job(2, job, ledger);  // ids only
  StateReplica other = replica();
  uint64_t seq = 0;
  try {
    decode_job(second.data(), second.size(), &seq, other);
    ADD_FAILURE() << "a job naming states the worker lacks was accepted";
  } catch (const WireError& e) {
    EXPECT_NE(std::string(e.what()).find("neither held by this worker nor sent"), std::string::npos)
        << e.what();
  }
  EXPECT_TRUE(held(other).empty());
  decode_job(first.data(), first.size(), &seq, other);
  EXPECT_EQ(decode_job(second.data(), second.size(), &seq, other).x, job.x);
}

// With the explorer's store, the states a worker lacks travel as the file's blobs (3-4x smaller
// than floats) and decode to the floats rank 0 holds.
TEST(JobWire, StatesTravelAsTheFilesBlobs) {
  JobInput job = sample_job();
  codec::EncodeSettings es;
  es.bound = 1e-4;
  std::map<int64_t, StateBlobs> file;
  std::map<int64_t, std::pair<std::vector<float>, std::vector<float>>> decoded;
  codec::DecodeScratch scratch;
  for (int64_t id : {3, 11, -4}) {
    const std::vector<float> x = ramp(30, 0.1f * float(id)), v = ramp(30, 0.3f);
    StateBlobs b{codec::encode(x.data(), 1, 10, es), codec::encode(v.data(), 1, 10, es)};
    std::vector<float> dx, dv;
    db::Error err;
    ASSERT_EQ(codec::decode_all(b.x.data(), b.x.size(), dx, scratch, &err), db::Status::Ok);
    ASSERT_EQ(codec::decode_all(b.v.data(), b.v.size(), dv, scratch, &err), db::Status::Ok);
    file[id] = b;
    decoded[id] = {dx, dv};
  }
  job.x = decoded[3].first;
  job.v = decoded[3].second;
  job.store = std::make_shared<StateCache>(
      1 << 20,
      [&](int64_t id) {
        return ExactState{decoded.at(id).first, decoded.at(id).second};
      },
      [&](int64_t id) { return file.at(id); });
  ReplicaLedger ledger;
  JobWireCounts counts;
  const std::vector<uint8_t> bytes = encode_job(1, job, ledger, &counts);
  EXPECT_EQ(counts.states_sent, 3);
  EXPECT_EQ(counts.sent_as_blobs, 3);
  StateReplica worker = replica();
  uint64_t seq = 0;
  const JobInput got = decode_job(bytes.data(), bytes.size(), &seq, worker);
  EXPECT_EQ(got.x, decoded[3].first);
  EXPECT_EQ(got.v, decoded[3].second);
  for (int64_t id : {11, -4}) EXPECT_EQ(worker.exact->get(id)->x, decoded[id].first) << id;
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
  const std::vector<uint8_t> job = fresh_job(1, sample_job());
  const std::vector<uint8_t> result = encode_result(1, sample_result());
  uint64_t seq = 0;
  for (size_t n = 0; n < job.size(); ++n) {
    StateReplica r = replica();
    EXPECT_THROW(decode_job(job.data(), n, &seq, r), WireError) << n;
    EXPECT_TRUE(held(r).empty()) << n;
  }
  for (size_t n = 0; n < result.size(); ++n)
    EXPECT_THROW(decode_result(result.data(), n, &seq), WireError) << n;
  std::vector<uint8_t> padded = job;
  padded.push_back(0);
  StateReplica r = replica();
  EXPECT_THROW(decode_job(padded.data(), padded.size(), &seq, r), WireError);
}

TEST(JobWire, WrongKindOrVersionIsRefusedByName) {
  const std::vector<uint8_t> job = fresh_job(1, sample_job());
  uint64_t seq = 0;
  EXPECT_THROW(decode_result(job.data(), job.size(), &seq), WireError);  // a job is not a result
  StateReplica r = replica();
  for (const uint32_t version : {kWireVersion - 1, kWireVersion + 1}) {
    std::vector<uint8_t> other = job;
    std::memcpy(other.data() + 4, &version, 4);
    try {
      decode_job(other.data(), other.size(), &seq, r);
      ADD_FAILURE() << "format " << version << " was accepted";
    } catch (const WireError& e) {
      EXPECT_NE(std::string(e.what()).find("version"), std::string::npos) << e.what();
    }
  }
  // The previous format (6: steering targets as copies) and a newer one are refused; this one
  // reads.
  EXPECT_EQ(decode_job(job.data(), job.size(), &seq, r).x, sample_job().x);
}

TEST(JobWire, HugeLengthIsRefusedBeforeAllocating) {
  std::vector<uint8_t> job = fresh_job(1, sample_job());
  // The first state's x element count sits after kind, version, seq, edge, the drop count (0),
  // the state count, the state's id and its form.
  const uint64_t huge = uint64_t(1) << 60;
  std::memcpy(job.data() + 4 + 4 + 8 + 4 + 4 + 4 + 8 + 4, &huge, 8);
  uint64_t seq = 0;
  StateReplica r = replica();
  try {
    decode_job(job.data(), job.size(), &seq, r);
    ADD_FAILURE() << "a huge length was accepted";
  } catch (const WireError& e) {
    EXPECT_NE(std::string(e.what()).find(": state x:"), std::string::npos) << e.what();
  }
  // A huge state count too.
  job = fresh_job(1, sample_job());
  const uint32_t many = 0xffffffffu;
  std::memcpy(job.data() + 4 + 4 + 8 + 4 + 4, &many, 4);
  EXPECT_THROW(decode_job(job.data(), job.size(), &seq, r), WireError);
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
