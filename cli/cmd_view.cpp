// `clothdb view FILE`: a local web page that plays the database live through the runtime library
// (clothrt), with the character's body capsules, controls for the walk through the motion graph,
// and the clip table of `clothdb clips list` (docs/guide/viewer.md).
//
// How frames reach the page: cpp-httplib 0.11 (Debian) has no WebSocket, so the page pulls, one
// request per connection: `GET /api/frames?dt=SECONDS&n=16&wait=MS` advances the server's one
// player up to n times by dt, ending before a node (passes_node), and answers with the frames'
// cloth on the render mesh (the artist's vertices, seam copies split: positions and normals in
// character space from clothrt_player_get_render_mesh, quantised: wire_frame_bytes) and body
// capsules as the body and the player's state at each as a JSON header. The page shows one per
// animation frame and always has the next request in flight, held by the server for `wait` ms
// (until the page's queue runs low), so a request's fixed cost is shared by up to sixteen frames
// and its latency is hidden. Every connection is closed after its answer, so none idles in
// cpp-httplib's polling keep-alive loop (run_view). The render mesh's triangles and the clip table
// are fetched once. Nobody asking (a paused page) costs nothing.
#include <pthread.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include <algorithm>
#include <atomic>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "cli_util.hpp"
#include "clips_list.hpp"
#include "clothrt.h"
#include "commands.hpp"
#include "explore/explorer.hpp"
#include "quality/clip_quality.hpp"
// Last: httplib.h pulls in <resolv.h>, whose `_res` macro breaks Eigen's headers included after it.
#include <httplib.h>

#ifndef CLOTHDB_SOURCE_DIR
#define CLOTHDB_SOURCE_DIR "."
#endif

namespace clothdb::cli {

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

// Limits of what a request may ask: a step longer than a second is not a frame (the page sends
// the time since its last request, capped), and blends longer than 600 frames are not blends.
constexpr double kMaxStepSeconds = 1.0;
constexpr double kMaxBlendFrames = 600;
// Frames per request: the page asks for several at a time, so the fixed cost of a request (a
// connection, thread wake-ups, parsing) is shared; more than 16 would only add latency to the
// controls that apply with the batch (slow motion's step).
constexpr int64_t kMaxBatch = 16;
// How long the page may ask the server to hold a batch (wait=MS), milliseconds.
constexpr int64_t kMaxWaitMs = 500;

struct ViewArgs {
  std::string file, host = "127.0.0.1", assets, scene;
  int port = 8080;
  uint64_t seed = 1;
};

// A request the page made wrong: answered with `status` and the message, never a crash.
struct BadRequest : std::runtime_error {
  int status;
  BadRequest(int s, const std::string& what) : std::runtime_error(what), status(s) {}
};

// Everything the server knows, behind one mutex: the player is used by one thread at a time
// (clothrt.h THREADING) and cpp-httplib answers on a pool of threads.
struct Viewer {
  std::string file;
  fs::path assets;      // the page's folder (viewer/), canonical
  fs::path three_root;  // viewer/node_modules/three, canonical ("" if three.js is not installed)
  clothrt_db* db = nullptr;
  clothrt_player* player = nullptr;
  uint32_t vertices = 0;
  std::vector<uint32_t> triangles;
  std::vector<int64_t> clip_ids;  // primary clips, id order
  // Per primary clip its last frame index and frame rate: where the runtime reaches the node at
  // the clip's end (passes_node).
  struct Span {
    double last, rate;
  };
  std::map<int64_t, Span> spans;
  std::vector<int64_t> cloth_clip_ids;  // for validating jumps
  json info;                            // GET /api/info, built once
  // Body capsules per primary clip, character space: frames x capsule_count x (ax, ay, az, bx, by,
  // bz, radius). Sent with each frame (7 floats a capsule after the positions).
  std::map<int64_t, std::vector<float>> capsules;
  size_t capsule_count = 0;
  std::string body_note;  // why the body is not drawn ("" when it is)

  std::mutex mu;
  uint64_t frames_served = 0;
  double last_us = 0;          // advance + positions of the last frame, µs
  std::vector<float> scratch;  // one frame's positions and normals as floats (under mu)

  // Answer bodies of /api/frames, handed back when cpp-httplib is done with them: a batch is
  // about 100 KB, and a fresh one per request cost page faults and zero-filling every time.
  std::mutex pool_mu;
  std::vector<std::string> pool;

  // Decodes every cloth clip once at start (warm_cache), so that frames served later never wait
  // for, nor pay for, decoding.
  std::thread warm;
  std::atomic<bool> stopping{false}, warming{false};

