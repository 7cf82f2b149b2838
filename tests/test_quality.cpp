// Clip quality metrics (precompute/quality/clip_quality.hpp) on constructed clips whose answer is
// known, the metrics a small precompute stores against the same metrics recomputed from the
// decoded frames, and `clothdb clips list` / `clip show` on that database.
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>

#include "cloth/self_intersection.hpp"
#include "clothrt.h"
#include "database/codec/codec.hpp"
#include "database/store/check.hpp"
#include "database/store/writer.hpp"
#include "explore/explorer.hpp"
#include "quality/clip_quality.hpp"
#include "support/cli.hpp"

using namespace clothdb;

namespace {

// A 5 x 5 node sheet, 0.4 m square, hanging in the XY plane; the top row pinned.
ClothModel sheet_model() {
  ClothMesh mesh = make_quad_grid(5, 5, 0.4, 0.4);
  std::vector<int> pins;
  for (int i = 0; i < mesh.vertex_count(); ++i)
    if (mesh.rest(1, i) > 0.399) pins.push_back(i);
  return make_model(mesh, Material{}, pins);
}

// F frames of the sheet at rest, moved by motion(f, vertex, axis) (metres).
template <typename F>
std::vector<float> clip_of(const ClothModel& model, int frames, F&& motion) {
  const int n = model.vertex_count();
  std::vector<float> out(size_t(frames) * n * 3);
  for (int f = 0; f < frames; ++f)
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < 3; ++k)
        out[(size_t(f) * n + i) * 3 + k] = float(model.mesh.rest(k, i) + motion(f, i, k));
  return out;
}

std::vector<std::vector<CapsuleCollider>> no_body(int frames) {
  return std::vector<std::vector<CapsuleCollider>>(frames);
}

int first_free(const ClothModel& m) {
  for (int i = 0; i < m.vertex_count(); ++i)
    if (m.inv_mass[i] > 0) return i;
  return -1;
}

}  // namespace

TEST(Quality, StretchedEdgeGivesItsExactStrain) {
  const ClothModel model = sheet_model();
  // Stretch one edge of a free vertex by 7 % in frame 3: move the vertex away from its neighbour
  // along the edge. Every other edge of that vertex changes less (it moves along this one only),
  // so the clip's strain is this edge's.
  const auto& e = model.mesh.edges.front();
  const Vec3 dir = (model.mesh.rest.col(e[1]) - model.mesh.rest.col(e[0])).normalized();
  const double l0 = model.edge_rest_length.front();
  const int moved = model.inv_mass[e[1]] > 0 ? e[1] : e[0];
  const double sign = moved == e[1] ? 1.0 : -1.0;
  const auto frames = clip_of(model, 6, [&](int f, int i, int k) {
    return f == 3 && i == moved ? sign * 0.07 * l0 * dir[k] : 0.0;
  });
  std::vector<FrameQuality> per_frame;
  const ClipQuality q = measure_clip(model, frames.data(), 6, no_body(6), &per_frame);
  EXPECT_NEAR(q.max_strain, 0.07, 1e-5);  // float positions
  EXPECT_EQ(q.worst_frame, 3);
  EXPECT_NEAR(per_frame[3].strain, 0.07, 1e-5);
  EXPECT_NEAR(per_frame[2].strain, 0.0, 1e-6);
  EXPECT_EQ(q.max_penetration, 0.0);
  EXPECT_EQ(q.halved_steps, -1);  // not visible in frames: the caller who ran the solver knows
}

