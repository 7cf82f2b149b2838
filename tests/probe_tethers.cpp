// Probe (not a CTest test): why the small explore graph of tests/test_explore.cpp needs many more
// cloth states with XPBD's long-range attachments (tethers) on. docs/SECONDARY_GRAPH.md has the
// figures. Run: build/tests/probe_tethers (HoldRepeated, then Explore, then Contraction, which
// reads Explore's databases); PROBE_EPS (m, default 0.02) and PROBE_FRAMES (default 3000) set the
// exploration's epsilon and frame budget.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>

#include "database/codec/codec.hpp"
#include "explore/explorer.hpp"
using namespace clothdb;
namespace {
CharacterScene scene_with(bool tethers, double drag) {
  SceneFile file = load_scene_file(std::string(CLOTHDB_SOURCE_DIR) + "/motions/skirt_walk.json");
  file.clips = {"01_03_level_walk"};
  file.skirt.vertices = 200;
  file.settle_frames = 10;
  file.settings.substeps = 6;
  file.settings.iterations = 1;
  file.skirt.flare = 1.5;
  file.skirt.length = 0.5;
  file.settings.tethers = tethers;
  file.air_drag = drag;
  return build_character_scene(file);
}
std::vector<float> flat(const Eigen::Matrix3Xd& m) {
  std::vector<float> o(m.size());
  for (Eigen::Index i = 0; i < m.size(); ++i) o[i] = float(m.data()[i]);
  return o;
}
}  // namespace
TEST(Probe, HoldRepeated) {
  for (bool tethers : {false, true}) {
    const CharacterScene scene = scene_with(tethers, 3.0);
    auto solver = make_solver(scene.file.solver, scene.model, scene.file.settings);
    const auto pose = clip_pose(scene.clips.front(), 0);
    ClothState s = settle_garment(scene, *solver, pose);
    std::vector<std::vector<JointPose>> hold(12, pose);
    std::vector<float> px = flat(s.x), pv = flat(s.v);
    std::printf("tethers=%d\n", tethers);
    for (int k = 0; k < 30; ++k) {
      PoseRun r = simulate_poses(scene, *solver, hold, 30.0, s);
      std::vector<float> x = flat(s.x), v = flat(s.v);
      const double d = db::state_distance(x, v, px, pv, 1.0 / 30);
      const double dx = db::state_distance(x, std::vector<float>(v.size(), 0), px,
                                           std::vector<float>(v.size(), 0), 0);
      double vmax = 0;
      for (Eigen::Index i = 0; i < s.v.cols(); ++i) vmax = std::max(vmax, s.v.col(i).norm());
      std::printf("  hold %2d: d %.3f mm (pos %.3f mm)  vmax %.4f m/s  strain %.4f\n", k, 1e3 * d,
                  1e3 * dx, vmax, r.metrics.back().max_strain);
      px = x;
      pv = v;
    }
  }
}
namespace {
std::vector<std::vector<JointPose>> sway(const std::vector<JointPose>& pose, double angle,
                                         int frames) {
  std::vector<std::vector<JointPose>> out;
  for (int k = 0; k < frames; ++k) {
    const double a = angle * std::sin(2 * 3.14159265358979 * k / (frames - 1));
    const Eigen::Quaterniond q(Eigen::AngleAxisd(a, Vec3::UnitY()));
    std::vector<JointPose> p = pose;
    for (auto& j : p) {
      j.position = pose[0].position + q * (j.position - pose[0].position);
      j.rotation = q * j.rotation;
    }
    out.push_back(std::move(p));
  }
  return out;
}
}  // namespace
TEST(Probe, Explore) {
  for (bool tethers : {false, true}) {
    const CharacterScene scene = scene_with(tethers, 3.0);
    const auto pose = clip_pose(scene.clips.front(), 0);
    ExploreGraph g;
    g.node_count = 1;
    g.rate = 30;
    g.edges.push_back({0, 0, "hold", std::vector<std::vector<JointPose>>(12, pose), 0});
    g.edges.push_back({0, 0, "sway", sway(pose, 0.6, 16), 0});
    const std::string path = testing::TempDir() + "/probe_" + std::to_string(tethers) +
                             (std::getenv("PROBE_EPS") ? std::getenv("PROBE_EPS") : "") + ".db";
    for (const char* s : {"", "-wal", "-shm"}) std::filesystem::remove(path + s);
    db::Writer w = db::Writer::create(path);
    prepare_database(w, scene, g, "{}");
    ExploreOptions o;
    o.epsilon = std::getenv("PROBE_EPS") ? atof(std::getenv("PROBE_EPS")) : 0.02;
    o.max_frames = std::getenv("PROBE_FRAMES") ? atol(std::getenv("PROBE_FRAMES")) : 3000;
    o.progress = false;
    o.threads = 2;
    const ExploreReport r = explore(scene, g, w, o);
    std::printf("tethers=%d: states %d clips %d dead %d converged %d frames %ld\n", tethers,
                r.states, r.clips, r.dead_ends, r.converged, r.frames);
    for (size_t i = 0; i < r.curve.size(); i += std::max<size_t>(1, r.curve.size() / 12))
      std::printf("   batch %3zu: states %4d dead %4d worst %.1f mm mean %.1f mm\n", i,
                  r.curve[i].states, r.curve[i].dead_ends, 1e3 * r.curve[i].worst_error,
                  1e3 * r.curve[i].mean_error);
    // Distances of every state to its nearest other state, and pinned/tether info.
    db::Reader rd;
    db::Error err;
    db::throw_if_error(rd.open(path, &err), err);
    std::vector<db::StoredState> st;
    db::throw_if_error(rd.cloth_states(&st, &err), err);
    codec::DecodeScratch sc;
    std::vector<std::vector<float>> X, V;
    for (auto& s : st) {
      std::vector<float> x, v;
      db::throw_if_error(rd.read_state(s.id, &x, &v, sc, &err), err);
      X.push_back(x);
      V.push_back(v);
    }
    // velocity magnitude RMS and position spread
    double vr = 0;
    for (auto& v : V) {
      double s2 = 0;
      for (float f : v) s2 += f * f;
      vr += std::sqrt(s2 / (v.size() / 3));
    }
    std::printf("   mean RMS speed of states %.4f m/s over %zu states\n", vr / V.size(), V.size());
    const size_t n = X.size();
    std::vector<double> nn(n, 1e9);
    for (size_t i = 0; i < n; ++i)
      for (size_t j = 0; j < n; ++j)
        if (i != j) nn[i] = std::min(nn[i], db::state_distance(X[i], V[i], X[j], V[j], 1.0 / 30));
    std::sort(nn.begin(), nn.end());
    if (n > 2)
      std::printf("   nearest-neighbour distance: min %.1f median %.1f max %.1f mm\n", 1e3 * nn[0],
                  1e3 * nn[n / 2], 1e3 * nn[n - 1]);
    // position-only vs velocity part
    double pos_only = 0, vel_only = 0;
    size_t cnt = 0;
    for (size_t i = 1; i < n && cnt < 200; ++i, ++cnt) {
      std::vector<float> z(V[i].size(), 0);
      pos_only += db::state_distance(X[i], z, X[i - 1], z, 0);
      vel_only += db::state_distance(z, V[i], z, V[i - 1], 1.0 / 30);
    }
    if (cnt)
      std::printf("   consecutive states: position part %.1f mm, velocity part %.1f mm\n",
                  1e3 * pos_only / cnt, 1e3 * vel_only / cnt);
  }
}
TEST(Probe, Contraction) {
  for (bool tethers : {false, true}) {
    const CharacterScene scene = scene_with(tethers, 3.0);
    const auto pose = clip_pose(scene.clips.front(), 0);
    const std::string path = testing::TempDir() + "/probe_" + std::to_string(tethers) + ".db";
    db::Reader rd;
    db::Error err;
    db::throw_if_error(rd.open(path, &err), err);
    std::vector<db::StoredState> st;
    db::throw_if_error(rd.cloth_states(&st, &err), err);
    codec::DecodeScratch sc;
    const Eigen::Isometry3d fr = character_frame(scene, pose);
    auto load = [&](int64_t id) {
      std::vector<float> x, v;
      db::throw_if_error(rd.read_state(id, &x, &v, sc, &err), err);
      ClothState s;
      s.x.resize(3, x.size() / 3);
      s.v.resize(3, x.size() / 3);
      for (size_t i = 0; i < x.size() / 3; ++i) {
        s.x.col(i) = fr * Vec3(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
        s.v.col(i) = fr.linear() * Vec3(v[3 * i], v[3 * i + 1], v[3 * i + 2]);
      }
      return s;
    };
    std::vector<std::vector<std::vector<JointPose>>> edges = {
        std::vector<std::vector<JointPose>>(12, pose), sway(pose, 0.6, 16)};
    for (int e = 0; e < 2; ++e) {
      std::vector<double> ratios;
      for (size_t i = 0; i + 1 < st.size() && i < 40; ++i) {
        ClothState a = load(st[i].id), b = load(st[i + 1].id);
        const double d0 = db::state_distance(flat(a.x), flat(a.v), flat(b.x), flat(b.v), 1.0 / 30);
        auto sa = make_solver(scene.file.solver, scene.model, scene.file.settings);
        auto sb = make_solver(scene.file.solver, scene.model, scene.file.settings);
        simulate_poses(scene, *sa, edges[e], 30.0, a);
        simulate_poses(scene, *sb, edges[e], 30.0, b);
        const double d1 = db::state_distance(flat(a.x), flat(a.v), flat(b.x), flat(b.v), 1.0 / 30);
        ratios.push_back(d1 / d0);
      }
      std::sort(ratios.begin(), ratios.end());
      std::printf(
          "tethers=%d edge %s: distance after/before over %zu pairs: min %.2f median %.2f max "
          "%.2f\n",
          tethers, e ? "sway" : "hold", ratios.size(), ratios.front(), ratios[ratios.size() / 2],
          ratios.back());
    }
  }
}