  ~Viewer() {
    stopping = true;
    if (warm.joinable()) warm.join();
    clothrt_player_destroy(player);
    clothrt_db_close(db);
  }
};

// One frame of /api/frames on the wire (viewer.js reads it; docs/guide/viewer.md, "How frames
// reach the page"), native byte order (little-endian on every machine a browser runs on):
//   4 float32      origin x, y, z and step: position = origin + step * q
//   7 c float32    the body's capsules (ax, ay, az, bx, by, bz, radius)
//   3 n int16      positions q, character space, over the frame's bounding box
//   3 n int8       unit normals times 127
//   0..3 bytes     padding to a multiple of 4
// Quantised because sending was a sixth of the server's CPU with 71 KB a frame as float32 (the TCP
// writes and the loopback delivery; docs/notebook/viewer.md): 9 bytes a vertex instead of 24, and
// less for the page to take in. The step
// is the box's largest half-extent / 32767 (a 1 m skirt: 15 µm, so at most 8 µm off), and normals
// are within 0.5 degrees: both below what the picture shows.
constexpr size_t kFrameHeadFloats = 4;

size_t wire_frame_bytes(size_t vertices, size_t capsules) {
  const size_t b = (kFrameHeadFloats + 7 * capsules) * sizeof(float) + 9 * vertices;
  return (b + 3) / 4 * 4;
}

void check(Viewer& v, int rc, const std::string& what) {
  if (rc != CLOTHRT_OK)
    throw std::runtime_error(what + ": " + clothrt_player_errmsg(v.player) + " (" +
                             clothrt_status_name(rc) + ")");
}

// A whole number in [lo, hi] from a query parameter or JSON text, or a 400 naming the field.
int64_t parse_int(const std::string& field, const std::string& text, int64_t lo, int64_t hi) {
  errno = 0;
  char* end = nullptr;
  const long long v = std::strtoll(text.c_str(), &end, 10);
  if (text.empty() || !end || *end != '\0' || errno == ERANGE || v < lo || v > hi)
    throw BadRequest(400, field + ": '" + text.substr(0, 40) + "' is not a whole number in [" +
                              std::to_string(lo) + ", " + std::to_string(hi) + "]");
  return v;
}

double parse_number(const std::string& field, const std::string& text, double lo, double hi) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || !end || *end != '\0' || !std::isfinite(v) || v < lo || v > hi)
    throw BadRequest(400, field + ": '" + text.substr(0, 40) + "' is not a number in [" +
                              fmt_g(lo) + ", " + fmt_g(hi) + "]");
  return v;
}

int64_t json_int(const json& body, const char* key, int64_t lo, int64_t hi) {
  if (!body.contains(key)) throw BadRequest(400, std::string("missing field '") + key + "'");
  const json& x = body.at(key);
  if (x.is_number_unsigned() && x.get<uint64_t>() > uint64_t(hi))
    throw BadRequest(400, std::string(key) + ": out of range");
  if (!x.is_number_integer()) throw BadRequest(400, std::string(key) + ": not a whole number");
  const int64_t v = x.get<int64_t>();
  if (v < lo || v > hi)
    throw BadRequest(400, std::string(key) + ": " + std::to_string(v) + " is not in [" +
                              std::to_string(lo) + ", " + std::to_string(hi) + "]");
  return v;
}

double json_number(const json& body, const char* key, double lo, double hi) {
  if (!body.contains(key)) throw BadRequest(400, std::string("missing field '") + key + "'");
  const json& x = body.at(key);
  if (!x.is_number()) throw BadRequest(400, std::string(key) + ": not a number");
  const double v = x.get<double>();
  if (!std::isfinite(v) || v < lo || v > hi)
    throw BadRequest(400, std::string(key) + ": " + fmt_g(v) + " is not in [" + fmt_g(lo) + ", " +
                              fmt_g(hi) + "]");
  return v;
}

int64_t known_primary_clip(const Viewer& v, int64_t id) {
  if (!std::binary_search(v.clip_ids.begin(), v.clip_ids.end(), id))
    throw BadRequest(404, "no primary clip " + std::to_string(id) + " in " + v.file);
  return id;
}

// The page's folder and three.js inside it; a missing three.js is reported by the page, not
// refused here (the C++ build works without npm).
void find_assets(Viewer& v, const std::string& dir) {
  std::error_code ec;
  const fs::path page = fs::path(dir) / "index.html";
  if (!fs::is_regular_file(page, ec))
    throw std::runtime_error("--assets " + dir + ": no index.html (the viewer's page folder, " +
                             "viewer/ in the repository)");
  v.assets = fs::canonical(dir, ec);
  const fs::path three = v.assets / "node_modules" / "three";
  if (fs::is_regular_file(three / "build" / "three.module.js", ec))
    v.three_root = fs::canonical(three, ec);
}

// Body capsules of every primary clip, in character space (what `clip show` draws), when the
// scene the database was made from can be rebuilt; otherwise the reason, shown by the page.
void load_body(Viewer& v, const std::string& scene_file) {
  try {
    db::Reader reader = open_reader(v.file);
    const DatabaseScene ds = load_database_scene(reader, scene_file);
    for (const ExploreEdge& e : ds.graph.edges) {
      std::vector<float>& flat = v.capsules[e.db_clip];
      for (const auto& frame : character_space_capsules(ds.scene, e.poses)) {
        if (v.capsule_count == 0) v.capsule_count = frame.size();
        if (frame.size() != v.capsule_count)
          throw std::runtime_error("the body has " + std::to_string(frame.size()) +
                                   " capsules in one frame and " + std::to_string(v.capsule_count) +
                                   " in another");
        for (const CapsuleCollider& c : frame)
          flat.insert(flat.end(), {float(c.a.x()), float(c.a.y()), float(c.a.z()), float(c.b.x()),
                                   float(c.b.y()), float(c.b.z()), float(c.radius)});
      }
    }
  } catch (const std::exception& e) {
    v.body_note = std::string("drawing without the body: ") + e.what();
    v.capsules.clear();
    v.capsule_count = 0;
  }
}

// Bytes of every cloth clip decoded, at most (float32 coordinates; the cache may hold them as
// 16-bit).
size_t decoded_bytes(const std::vector<db::ClothClip>& clips, uint32_t vertices) {
  size_t frames = 0;
  for (const auto& c : clips) frames += size_t(std::max(c.frame_count, 0));
  return frames * vertices * 3 * sizeof(float);
}

// The largest decoded database the viewer holds in memory whole (a workstation's viewer; larger
// files play with the runtime's default cache and its prefetching).
constexpr size_t kWholeCacheBytes = size_t(1) << 30;