TEST(Quality, VertexAtAKnownDepthInsideACapsule) {
  const ClothModel model = sheet_model();
  const int a = first_free(model);
  int b = -1;
  for (int i = model.vertex_count() - 1; i >= 0; --i)
    if (model.inv_mass[i] > 0 && i != a) b = i, i = -1;
  const int pin = model.kinematic.front();
  // A capsule along z through vertex a's rest position, radius 0.02; in frame 2 vertex a sits on
  // its axis (depth 0.02) and vertex b is carried to 0.015 from another capsule's axis (depth
  // 0.005). A pinned vertex inside a capsule does not count (pins sit where their bone puts them).
  const int frames_n = 5;
  auto frames = clip_of(model, frames_n, [](int, int, int) { return 0.0; });
  std::vector<std::vector<CapsuleCollider>> body(frames_n);
  const Vec3 pa = model.mesh.rest.col(a), pb = model.mesh.rest.col(b),
             pp = model.mesh.rest.col(pin);
  for (int f = 0; f < frames_n; ++f) {
    CapsuleCollider c;
    c.radius = 0.02;
    // Off to the side (no contact) except in frame 2.
    const Vec3 off = f == 2 ? Vec3(0, 0, 0) : Vec3(1, 0, 0);
    c.a = pa + off + Vec3(0, 0, -0.1);
    c.b = pa + off + Vec3(0, 0, 0.1);
    body[size_t(f)].push_back(c);
    CapsuleCollider d = c;
    d.a = pb + off + Vec3(0.015, 0, -0.1);
    d.b = pb + off + Vec3(0.015, 0, 0.1);
    body[size_t(f)].push_back(d);
    CapsuleCollider around_pin = c;  // always swallowing the pin
    around_pin.a = pp + Vec3(0, 0, -0.1);
    around_pin.b = pp + Vec3(0, 0, 0.1);
    around_pin.radius = 0.001;
    body[size_t(f)].push_back(around_pin);
  }
  const ClipQuality q = measure_clip(model, frames.data(), frames_n, body);
  EXPECT_NEAR(q.max_penetration, 0.02, 1e-6);
  EXPECT_NEAR(q.mean_penetration, 0.5 * (0.02 + 0.005), 1e-6);  // over the 2 penetrating pairs
  EXPECT_EQ(q.worst_frame, 2);
}

TEST(Quality, NoiseRaisesJitterAndSmoothMotionDoesNot) {
  const ClothModel model = sheet_model();
  const int frames_n = 60;
  const double dt = 1.0 / 30;
  // A 10 cm, 1 Hz swing of every free vertex: smooth motion the cloth makes all the time.
  auto swing = [&](int f, int i, int k) {
    return model.inv_mass[i] > 0 && k == 2 ? 0.1 * std::sin(2 * M_PI * f * dt) : 0.0;
  };
  const auto smooth = clip_of(model, frames_n, swing);
  const ClipQuality qs = measure_clip(model, smooth.data(), frames_n, no_body(frames_n));
  EXPECT_LT(qs.jitter, 3e-5);  // 0.1 m * (2 pi / 30)^4 / sqrt(70) = 23 um, plus float rounding
  // A cubic in time is not jitter at all (only float rounding remains).
  const auto cubic = clip_of(model, frames_n, [&](int f, int i, int k) {
    const double t = f * dt;
    return model.inv_mass[i] > 0 && k == 0 ? 0.05 * t * t * t - 0.1 * t : 0.0;
  });
  EXPECT_LT(measure_clip(model, cubic.data(), frames_n, no_body(frames_n)).jitter, 2e-6);
  // The same swing plus independent per-frame noise of 0.5 mm per coordinate: jitter reads the
  // noise's RMS vector length, sqrt(3) * 0.5 mm (normalised fourth difference), not the swing.
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.0005);
  const auto noisy =
      clip_of(model, frames_n, [&](int f, int i, int k) { return swing(f, i, k) + noise(rng); });
  const ClipQuality qn = measure_clip(model, noisy.data(), frames_n, no_body(frames_n));
  EXPECT_NEAR(qn.jitter, std::sqrt(3.0) * 0.0005, 0.1 * std::sqrt(3.0) * 0.0005);
  EXPECT_GT(qn.jitter, 20 * qs.jitter);
  // What it cannot tell from flicker: an impact (every free vertex moving at 1 m/s stopped dead in
  // frame 20) is high-frequency too. Its fourth differences are (1, -2, 1) times the 33 mm
  // velocity step on frames 19..21: sqrt(6 / 70) of it over the clip's 56 measured frames.
  const auto impact = clip_of(model, frames_n, [&](int f, int i, int k) {
    return model.inv_mass[i] > 0 && k == 2 ? std::min(f, 20) * dt : 0.0;
  });
  EXPECT_NEAR(measure_clip(model, impact.data(), frames_n, no_body(frames_n)).jitter,
              dt * std::sqrt(6.0 / 70 / 56), 1e-6);
  // Too short for a fourth difference: 0, not garbage.
  EXPECT_EQ(measure_clip(model, noisy.data(), 4, no_body(4)).jitter, 0.0);
}

