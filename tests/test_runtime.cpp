// The playback runtime (README.md#what-is-in-the-tree): the C API of clothrt on synthetic databases
// laid out as docs/SECONDARY_GRAPH.md says: stored frames played back exactly, interpolation,
// blends without pops (also when interrupted), fallbacks to the nearest state, world space and
// strides, errors with the last good pose, many players on threads, and no allocation per frame.
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <new>
#include <string>
#include <thread>
#include <vector>

#include "clothrt.h"
#include "database/codec/codec.hpp"
#include "database/store/writer.hpp"
#include "runtime/tools/synthetic_db.hpp"
#include "support/allocation_counter.hpp"
#include "support/temp_dir.hpp"

namespace clothdb {
namespace {

namespace fs = std::filesystem;

using test::TempDir;

constexpr uint32_t kSide = 16;  // 256 vertices
constexpr double kRate = 30.0;

// A database, the ids the builder gave its rows, and every clip decoded by the codec directly.
struct Fixture {
  TempDir dir;
  std::string path = dir.file("demo.clothdb");
  synthetic::Spec spec = synthetic::demo_spec(kSide);
  synthetic::Built built;
  std::map<int64_t, std::vector<float>> frames;  // cloth clip id -> decoded frames
  size_t n = 0;                                  // floats per frame