// On a thread of its own, a second player starts every cloth clip once: the clips are decoded
// into the shared cache while the page loads, instead of while frames are served (where decoding
// the clips the random walk reached was about a sixth of the server's CPU).
void warm_cache(Viewer& v) {
  v.warming = true;
  v.warm = std::thread([&v] {
    // At a lower priority (Linux: per thread), so the page's own loading comes first on a small
    // machine.
    setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), 10);
    const auto t0 = Clock::now();
    clothrt_player* p = nullptr;
    if (clothrt_player_create(v.db, &p) != CLOTHRT_OK) return;
    size_t done = 0;
    for (const int64_t id : v.cloth_clip_ids) {
      if (v.stopping) break;
      if (clothrt_player_start_cloth_clip(p, id) == CLOTHRT_OK) ++done;
    }
    clothrt_player_destroy(p);
    v.warming = false;
    std::fprintf(stderr, "view: %zu cloth clips decoded into the cache in %.2f s\n", done,
                 std::chrono::duration<double>(Clock::now() - t0).count());
  });
}

void open_viewer(Viewer& v, const ViewArgs& a) {
  v.file = a.file;
  clothrt_db_options options;
  clothrt_db_options_init(&options);
  int rc = clothrt_db_open(a.file.c_str(), &options, &v.db);
  if (rc != CLOTHRT_OK)
    throw std::runtime_error(std::string(clothrt_last_open_errmsg()) + " (" +
                             clothrt_status_name(rc) + ")");
  std::vector<db::ClothClip> cloth_clips;
  {
    db::Reader reader = open_reader(a.file);
    db::Error err;
    if (reader.cloth_clips(&cloth_clips, &err) != db::Status::Ok)
      throw std::runtime_error(err.message);
  }
  // Room for every clip decoded, when that is at most kWholeCacheBytes (warm_cache fills it).
  const size_t whole = decoded_bytes(cloth_clips, clothrt_db_vertex_count(v.db));
  const bool keep_all = whole > 0 && whole <= kWholeCacheBytes;
  if (keep_all && whole + whole / 4 > options.cache_bytes) {
    clothrt_db_close(v.db);
    v.db = nullptr;
    options.cache_bytes = whole + whole / 4;
    rc = clothrt_db_open(a.file.c_str(), &options, &v.db);
    if (rc != CLOTHRT_OK)
      throw std::runtime_error(std::string(clothrt_last_open_errmsg()) + " (" +
                               clothrt_status_name(rc) + ")");
  }
  // The render mesh (clothrt.h): what a game draws, with normals from the runtime.
  v.vertices = clothrt_db_render_vertex_count(v.db);
  v.triangles.resize(size_t(clothrt_db_render_triangle_count(v.db)) * 3);
  if (clothrt_db_render_triangles(v.db, v.triangles.data(), v.triangles.size()) != CLOTHRT_OK)
    throw std::runtime_error(a.file + ": triangles: " + clothrt_db_errmsg(v.db));
  for (const auto& c : cloth_clips) v.cloth_clip_ids.push_back(c.id);
  std::sort(v.cloth_clip_ids.begin(), v.cloth_clip_ids.end());
  json clips = json::array();
  for (size_t i = 0; i < clothrt_db_clip_count(v.db); ++i) {
    clothrt_clip_info ci;
    if (clothrt_db_clip_info(v.db, i, &ci) != CLOTHRT_OK)
      throw std::runtime_error(a.file + ": clip info: " + clothrt_db_errmsg(v.db));
    v.clip_ids.push_back(ci.id);
    v.spans[ci.id] = {double(ci.frame_count - 1), ci.frame_rate};
    clips.push_back({{"id", ci.id},
                     {"name", ci.name},
                     {"frames", ci.frame_count},
                     {"frame_rate", ci.frame_rate},
                     {"has_cloth", bool(ci.has_cloth)}});
  }
  std::sort(v.clip_ids.begin(), v.clip_ids.end());
  if (v.cloth_clip_ids.empty()) throw std::runtime_error(a.file + ": has no cloth clips to play");

  if (clothrt_player_create(v.db, &v.player) != CLOTHRT_OK)
    throw std::runtime_error(a.file + ": creating a player: " + clothrt_db_errmsg(v.db));
  check(v, clothrt_player_set_random(v.player, 0, a.seed), "random mode");
  check(v, clothrt_player_start(v.player, 0), a.file + ": start");
  std::vector<float> first(size_t(v.vertices) * 6);
  const clothrt_render_output first_out{first.data(), 12, first.data() + size_t(v.vertices) * 3, 12,
                                        nullptr,      0};
  check(v, clothrt_player_get_render_mesh(v.player, &first_out, nullptr), a.file + ": positions");
  load_body(v, a.scene);
  if (keep_all) warm_cache(v);

  json metrics = json::array();
  for (const ClipMetricName& m : clip_metrics())
    metrics.push_back({{"name", m.name}, {"key", m.json_key}});
  v.info = {{"file", fs::path(a.file).filename().string()},
            {"vertices", v.vertices},
            {"triangles", v.triangles.size() / 3},
            {"clips", clips},
            {"start_clip", clothrt_db_start_clip(v.db)},
            {"metrics", metrics},
            {"body", v.body_note.empty()},
            {"capsules", v.capsule_count},
            {"frame_bytes", wire_frame_bytes(v.vertices, v.capsule_count)},
            {"body_note", v.body_note}};
}

// The body capsules at the player's primary clip and frame (the nearest stored pose), 7 floats
// each; zeros (radius 0: not drawn) where the clip has no poses.
void body_at(Viewer& v, float* out) {
  if (v.capsule_count == 0) return;
  const size_t floats = v.capsule_count * 7;
  std::fill(out, out + floats, 0.0f);
  clothrt_frame_info fi{};
  clothrt_player_info(v.player, &fi);
  auto it = v.capsules.find(fi.primary_clip);
  if (it == v.capsules.end() || it->second.empty()) return;
  const size_t frames = it->second.size() / floats;
  const size_t f = std::min(frames - 1, size_t(std::max(0.0, std::round(fi.primary_frame))));
  std::copy_n(it->second.data() + f * floats, floats, out);
}