TEST(Quality, PopIsTheLargestVertexJump) {
  const std::vector<float> last = {0, 0, 0, 1, 1, 1, 2, 0, 0};
  std::vector<float> target = last;
  EXPECT_EQ(transition_pop(last.data(), target.data(), 3), 0.0);
  target[3] += 0.003f, target[4] += 0.004f;  // vertex 1 jumps 5 mm
  target[6] -= 0.001f;                       // vertex 2 1 mm
  EXPECT_NEAR(transition_pop(last.data(), target.data(), 3), 0.005, 1e-6);
}

TEST(Quality, RejectsMismatchedSizes) {
  const ClothModel model = sheet_model();
  const auto frames = clip_of(model, 5, [](int, int, int) { return 0.0; });
  EXPECT_THROW(measure_clip(model, frames.data(), 5, no_body(4)), std::invalid_argument);
}

// ---- a small precompute -----------------------------------------------------------------------

namespace {

const std::string kMotions = std::string(CLOTHDB_SOURCE_DIR) + "/motions/";

// The small scene and one-node graph of test_explore.cpp: a held pose and a sway.
CharacterScene small_scene() {
  SceneFile file = load_scene_file(kMotions + "skirt_walk.json");
  file.clips = {"01_03_level_walk"};
  file.skirt.vertices = 200;
  file.settle_frames = 10;
  file.settings.substeps = 6;
  file.settings.iterations = 1;
  file.settings.tethers = false;
  file.settings.stretch_iterations = 0;  // as in explore_fixture.hpp
  file.settings.strain_limit = 0.0;
  file.air_drag = 3.0;
  return build_character_scene(file);
}

ExploreGraph small_graph(const CharacterScene& scene) {
  const auto pose = clip_pose(scene.clips.front(), 0);
  ExploreGraph g;
  g.node_count = 1;
  g.rate = 30;
  g.edges.push_back({0, 0, "hold", std::vector<std::vector<JointPose>>(12, pose), 0});
  std::vector<std::vector<JointPose>> sway;
  for (int k = 0; k < 16; ++k) {
    const double a = 0.6 * std::sin(2 * M_PI * k / 15);
    const Eigen::Quaterniond q(Eigen::AngleAxisd(a, Vec3::UnitY()));
    std::vector<JointPose> p = pose;
    for (auto& j : p) {
      j.position = pose[0].position + q * (j.position - pose[0].position);
      j.rotation = q * j.rotation;
    }
    sway.push_back(std::move(p));
  }
  g.edges.push_back({0, 0, "sway", sway, 0});
  return g;
}

std::string fresh_db(const std::string& name) {
  // Per process: CTest runs the tests of this file in parallel processes.
  const std::string path =
      testing::TempDir() + "/clothdb_quality_" + std::to_string(getpid()) + "_" + name + ".db";
  for (const char* suffix : {"", "-wal", "-shm"}) std::filesystem::remove(path + suffix);
  return path;
}

// Builds (once per test binary) a small explored database.
const std::string& small_db(const CharacterScene& scene) {
  static const std::string path = [&] {
    const std::string p = fresh_db("small");
    ExploreGraph graph = small_graph(scene);
    db::Writer writer = db::Writer::create(p);
    prepare_database(writer, scene, graph, "{}");
    ExploreOptions options;
    options.epsilon = 0.02;
    options.max_frames = 120;
    options.progress = false;
    explore(scene, graph, writer, options);
    return p;
  }();
  return path;
}

}  // namespace

