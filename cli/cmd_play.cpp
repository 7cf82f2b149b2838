// `clothdb play FILE`: plays a path through the motion graph with the runtime library (clothrt)
// and writes the cloth for Blender plus PNG previews; `clothdb bench runtime FILE`: per-frame cost
// of playback for one and for many players, memory, and where the time goes
// (docs/RESULTS.md#runtime-playback-cost-and-memory).
#include <unistd.h>
#include <zstd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "cli_util.hpp"
#include "clothrt.h"
#include "commands.hpp"
#include "compress/recode.hpp"
#include "database/codec/codec.hpp"
#include "database/store/writer.hpp"
#include "exchange/body_mesh.hpp"
#include "exchange/point_cache.hpp"
#include "explore/explorer.hpp"
#include "quality/clip_quality.hpp"
#include "render/preview.hpp"
#include "report/output.hpp"
#include "report/stats.hpp"
#include "runtime/tools/synthetic_db.hpp"

namespace clothdb::cli {

namespace {

using Clock = std::chrono::steady_clock;

// Owns a database handle and its players; throws with the library's message on failure.
struct Runtime {
  clothrt_db* db = nullptr;
  std::vector<clothrt_player*> players;
  Runtime(const std::string& path, const clothrt_db_options& options) {
    const int rc = clothrt_db_open(path.c_str(), &options, &db);
    if (rc != CLOTHRT_OK)
      throw std::runtime_error(std::string(clothrt_last_open_errmsg()) + " (" +
                               clothrt_status_name(rc) + ")");
  }
  ~Runtime() {
    for (clothrt_player* p : players) clothrt_player_destroy(p);
    clothrt_db_close(db);
  }
  Runtime(const Runtime&) = delete;
  Runtime& operator=(const Runtime&) = delete;
  clothrt_player* add_player() {
    clothrt_player* p = nullptr;
    check(clothrt_player_create(db, &p), "creating a player");
    players.push_back(p);
    return p;
  }
  void check(int rc, const char* what, clothrt_player* p = nullptr) const {
    if (rc == CLOTHRT_OK) return;
    throw std::runtime_error(std::string(what) + ": " +
                             (p ? clothrt_player_errmsg(p) : clothrt_db_errmsg(db)));
  }
  int64_t clip_id(const std::string& token) const {
    int64_t id = 0;
    if (clothrt_db_find_clip(db, token.c_str(), &id) == CLOTHRT_OK) return id;
    char* end = nullptr;
    const long long v = std::strtoll(token.c_str(), &end, 10);
    if (end && *end == '\0' && !token.empty())
      for (size_t i = 0; i < clothrt_db_clip_count(db); ++i) {
        clothrt_clip_info ci;
        if (clothrt_db_clip_info(db, i, &ci) == CLOTHRT_OK && ci.id == v) return v;
      }
    throw std::runtime_error("no primary clip named or numbered '" + token + "'");
  }
};

struct Summary {
  double median = 0, p99 = 0, mean = 0;
};

Summary summarise(std::vector<double> us) {
  Summary s;
  if (us.empty()) return s;
  double sum = 0;
  for (double v : us) sum += v;
  s.mean = sum / double(us.size());
  s.median = report::median(us);
  s.p99 = report::percentile(std::move(us), 0.99);
  return s;
}

double us_since(Clock::time_point t) {
  return std::chrono::duration<double, std::micro>(Clock::now() - t).count();
}

std::vector<int64_t> cloth_clip_ids(const std::string& path) {
  db::Reader r;
  Error err;
  if (r.open(path, &err) != Status::Ok) throw std::runtime_error(err.message);
  std::vector<db::ClothClip> clips;
  if (r.cloth_clips(&clips, &err) != Status::Ok) throw std::runtime_error(err.message);
  std::vector<int64_t> ids;
  for (const db::ClothClip& c : clips) ids.push_back(c.id);
  return ids;
}

// ---- clothdb play -----------------------------------------------------------------------------

struct PlayArgs {
  std::string file, path = "random", out;
  std::string scene;          // scene file to rebuild the body from; empty: the database's
  std::string view = "auto";  // preview camera: front, back, side; auto: the garment's
  double seconds = 10, fps = 0, blend_frames = 8;
  uint64_t seed = 1;
  int preview_every = 30, width = 480, height = 360;
};

// Limits of `play`, checked before anything is allocated or written: the whole clip is held in
// memory (PC2 writes it in one piece), so the frame count times the garment size is capped.
constexpr double kMaxPlaySeconds = 3600;
constexpr double kMaxPlayFps = 1000;
constexpr size_t kMaxPlayBytes = size_t(2) << 30;  // positions held for the PC2, 2 GiB
constexpr int kMaxPreviewSide = 8192;

void validate_play(const PlayArgs& a) {
  auto bad = [](const std::string& what) { throw std::invalid_argument(what); };
  if (!std::isfinite(a.seconds) || a.seconds < 0 || a.seconds > kMaxPlaySeconds)
    bad("--seconds " + fmt_g(a.seconds) + ": expected a number of seconds in [0, " +
        fmt_g(kMaxPlaySeconds) + "] (0: to the end of --path)");
  if (a.path == "random" && !(a.seconds > 0))
    bad("--path random needs --seconds > 0 (it never ends by itself)");
  if (!std::isfinite(a.fps) || a.fps < 0 || a.fps > kMaxPlayFps)
    bad("--fps " + fmt_g(a.fps) + ": expected a frame rate in (0, " + fmt_g(kMaxPlayFps) +
        "] Hz, or 0 for the database's");
  if (!std::isfinite(a.blend_frames) || a.blend_frames < 0 || a.blend_frames > 1e6)
    bad("--blend-frames " + fmt_g(a.blend_frames) + ": expected a number of frames in [0, 1e6]");
  if (a.preview_every < 0) bad("--preview-every must be >= 0 (0: no previews)");
  if (a.view != "auto") try {
      parse_preview_view(a.view);
    } catch (const std::invalid_argument& e) {
      bad(std::string("--view: ") + e.what() + " or auto");
    }
  if (a.width < 16 || a.width > kMaxPreviewSide || a.height < 16 || a.height > kMaxPreviewSide)
    bad("--width " + std::to_string(a.width) + " --height " + std::to_string(a.height) +
        ": preview sides must be in [16, " + std::to_string(kMaxPreviewSide) + "] pixels");
}

void run_play(const PlayArgs& a) {
  validate_play(a);
  clothrt_db_options options;
  clothrt_db_options_init(&options);
  Runtime rt(a.file, options);
  clothrt_player* p = rt.add_player();
  rt.check(clothrt_player_set_blend_frames(p, a.blend_frames), "--blend-frames", p);
  const bool random = a.path == "random";
  std::vector<int64_t> path;
  if (!random)
    for (const std::string& token : split_list(a.path)) path.push_back(rt.clip_id(token));
  if (!random && path.empty()) throw std::runtime_error("--path names no clips");
  rt.check(clothrt_player_set_random(p, random, a.seed), "random mode", p);
  rt.check(clothrt_player_start(p, random ? 0 : path[0]), "start", p);
  size_t next = 1;
  if (!random && next < path.size()) rt.check(clothrt_player_set_next(p, path[next]), "path", p);

  clothrt_clip_info first;
  rt.check(clothrt_db_clip_info(rt.db, 0, &first), "clip info");
  const double fps = a.fps > 0 ? a.fps : first.frame_rate;
  if (!(fps > 0) || !std::isfinite(fps) || fps > kMaxPlayFps)
    throw std::runtime_error(a.file + ": primary clip " + std::to_string(first.id) +
                             " has frame rate " + fmt_g(first.frame_rate) + "; give --fps in (0, " +
                             fmt_g(kMaxPlayFps) + "]");
  const uint32_t vertices = clothrt_db_vertex_count(rt.db);
  const size_t n = size_t(vertices) * 3;
  // Every frame is kept for the PC2: cap the frames before allocating any of them.
  const size_t max_kept = std::max<size_t>(1, kMaxPlayBytes / (n * sizeof(float)));
  const double asked = a.seconds * fps + 1;
  if (a.seconds > 0 && asked > double(max_kept))
    throw std::invalid_argument("--seconds " + fmt_g(a.seconds) + " at " + fmt_g(fps) + " fps is " +
                                fmt_g(asked) + " frames of " + std::to_string(vertices) +
                                " vertices; at most " + std::to_string(max_kept) + " frames (" +
                                std::to_string(kMaxPlayBytes >> 20) +
                                " MiB) fit: lower --seconds or --fps");
  std::vector<uint32_t> tri(size_t(clothrt_db_triangle_count(rt.db)) * 3);
  rt.check(clothrt_db_triangles(rt.db, tri.data(), tri.size()), "triangles");

  PointCache pc;
  pc.vertex_count = int(vertices);
  std::ostringstream csv;
  csv << "frame,time_s,primary_clip,primary_frame,cloth_clip,cloth_state,blending,blend_weight,"
         "fallback,holding,status\n";
  std::vector<float> x(n);
  std::vector<std::pair<int64_t, double>> primary;  // per frame: primary clip and frame
  clothrt_frame_info info{};
  int errors = 0;
  const long max_frames = a.seconds > 0 ? long(std::lround(a.seconds * fps)) + 1 : 0;
  for (long f = 0;; ++f) {
    if (max_frames && f >= max_frames) break;
    if (size_t(f) >= max_kept)
      throw std::runtime_error("--path plays more than " + std::to_string(max_kept) + " frames (" +
                               std::to_string(kMaxPlayBytes >> 20) +
                               " MiB of positions): give --seconds or a lower --fps");
    int rc = CLOTHRT_OK;
    if (f > 0) {
      const uint64_t before = info.transitions;
      rc = clothrt_player_advance(p, 1.0 / fps);
      clothrt_player_info(p, &info);
      if (rc != CLOTHRT_OK) {
        ++errors;
        std::fprintf(stderr, "frame %ld: %s (holding the last good pose)\n", f,
                     clothrt_player_errmsg(p));
      }
      if (!random && info.transitions != before) {
        // path[next] is now playing (or, past the path's end, the player's default: stop).
        if (next >= path.size()) break;
        if (++next < path.size()) rt.check(clothrt_player_set_next(p, path[next]), "path", p);
      }
    } else {
      clothrt_player_info(p, &info);
    }
    rt.check(clothrt_player_get_positions(p, x.data(), 12, nullptr), "positions", p);
    pc.positions.insert(pc.positions.end(), x.begin(), x.end());
    ++pc.frame_count;
    primary.push_back({info.primary_clip, info.primary_frame});
    csv << f << ',' << double(f) / fps << ',' << info.primary_clip << ',' << info.primary_frame
        << ',' << info.cloth_clip << ',' << info.cloth_state << ',' << info.blending << ','
        << info.blend_weight << ',' << info.fallback << ',' << info.holding << ','
        << clothrt_status_name(rc) << '\n';
  }

  std::vector<std::array<int, 3>> triangles(tri.size() / 3);
  for (size_t t = 0; t < triangles.size(); ++t)
    triangles[t] = {int(tri[3 * t]), int(tri[3 * t + 1]), int(tri[3 * t + 2])};

  // The body under the cloth: the colliders at each frame's primary clip and frame (the nearest
  // stored pose), in character space like the cloth, from the scene the database was made from
  // (as `clothdb view` draws it). Without that scene, the cloth is written alone, with the reason.
  std::vector<std::vector<CapsuleCollider>> body, skeleton;  // skeleton: for the previews
  std::string body_note;
  PreviewView view = PreviewView::Front;
  try {
    db::Reader reader = open_reader(a.file);
    const DatabaseScene ds = load_database_scene(reader, a.scene);
    if (ds.scene.file.garment_kind == GarmentKind::Cape) view = PreviewView::Back;
    std::map<int64_t, const ExploreEdge*> edge_of;
    for (const ExploreEdge& e : ds.graph.edges) edge_of[e.db_clip] = &e;
    for (const auto& [clip, frame] : primary) {
      const auto it = edge_of.find(clip);
      if (it == edge_of.end() || it->second->poses.empty())
        throw std::runtime_error("primary clip " + std::to_string(clip) + " has no poses");
      const auto& poses = it->second->poses;
      const size_t k = std::min(poses.size() - 1, size_t(std::max(0.0, std::round(frame))));
      body.push_back(character_space_capsules(ds.scene, {poses[k]}).front());
      skeleton.push_back(character_space_skeleton(ds.scene, {poses[k]}).front());
    }
  } catch (const std::exception& e) {
    body.clear();
    skeleton.clear();
    body_note = e.what();
    std::fprintf(stderr, "play: writing the cloth without the body: %s\n", e.what());
  }
  if (a.view != "auto") view = parse_preview_view(a.view);

  Staging stage(a.out, "play");
  std::vector<std::string> written = {"garment.obj", "cloth.pc2", "path.csv"};
  {
    // The artist's topology (docs/guide/mesh_garments.md): their vertex order, faces, UVs.
    db::Reader reader;
    db::ArtistMesh artist;
    Error err;
    if (reader.open(a.file, &err) != Status::Ok || reader.artist_mesh(&artist, &err) != Status::Ok)
      throw std::runtime_error(err.message);
    const PointCache artist_pc = artist_order(artist, pc);
    write_artist_obj(stage.path("garment.obj"), "garment", artist_pc.positions.data(), artist);
    write_pc2(stage.path("cloth.pc2"), artist_pc);
  }
  write_file_atomic(stage.path("path.csv"), csv.str());
  if (!body.empty()) {
    // Blender: import body.obj and add a Mesh Cache modifier with body.pc2, as for the cloth.
    PointCache bc;
    for (const auto& capsules : body) {
      append_capsule_mesh_positions(capsules, bc.positions);
      ++bc.frame_count;
    }
    bc.vertex_count = int(bc.positions.size() / (3 * size_t(bc.frame_count)));
    write_obj(stage.path("body.obj"), "body", bc.positions.data(), bc.vertex_count,
              capsule_mesh_triangles(int(body.front().size())));
    write_pc2(stage.path("body.pc2"), bc);
    written.push_back("body.obj");
    written.push_back("body.pc2");
  }
  int previews = 0;
  if (a.preview_every > 0) {
    written.push_back("previews");
    make_directories(stage.path("previews"));
    Eigen::Matrix3Xd all(3, 0);
    auto frame_matrix = [&](int f) {
      Eigen::Matrix3Xd m(3, vertices);
      const float* src = pc.positions.data() + size_t(f) * n;
      for (uint32_t v = 0; v < vertices; ++v)
        for (int k = 0; k < 3; ++k) m(k, v) = src[3 * v + k];
      return m;
    };
    for (int f = 0; f < pc.frame_count; f += a.preview_every) {
      const Eigen::Matrix3Xd m = frame_matrix(f);
      all.conservativeResize(3, all.cols() + m.cols());
      all.rightCols(m.cols()) = m;
    }
    // The camera frames the garment (over every previewed frame), from the chosen side.
    const PreviewCamera cam = frame_points(all, 1.5, view);
    double floor = all.row(1).minCoeff() - 0.05;
    for (const auto& capsules : body)
      for (const CapsuleCollider& c : capsules)
        floor = std::min(floor, std::min(c.a.y(), c.b.y()) - c.radius);
    for (int f = 0; f < pc.frame_count; f += a.preview_every) {
      const Eigen::Matrix3Xd m = frame_matrix(f);
      PreviewScene scene;
      scene.cloth = &m;
      scene.triangles = &triangles;
      if (!body.empty()) {
        scene.capsules = body[size_t(f)];
        scene.skeleton = skeleton[size_t(f)];
      }
      scene.floor_height = floor;
      char name[64];
      std::snprintf(name, sizeof name, "/previews/frame_%04d.png", f);
      write_png(stage.dir.string() + name, render_preview(scene, cam, a.width, a.height), a.width,
                a.height);
      ++previews;
    }
  }
  stage.commit(written);
  clothrt_stats stats;
  clothrt_db_stats(rt.db, &stats);
  std::printf(
      "played %d frames at %g fps (%.2f s): %llu transitions, %llu fallbacks, %llu "
      "interrupted blends, %d errors; %llu clips decoded, cache %.1f MB\n"
      "wrote %s/{garment.obj,cloth.pc2,path.csv%s} and %d previews from the %s (character "
      "space)%s%s\n",
      pc.frame_count, fps, (pc.frame_count - 1) / fps, (unsigned long long)info.transitions,
      (unsigned long long)info.fallbacks, (unsigned long long)info.interrupted_blends, errors,
      (unsigned long long)stats.clip_loads, stats.cache_bytes / 1048576.0, a.out.c_str(),
      body.empty() ? "" : ",body.obj,body.pc2", previews, preview_view_name(view),
      body.empty() ? "; no body: " : "", body_note.c_str());
}

// ---- clothdb bench runtime --------------------------------------------------------------------

// Share of codec::decode_frames time spent inside zstd, measured on the file's own blobs: each
// chunk decompressed alone against the whole blob decoded (the library cannot split the two
// without instrumenting the codec).
double zstd_fraction(const std::string& path, size_t max_clips) {
  db::Reader r;
  Error err;
  if (r.open(path, &err) != Status::Ok) return 0;
  std::vector<db::ClothClip> clips;
  if (r.cloth_clips(&clips, &err) != Status::Ok) return 0;
  std::vector<uint8_t> blob;
  std::vector<float> out;
  std::vector<uint8_t> raw;
  std::vector<codec::ChunkSpan> spans;
  codec::DecodeScratch scratch;
  ZSTD_DCtx* dctx = ZSTD_createDCtx();
  double zstd_us = 0, decode_us = 0;
  for (size_t c = 0; c < clips.size() && c < max_clips; ++c) {
    if (r.clip_blob(clips[c].id, &blob, &err) != Status::Ok) continue;
    if (codec::chunk_spans(blob.data(), blob.size(), &spans, &err) != Status::Ok) continue;
    auto t0 = Clock::now();
    for (const codec::ChunkSpan& span : spans) {
      const unsigned long long raw_size =
          ZSTD_getFrameContentSize(blob.data() + span.offset, span.size);
      if (raw_size == ZSTD_CONTENTSIZE_ERROR || raw_size == ZSTD_CONTENTSIZE_UNKNOWN) break;
      raw.resize(size_t(raw_size));
      ZSTD_decompressDCtx(dctx, raw.data(), raw.size(), blob.data() + span.offset, span.size);
    }
    zstd_us += us_since(t0);
    t0 = Clock::now();
    if (r.decode_all(blob, &out, scratch, &err) != Status::Ok) continue;  // with its basis (v2)
    decode_us += us_since(t0);
  }
  ZSTD_freeDCtx(dctx);
  return decode_us > 0 ? std::min(1.0, zstd_us / decode_us) : 0;
}

struct Scenario {
  std::string name;
  Summary per_frame;  // µs per frame (all players)
  size_t frames = 0;
  clothrt_stats stats{};
  size_t player_bytes = 0;
  double wall_us = 0;
  double zstd_share = 0;
};

// Plays `players` random players for `frames` frames at `dt`, each starting at a different cloth
// clip, timing each frame (advance + positions for every player).
Scenario run_scenario(const std::string& name, const std::string& path,
                      const clothrt_db_options& options, int players, int frames, double dt,
                      int warm_frames, bool pre_decode, bool world, double zfrac,
                      bool stagger = false, bool paced = false, int render = 0) {
  Runtime rt(path, options);
  const std::vector<int64_t> clips = cloth_clip_ids(path);
  // render 0: simulation positions; 1: the render mesh's positions and normals, interleaved as a
  // vertex buffer (position, normal, tangent: 40-byte stride); 2: with tangents too.
  const uint32_t vertices =
      render ? clothrt_db_render_vertex_count(rt.db) : clothrt_db_vertex_count(rt.db);
  std::vector<std::vector<float>> out(size_t(players),
                                      std::vector<float>(size_t(vertices) * (render ? 10 : 3)));
  for (int i = 0; i < players; ++i) {
    clothrt_player* p = rt.add_player();
    rt.check(clothrt_player_set_random(p, 1, uint64_t(7919 * i + 1)), "random", p);
    if (pre_decode && i == 0)
      for (int64_t c : clips) rt.check(clothrt_player_start_cloth_clip(p, c), "pre-decode", p);
    rt.check(clothrt_player_start_cloth_clip(p, clips[size_t(i) % clips.size()]), "start", p);
    // A crowd is not in step: start each player somewhere inside its first clip.
    if (stagger) rt.check(clothrt_player_advance(p, dt * double((i * 37) % 59)), "stagger", p);
  }
  const float c = std::cos(0.3f), s = std::sin(0.3f);
  const float root[16] = {c, 0, -s, 0, 0, 1, 0, 0, s, 0, c, 0, 1.5f, 0, -0.5f, 1};
  auto frame = [&] {
    for (size_t i = 0; i < rt.players.size(); ++i) {
      clothrt_player* p = rt.players[i];
      const int rc = clothrt_player_advance(p, dt);
      if (rc != CLOTHRT_OK) rt.check(rc, "advance", p);
      if (render) {
        float* vb = out[i].data();
        const clothrt_render_output ro{vb, 40, vb + 3, 40, render > 1 ? vb + 6 : nullptr, 40};
        clothrt_player_get_render_mesh(p, &ro, world ? root : nullptr);
      } else {
        clothrt_player_get_positions(p, out[i].data(), 12, world ? root : nullptr);
      }
    }
  };
  for (int f = 0; f < warm_frames; ++f) frame();
  clothrt_db_reset_stats(rt.db);
  clothrt_db_set_timing(rt.db, 1);
  // Timing inside the library costs two clock reads per call; the per-frame figures come from a
  // separate pass without it.
  for (int f = 0; f < std::min(frames, 600); ++f) frame();
  Scenario sc;
  sc.name = name;
  clothrt_db_stats(rt.db, &sc.stats);
  clothrt_db_set_timing(rt.db, 0);
  clothrt_db_reset_stats(rt.db);
  std::vector<double> us(static_cast<size_t>(frames));
  const auto start = Clock::now();
  for (int f = 0; f < frames; ++f) {
    const auto t0 = Clock::now();
    frame();
    us[size_t(f)] = us_since(t0);
    // Paced like a game: the next frame starts dt after this one, so background decoding gets the
    // wall time it would have in a game.
    if (paced) std::this_thread::sleep_until(t0 + std::chrono::duration<double>(dt));
  }
  sc.wall_us = us_since(start);
  sc.per_frame = summarise(us);
  sc.frames = size_t(frames);
  clothrt_stats totals;
  clothrt_db_stats(rt.db, &totals);
  // Keep the timed pass's load counters and memory; the shares come from the instrumented pass.
  sc.stats.cache_bytes = std::max(sc.stats.cache_bytes, totals.cache_bytes);
  sc.stats.clip_loads = totals.clip_loads;
  sc.stats.stalls = totals.stalls;
  for (clothrt_player* p : rt.players) sc.player_bytes += clothrt_player_memory(p);
  sc.zstd_share = zfrac;
  return sc;
}

void print_scenario(const Scenario& sc, int players) {
  const clothrt_stats& s = sc.stats;
  const double decode = double(s.decode_ns) * (1 - sc.zstd_share) + double(s.repack_ns);
  const double zstd = double(s.decode_ns) * sc.zstd_share;
  const double play = double(s.sample_ns) + double(s.transition_ns);
  const double total = double(s.sqlite_ns) + zstd + decode + play;
  auto pct = [&](double v) { return total > 0 ? 100.0 * v / total : 0.0; };
  std::printf(
      "%s\n  per frame (%d player%s): median %.2f us, p99 %.2f us, mean %.2f us over %zu "
      "frames (%.2f us per player-frame amortised)\n",
      sc.name.c_str(), players, players == 1 ? "" : "s", sc.per_frame.median, sc.per_frame.p99,
      sc.per_frame.mean, sc.frames, sc.per_frame.mean / players);
  std::printf(
      "  clips decoded in the timed run: %llu (stalls %llu); memory: cache %.1f MB (cap "
      "%.0f MB) + graph %.2f MB + players %.2f MB = %.1f MB\n",
      (unsigned long long)s.clip_loads, (unsigned long long)s.stalls, s.cache_bytes / 1048576.0,
      s.cache_cap / 1048576.0, s.metadata_bytes / 1048576.0, sc.player_bytes / 1048576.0,
      (s.cache_bytes + s.metadata_bytes + sc.player_bytes) / 1048576.0);
  std::printf(
      "  time shares (instrumented pass): SQLite %.1f%%, zstd %.1f%%, decoding %.1f%%, "
      "playback (sampling, blending, copying) %.1f%%\n",
      pct(double(s.sqlite_ns)), pct(zstd), pct(decode), pct(play));
}

double memcpy_us(size_t bytes) {
  std::vector<uint8_t> a(bytes, 1), b(bytes, 2);
  std::vector<double> us;
  for (int i = 0; i < 2000; ++i) {
    const auto t0 = Clock::now();
    std::memcpy(b.data(), a.data(), bytes);
    us.push_back(us_since(t0));
    a[size_t(i) % bytes] = b[size_t(i * 7) % bytes];  // keep the copies observable
  }
  return summarise(us).median;
}

struct BenchArgs {
  std::string file;
  int frames = 3000, players = 100;
  size_t cache_mb = 32;
  std::string codec = "v1";  // synthetic: the codec of the databases built
  uint32_t modes = 64;
};

void run_bench(const BenchArgs& a) {
  if (a.codec != "v1" && a.file != "synthetic")
    throw std::runtime_error(
        "--codec v2, v3: only with FILE synthetic (recode a file with `clothdb db recode FILE "
        "--codec v2` or v3)");
  std::printf(
      "clothdb bench runtime %s\nmachine: %s, %u hardware threads; all scenarios run "
      "players on one thread\n\n",
      a.file.c_str(), cpu_model().c_str(), std::thread::hardware_concurrency());
  std::string big = a.file, small = a.file;
  std::filesystem::path tmp;
  if (a.file == "synthetic") {
    tmp = std::filesystem::temp_directory_path() /
          ("clothdb_bench_runtime_" + std::to_string(::getpid()));
    std::filesystem::create_directories(tmp);
    big = (tmp / "sheet10k.clothdb").string();
    small = (tmp / "sheet2k.clothdb").string();
    std::fprintf(stderr, "building synthetic databases in %s ...\n", tmp.c_str());
    const auto t0 = Clock::now();
    // The large garment with an artist's mesh (quads, a UV seam): the render-mesh scenarios.
    synthetic::Spec big_spec = synthetic::bench_spec(100, 4);
    big_spec.artist_mesh = true;
    const auto b = synthetic::build(big, big_spec);
    const auto s = synthetic::build(small, synthetic::bench_spec(45, 16));
    std::printf(
        "synthetic databases (runtime/tools/synthetic_db.hpp; smooth made-up motion, not "
        "simulation): %u vertices x %zu clips of 60 frames, and %u vertices x %zu clips "
        "(built in %.1f s)\n",
        b.vertices, b.clip.size(), s.vertices, s.clip.size(), us_since(t0) / 1e6);
    if (a.codec != "v1") {
      // Every blob recoded (--always: even where v1 is smaller), so every frame played is
      // decoded through the subspace, with the basis in the runtime's memory. Version 3 within
      // the contract RMS 1 / max 3 / jitter 0.1 mm.
      for (const std::string& path : {big, small}) {
        RecodeOptions o;
        o.modes = a.modes;
        o.always = true;
        if (a.codec == "v3") {
          o.codec = 3;
          o.contract = {0.001, 0.003, codec::kDefaultJitterCap};
        }
        const RecodeReport r = recode_database(path, o);
        std::printf(
            "  %s recoded to codec %s: basis of %u modes, blobs %.2f -> %.2f MB, largest new "
            "error %.3f mm\n",
            std::filesystem::path(path).filename().c_str(), a.codec.c_str(), r.basis_modes,
            r.blob_bytes_before / 1e6, r.blob_bytes_after / 1e6, r.max_error * 1e3);
      }
    }
    std::printf("\n");
  }
  uint32_t vertices = 0;
  {
    Runtime rt(big, clothrt_db_options{size_t(1) << 20, 0, 1.0});
    vertices = clothrt_db_vertex_count(rt.db);
  }
  const size_t out_bytes = size_t(vertices) * 12;
  const double copy = memcpy_us(out_bytes);
  const double zbig = zstd_fraction(big, 8), zsmall = zstd_fraction(small, 8);
  std::printf("memcpy of one frame of output (%u vertices, %.0f KB): %.2f us (median)\n\n",
              vertices, out_bytes / 1024.0, copy);

  clothrt_db_options warm{size_t(1) << 30, 1, 1.0};
  Scenario s1 = run_scenario("[1] 1 player, clips decoded (warm cache), stored rate (dt = 1/30 s)",
                             big, warm, 1, a.frames, 1.0 / 30, 600, true, false, zbig);
  print_scenario(s1, 1);
  std::printf("  ratio to the memcpy of its output: %.1fx\n\n", s1.per_frame.median / copy);
  Scenario s2 =
      run_scenario("[2] 1 player, warm cache, game rate 60 Hz (interpolating), world space", big,
                   warm, 1, a.frames, 1.0 / 60, 600, true, true, zbig);
  print_scenario(s2, 1);
  std::printf("  ratio to the memcpy of its output: %.1fx\n\n", s2.per_frame.median / copy);
  // Every clip decoded on first use and evicted soon after: the cap holds about two clips.
  const size_t clip_bytes = size_t(vertices) * 6 * 60;
  clothrt_db_options cold{2 * clip_bytes + clip_bytes / 2, 0, 1.0};
  Scenario s3 = run_scenario(
      "[3] 1 player, decoding included: cache of ~2 clips, decoding on the player's thread", big,
      cold, 1, a.frames, 1.0 / 30, 0, false, false, zbig);
  print_scenario(s3, 1);
  std::printf("\n");
  clothrt_db_options cold_bg{2 * clip_bytes + clip_bytes / 2, 1, 1.0};
  Scenario s4 = run_scenario(
      "[4] 1 player, decoding included, on the database's prefetch thread; paced at 30 Hz, "
      "the player's thread timed",
      big, cold_bg, 1, std::min(a.frames, 600), 1.0 / 30, 0, false, false, zbig, false, true);
  print_scenario(s4, 1);
  std::printf("\n");
  clothrt_db_options many{a.cache_mb << 20, 0, 1.0};
  Scenario s5 =
      run_scenario("[5] " + std::to_string(a.players) + " players on different clips, " +
                       std::to_string(a.cache_mb) +
                       " MB cache, decoding on the same thread (one core), not in step",
                   small, many, a.players, a.frames / 3, 1.0 / 30, 0, false, false, zsmall, true);
  print_scenario(s5, a.players);
  std::printf("\n");
  uint32_t render_vertices = 0;
  {
    Runtime rt(big, clothrt_db_options{size_t(1) << 20, 0, 1.0});
    render_vertices = clothrt_db_render_vertex_count(rt.db);
  }
  Scenario s6 = run_scenario(
      "[6] as [2] on the render mesh (" + std::to_string(render_vertices) +
          " vertices, seam copies included): positions + normals into a 40-byte-stride vertex "
          "buffer",
      big, warm, 1, a.frames, 1.0 / 60, 600, true, true, zbig, false, false, 1);
  print_scenario(s6, 1);
  std::printf("\n");
  Scenario s7 = run_scenario("[7] as [6] with tangents (the mesh has UVs)", big, warm, 1, a.frames,
                             1.0 / 60, 600, true, true, zbig, false, false, 2);
  print_scenario(s7, 1);
  std::printf("\n");
  if (!tmp.empty()) std::filesystem::remove_all(tmp);
}

}  // namespace

void register_play_commands(CLI::App& app) {
  auto a = std::make_shared<PlayArgs>();
  CLI::App* cmd = app.add_subcommand(
      "play",
      "Plays a path through a database's motion graph with the runtime library and writes "
      "DIR/garment.obj + DIR/cloth.pc2 on the artist's mesh (Blender: import the OBJ, add a Mesh "
      "Cache modifier with the PC2), the body's colliders beside it as DIR/body.obj + "
      "DIR/body.pc2 (when the scene the database was made from can be rebuilt), DIR/path.csv "
      "(clip, state, blend and fallback per frame) and PNG previews of cloth and body in "
      "DIR/previews/. Positions are in character space.");
  cmd->add_option("FILE", a->file, "Database")->required();
  cmd->add_option("--path", a->path,
                  "'random', or primary clips by name or id, comma-separated: the first is "
                  "played from its source node, each next one at the following node; playback "
                  "stops at the end of the last")
      ->capture_default_str();
  cmd->add_option("--seconds", a->seconds, "Stop after this long (0: at the end of --path)")
      ->capture_default_str();
  cmd->add_option("--out", a->out, "Output directory")->required();
  cmd->add_option("--seed", a->seed, "Seed of the random path")->capture_default_str();
  cmd->add_option("--fps", a->fps, "Output frame rate (0: the database's)")->capture_default_str();
  cmd->add_option("--blend-frames", a->blend_frames, "Blend length at transitions")
      ->capture_default_str();
  cmd->add_option("--preview-every", a->preview_every, "A PNG preview every N frames (0: none)")
      ->capture_default_str();
  cmd->add_option("--width", a->width, "Preview width")->capture_default_str();
  cmd->add_option("--view", a->view,
                  "Previews seen from the front, back or side; auto: from the back for a cape, "
                  "else the front")
      ->capture_default_str();
  cmd->add_option("--scene", a->scene,
                  "Scene file to rebuild the body from (default: the path the database records; "
                  "its content must match)");
  cmd->add_option("--height", a->height, "Preview height")->capture_default_str();
  cmd->callback([a] { run_play(*a); });
}

void register_bench_runtime(CLI::App& bench) {
  auto a = std::make_shared<BenchArgs>();
  CLI::App* cmd = bench.add_subcommand(
      "runtime",
      "Per-frame cost of the playback runtime: one player of the largest garment with its clips "
      "decoded and with decoding included, and many players of a smaller one sharing a "
      "database; the render mesh's positions and normals (and tangents); memory; shares of "
      "SQLite, zstd, decoding and playback. FILE 'synthetic' builds a 10,000-vertex database "
      "(with an artist's mesh: quads, a UV seam) and a 2,025-vertex one in a temporary "
      "directory; a real file is used for all scenarios.");
  cmd->add_option("FILE", a->file, "Database, or 'synthetic'")->required();
  cmd->add_option("--frames", a->frames, "Timed frames per single-player scenario")
      ->capture_default_str()
      ->check(number_in(1, 1e7));
  cmd->add_option("--players", a->players, "Players in the shared-database scenario")
      ->capture_default_str()
      ->check(number_in(1, 1e4));
  cmd->add_option("--cache-mb", a->cache_mb, "Cache cap of the shared-database scenario, MB")
      ->capture_default_str()
      ->check(number_in(1, 1e6));
  cmd->add_option("--codec", a->codec,
                  "With FILE synthetic: v1, v2 or v3 (every blob recoded to the subspace codec; "
                  "v3 within RMS 1 / max 3 / jitter 0.1 mm; "
                  "docs/DATABASE.md, \"version 2\")")
      ->check(CLI::IsMember({"v1", "v2", "v3"}))
      ->capture_default_str();
  cmd->add_option("--modes", a->modes, "--codec v2, v3: basis modes")
      ->check(CLI::Range(1u, codec::kMaxBasisModes))
      ->capture_default_str();
  cmd->callback([a] { run_bench(*a); });
}

}  // namespace clothdb::cli