// JSON text of `j`, with bytes that are not UTF-8 (a request's own text quoted back in an error,
// cut at 40 bytes) replaced instead of throwing.
std::string text_of(const json& j) {
  return j.dump(-1, ' ', false, json::error_handler_t::replace);
}

// `x` appended as JSON: the shortest text that reads back as the same double (what nlohmann::json
// writes, but for the ".0" of whole numbers), null when it is not finite.
void append_number(std::string& out, double x) {
  if (!std::isfinite(x)) {
    out += "null";
    return;
  }
  char buf[32];
  out.append(buf, std::to_chars(buf, buf + sizeof buf, x).ptr);
}

template <class Int>
void append_int(std::string& out, Int x) {
  char buf[24];
  out.append(buf, std::to_chars(buf, buf + sizeof buf, x).ptr);
}

// Whether advancing the player by dt reaches the node at the end of its primary clip, by the
// runtime's rule (clip time += dt * frame rate; the node at the last frame), where the next clip is
// chosen and a blend starts. Not at a dead end (the player already on the last frame stays there).
bool passes_node(const Viewer& v, double dt) {
  clothrt_frame_info fi{};
  clothrt_player_info(v.player, &fi);
  const auto it = v.spans.find(fi.primary_clip);
  if (it == v.spans.end()) return false;
  const Viewer::Span& s = it->second;
  return fi.primary_frame < s.last && fi.primary_frame + dt * s.rate >= s.last;
}

// The player's state as the page shows it (the JSON header of each frame, the answer to a
// control) appended to `out` as a JSON object, with `error` when not null. Written out here
// rather than built as a nlohmann::json (a map node per field, then the text): eight of those per
// request were 6-7 % of the server's CPU (docs/notebook/viewer.md).
void append_state(Viewer& v, std::string& out, const char* error = nullptr) {
  clothrt_frame_info fi{};
  clothrt_player_info(v.player, &fi);
  clothrt_stats stats{};
  clothrt_db_stats(v.db, &stats);
  int64_t succ[64];
  size_t count = 0;
  clothrt_db_successors(v.db, fi.primary_clip, succ, 64, &count);
  const auto flag = [](int b) { return b ? "true" : "false"; };
  out += "{\"primary_clip\":";
  append_int(out, fi.primary_clip);
  out += ",\"primary_frame\":";
  append_number(out, fi.primary_frame);
  out += ",\"cloth_clip\":";
  append_int(out, fi.cloth_clip);
  out += ",\"cloth_state\":";
  append_int(out, fi.cloth_state);
  out += ",\"next_clip\":";
  append_int(out, fi.next_clip);
  out += ",\"blending\":";
  out += flag(fi.blending);
  out += ",\"blend_weight\":";
  append_number(out, fi.blend_weight);
  out += ",\"fallback\":";
  out += flag(fi.fallback);
  out += ",\"holding\":";
  out += flag(fi.holding);
  out += ",\"transitions\":";
  append_int(out, fi.transitions);
  out += ",\"successors\":[";
  for (size_t i = 0; i < std::min<size_t>(count, 64); ++i) {
    if (i) out += ',';
    append_int(out, succ[i]);
  }
  out += "],\"stalls\":";
  append_int(out, stats.stalls);
  out += ",\"runtime_us\":";
  append_number(out, v.last_us);
  out += ",\"frame\":";
  append_int(out, v.frames_served);
  if (error) {
    out += ",\"error\":";
    out += text_of(json(error));
  }
  out += '}';
}

// POST /api/control {"action": ...}: the player's controls; the answer is the state after.
std::string control(Viewer& v, const std::string& text) {
  const json body = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (body.is_discarded() || !body.is_object())
    throw BadRequest(400, "the body is not a JSON object");
  if (!body.contains("action") || !body.at("action").is_string())
    throw BadRequest(400, "missing string field 'action'");
  const std::string action = body.at("action").get<std::string>();
  const int64_t max_id = std::numeric_limits<int64_t>::max();
  std::lock_guard<std::mutex> lock(v.mu);
  int rc = CLOTHRT_OK;
  if (action == "next") {
    const int64_t clip = known_primary_clip(v, json_int(body, "clip", 1, max_id));
    rc = clothrt_player_set_next(v.player, clip);
    if (rc != CLOTHRT_OK)
      throw BadRequest(409, "clip " + std::to_string(clip) +
                                " cannot follow: " + clothrt_player_errmsg(v.player));
  } else if (action == "random") {
    if (!body.contains("enabled") || !body.at("enabled").is_boolean())
      throw BadRequest(400, "random: missing boolean field 'enabled'");
    const uint64_t seed = body.contains("seed") ? uint64_t(json_int(body, "seed", 0, max_id)) : 1;
    rc = clothrt_player_set_random(v.player, body.at("enabled").get<bool>(), seed);
  } else if (action == "blend") {
    rc = clothrt_player_set_blend_frames(v.player, json_number(body, "frames", 0, kMaxBlendFrames));
  } else if (action == "jump") {
    const int64_t clip = json_int(body, "cloth_clip", 1, max_id);
    if (!std::binary_search(v.cloth_clip_ids.begin(), v.cloth_clip_ids.end(), clip))
      throw BadRequest(404, "no cloth clip " + std::to_string(clip) + " in " + v.file);
    rc = clothrt_player_start_cloth_clip(v.player, clip);
  } else if (action == "start") {
    const int64_t clip = known_primary_clip(v, json_int(body, "clip", 1, max_id));
    rc = clothrt_player_start(v.player, clip);
  } else {
    throw BadRequest(
        400, "unknown action '" + action.substr(0, 40) + "' (next, random, blend, jump, start)");
  }
  if (rc != CLOTHRT_OK)
    throw BadRequest(rc == CLOTHRT_ERR_NOT_FOUND ? 404 : 409,
                     action + ": " + clothrt_player_errmsg(v.player));
  std::string out;
  append_state(v, out);
  return out;
}