TEST(Quality, PrecomputeStoresWhatTheDecodedFramesMeasure) {
  const CharacterScene scene = small_scene();
  const ExploreGraph graph = small_graph(scene);
  const std::string& path = small_db(scene);
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok) << err.message;
  std::vector<db::ClothClip> clips;
  std::vector<db::ClothEdge> edges;
  std::vector<db::PrimaryClip> primary;
  ASSERT_EQ(r.cloth_clips(&clips, &err), db::Status::Ok);
  ASSERT_EQ(r.cloth_edges(&edges, &err), db::Status::Ok);
  ASSERT_EQ(r.primary_clips(&primary, &err), db::Status::Ok);
  ASSERT_GE(clips.size(), 4u);
  // The stored metrics were measured on the frames before encoding; the decoded ones differ by at
  // most the bound b per coordinate (sqrt(3) b per vertex), hence:
  const double b = r.codec().position_bound, vertex_bound = std::sqrt(3.0) * b;
  double min_rest = 1e9;
  for (double l : scene.model.edge_rest_length) min_rest = std::min(min_rest, l);
  codec::DecodeScratch scratch;
  bool any_strain = false, any_jitter = false;
  for (const auto& c : clips) {
    SCOPED_TRACE("clip " + std::to_string(c.id));
    std::string name;
    for (const auto& p : primary)
      if (p.id == c.primary_clip) name = p.name;
    const ExploreEdge* edge = nullptr;
    for (const auto& e : graph.edges)
      if (e.name == name) edge = &e;
    ASSERT_NE(edge, nullptr);
    std::vector<uint8_t> blob;
    std::vector<float> frames;
    ASSERT_EQ(r.clip_blob(c.id, &blob, &err), db::Status::Ok);
    ASSERT_EQ(codec::decode_all(blob.data(), blob.size(), frames, scratch, &err), db::Status::Ok);
    const ClipQuality q = measure_clip(scene, edge->poses, frames);
    // Edge lengths move by at most 2 sqrt(3) b: strain by that over the rest length.
    EXPECT_NEAR(c.max_strain, q.max_strain, 2 * vertex_bound / min_rest);
    EXPECT_NEAR(c.max_penetration, q.max_penetration, vertex_bound);
    // The fourth difference of errors <= b has length <= 16 sqrt(3) b, / sqrt(70).
    EXPECT_NEAR(c.jitter, q.jitter, 16 * vertex_bound / std::sqrt(70.0));
    ASSERT_FALSE(std::isnan(c.mean_penetration));
    EXPECT_GE(c.mean_penetration, 0.0);
    EXPECT_LE(c.mean_penetration, c.max_penetration);
    EXPECT_EQ(c.halved_steps, 0);  // XPBD never halves
    EXPECT_GE(c.worst_frame, 0);
    EXPECT_LT(c.worst_frame, c.frame_count);
    // Crossings are stored as simulated; the codec's rounding (at most the bound, 0.1 mm by
    // default) must not put the cloth through itself where it was not.
    ASSERT_GE(c.self_intersections, 0);
    EXPECT_LE(q.self_intersections, c.self_intersections);
    any_strain |= c.max_strain > 0;
    any_jitter |= c.jitter > 0;
    // Pop: the clip's decoded last frame against the decoded positions of its edge's state.
    for (const auto& e : edges) {
      if (e.from_clip != c.id) continue;
      std::vector<float> x, v;
      ASSERT_EQ(r.read_state(e.to_state, &x, &v, scratch, &err), db::Status::Ok);
      const size_t n = x.size() / 3;
      const double pop =
          transition_pop(frames.data() + (size_t(c.frame_count) - 1) * n * 3, x.data(), n);
      EXPECT_NEAR(e.pop, pop, 1e-12) << "edge " << e.id;
      // An edge into the clip's own end only carries the codec's rounding.
      if (e.blend_error == 0) {
        EXPECT_LE(e.pop, 2 * vertex_bound);
      }
    }
  }
  EXPECT_TRUE(any_strain);
  EXPECT_TRUE(any_jitter);
}