  Fixture() {
    built = synthetic::build(path, spec);
    n = size_t(built.vertices) * 3;
    db::Reader r;
    Error err;
    EXPECT_EQ(r.open(path, &err), Status::Ok) << err.message;
    codec::DecodeScratch scratch;
    std::vector<uint8_t> blob;
    for (const auto& [key, id] : built.clip) {
      EXPECT_EQ(r.clip_blob(id, &blob, &err), Status::Ok);
      EXPECT_EQ(codec::decode_all(blob.data(), blob.size(), frames[id], scratch, &err), Status::Ok);
    }
  }
  const float* frame(int64_t clip, size_t f) const { return frames.at(clip).data() + f * n; }
  size_t frame_count(int64_t clip) const { return frames.at(clip).size() / n; }
  // Largest vertex displacement between consecutive stored frames of a clip.
  double internal_jump(int64_t clip) const {
    double m = 0;
    for (size_t f = 0; f + 1 < frame_count(clip); ++f)
      m = std::max(m, max_displacement(frame(clip, f), frame(clip, f + 1)));
    return m;
  }
  double max_displacement(const float* a, const float* b) const {
    double m = 0;
    for (size_t i = 0; i < n; i += 3) {
      const double dx = a[i] - b[i], dy = a[i + 1] - b[i + 1], dz = a[i + 2] - b[i + 2];
      m = std::max(m, std::sqrt(dx * dx + dy * dy + dz * dz));
    }
    return m;
  }
  // The clip the secondary graph continues with from clip `from` along edge index `edge`.
  int64_t follow(int64_t from, int edge) const {
    db::Reader r;
    Error err;
    EXPECT_EQ(r.open(path, &err), Status::Ok);
    std::vector<db::ClothEdge> edges;
    EXPECT_EQ(r.cloth_edges(&edges, &err), clothdb::Status::Ok);
    for (const db::ClothEdge& e : edges)
      if (e.from_clip == from)
        for (const auto& [key, id] : built.clip)
          if (built.states[size_t(key.first)] == e.to_state && key.second == edge) return id;
    return 0;
  }
};

double max_abs_diff(const float* a, const float* b, size_t n) {
  double m = 0;
  for (size_t i = 0; i < n; ++i) m = std::max(m, double(std::fabs(a[i] - b[i])));
  return m;
}

struct Handles {
  clothrt_db* db = nullptr;
  clothrt_player* player = nullptr;
  ~Handles() {
    clothrt_player_destroy(player);
    clothrt_db_close(db);
  }
};

void open(const Fixture& fx, Handles& h, int threads = 1, size_t cache = 0) {
  clothrt_db_options o;
  clothrt_db_options_init(&o);
  o.prefetch_threads = threads;
  if (cache) o.cache_bytes = cache;
  ASSERT_EQ(clothrt_db_open(fx.path.c_str(), &o, &h.db), CLOTHRT_OK) << clothrt_last_open_errmsg();
  ASSERT_EQ(clothrt_player_create(h.db, &h.player), CLOTHRT_OK);
}

// One played frame: the pose and what the player reported.
struct Played {
  std::vector<float> x;
  clothrt_frame_info info;
  int code;
};

Played play_frame(clothrt_player* p, size_t n, double dt) {
  Played out;
  out.code = clothrt_player_advance(p, dt);
  out.x.resize(n);
  EXPECT_EQ(clothrt_player_get_positions(p, out.x.data(), 12, nullptr), CLOTHRT_OK);
  clothrt_player_info(p, &out.info);
  return out;
}

// A path through the demo graph (edge indices): e0 0->1, e1 1->0, e2 1->1 (loop), e3 0->0 (loop).
const std::vector<int> kPath = {0, 2, 2, 1, 3, 0, 1, 0, 2, 1, 3, 3, 0};

std::vector<Played> play_path(const Fixture& fx, clothrt_player* p, const std::vector<int>& path,
                              double dt) {
  EXPECT_EQ(clothrt_player_start(p, fx.built.primary[size_t(path[0])]), CLOTHRT_OK);
  std::vector<Played> out;
  size_t next = 1;
  if (next < path.size()) {
    EXPECT_EQ(clothrt_player_set_next(p, fx.built.primary[size_t(path[next])]), CLOTHRT_OK)
        << clothrt_player_errmsg(p);
  }
  out.push_back(play_frame(p, fx.n, 0.0));
  while (next < path.size()) {
    out.push_back(play_frame(p, fx.n, dt));
    if (out.back().info.transitions != out[out.size() - 2].info.transitions) {
      ++next;
      if (next < path.size()) {
        EXPECT_EQ(clothrt_player_set_next(p, fx.built.primary[size_t(path[next])]), CLOTHRT_OK)
            << clothrt_player_errmsg(p);
      }
    }
  }
  return out;
}

// Checks the no-pop rule on a played sequence: wherever a transition or a blend happens, the
// jump between consecutive frames is at most the largest jump inside the clips around it.
// Returns the number of frames checked.
int check_no_pop(const Fixture& fx, const std::vector<Played>& played, double slack = 1e-6) {
  int checked = 0;
  for (size_t k = 1; k < played.size(); ++k) {
    const clothrt_frame_info& a = played[k - 1].info;
    const clothrt_frame_info& b = played[k].info;
    if (a.transitions == b.transitions && !b.blending) continue;
    const double bound = std::max(fx.internal_jump(a.cloth_clip), fx.internal_jump(b.cloth_clip));
    const double jump = fx.max_displacement(played[k - 1].x.data(), played[k].x.data());
    EXPECT_LE(jump, bound + slack) << "frame " << k << ": clip " << a.cloth_clip << " -> "
                                   << b.cloth_clip << (b.blending ? " (blending)" : "");
    ++checked;
  }
  return checked;
}

// The player's blend rule, as docs/SECONDARY_GRAPH.md states it, restated here from the file's
// recorded errors (not from the player's state): a blend starts at a transition onto another
// state (the clip's recorded edge blend error > 0, a fallback, or a link) and fades the offset
// linearly over max(blend_frames, min(60, link error / 1 mm)) stored frames, so a link blend
// moves the cloth by at most about 1 mm of link error per frame.
constexpr double kLinkErrorPerFrame = 1e-3;  // m
constexpr double kMaxLinkBlendFrames = 60;

// What the file records about how each clip continues: its edge's blend error and target state,
// and the links (from state, primary clip) -> their blend error.
struct Recorded {
  std::map<int64_t, double> edge_error;                      // clip -> blend error
  std::map<int64_t, int64_t> to_state;                       // clip -> state its edge lands on
  std::map<std::pair<int64_t, int64_t>, double> link_error;  // (state, primary) -> error
};

Recorded recorded(const Fixture& fx) {
  Recorded out;
  db::Reader r;
  Error err;
  EXPECT_EQ(r.open(fx.path, &err), Status::Ok) << err.message;
  std::vector<db::ClothEdge> edges;
  std::vector<db::ClothLink> links;
  EXPECT_EQ(r.cloth_edges(&edges, &err), Status::Ok);
  EXPECT_EQ(r.cloth_links(&links, &err), Status::Ok);
  for (const db::ClothEdge& e : edges) {
    out.edge_error[e.from_clip] = e.blend_error;
    out.to_state[e.from_clip] = e.to_state;
  }
  for (const db::ClothLink& l : links)
    out.link_error[{l.from_state, l.primary_clip}] = l.blend_error;
  return out;
}

// A clip's stored pose at (fractional) frame t, interpolated as the runtime's contract says.
std::vector<double> clip_pose(const Fixture& fx, int64_t clip, double t) {
  const size_t last = fx.frame_count(clip) - 1;
  size_t f0 = size_t(std::clamp(std::floor(t), 0.0, double(last)));
  double a = t - std::floor(t);
  if (f0 >= last) f0 = last, a = 0;
  const size_t f1 = std::min(f0 + 1, last);
  std::vector<double> x(fx.n);
  for (size_t i = 0; i < fx.n; ++i) {
    const double x0 = fx.frame(clip, f0)[i], x1 = fx.frame(clip, f1)[i];
    x[i] = x0 + a * (x1 - x0);
  }
  return x;
}

// RMS over vertices of a - b (the norm the blend error is recorded in).
template <class A, class B>
double rms(const A& a, const B& b, size_t n) {
  double sum = 0;
  for (size_t i = 0; i < n; ++i)
    sum += (double(a[i]) - double(b[i])) * (double(a[i]) - double(b[i]));
  return std::sqrt(sum / double(n / 3));
}

struct BlendReport {
  int frames = 0;       // frame pairs checked (every one of the sequence)
  int blends = 0;       // blends started
  int link_blends = 0;  // of which through a link
  int ended = 0;        // blends seen to end inside a clip (the first frame after checked too)
  double worst = 0;     // largest measured / allowed
};

// Checks EVERY played frame against the blend rule above. The residual b = shown - stored pose
// of the clip being played is the blend's r(t) * offset; between two frames of one clip it may
// change by at most M * dt / span (M: an upper bound of the offset's RMS, measured from the
// stored frames at the transition that started the blend; span from the recorded errors), and
// once the span is over it must be zero. Across a transition the shown pose may move by the
// clips' own motion to and from the node, plus what the old blend fades by then and the new one
// by now (or, with no blend, the gap between the old clip's end and the new clip's start).
BlendReport check_blend_continuity(const Fixture& fx, const std::vector<Played>& played,
                                   double blend_frames, double slack = 2e-6) {
  const Recorded rec = recorded(fx);
  BlendReport out;
  double M = 0, span = 1;  // the blend in progress (M = 0: none)
  double start_t = 0;      // primary frame at which it started (0 for a blend from a transition)
  std::vector<double> prev_b;
  for (size_t k = 0; k < played.size(); ++k) {
    const clothrt_frame_info& b = played[k].info;
    if (b.holding || b.cloth_clip == 0) {
      ADD_FAILURE() << "frame " << k << " holds: this check is for sequences that play";
      return out;
    }
    const std::vector<double> c = clip_pose(fx, b.cloth_clip, b.primary_frame);
    std::vector<double> res(fx.n);
    for (size_t i = 0; i < fx.n; ++i) res[i] = double(played[k].x[i]) - c[i];
    if (k == 0) {
      EXPECT_LE(rms(res, std::vector<double>(fx.n, 0.0), fx.n), slack) << "the first frame";
      prev_b = res;
      continue;
    }
    const clothrt_frame_info& a = played[k - 1].info;
    double measured = 0, allowed = 0;
    if (a.transitions == b.transitions) {
      const double dt = b.primary_frame - a.primary_frame;
      measured = rms(res, prev_b, fx.n);
      allowed = M * dt / span + slack;
      // Over its span the blend has faded out completely, and stays out.
      if (M > 0 && b.primary_frame - start_t >= span) {
        EXPECT_LE(rms(res, std::vector<double>(fx.n, 0.0), fx.n), slack)
            << "frame " << k << ": the blend is still showing " << span << " frames after it began";
        if (a.primary_frame - start_t < span) ++out.ended;
        M = 0;
      }
    } else {
      EXPECT_EQ(b.transitions, a.transitions + 1) << "frame " << k << ": two nodes in one step";
      const int64_t from = a.cloth_clip, to = b.cloth_clip;
      const double end = double(fx.frame_count(from) - 1);
      const std::vector<double> from_end = clip_pose(fx, from, end),
                                to_start = clip_pose(fx, to, 0);
      const double gap = rms(from_end, to_start, fx.n);
      const double motion = rms(from_end, clip_pose(fx, from, a.primary_frame), fx.n) +
                            rms(clip_pose(fx, to, b.primary_frame), to_start, fx.n);
      const double old_fade = M * std::max(0.0, end - a.primary_frame) / span;
      double link = 0;
      if (auto s = rec.to_state.find(from); s != rec.to_state.end())
        if (auto l = rec.link_error.find({s->second, b.primary_clip}); l != rec.link_error.end())
          link = l->second;
      const bool blend =
          blend_frames > 0 && (b.fallback || rec.edge_error.at(from) > 0 || link > 0);
      measured = rms(played[k].x, played[k - 1].x, fx.n);
      // What is left of the blend in progress at the node (by the rule, not the player's word).
      const double r_end = M > 0 ? std::clamp(1 - (end - start_t) / span, 0.0, 1.0) : 0.0;
      if (blend) {
        // The new offset: the pose at the node (old clip's end plus what is left of its blend)
        // minus the new clip's first frame.
        M = gap + M * r_end;
        span = std::max(blend_frames, std::min(kMaxLinkBlendFrames, link / kLinkErrorPerFrame));
        start_t = 0;
        allowed = motion + old_fade + M * b.primary_frame / span + slack;
        ++out.blends;
        out.link_blends += link > 0;
      } else {
        // No new blend: one in progress carries on across the node, on the new clip's clock.
        allowed = motion + gap + old_fade + M * b.primary_frame / span + slack;
        start_t -= end;
        if (r_end <= 0) M = 0;
      }
    }
    out.worst = std::max(out.worst, measured / allowed);
    EXPECT_LE(measured, allowed) << "frame " << k << ": clip " << a.cloth_clip << " -> "
                                 << b.cloth_clip << ", primary frame " << a.primary_frame << " -> "
                                 << b.primary_frame << ", blend span " << span << " frames"
                                 << (b.blending ? " (blending)" : "");
    prev_b = res;
    ++out.frames;
  }
  return out;
}

TEST(Runtime, OpenReportsErrors) {
  TempDir dir;
  clothrt_db* db = nullptr;
  EXPECT_EQ(clothrt_db_open(dir.file("missing.clothdb").c_str(), nullptr, &db), CLOTHRT_ERR_IO);
  EXPECT_EQ(db, nullptr);
  EXPECT_NE(std::string(clothrt_last_open_errmsg()).find("missing.clothdb"), std::string::npos);
  std::ofstream(dir.file("text.clothdb")) << "not a database at all, just some text\n";
  EXPECT_EQ(clothrt_db_open(dir.file("text.clothdb").c_str(), nullptr, &db),
            CLOTHRT_ERR_NOT_CLOTHDB);
  EXPECT_EQ(clothrt_db_open(nullptr, nullptr, &db), CLOTHRT_ERR_INVALID);
  EXPECT_EQ(clothrt_db_open("x", nullptr, nullptr), CLOTHRT_ERR_INVALID);
  // A database with no cloth in it.
  {
    db::Writer w = db::Writer::create(dir.file("empty.clothdb"));
    db::Garment g;
    g.rest_positions = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    g.triangles = {0, 1, 2};
    w.put_garment(g);
  }
  EXPECT_EQ(clothrt_db_open(dir.file("empty.clothdb").c_str(), nullptr, &db),
            CLOTHRT_ERR_NOT_FOUND);
  clothrt_db_close(nullptr);
  clothrt_player_destroy(nullptr);
  EXPECT_STREQ(clothrt_status_name(CLOTHRT_ERR_CORRUPT), "corrupt");
}

TEST(Runtime, GraphQueries) {
  Fixture fx;
  Handles h;
  open(fx, h);
  EXPECT_EQ(clothrt_db_vertex_count(h.db), kSide * kSide);
  EXPECT_EQ(clothrt_db_triangle_count(h.db), 2 * (kSide - 1) * (kSide - 1));
  std::vector<uint32_t> tris(3 * clothrt_db_triangle_count(h.db));
  EXPECT_EQ(clothrt_db_triangles(h.db, tris.data(), tris.size()), CLOTHRT_OK);
  EXPECT_EQ(clothrt_db_triangles(h.db, tris.data(), 2), CLOTHRT_ERR_INVALID);
  ASSERT_EQ(clothrt_db_clip_count(h.db), 4u);
  EXPECT_EQ(clothrt_db_start_clip(h.db), fx.built.primary[0]);
  clothrt_clip_info ci;
  ASSERT_EQ(clothrt_db_clip_info(h.db, 0, &ci), CLOTHRT_OK);
  EXPECT_EQ(ci.frame_count, 40);
  EXPECT_DOUBLE_EQ(ci.frame_rate, kRate);
  EXPECT_EQ(ci.successor_count, 2u);
  EXPECT_TRUE(ci.has_cloth);
  int64_t id = 0;
  EXPECT_EQ(clothrt_db_find_clip(h.db, ci.name, &id), CLOTHRT_OK);
  EXPECT_EQ(id, fx.built.primary[0]);
  EXPECT_EQ(clothrt_db_find_clip(h.db, "no such clip", &id), CLOTHRT_ERR_NOT_FOUND);
  int64_t succ[4];
  size_t count = 0;
  ASSERT_EQ(clothrt_db_successors(h.db, fx.built.primary[0], succ, 4, &count), CLOTHRT_OK);
  ASSERT_EQ(count, 2u);  // the edges leaving node 1: e1 and e2
  EXPECT_EQ(succ[0], fx.built.primary[1]);
  EXPECT_EQ(succ[1], fx.built.primary[2]);
}

TEST(Runtime, CallOrderAndArgumentErrors) {
  Fixture fx;
  Handles h;
  open(fx, h);
  std::vector<float> x(fx.n);
  EXPECT_EQ(clothrt_player_advance(h.player, 0.1), CLOTHRT_ERR_INVALID);
  EXPECT_EQ(clothrt_player_get_positions(h.player, x.data(), 12, nullptr), CLOTHRT_ERR_INVALID);
  EXPECT_EQ(clothrt_player_start(h.player, 987654), CLOTHRT_ERR_NOT_FOUND);
  ASSERT_EQ(clothrt_player_start(h.player, 0), CLOTHRT_OK);
  EXPECT_EQ(clothrt_player_advance(h.player, -1.0), CLOTHRT_ERR_INVALID);
  EXPECT_EQ(clothrt_player_advance(h.player, NAN), CLOTHRT_ERR_INVALID);
  EXPECT_EQ(clothrt_player_get_positions(h.player, x.data(), 8, nullptr), CLOTHRT_ERR_INVALID);
  EXPECT_EQ(clothrt_player_get_positions(h.player, nullptr, 12, nullptr), CLOTHRT_ERR_INVALID);
  // e3 (0 -> 0) does not leave node 1, where e0 ends.
  EXPECT_EQ(clothrt_player_set_next(h.player, fx.built.primary[3]), CLOTHRT_ERR_INVALID);
  EXPECT_NE(std::string(clothrt_player_errmsg(h.player)).find("does not follow"),
            std::string::npos);
  EXPECT_EQ(clothrt_player_set_next(h.player, 987654), CLOTHRT_ERR_NOT_FOUND);
  EXPECT_EQ(clothrt_player_set_blend_frames(h.player, -2), CLOTHRT_ERR_INVALID);
  EXPECT_EQ(clothrt_player_advance(nullptr, 0.1), CLOTHRT_ERR_INVALID);
}

// Frame by frame at the stored rate, the player shows the stored frames of the clips the cloth
// graph prescribes, except while a blend is fading out.
TEST(Runtime, PlaysStoredFramesAlongTheGraph) {
  Fixture fx;
  for (int threads : {0, 1}) {
    Handles h;
    open(fx, h, threads);
    const std::vector<Played> played = play_path(fx, h.player, kPath, 1.0 / kRate);
    int compared = 0, transitions = 0;
    for (size_t k = 0; k < played.size(); ++k) {
      const Played& p = played[k];
      ASSERT_EQ(p.code, CLOTHRT_OK);
      EXPECT_FALSE(p.info.fallback);  // kPath avoids the unexplored pair
      if (k > 0 && p.info.transitions != played[k - 1].info.transitions) {
        ++transitions;
        // The clip the cloth graph continues with.
        const int edge =
            int(std::find(fx.built.primary.begin(), fx.built.primary.end(), p.info.primary_clip) -
                fx.built.primary.begin());
        EXPECT_EQ(p.info.cloth_clip, fx.follow(played[k - 1].info.cloth_clip, edge));
      }
      if (p.info.blending) continue;
      const double f = p.info.primary_frame;
      ASSERT_NEAR(f, std::round(f), 1e-6);
      EXPECT_LE(max_abs_diff(p.x.data(), fx.frame(p.info.cloth_clip, size_t(std::lround(f))), fx.n),
                2e-6)
          << "frame " << k;
      ++compared;
    }
    EXPECT_EQ(transitions, int(kPath.size()) - 1);
    EXPECT_GT(compared, 300);
  }
}

// At any game time step the pose is the linear interpolation of the stored frames around it.
TEST(Runtime, InterpolatesAtArbitraryTimeSteps) {
  Fixture fx;
  Handles h;
  open(fx, h);
  const double dt = 1.0 / 73.0;
  const std::vector<Played> played = play_path(fx, h.player, {0, 2, 1}, dt);
  int compared = 0;
  for (const Played& p : played) {
    if (p.info.blending) continue;
    const double t = p.info.primary_frame;
    const size_t f0 = size_t(std::floor(t));
    const size_t last = fx.frame_count(p.info.cloth_clip) - 1;
    const size_t f1 = std::min(f0 + 1, last);
    const float a = float(t - double(f0));
    std::vector<float> expect(fx.n);
    for (size_t i = 0; i < fx.n; ++i) {
      const float x0 = fx.frame(p.info.cloth_clip, f0)[i], x1 = fx.frame(p.info.cloth_clip, f1)[i];
      expect[i] = x0 + a * (x1 - x0);
    }
    EXPECT_LE(max_abs_diff(p.x.data(), expect.data(), fx.n), 5e-6);
    ++compared;
  }
  EXPECT_GT(compared, 150);
}

// Advance in steps no longer than `step` (shorter than any clip: nothing is passed whole).
void advance_in_steps(clothrt_player* p, double total, double step) {
  while (total > 0) {
    const double dt = std::min(step, total);
    ASSERT_EQ(clothrt_player_advance(p, dt), CLOTHRT_OK) << clothrt_player_errmsg(p);
    total -= dt;
  }
}

// A long step lands where small steps land: the deterministic walk (nothing random, nothing
// named) by skipping whole turns of its cycle, in bounded work whatever dt is.
TEST(Runtime, LongStepLandsWhereSmallStepsLand) {
  Fixture fx;
  Handles ha, hb;
  open(fx, ha, 0);
  open(fx, hb, 0);
  // A step of a few hundred clips, checked against stepping frame by frame.
  const double dt = 500.3;
  ASSERT_EQ(clothrt_player_start(ha.player, fx.built.primary[0]), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_start(hb.player, fx.built.primary[0]), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_advance(ha.player, dt), CLOTHRT_OK) << clothrt_player_errmsg(ha.player);
  advance_in_steps(hb.player, dt, 1.0 / kRate);
  clothrt_frame_info a, b;
  clothrt_player_info(ha.player, &a);
  clothrt_player_info(hb.player, &b);
  EXPECT_EQ(a.primary_clip, b.primary_clip);
  EXPECT_EQ(a.cloth_clip, b.cloth_clip);
  EXPECT_NEAR(a.primary_frame, b.primary_frame, 1e-6 * dt * kRate);
  EXPECT_EQ(a.transitions, b.transitions);
  EXPECT_GT(a.transitions, 100u);
  std::vector<float> xa(fx.n), xb(fx.n);
  ASSERT_EQ(clothrt_player_get_positions(ha.player, xa.data(), 12, nullptr), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_get_positions(hb.player, xb.data(), 12, nullptr), CLOTHRT_OK);
  EXPECT_LE(max_abs_diff(xa.data(), xb.data(), fx.n), 1e-3);
}

TEST(Runtime, StepOfABillionSecondsReturnsAtOnceWithTheRightClipAndFrame) {
  Fixture fx;
  Handles h, ref;
  open(fx, h, 0);
  open(fx, ref, 0);
  // The deterministic walk's period, measured by stepping: the time until the player is back at
  // the start of the same primary and cloth clip.
  ASSERT_EQ(clothrt_player_start(ref.player, fx.built.primary[0]), CLOTHRT_OK);
  clothrt_frame_info start, info;
  clothrt_player_info(ref.player, &start);
  double period = 0;
  uint64_t per_turn = 0;
  for (int k = 0; k < 100; ++k) {
    clothrt_player_info(ref.player, &info);
    double length = 0;
    for (size_t i = 0; i < clothrt_db_clip_count(ref.db); ++i) {
      clothrt_clip_info ci;
      if (clothrt_db_clip_info(ref.db, i, &ci) == CLOTHRT_OK && ci.id == info.primary_clip)
        length = (ci.frame_count - 1) / ci.frame_rate;
    }
    ASSERT_GT(length, 0);
    period += length;
    // Half a frame into the next clip, so rounding cannot leave the player short of the node.
    advance_in_steps(ref.player, length + 0.5 / kRate - info.primary_frame / kRate, 1.0 / kRate);
    clothrt_player_info(ref.player, &info);
    if (info.primary_clip == start.primary_clip && info.cloth_clip == start.cloth_clip) {
      per_turn = info.transitions;
      break;
    }
  }
  ASSERT_GT(per_turn, 0u) << "no cycle found";
  // Where 1e9 s lands: the same place as 1e9 mod period, stepped frame by frame.
  const double big = 1e9;
  const double rest = std::fmod(big, period);
  clothrt_player_destroy(ref.player);
  ASSERT_EQ(clothrt_player_create(ref.db, &ref.player), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_start(ref.player, fx.built.primary[0]), CLOTHRT_OK);
  advance_in_steps(ref.player, rest, 1.0 / kRate);
  clothrt_frame_info want;
  clothrt_player_info(ref.player, &want);

  ASSERT_EQ(clothrt_player_start(h.player, fx.built.primary[0]), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_advance(h.player, big), CLOTHRT_OK) << clothrt_player_errmsg(h.player);
  clothrt_player_info(h.player, &info);
  EXPECT_EQ(info.primary_clip, want.primary_clip);
  EXPECT_EQ(info.cloth_clip, want.cloth_clip);
  EXPECT_NEAR(info.primary_frame, want.primary_frame, 1e-3);
  EXPECT_EQ(info.transitions, uint64_t(std::floor(big / period)) * per_turn + want.transitions);
  // Steps up to the largest double return too, and leave a playable pose.
  for (double huge : {1e300, 1.7e308}) {
    ASSERT_EQ(clothrt_player_advance(h.player, huge), CLOTHRT_OK);
    clothrt_player_info(h.player, &info);
    EXPECT_GE(info.primary_frame, 0.0);
    EXPECT_LE(info.primary_frame, 40.0);
    std::vector<float> x(fx.n);
    ASSERT_EQ(clothrt_player_get_positions(h.player, x.data(), 12, nullptr), CLOTHRT_OK);
    for (float v : x) ASSERT_TRUE(std::isfinite(v));
  }
}

// Random mode: a long step makes the same random choices as small steps (same path), and a step
// far past the walk cap still returns with a clip and a frame inside it.
TEST(Runtime, LongRandomStepMakesTheSameChoicesAsSmallSteps) {
  Fixture fx;
  Handles ha, hb;
  open(fx, ha, 0);
  open(fx, hb, 0);
  for (Handles* h : {&ha, &hb}) {
    ASSERT_EQ(clothrt_player_set_random(h->player, 1, 12345), CLOTHRT_OK);
    ASSERT_EQ(clothrt_player_start(h->player, fx.built.primary[0]), CLOTHRT_OK);
  }
  const double dt = 300.7;
  ASSERT_EQ(clothrt_player_advance(ha.player, dt), CLOTHRT_OK) << clothrt_player_errmsg(ha.player);
  advance_in_steps(hb.player, dt, 1.0 / kRate);
  clothrt_frame_info a, b;
  clothrt_player_info(ha.player, &a);
  clothrt_player_info(hb.player, &b);
  EXPECT_EQ(a.primary_clip, b.primary_clip);
  EXPECT_EQ(a.cloth_clip, b.cloth_clip);
  EXPECT_EQ(a.transitions, b.transitions);
  EXPECT_EQ(a.fallbacks, b.fallbacks);
  EXPECT_NEAR(a.primary_frame, b.primary_frame, 1e-4);
  ASSERT_EQ(clothrt_player_advance(ha.player, 1e9), CLOTHRT_OK);
  clothrt_player_info(ha.player, &a);
  EXPECT_GT(a.transitions, b.transitions + 4000);  // the walk cap: 4,096 nodes
  EXPECT_GE(a.primary_frame, 0.0);
  EXPECT_LE(a.primary_frame, 40.0);
  EXPECT_NE(a.cloth_clip, 0);
}

TEST(Runtime, NoPopAtTransitions) {
  Fixture fx;
  Handles h;
  open(fx, h);
  ASSERT_EQ(clothrt_player_set_blend_frames(h.player, 8), CLOTHRT_OK);
  const std::vector<Played> played = play_path(fx, h.player, kPath, 1.0 / kRate);
  int blends = 0;
  for (size_t k = 1; k < played.size(); ++k)
    blends += played[k].info.blending && !played[k - 1].info.blending;
  EXPECT_GE(blends, 3);
  EXPECT_GT(check_no_pop(fx, played), 20);
  // Every frame, the first after each blend ends included.
  const BlendReport report = check_blend_continuity(fx, played, 8);
  EXPECT_EQ(report.frames, int(played.size()) - 1);
  EXPECT_GE(report.blends, 3);
  EXPECT_GE(report.ended, 3);

  // The same path snapping instead of blending pops: the check above has teeth.
  Handles snap;
  open(fx, snap);
  ASSERT_EQ(clothrt_player_set_blend_frames(snap.player, 0), CLOTHRT_OK);
  const std::vector<Played> snapped = play_path(fx, snap.player, kPath, 1.0 / kRate);
  double worst_ratio = 0;
  for (size_t k = 1; k < snapped.size(); ++k) {
    const clothrt_frame_info& a = snapped[k - 1].info;
    const clothrt_frame_info& b = snapped[k].info;
    if (a.transitions == b.transitions) continue;
    const double bound = std::max(fx.internal_jump(a.cloth_clip), fx.internal_jump(b.cloth_clip));
    worst_ratio = std::max(
        worst_ratio, fx.max_displacement(snapped[k - 1].x.data(), snapped[k].x.data()) / bound);
  }
  EXPECT_GT(worst_ratio, 1.0);
}

// Blends longer than the clips: every transition interrupts the blend before it, and the pose
// still never jumps.
TEST(Runtime, InterruptedBlendStaysContinuous) {
  Fixture fx;
  for (double dt : {1.0 / kRate, 1.0 / 57.0}) {
    Handles h;
    open(fx, h);
    ASSERT_EQ(clothrt_player_set_blend_frames(h.player, 50), CLOTHRT_OK);
    const std::vector<Played> played = play_path(fx, h.player, kPath, dt);
    EXPECT_GE(played.back().info.interrupted_blends, 3u);
    // At the finer step the clips' own jumps (per stored frame) overstate the motion per game
    // frame, which makes the check stricter, not looser.
    EXPECT_GT(check_no_pop(fx, played), 50);
    const BlendReport report = check_blend_continuity(fx, played, 50);
    EXPECT_EQ(report.frames, int(played.size()) - 1);
    EXPECT_GE(report.blends, 3);
  }
}

// A link (a dead end closed to the clip of another state, as a budget-limited precompute leaves
// it) blends over its recorded error / 1 mm frames: on the unexplored pair (state 4 along e2),
// linked to state 3's clip along e2 with their distance (about 5 cm) as its error, the cloth
// moves by at most about 1 mm of that error per frame, not error / blend_frames.
TEST(Runtime, LinkBlendsOverItsErrorPerMillimetre) {
  Fixture fx;
  const int64_t into = fx.built.clip.at({1, 0});  // ends at state 4 (node 1, local 1)
  ASSERT_EQ(fx.built.clip.count({4, 2}), 0u);
  double error = 0;
  {
    db::Reader r;
    Error err;
    ASSERT_EQ(r.open(fx.path, &err), Status::Ok);
    codec::DecodeScratch scratch;
    std::vector<float> x4, v4, x3, v3;
    ASSERT_EQ(r.read_state(fx.built.states[4], &x4, &v4, scratch, &err), Status::Ok);
    ASSERT_EQ(r.read_state(fx.built.states[3], &x3, &v3, scratch, &err), Status::Ok);
    error = synthetic::rms_distance(x4.data(), x3.data(), x4.size());
  }
  ASSERT_GT(error, 0.02);  // so that error / 1 mm is well above blend_frames
  {
    db::Writer w = db::Writer::open(fx.path);
    db::ClothLink link;
    link.from_state = fx.built.states[4];
    link.primary_clip = fx.built.primary[2];
    link.to_clip = fx.built.clip.at({3, 2});
    link.blend_error = error;
    w.add_cloth_link(link);
  }
  Handles h;
  open(fx, h);
  ASSERT_EQ(clothrt_player_set_blend_frames(h.player, 8), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_start_cloth_clip(h.player, into), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_set_next(h.player, fx.built.primary[2]), CLOTHRT_OK);
  std::vector<Played> played{play_frame(h.player, fx.n, 0)};
  // Into the linked clip and on around the loop, past the end of the link's blend.
  while (played.size() < 150) {
    played.push_back(play_frame(h.player, fx.n, 1.0 / kRate));
    ASSERT_EQ(played.back().code, CLOTHRT_OK);
    if (played.back().info.next_clip == 0) {
      ASSERT_EQ(clothrt_player_set_next(h.player, fx.built.primary[2]), CLOTHRT_OK);
    }
  }
  bool linked = false;
  for (const Played& p : played) {
    EXPECT_FALSE(p.info.fallback);
    linked |= p.info.cloth_clip == fx.built.clip.at({3, 2});
  }
  EXPECT_TRUE(linked);
  const BlendReport report = check_blend_continuity(fx, played, 8);
  EXPECT_EQ(report.frames, int(played.size()) - 1);
  EXPECT_GE(report.link_blends, 1);
}

// Nearest state by the distance of docs/SECONDARY_GRAPH.md (velocities are at rest here).
int nearest_state(const Fixture& fx, int from_state, const std::vector<int>& candidates) {
  db::Reader r;
  Error err;
  EXPECT_EQ(r.open(fx.path, &err), Status::Ok);
  codec::DecodeScratch scratch;
  std::vector<float> x, v, y, w;
  EXPECT_EQ(r.read_state(fx.built.states[size_t(from_state)], &x, &v, scratch, &err), Status::Ok);
  int best = -1;
  double best_d = 1e30;
  for (int c : candidates) {
    EXPECT_EQ(r.read_state(fx.built.states[size_t(c)], &y, &w, scratch, &err), Status::Ok);
    const double d = synthetic::rms_distance(x.data(), y.data(), x.size());
    if (d < best_d) {
      best_d = d;
      best = c;
    }
  }
  return best;
}

TEST(Runtime, FallsBackToNearestStateForUnexploredTransition) {
  Fixture fx;
  // Clip (state 1, e0) ends at state 4 (node 1, local 1), and (state 4, e2) was never explored.
  const int64_t into = fx.built.clip.at({1, 0});
  ASSERT_EQ(fx.built.clip.count({4, 2}), 0u);
  const int expect_state = nearest_state(fx, 4, {3, 5});
  for (int threads : {0, 1}) {
    Handles h;
    open(fx, h, threads);
    ASSERT_EQ(clothrt_player_set_blend_frames(h.player, 12), CLOTHRT_OK);
    ASSERT_EQ(clothrt_player_start_cloth_clip(h.player, into), CLOTHRT_OK);
    ASSERT_EQ(clothrt_player_set_next(h.player, fx.built.primary[2]), CLOTHRT_OK);
    std::vector<Played> played{play_frame(h.player, fx.n, 0)};
    while (played.back().info.transitions == 0)
      played.push_back(play_frame(h.player, fx.n, 1.0 / kRate));
    for (int i = 0; i < 20; ++i) played.push_back(play_frame(h.player, fx.n, 1.0 / kRate));
    const clothrt_frame_info& info = played.back().info;
    EXPECT_TRUE(info.fallback);
    EXPECT_EQ(info.fallbacks, 1u);
    EXPECT_EQ(info.primary_clip, fx.built.primary[2]);
    EXPECT_EQ(info.cloth_state, fx.built.states[size_t(expect_state)]);
    EXPECT_EQ(info.cloth_clip, fx.built.clip.at({expect_state, 2}));
    for (const Played& p : played) EXPECT_EQ(p.code, CLOTHRT_OK);
    EXPECT_GT(check_no_pop(fx, played), 5);
    EXPECT_GE(check_blend_continuity(fx, played, 12).blends, 1);
    clothrt_stats stats;
    ASSERT_EQ(clothrt_db_stats(h.db, &stats), CLOTHRT_OK);
    // This one, and the prefetch of the next node's unexplored pair (s5 along e2 ends at s4).
    EXPECT_GE(stats.fallbacks_resolved, 1u);
  }
}

TEST(Runtime, WorldSpaceWithStride) {
  Fixture fx;
  Handles h;
  open(fx, h);
  ASSERT_EQ(clothrt_player_start(h.player, 0), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_advance(h.player, 0.37), CLOTHRT_OK);
  std::vector<float> local(fx.n);
  ASSERT_EQ(clothrt_player_get_positions(h.player, local.data(), 12, nullptr), CLOTHRT_OK);
  // Rotation by 0.7 rad about +y (the heading) and a translation, column-major.
  const float c = std::cos(0.7f), s = std::sin(0.7f);
  const float m[16] = {c, 0, -s, 0, 0, 1, 0, 0, s, 0, c, 0, 3.0f, 0.1f, -2.0f, 1};
  const size_t stride = 8;  // floats: position + 5 floats the renderer owns
  const size_t vertices = fx.n / 3;
  std::vector<float> vb(vertices * stride, -123.0f);
  ASSERT_EQ(clothrt_player_get_positions(h.player, vb.data(), stride * 4, m), CLOTHRT_OK);
  std::vector<float> plain(vertices * stride, -123.0f);
  ASSERT_EQ(clothrt_player_get_positions(h.player, plain.data(), stride * 4, nullptr), CLOTHRT_OK);
  for (size_t v = 0; v < vertices; ++v) {
    const float x = local[3 * v], y = local[3 * v + 1], z = local[3 * v + 2];
    EXPECT_NEAR(vb[v * stride], c * x + s * z + 3.0f, 1e-5);
    EXPECT_NEAR(vb[v * stride + 1], y + 0.1f, 1e-5);
    EXPECT_NEAR(vb[v * stride + 2], -s * x + c * z - 2.0f, 1e-5);
    for (size_t k = 0; k < 3; ++k) EXPECT_EQ(plain[v * stride + k], local[3 * v + k]);
    for (size_t k = 3; k < stride; ++k) {
      EXPECT_EQ(vb[v * stride + k], -123.0f);
      EXPECT_EQ(plain[v * stride + k], -123.0f);
    }
  }
}

// Replaces a clip's stored frames with `blob` directly in SQLite (as disk damage would).
void overwrite_blob(const std::string& path, int64_t clip, const std::vector<uint8_t>& blob) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  sqlite3_stmt* st = nullptr;
  ASSERT_EQ(
      sqlite3_prepare_v2(db, "UPDATE cloth_clip SET frames = ? WHERE id = ?", -1, &st, nullptr),
      SQLITE_OK);
  sqlite3_bind_blob(st, 1, blob.data(), int(blob.size()), SQLITE_TRANSIENT);
  sqlite3_bind_int64(st, 2, clip);
  EXPECT_EQ(sqlite3_step(st), SQLITE_DONE);
  sqlite3_finalize(st);
  sqlite3_close(db);
}

std::vector<uint8_t> read_blob(const std::string& path, int64_t clip) {
  db::Reader r;
  Error err;
  EXPECT_EQ(r.open(path, &err), Status::Ok);
  std::vector<uint8_t> blob;
  EXPECT_EQ(r.clip_blob(clip, &blob, &err), Status::Ok);
  return blob;
}

void exec(const std::string& path, const std::string& sql) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  EXPECT_EQ(sqlite3_exec(db, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(db);
}

// Plays e0 then e2 into a damaged clip: the transition reports the error, the pose stays the last
// good one (the end of the clip before) while the character moves on, and the player recovers at
// the next node.
void expect_error_and_last_good_pose(Fixture& fx, int threads, int expected_code) {
  Handles h;
  open(fx, h, threads);
  ASSERT_EQ(clothrt_player_set_blend_frames(h.player, 0), CLOTHRT_OK);
  const int64_t first = fx.built.clip.at({0, 0});  // ends at state 3 (node 1, local 0)
  ASSERT_EQ(clothrt_player_start_cloth_clip(h.player, first), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_set_next(h.player, fx.built.primary[2]), CLOTHRT_OK);
  std::vector<Played> played{play_frame(h.player, fx.n, 0)};
  while (played.back().info.transitions == 0)
    played.push_back(play_frame(h.player, fx.n, 1.0 / kRate));
  const Played& failed = played.back();
  EXPECT_EQ(failed.code, expected_code);
  EXPECT_TRUE(failed.info.holding);
  EXPECT_EQ(failed.info.cloth_clip, 0);
  EXPECT_EQ(failed.info.primary_clip, fx.built.primary[2]);
  // The message names the file and the damaged clip (`play` showed neither; docs/GUIDE.md#limits).
  const std::string msg = clothrt_player_errmsg(h.player);
  EXPECT_NE(msg.find(fx.path + ": cloth clip " + std::to_string(fx.built.clip.at({3, 2}))),
            std::string::npos)
      << msg;
  const float* last_good = fx.frame(first, fx.frame_count(first) - 1);
  EXPECT_LE(max_abs_diff(failed.x.data(), last_good, fx.n), 2e-6);
  // Holding while e2 plays on.
  ASSERT_EQ(clothrt_player_set_next(h.player, fx.built.primary[1]), CLOTHRT_OK);
  for (int i = 0; i < 10; ++i) {
    const Played p = play_frame(h.player, fx.n, 1.0 / kRate);
    EXPECT_EQ(p.code, CLOTHRT_OK);
    EXPECT_TRUE(p.info.holding);
    EXPECT_EQ(p.x, failed.x);
  }
  // At the next node it restarts from the first state with cloth along e1, blending from the
  // held pose.
  ASSERT_EQ(clothrt_player_set_blend_frames(h.player, 8), CLOTHRT_OK);
  Played p = play_frame(h.player, fx.n, 1.0 / kRate);
  while (p.info.transitions == failed.info.transitions) p = play_frame(h.player, fx.n, 1.0 / kRate);
  EXPECT_EQ(p.code, CLOTHRT_OK);
  EXPECT_FALSE(p.info.holding);
  EXPECT_TRUE(p.info.fallback);
  EXPECT_EQ(p.info.primary_clip, fx.built.primary[1]);
  EXPECT_EQ(p.info.cloth_clip, fx.built.clip.at({3, 1}));
  for (float v : p.x) ASSERT_TRUE(std::isfinite(v));
}

TEST(Runtime, CorruptClipGivesErrorAndLastGoodPose) {
  Fixture fx;
  const int64_t victim = fx.built.clip.at({3, 2});  // state 3 along the loop e2
  std::vector<uint8_t> blob = read_blob(fx.path, victim);
  blob[blob.size() - 5] ^= 0x5a;  // inside the compressed data: a chunk checksum fails
  overwrite_blob(fx.path, victim, blob);
  for (int threads : {0, 1}) expect_error_and_last_good_pose(fx, threads, CLOTHRT_ERR_CORRUPT);
}

TEST(Runtime, TruncatedClipGivesError) {
  Fixture fx;
  const int64_t victim = fx.built.clip.at({3, 2});
  std::vector<uint8_t> blob = read_blob(fx.path, victim);
  blob.resize(blob.size() / 2);
  overwrite_blob(fx.path, victim, blob);
  expect_error_and_last_good_pose(fx, 1, CLOTHRT_ERR_CORRUPT);
}

TEST(Runtime, ClipDeletedAfterOpenGivesNotFound) {
  Fixture fx;
  const int64_t victim = fx.built.clip.at({3, 2});
  Handles keep;  // opened before the damage: its graph still lists the clip
  open(fx, keep, 0);
  Handles h;
  open(fx, h, 0);
  exec(fx.path, "DELETE FROM cloth_clip WHERE id = " + std::to_string(victim));
  ASSERT_EQ(clothrt_player_set_blend_frames(h.player, 0), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_start_cloth_clip(h.player, fx.built.clip.at({0, 0})), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_set_next(h.player, fx.built.primary[2]), CLOTHRT_OK);
  int code = CLOTHRT_OK;
  clothrt_frame_info info{};
  while (info.transitions == 0) {
    code = clothrt_player_advance(h.player, 1.0 / kRate);
    clothrt_player_info(h.player, &info);
  }
  EXPECT_EQ(code, CLOTHRT_ERR_NOT_FOUND);
  EXPECT_TRUE(info.holding);
}

// Random bytes over a whole clip and a damaged cloth edge must never crash: every frame returns a
// code and finite positions.
TEST(Runtime, DamagedDataNeverCrashes) {
  Fixture fx;
  std::vector<uint8_t> noise(4000);
  uint64_t s = 7;
  for (uint8_t& b : noise) b = uint8_t((s = s * 6364136223846793005ull + 1) >> 56);
  overwrite_blob(fx.path, fx.built.clip.at({0, 0}), noise);
  std::vector<uint8_t> blob = read_blob(fx.path, fx.built.clip.at({3, 1}));
  std::fill(blob.begin() + 8, blob.begin() + 24, uint8_t(0xff));  // header counts
  codec::detail::reseal(blob.data(), blob.size());
  overwrite_blob(fx.path, fx.built.clip.at({3, 1}), blob);
  Handles h;
  open(fx, h, 1);
  ASSERT_EQ(clothrt_player_set_random(h.player, 1, 99), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_start_cloth_clip(h.player, fx.built.clip.at({1, 0})), CLOTHRT_OK);
  int errors = 0;
  for (int f = 0; f < 30 * 60; ++f) {
    const Played p = play_frame(h.player, fx.n, 1.0 / kRate);
    errors += p.code != CLOTHRT_OK;
    for (float v : p.x) ASSERT_TRUE(std::isfinite(v));
  }
  EXPECT_GT(errors, 0);
}

// Many players on threads sharing one database with a cache far smaller than the clips: the poses
// are exactly those of the same random paths played one at a time with everything cached.
TEST(Runtime, PlayersOnThreadsShareOneDatabase) {
  Fixture fx;
  constexpr int kPlayers = 8, kThreads = 4, kFrames = 600;
  auto run = [&](clothrt_db* db, int p) {
    clothrt_player* player = nullptr;
    EXPECT_EQ(clothrt_player_create(db, &player), CLOTHRT_OK);
    clothrt_player_set_random(player, 1, uint64_t(1000 + p));
    clothrt_player_set_blend_frames(player, 6);
    EXPECT_EQ(clothrt_player_start(player, 0), CLOTHRT_OK);
    std::vector<float> x(fx.n);
    double hash = 0;
    for (int f = 0; f < kFrames; ++f) {
      EXPECT_EQ(clothrt_player_advance(player, 1.0 / (40 + p)), CLOTHRT_OK);
      EXPECT_EQ(clothrt_player_get_positions(player, x.data(), 12, nullptr), CLOTHRT_OK);
      for (size_t i = 0; i < fx.n; i += 37) hash += x[i] * double(f % 13 + 1);
    }
    clothrt_player_destroy(player);
    return hash;
  };
  std::vector<double> expect(kPlayers);
  {
    clothrt_db* db = nullptr;
    ASSERT_EQ(clothrt_db_open(fx.path.c_str(), nullptr, &db), CLOTHRT_OK);
    for (int p = 0; p < kPlayers; ++p) expect[size_t(p)] = run(db, p);
    clothrt_db_close(db);
  }
  for (int threads : {0, 2}) {
    clothrt_db_options o;
    clothrt_db_options_init(&o);
    o.prefetch_threads = threads;
    o.cache_bytes = 1;  // everything not pinned is evicted at once
    clothrt_db* db = nullptr;
    ASSERT_EQ(clothrt_db_open(fx.path.c_str(), &o, &db), CLOTHRT_OK);
    std::vector<double> got(kPlayers);
    std::vector<std::thread> pool;
    for (int t = 0; t < kThreads; ++t)
      pool.emplace_back([&, t] {
        for (int p = t; p < kPlayers; p += kThreads) got[size_t(p)] = run(db, p);
      });
    for (std::thread& t : pool) t.join();
    for (int p = 0; p < kPlayers; ++p) EXPECT_EQ(got[size_t(p)], expect[size_t(p)]) << p;
    clothrt_stats stats;
    clothrt_db_stats(db, &stats);
    EXPECT_GT(stats.clip_evictions, 0u);
    EXPECT_EQ(stats.load_failures, 0u);
    clothrt_db_close(db);
  }
}

TEST(Runtime, NoAllocationPerFrameAfterWarmUp) {
  Fixture fx;
  for (int threads : {0, 1}) {
    Handles h;
    open(fx, h, threads);
    clothrt_db_set_timing(h.db, 1);
    ASSERT_EQ(clothrt_player_set_random(h.player, 1, 5), CLOTHRT_OK);
    ASSERT_EQ(clothrt_player_start(h.player, 0), CLOTHRT_OK);
    std::vector<float> x(fx.n * 2);
    const float m[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 1, 2, 3, 1};
    clothrt_frame_info info;
    auto frames = [&](int count) {
      for (int f = 0; f < count; ++f) {
        EXPECT_EQ(clothrt_player_advance(h.player, 1.0 / 60), CLOTHRT_OK);
        EXPECT_EQ(clothrt_player_get_positions(h.player, x.data(), 24, f % 2 ? m : nullptr),
                  CLOTHRT_OK);
        clothrt_player_info(h.player, &info);
      }
    };
    // Warm up until the random path has decoded every clip of the graph.
    clothrt_stats before;
    for (int minute = 0; minute < 30; ++minute) {
      frames(60 * 60);
      clothrt_db_stats(h.db, &before);
      if (before.clip_loads == fx.built.clip.size()) break;
    }
    ASSERT_EQ(before.clip_loads, fx.built.clip.size());
    const uint64_t allocations = g_allocations.load();
    frames(60 * 30);
    EXPECT_EQ(g_allocations.load() - allocations, 0u);
    clothrt_stats after;
    clothrt_db_stats(h.db, &after);
    EXPECT_EQ(after.clip_loads, before.clip_loads);
    EXPECT_EQ(after.fallbacks_resolved, before.fallbacks_resolved);
    EXPECT_GT(after.frames_sampled, before.frames_sampled);
    EXPECT_GT(info.transitions, 20u);
  }
}

TEST(Runtime, StatsAndMemory) {
  Fixture fx;
  Handles h;
  open(fx, h, 1, size_t(8) << 20);
  clothrt_db_set_timing(h.db, 1);
  ASSERT_EQ(clothrt_player_set_random(h.player, 1, 11), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_start(h.player, 0), CLOTHRT_OK);
  std::vector<float> x(fx.n);
  for (int f = 0; f < 600; ++f) {
    ASSERT_EQ(clothrt_player_advance(h.player, 1.0 / kRate), CLOTHRT_OK);
    ASSERT_EQ(clothrt_player_get_positions(h.player, x.data(), 12, nullptr), CLOTHRT_OK);
  }
  clothrt_stats s;
  ASSERT_EQ(clothrt_db_stats(h.db, &s), CLOTHRT_OK);
  EXPECT_GT(s.clip_loads, 2u);
  EXPECT_GT(s.cache_bytes, 0u);
  EXPECT_LE(s.cache_bytes, s.cache_cap);
  EXPECT_EQ(s.cache_cap, size_t(8) << 20);
  EXPECT_GT(s.metadata_bytes, 0u);
  EXPECT_GT(s.sqlite_ns, 0u);
  EXPECT_GT(s.decode_ns, 0u);
  EXPECT_GT(s.sample_ns, 0u);
  EXPECT_EQ(s.frames_sampled, 600u);
  // Decoded clips are kept as 16-bit integers: 6 bytes per vertex and frame.
  EXPECT_LE(s.cache_bytes, s.clips_cached * size_t(40) * fx.n * 2);
  EXPECT_GE(clothrt_player_memory(h.player), 2 * fx.n * sizeof(float));
}

}  // namespace
}  // namespace clothdb