const char* content_type(const fs::path& p) {
  const std::string ext = p.extension().string();
  if (ext == ".html") return "text/html; charset=utf-8";
  if (ext == ".js") return "text/javascript; charset=utf-8";
  if (ext == ".css") return "text/css; charset=utf-8";
  if (ext == ".json") return "application/json";
  if (ext == ".png") return "image/png";
  return "application/octet-stream";
}

// Every answer goes out through a content provider, as it is: cpp-httplib compresses a plain body
// of a text or JSON type with Brotli at its best (slowest) quality, which took seconds for
// three.js (1.3 MB) and milliseconds of server CPU for each JSON table, for a page served over
// loopback.
void reply(httplib::Response& res, std::string body, const char* type) {
  auto data = std::make_shared<const std::string>(std::move(body));
  res.set_content_provider(data->size(), type,
                           [data](size_t offset, size_t length, httplib::DataSink& sink) {
                             return sink.write(data->data() + offset, length);
                           });
}

// Writes one frame (positions p, normals nr: 3 n floats each; capsules already at their place
// after the head) at `out`.
void quantise_frame(const float* p, const float* nr, size_t n, size_t capsules, char* out) {
  // The box: NaN fails every comparison and is left out.
  float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  size_t v = 0;
#if defined(__SSE2__)
  // Four vertices (12 floats, three loads) at a time, as the quantising below: lane j of load r
  // holds coordinate (4 r + j) % 3. The scalar loop (three dependent min/max chains, which the
  // compiler does not vectorise over the interleaved x, y, z) was a third of this function.
  // minps/maxps return their second operand when either is NaN: the running box is kept.
  __m128 mn[3], mx[3];
  for (int r = 0; r < 3; ++r) mn[r] = _mm_set1_ps(INFINITY), mx[r] = _mm_set1_ps(-INFINITY);
  for (; v + 4 <= n; v += 4)
    for (int r = 0; r < 3; ++r) {
      const __m128 x = _mm_loadu_ps(p + 3 * v + 4 * size_t(r));
      mn[r] = _mm_min_ps(x, mn[r]);
      mx[r] = _mm_max_ps(x, mx[r]);
    }
  float a[12], b[12];
  for (int r = 0; r < 3; ++r) _mm_storeu_ps(a + 4 * r, mn[r]), _mm_storeu_ps(b + 4 * r, mx[r]);
  for (int j = 0; j < 12; ++j) {
    lo[j % 3] = std::min(lo[j % 3], a[j]);
    hi[j % 3] = std::max(hi[j % 3], b[j]);
  }
#endif
  for (; v < n; ++v)
    for (int k = 0; k < 3; ++k) {
      const float x = p[3 * v + size_t(k)];
      lo[k] = x < lo[k] ? x : lo[k];
      hi[k] = x > hi[k] ? x : hi[k];
    }
  float head[kFrameHeadFloats];
  float half = 0;
  for (int k = 0; k < 3; ++k) {
    const bool ok = lo[k] <= hi[k] && std::isfinite(hi[k] - lo[k]);
    head[k] = ok ? 0.5f * (lo[k] + hi[k]) : 0.0f;
    half = std::max(half, ok ? 0.5f * (hi[k] - lo[k]) : 0.0f);
  }
  const float step = half > 0 ? half / 32767.0f : 1.0f;
  head[3] = step;
  std::memcpy(out, head, sizeof head);
  const float inv = 1.0f / step;
  int16_t* q = reinterpret_cast<int16_t*>(out + (kFrameHeadFloats + 7 * capsules) * sizeof(float));
  int8_t* qn = reinterpret_cast<int8_t*>(q + 3 * n);
  size_t i = 0;
#if defined(__SSE2__)
  // Four vertices (12 floats) at a time: rounded to nearest by the conversion, clamped by the
  // saturating packs (NaN, never expected, becomes the most negative value). The scalar code with
  // std::lrint (a libm call per value) or branches took longer than the socket writes it saved.
  const __m128 o0 = _mm_setr_ps(head[0], head[1], head[2], head[0]);
  const __m128 o1 = _mm_setr_ps(head[1], head[2], head[0], head[1]);
  const __m128 o2 = _mm_setr_ps(head[2], head[0], head[1], head[2]);
  const __m128 s = _mm_set1_ps(inv), s8 = _mm_set1_ps(127.0f);
  for (; i + 12 <= 3 * n; i += 12) {
    const __m128i a = _mm_cvtps_epi32(_mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(p + i), o0), s));
    const __m128i b = _mm_cvtps_epi32(_mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(p + i + 4), o1), s));
    const __m128i c = _mm_cvtps_epi32(_mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(p + i + 8), o2), s));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(q + i), _mm_packs_epi32(a, b));
    _mm_storel_epi64(reinterpret_cast<__m128i*>(q + i + 8), _mm_packs_epi32(c, c));
    const __m128i na = _mm_cvtps_epi32(_mm_mul_ps(_mm_loadu_ps(nr + i), s8));
    const __m128i nb = _mm_cvtps_epi32(_mm_mul_ps(_mm_loadu_ps(nr + i + 4), s8));
    const __m128i nc = _mm_cvtps_epi32(_mm_mul_ps(_mm_loadu_ps(nr + i + 8), s8));
    const __m128i n8 = _mm_packs_epi16(_mm_packs_epi32(na, nb), _mm_packs_epi32(nc, nc));
    _mm_storel_epi64(reinterpret_cast<__m128i*>(qn + i), n8);
    const int last = _mm_cvtsi128_si32(_mm_srli_si128(n8, 8));
    std::memcpy(qn + i + 8, &last, 4);
  }