// The demo's bound (0.1 mm per coordinate) on a garment simulated with self-collision: the decoded
// frames have no crossing that the simulated ones did not have (docs/guide/self_collision.md).
TEST(Quality, DecodedFramesAtTheDemoBoundAddNoCrossings) {
  SceneFile file = load_scene_file(kMotions + "skirt_walk.json");
  file.clips = {"01_03_level_walk"};
  file.skirt.vertices = 300;
  file.settle_frames = 10;
  file.settings.substeps = 8;
  file.settings.self_collision_thickness_mm = 4;
  const CharacterScene scene = build_character_scene(file);
  ExploreGraph graph = small_graph(scene);
  const std::string path = fresh_db("demo_bound");
  {
    db::CodecSettings codec;
    codec.position_bound = 1e-4;
    db::Writer writer = db::Writer::create(path, codec);
    prepare_database(writer, scene, graph, "{}");
    ExploreOptions options;
    options.epsilon = 0.02;
    options.max_frames = 60;
    options.progress = false;
    explore(scene, graph, writer, options);
  }
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok) << err.message;
  EXPECT_DOUBLE_EQ(r.codec().position_bound, 1e-4);
  std::vector<db::ClothClip> clips;
  ASSERT_EQ(r.cloth_clips(&clips, &err), db::Status::Ok);
  ASSERT_FALSE(clips.empty());
  codec::DecodeScratch scratch;
  const int n = scene.model.vertex_count();
  for (const auto& c : clips) {
    SCOPED_TRACE("clip " + std::to_string(c.id));
    ASSERT_GE(c.self_intersections, 0);  // stored by the precompute
    std::vector<uint8_t> blob;
    std::vector<float> frames;
    ASSERT_EQ(r.clip_blob(c.id, &blob, &err), db::Status::Ok);
    ASSERT_EQ(codec::decode_all(blob.data(), blob.size(), frames, scratch, &err), db::Status::Ok);
    ASSERT_EQ(frames.size(), size_t(c.frame_count) * size_t(n) * 3);
    for (int f = 0; f < c.frame_count; ++f) {
      const Eigen::Matrix3Xf x =
          Eigen::Map<const Eigen::Matrix3Xf>(frames.data() + size_t(f) * size_t(n) * 3, 3, n);
      EXPECT_LE(count_self_intersections(scene.model.mesh, x.cast<double>()), c.self_intersections)
          << "frame " << f;
    }
  }
}

TEST(Quality, Version4FilesHaveNoStoredCrossingsUntilMigrated) {
  const CharacterScene scene = small_scene();
  const std::string v4 = fresh_db("v4");
  std::filesystem::copy_file(small_db(scene), v4);
  {
    sqlite3* h = nullptr;
    ASSERT_EQ(sqlite3_open(v4.c_str(), &h), SQLITE_OK);
    char* msg = nullptr;
    const int rc = sqlite3_exec(
        h, "ALTER TABLE cloth_clip DROP COLUMN self_intersections; PRAGMA user_version = 4;",
        nullptr, nullptr, &msg);
    ASSERT_EQ(rc, SQLITE_OK) << (msg ? msg : "");
    sqlite3_close(h);
  }
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(v4, &err), db::Status::Ok) << err.message;
  EXPECT_EQ(r.schema_version(), 4);
  std::vector<db::ClothClip> clips;
  ASSERT_EQ(r.cloth_clips(&clips, &err), db::Status::Ok) << err.message;
  ASSERT_FALSE(clips.empty());
  for (const auto& c : clips) EXPECT_EQ(c.self_intersections, -1);
  r.close();
  EXPECT_TRUE(db::check_database(v4).ok());
  {
    db::Writer w = db::Writer::open(v4);
    db::ClipMetrics m = clips[0].metrics();
    m.self_intersections = 3;
    w.set_clip_metrics(clips[0].id, m);
  }
  ASSERT_EQ(r.open(v4, &err), db::Status::Ok) << err.message;
  EXPECT_EQ(r.schema_version(), db::kSchemaVersion);
  std::vector<db::ClothClip> after;
  ASSERT_EQ(r.cloth_clips(&after, &err), db::Status::Ok);
  EXPECT_EQ(after[0].self_intersections, 3);
  EXPECT_EQ(after[1].self_intersections, -1);
  EXPECT_TRUE(db::check_database(v4).ok());
}