#endif
  auto round_to = [](float t, float lim) {
    t = std::min(lim, std::max(-lim, t));
    return int(std::nearbyint(t));
  };
  for (; i < 3 * n; ++i) {
    q[i] = int16_t(round_to((p[i] - head[i % 3]) * inv, 32767.0f));
    qn[i] = int8_t(round_to(nr[i] * 127.0f, 127.0f));
  }
  std::memset(
      qn + 3 * n, 0,
      wire_frame_bytes(n, capsules) - (kFrameHeadFloats + 7 * capsules) * sizeof(float) - 9 * n);
}

// A pooled body for /api/frames with at least `bytes` bytes (contents left as they were).
std::string take_body(Viewer& v, size_t bytes) {
  std::string body;
  {
    std::lock_guard<std::mutex> lock(v.pool_mu);
    if (!v.pool.empty()) {
      body = std::move(v.pool.back());
      v.pool.pop_back();
    }
  }
  if (body.size() < bytes) body.resize(bytes);  // (never shrunk: see reply_pooled)
  return body;
}

// As reply() with the first `size` bytes of `body` (a pooled body keeps its length, so that taking
// it again never zero-fills), and the body goes back to the pool once sent (cpp-httplib's releaser
// runs when the response is destroyed).
void reply_pooled(httplib::Response& res, Viewer& v, std::string body, size_t size,
                  const char* type) {
  auto data = std::make_shared<std::string>(std::move(body));
  res.set_content_provider(
      size, type,
      [data](size_t offset, size_t length, httplib::DataSink& sink) {
        return sink.write(data->data() + offset, length);
      },
      [data, &v](bool) {
        std::lock_guard<std::mutex> lock(v.pool_mu);
        if (v.pool.size() < 8) v.pool.push_back(std::move(*data));
      });
}

// A file below `root` named by the request's (decoded) path `rel`, or a 4xx: nothing outside
// `root` is ever served, whatever "..", symbolic links or encodings the path uses.
void serve_file(const fs::path& root, const std::string& rel, httplib::Response& res) {
  if (root.empty()) throw BadRequest(404, "three.js is not installed (scripts/setup.sh)");
  if (rel.empty() || rel.find('\0') != std::string::npos || rel.size() > 512)
    throw BadRequest(400, "bad path");
  std::error_code ec;
  const fs::path p = fs::weakly_canonical(root / fs::path(rel).relative_path(), ec);
  const std::string r = root.string() + "/";
  if (ec || p.string().compare(0, r.size(), r) != 0)
    throw BadRequest(403, "the path leaves the served folder");
  if (!fs::is_regular_file(p, ec)) throw BadRequest(404, "no such file");
  std::ifstream in(p, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  reply(res, text.str(), content_type(p));
}

// The page's module, relative to the page's folder: dist/viewer.js (viewer.js with the parts of
// three.js it uses, bundled and minified by esbuild: scripts/setup.sh) while it is at least as new
// as viewer.js; else viewer.js itself, which imports three.js through index.html's import map. The
// bundle is about a quarter of three.js's bytes, which the browser compiles before anything is
// drawn: about 0.2 s of a page load here (docs/notebook/viewer.md). Checked at every request, so
// an edited viewer.js is served as it is until the bundle is made again.
std::string page_module(const fs::path& assets) {
  std::error_code ec;
  const auto bundle = fs::last_write_time(assets / "dist" / "viewer.js", ec);
  if (ec) return "viewer.js";
  const auto source = fs::last_write_time(assets / "viewer.js", ec);
  return !ec && bundle >= source ? "dist/viewer.js" : "viewer.js";
}

std::string missing_three_page() {
  return "<!doctype html><meta charset=utf-8><title>clothdb view: three.js is missing</title>"
         "<h1>three.js is missing</h1><p id=error>The viewer draws with three.js, installed from "
         "npm into <code>viewer/node_modules</code>. Run <code>scripts/setup.sh</code> (it runs "
         "<code>npm ci</code> in <code>viewer/</code> when npm is installed), then restart "
         "<code>clothdb view</code>.</p>";
}

// Runs a handler, turning its exceptions into answers: BadRequest -> its 4xx, anything else ->
// 500 with the message. The server keeps serving either way.
template <class F>
httplib::Server::Handler guarded(F f) {
  return [f](const httplib::Request& req, httplib::Response& res) {
    try {
      f(req, res);
    } catch (const BadRequest& e) {
      res.status = e.status;
      reply(res, text_of(json{{"error", e.what()}}), "application/json");
    } catch (const std::exception& e) {
      res.status = 500;
      reply(res, text_of(json{{"error", e.what()}}), "application/json");
    }
  };
}

void add_routes(httplib::Server& svr, Viewer& v) {
  // First: cpp-httplib tries the routes in order, each a std::regex match, and this one is asked
  // for several times a second.
  // After `wait` ms, n frames, each dt seconds after the one before (dt 0: the current pose
  // again): each frame's positions and body capsules, one frame after another, as the body; their
  // states as a JSON array in a header.
  svr.Get(
      "/api/frames", guarded([&v](const httplib::Request& req, httplib::Response& res) {
        const double dt = req.has_param("dt")
                              ? parse_number("dt", req.get_param_value("dt"), 0, kMaxStepSeconds)
                              : 0.0;
        const int64_t n =
            req.has_param("n") ? parse_int("n", req.get_param_value("n"), 1, kMaxBatch) : 1;
        // The page asks for its next batch as soon as one arrives and says how long to hold
        // the answer (until its queue runs low): the server is the page's timer (one sleep, not
        // a loaded browser's timers), and the request's latency is hidden. Controls sent
        // meanwhile apply to it.
        const int64_t wait_ms = req.has_param("wait")
                                    ? parse_int("wait", req.get_param_value("wait"), 0, kMaxWaitMs)
                                    : 0;
        if (wait_ms > 0) std::this_thread::sleep_for(std::chrono::milliseconds(wait_ms));
        // Each frame as wire_frame_bytes says.
        const size_t nv = v.vertices, frame_bytes = wire_frame_bytes(nv, v.capsule_count);
        std::string body = take_body(v, size_t(n) * frame_bytes);
        std::string states = "[";
        states.reserve(size_t(n) * 320);
        std::lock_guard<std::mutex> lock(v.mu);
        v.scratch.resize(nv * 6);
        float* p = v.scratch.data();
        // A batch ends before the frame that reaches a node, which starts the next batch: that
        // frame is then made only when the page is about to show it (the hold), so a next-clip
        // choice or blend length set until then applies at this node, however long the batches
        // are in the middle of a clip.
        int64_t k = 0;
        for (; k < n; ++k) {
          if (k > 0 && passes_node(v, dt)) break;
          const auto t0 = Clock::now();
          const int rc = clothrt_player_advance(v.player, dt);
          const clothrt_render_output ro{p, 12, p + nv * 3, 12, nullptr, 0};
          clothrt_player_get_render_mesh(v.player, &ro, nullptr);
          v.last_us = std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
          char* out = body.data() + size_t(k) * frame_bytes;
          // (Aligned: the body is malloc'ed and frame_bytes a multiple of 4.)
          body_at(v, reinterpret_cast<float*>(out) + kFrameHeadFloats);
          quantise_frame(p, p + nv * 3, nv, v.capsule_count, out);
          ++v.frames_served;
          if (k > 0) states += ',';
          append_state(v, states, rc != CLOTHRT_OK ? clothrt_player_errmsg(v.player) : nullptr);
        }
        states += ']';
        res.set_header("X-Clothdb-Frames", states);
        reply_pooled(res, v, std::move(body), size_t(k) * frame_bytes, "application/octet-stream");
      }));
  svr.Get("/", guarded([&v](const httplib::Request&, httplib::Response& res) {
            if (v.three_root.empty()) {
              res.status = 503;
              reply(res, missing_three_page(), "text/html; charset=utf-8");
              return;
            }
            serve_file(v.assets, "index.html", res);
          }));
  svr.Get("/viewer.js", guarded([&v](const httplib::Request&, httplib::Response& res) {
            serve_file(v.assets, page_module(v.assets), res);
          }));
  svr.Get("/viewer.css", guarded([&v](const httplib::Request&, httplib::Response& res) {
            serve_file(v.assets, "viewer.css", res);
          }));
  svr.Get(R"(/three/(.*))", guarded([&v](const httplib::Request& req, httplib::Response& res) {
            serve_file(v.three_root, req.matches[1].str(), res);
          }));
  svr.Get("/api/info", guarded([&v](const httplib::Request&, httplib::Response& res) {
            reply(res, text_of(v.info), "application/json");
          }));
  svr.Get("/api/triangles", guarded([&v](const httplib::Request&, httplib::Response& res) {
            reply(res,
                  std::string(reinterpret_cast<const char*>(v.triangles.data()),
                              v.triangles.size() * sizeof(uint32_t)),
                  "application/octet-stream");
          }));
  svr.Get("/api/clips", guarded([&v](const httplib::Request& req, httplib::Response& res) {
            const std::string by = req.has_param("by") ? req.get_param_value("by") : "strain";
            const auto names = clip_metrics();
            if (std::none_of(names.begin(), names.end(),
                             [&](const ClipMetricName& m) { return m.name == by; }))
              throw BadRequest(400, "by: unknown metric '" + by.substr(0, 40) + "'");
            db::Reader reader = open_reader(v.file);
            reply(res, text_of(clips_list_json(reader, by, 0)), "application/json");
          }));
  svr.Post("/api/control", guarded([&v](const httplib::Request& req, httplib::Response& res) {
             reply(res, control(v, req.body), "application/json");
           }));
  // The server's own CPU time and frames served, for viewer/bench.mjs.
  svr.Get("/api/stats", guarded([&v](const httplib::Request&, httplib::Response& res) {
            rusage ru{};
            getrusage(RUSAGE_SELF, &ru);
            const double cpu = double(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) +
                               1e-6 * double(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec);
            std::lock_guard<std::mutex> lock(v.mu);
            reply(res,
                  text_of(json{{"cpu_seconds", cpu},
                               {"frames", v.frames_served},
                               {"warming", v.warming.load()}}),
                  "application/json");
          }));
}

// SIGINT/SIGTERM stop the server, from a thread that waits for them. They are blocked in every
// other thread, from before the database opens (its prefetch thread inherits the mask), so no
// thread is ever killed mid-request. A signal before serving exits at once (nothing is written).
struct StopSignals {
  sigset_t set;
  std::atomic<int> caught{0};
  std::atomic<bool> serving{false}, finished{false};
  httplib::Server* server = nullptr;
  std::thread waiter;

  explicit StopSignals(httplib::Server* svr) : server(svr) {
    sigemptyset(&set);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGTERM);
    sigaddset(&set, SIGUSR1);  // wakes the waiter when the server stops by itself
    pthread_sigmask(SIG_BLOCK, &set, nullptr);
    // A shell starts background jobs with SIGINT ignored, and an ignored signal never reaches
    // sigwait: the default disposition (never acted on while blocked) lets Ctrl-C / kill -INT in.
    signal(SIGINT, SIG_DFL);
    signal(SIGTERM, SIG_DFL);
    waiter = std::thread([this] {
      int sig = 0;
      sigwait(&set, &sig);
      if (sig == SIGUSR1) return;
      caught = sig;
      if (!serving) {
        std::fprintf(stderr, "view: stopped by signal %d before serving\n", sig);
        std::_Exit(128 + sig);
      }
      // stop() is a no-op until listen has started: repeat until the server has stopped.
      while (!finished) {
        server->stop();
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
      }
    });
  }
  ~StopSignals() {
    finished = true;
    if (caught == 0) pthread_kill(waiter.native_handle(), SIGUSR1);
    waiter.join();
  }
  StopSignals(const StopSignals&) = delete;
  StopSignals& operator=(const StopSignals&) = delete;
};