TEST(Quality, Version1FilesAreReadAsUnknownAndMigratedByTheWriter) {
  const CharacterScene scene = small_scene();
  const std::string v1 = fresh_db("v1");
  std::filesystem::copy_file(small_db(scene), v1);
  {
    // What a file written before the metrics looks like: no metric columns, user_version 1.
    sqlite3* h = nullptr;
    ASSERT_EQ(sqlite3_open(v1.c_str(), &h), SQLITE_OK);
    char* msg = nullptr;
    const int rc = sqlite3_exec(h,
                                "ALTER TABLE cloth_clip DROP COLUMN mean_penetration; "
                                "ALTER TABLE cloth_clip DROP COLUMN jitter; "
                                "ALTER TABLE cloth_clip DROP COLUMN halved_steps; "
                                "ALTER TABLE cloth_clip DROP COLUMN worst_frame; "
                                "ALTER TABLE cloth_clip DROP COLUMN self_intersections; "
                                "ALTER TABLE cloth_edge DROP COLUMN pop; PRAGMA user_version = 1;",
                                nullptr, nullptr, &msg);
    ASSERT_EQ(rc, SQLITE_OK) << (msg ? msg : "");
    sqlite3_close(h);
  }
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(v1, &err), db::Status::Ok) << err.message;
  EXPECT_EQ(r.schema_version(), 1);
  std::vector<db::ClothClip> clips;
  std::vector<db::ClothEdge> edges;
  ASSERT_EQ(r.cloth_clips(&clips, &err), db::Status::Ok) << err.message;
  ASSERT_EQ(r.cloth_edges(&edges, &err), db::Status::Ok) << err.message;
  ASSERT_FALSE(clips.empty());
  EXPECT_GT(clips[0].max_strain, 0.0);  // the version 1 metrics are still there
  EXPECT_TRUE(std::isnan(clips[0].jitter));
  EXPECT_EQ(clips[0].worst_frame, -1);
  EXPECT_EQ(clips[0].self_intersections, -1);
  EXPECT_TRUE(std::isnan(edges[0].pop));
  r.close();
  EXPECT_TRUE(db::check_database(v1).ok());
  // The runtime plays a version 1 file.
  clothrt_db* rt = nullptr;
  ASSERT_EQ(clothrt_db_open(v1.c_str(), nullptr, &rt), CLOTHRT_OK) << clothrt_last_open_errmsg();
  clothrt_player* player = nullptr;
  ASSERT_EQ(clothrt_player_create(rt, &player), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_start_cloth_clip(player, clips[0].id), CLOTHRT_OK);
  for (int f = 0; f < 30; ++f) EXPECT_EQ(clothrt_player_advance(player, 1.0 / 30), CLOTHRT_OK);
  clothrt_player_destroy(player);
  clothrt_db_close(rt);
  // Opening it for writing migrates it in place: same rows, the new columns NULL until measured.
  {
    db::Writer w = db::Writer::open(v1);
    db::ClipMetrics m = clips[0].metrics();
    m.jitter = 0.001;
    m.worst_frame = 0;
    w.set_clip_metrics(clips[0].id, m);
  }
  ASSERT_EQ(r.open(v1, &err), db::Status::Ok) << err.message;
  EXPECT_EQ(r.schema_version(), db::kSchemaVersion);
  std::string version;
  ASSERT_EQ(r.meta("format_version", &version, &err), db::Status::Ok);
  EXPECT_EQ(version, std::to_string(db::kSchemaVersion));
  std::vector<db::ClothClip> after;
  ASSERT_EQ(r.cloth_clips(&after, &err), db::Status::Ok);
  ASSERT_EQ(after.size(), clips.size());
  EXPECT_DOUBLE_EQ(after[0].jitter, 0.001);
  EXPECT_DOUBLE_EQ(after[0].max_strain, clips[0].max_strain);
  EXPECT_TRUE(std::isnan(after[1].jitter));
  EXPECT_TRUE(db::check_database(v1).ok());
}

// ---- the CLI ----------------------------------------------------------------------------------

namespace {

struct Output {
  int status = 0;
  std::string out, err;
};

// stdout and stderr apart: the --json output must parse on its own.
Output run_cli(const std::string& args) {
  const std::string stem = testing::TempDir() + "/clothdb_quality_cli_" + std::to_string(getpid());
  const pid_t pid =
      test::start_clothdb(test::split_arguments(args), stem + ".out", false, stem + ".err");
  const test::CliResult r = test::wait_clothdb(pid, stem + ".out");
  return {r.code, r.output, test::read_text(stem + ".err")};
}

}  // namespace