void run_view(const ViewArgs& a) {
  if (a.port < 0 || a.port > 65535)
    throw std::invalid_argument("--port " + std::to_string(a.port) + ": expected 0..65535");
  httplib::Server svr;
  StopSignals signals(&svr);
  // Everything is checked before serving: a bad database exits non-zero naming the file.
  Viewer v;
  find_assets(v, a.assets.empty() ? std::string(CLOTHDB_SOURCE_DIR) + "/viewer" : a.assets);
  open_viewer(v, a);
  if (!v.body_note.empty()) std::fprintf(stderr, "view: %s\n", v.body_note.c_str());
  if (v.three_root.empty())
    std::fprintf(stderr,
                 "view: three.js is missing in %s/node_modules (run scripts/setup.sh); the page "
                 "says so\n",
                 v.assets.string().c_str());
  if (page_module(v.assets) == "viewer.js")
    std::fprintf(stderr,
                 "view: %s/dist/viewer.js is missing or older than viewer.js: serving viewer.js "
                 "unbundled, which loads slower (scripts/setup.sh bundles it)\n",
                 v.assets.string().c_str());

  // One request per connection (cpp-httplib answers with "Connection: close"). Between two
  // requests a kept-alive connection waits in cpp-httplib 0.11's keep-alive loop, which polls it
  // every 10 ms and sleeps 1 ms in between: two wake-ups per 11 ms of the page's reaction time
  // (80 ms between an answer and the page's next request at load 10: a third of the server's CPU;
  // docs/notebook/viewer.md). A fresh loopback connection (accept, a worker woken, the close)
  // costs less than one such wait, and nothing idles in the loop: the page's other connections
  // (its files, the controls) no longer poll for two seconds after their last request either.
  svr.set_keep_alive_max_count(1);
  // cpp-httplib also waits in that loop for a connection's first request: a connection opened
  // ahead (browsers pre-connect) is dropped after this long.
  svr.set_keep_alive_timeout(2);
  // Headers and body go out in two writes: without TCP_NODELAY, Nagle's algorithm and delayed
  // ACKs held every frame back by tens of milliseconds.
  svr.set_tcp_nodelay(true);
  svr.set_payload_max_length(1 << 20);
  add_routes(svr, v);
  const int port = a.port == 0 ? svr.bind_to_any_port(a.host.c_str())
                               : (svr.bind_to_port(a.host.c_str(), a.port) ? a.port : -1);
  if (port <= 0)
    throw std::runtime_error("cannot listen on " + a.host + ":" + std::to_string(a.port));
  std::printf("http://%s:%d/\n", a.host.c_str(), port);
  std::fflush(stdout);
  std::fprintf(stderr, "view: playing %s (%u vertices); Ctrl-C stops\n", a.file.c_str(),
               v.vertices);
  signals.serving = true;
  const bool ok = svr.listen_after_bind();
  const int caught = signals.caught;
  if (!ok && caught == 0) throw std::runtime_error("the server stopped unexpectedly");
  std::fprintf(stderr, "view: stopped (%s)\n",
               caught == SIGINT    ? "SIGINT"
               : caught == SIGTERM ? "SIGTERM"
                                   : "server");
}

}  // namespace

void register_view_command(CLI::App& app) {
  auto a = std::make_shared<ViewArgs>();
  CLI::App* cmd = app.add_subcommand(
      "view",
      "Plays FILE live in the browser through the runtime library: a local web page with the "
      "cloth, the character's body capsules, the next-clip choice at each node, random walk, "
      "pause, single step, slow motion, blend frames, and the clip table of `clips list`. The "
      "first line printed is the page's URL; Ctrl-C stops. docs/guide/viewer.md.");
  cmd->add_option("FILE", a->file, "clothdb database")->required();
  cmd->add_option("--port", a->port, "TCP port (0: any free port)")->capture_default_str();
  cmd->add_option("--host", a->host,
                  "Address to bind (127.0.0.1: this machine only; use SSH port forwarding "
                  "from elsewhere)")
      ->capture_default_str();
  cmd->add_option("--assets", a->assets,
                  "The page's folder (default: viewer/ of the source tree this was built from)");
  cmd->add_option("--scene", a->scene,
                  "Scene file the database was made from, for the body capsules (default: the "
                  "one the database stores; needed only for files made before scenes were "
                  "stored)");
  cmd->add_option("--seed", a->seed, "Seed of the random walk")->capture_default_str();
  cmd->callback([a] { run_view(*a); });
}

}  // namespace clothdb::cli