TEST(Quality, ClipsListSortsByTheMetricAndExplainsBadInput) {
  const CharacterScene scene = small_scene();
  const std::string& path = small_db(scene);
  for (const std::string by :
       {"strain", "penetration", "mean-penetration", "jitter", "halved", "pop"}) {
    SCOPED_TRACE(by);
    const Output o = run_cli("clips list " + path + " --worst 3 --by " + by + " --json");
    ASSERT_EQ(o.status, 0) << o.err;
    const nlohmann::json j = nlohmann::json::parse(o.out);
    ASSERT_EQ(j["clips"].size(), 3u);
    const std::string key = by == "strain"             ? "max_strain_percent"
                            : by == "penetration"      ? "max_penetration_mm"
                            : by == "mean-penetration" ? "mean_penetration_mm"
                            : by == "jitter"           ? "jitter_mm"
                            : by == "halved"           ? "halved_steps"
                                                       : "worst_pop_mm";
    for (size_t k = 1; k < 3; ++k)
      EXPECT_GE(j["clips"][k - 1][key].get<double>(), j["clips"][k][key].get<double>());
  }
  // The first row of --by jitter is the clip with the largest stored jitter.
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  std::vector<db::ClothClip> clips;
  EXPECT_EQ(r.cloth_clips(&clips, &err), clothdb::Status::Ok);
  const auto worst = std::max_element(
      clips.begin(), clips.end(), [](const auto& a, const auto& b) { return a.jitter < b.jitter; });
  const Output table = run_cli("clips list " + path + " --by jitter --worst 1");
  ASSERT_EQ(table.status, 0) << table.err;
  const nlohmann::json j =
      nlohmann::json::parse(run_cli("clips list " + path + " --by jitter --worst 1 --json").out);
  EXPECT_EQ(j["clips"][0]["id"].get<int64_t>(), worst->id);
  EXPECT_NE(table.out.find("jitter"), std::string::npos) << table.out;
  // --by self-intersections lists the stored counts (no decoding needed).
  const nlohmann::json cross = nlohmann::json::parse(
      run_cli("clips list " + path + " --by self-intersections --worst 0 --json").out);
  ASSERT_EQ(cross["clips"].size(), clips.size());
  for (const auto& row : cross["clips"]) {
    for (const auto& c : clips) {
      if (c.id == row["id"].get<int64_t>()) {
        EXPECT_EQ(row["self_intersections"].get<int>(), c.self_intersections);
      }
    }
  }

  const Output bad_metric = run_cli("clips list " + path + " --by wobble");
  EXPECT_EQ(bad_metric.status, 1);
  EXPECT_NE(bad_metric.err.find("unknown metric 'wobble'"), std::string::npos) << bad_metric.err;
  const std::string text = testing::TempDir() + "/clothdb_quality_not_a_db.txt";
  std::ofstream(text) << "hello";
  const Output not_db = run_cli("clips list " + text);
  EXPECT_EQ(not_db.status, 1);
  EXPECT_NE(not_db.err.find("not a clothdb database"), std::string::npos) << not_db.err;
}

TEST(Quality, ClipShowPrintsMetricsAndWritesAContactSheet) {
  const CharacterScene scene = small_scene();
  const std::string& path = small_db(scene);
  const std::string png =
      testing::TempDir() + "/clothdb_quality_clip1_" + std::to_string(getpid()) + ".png";
  std::filesystem::remove(png);
  // This database was prepared without a motion graph: the sheet is drawn without the body, and
  // says so.
  const Output o = run_cli("clip show " + path + " 1 --png " + png + " --tiles 4 --tile-size 96");
  ASSERT_EQ(o.status, 0) << o.err;
  EXPECT_NE(o.out.find("max strain"), std::string::npos) << o.out;
  EXPECT_NE(o.out.find("out edges:"), std::string::npos) << o.out;
  EXPECT_NE(o.out.find("pop"), std::string::npos) << o.out;
  EXPECT_NE(o.err.find("without the body"), std::string::npos) << o.err;
  ASSERT_TRUE(std::filesystem::exists(png));
  std::ifstream in(png, std::ios::binary);
  char magic[4] = {};
  in.read(magic, 4);
  EXPECT_EQ(std::string(magic + 1, 3), "PNG");

  const Output missing = run_cli("clip show " + path + " 999999 --no-png");
  EXPECT_EQ(missing.status, 1);
  EXPECT_NE(missing.err.find("no cloth clip 999999"), std::string::npos) << missing.err;
}
