#include "edit/clip_edit.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <stdexcept>

#include "database/codec/codec.hpp"
#include "exchange/body_mesh.hpp"
#include "exchange/point_cache.hpp"
#include "explore/auto_solver.hpp"
#include "quality/clip_quality.hpp"
#include "report/output.hpp"

namespace clothdb {

namespace {

[[noreturn]] void fail(const std::string& message) {
  throw std::runtime_error(message);
}

void check(db::Status st, const db::Error& err) {
  if (st != db::Status::Ok) fail(err.message);
}

// The explorer's epsilon of the newest run that recorded one (its RunSettings record; runs whose
// settings do not parse, e.g. written by an older build with an invalid value, are passed over).
double database_epsilon(db::Reader& reader) {
  std::vector<db::Run> runs;
  db::Error err;
  check(reader.runs(&runs, &err), err);
  for (auto it = runs.rbegin(); it != runs.rend(); ++it) {
    try {
      return db::parse_run_settings_json(it->settings,
                                         reader.path() + ": run " + std::to_string(it->id))
          .epsilon;
    } catch (const db::SettingsError&) {
    }
  }
  fail(reader.path() +
       ": no run records its epsilon (not made by `clothdb precompute`); give "
       "--epsilon");
}

const ExploreEdge& edge_of_clip(const EditContext& ctx, const db::ClothClip& row, int* index) {
  const auto& edges = ctx.scene.graph.edges;
  for (size_t e = 0; e < edges.size(); ++e)
    if (edges[e].db_clip == row.primary_clip) {
      if (index) *index = static_cast<int>(e);
      if (static_cast<int>(edges[e].poses.size()) != row.frame_count)
        fail(ctx.path + ": cloth clip " + std::to_string(row.id) + " has " +
             std::to_string(row.frame_count) + " frames, its primary edge '" + edges[e].name +
             "' " + std::to_string(edges[e].poses.size()));
      return edges[e];
    }
  fail(ctx.path + ": cloth clip " + std::to_string(row.id) + " is along primary clip " +
       std::to_string(row.primary_clip) + ", which no edge of the motion graph is");
}

struct StateData {
  std::vector<float> x, v;
};

StateData decode_state(db::Reader& reader, int64_t id) {
  StateData s;
  codec::DecodeScratch scratch;
  db::Error err;
  check(reader.read_state(id, &s.x, &s.v, scratch, &err), err);
  return s;
}

// Where every path begins: the first state stored at the graph's start node (the settled rest
// state; 0 if there is none).
int64_t start_state_id(const std::vector<db::StoredState>& states, const ExploreGraph& graph) {
  return db::start_state(states, node_edges(graph), graph.start_node);
}

// The state an end of a clip is in: positions of `at`, velocity from the neighbouring frame
// (displacement per frame times the rate). `other` > `at` for the start, < for the end.
void end_state(const std::vector<float>& frames, size_t per_frame, int at, int other, double rate,
               std::vector<float>* x, std::vector<float>* v) {
  x->assign(frames.begin() + static_cast<long>(per_frame * at),
            frames.begin() + static_cast<long>(per_frame * (at + 1)));
  v->assign(per_frame, 0.0f);
  if (other == at) return;
  const double sign = other > at ? 1.0 : -1.0;
  for (size_t i = 0; i < per_frame; ++i)
    (*v)[i] = static_cast<float>(sign * rate *
                                 (frames[per_frame * other + i] - frames[per_frame * at + i]));
}

// How far an edit moves one end of a clip: the state distance between that end of the new and of
// the old frames.
double end_move(const std::vector<float>& now, const std::vector<float>& before, size_t per_frame,
                int at, int other, double rate) {
  std::vector<float> xa, va, xb, vb;
  end_state(now, per_frame, at, other, rate, &xa, &va);
  end_state(before, per_frame, at, other, rate, &xb, &vb);
  return db::state_distance(xa, va, xb, vb, 1.0 / rate);
}

// Ramps frames toward `original` so that the two frames at `end` (0 or the last) are the
// original's and the edit fades in over `ramp` frames (smoothstep).
void ramp_to_original(std::vector<float>& frames, const std::vector<float>& original,
                      size_t per_frame, int frame_count, bool at_start, int ramp) {
  const int hold = std::min(2, frame_count);
  const int span = std::min(frame_count, hold + std::max(0, ramp));
  for (int k = 0; k < span; ++k) {
    const int f = at_start ? k : frame_count - 1 - k;
    double w = 1.0;  // weight of the original
    if (k >= hold) {
      const double t = double(k - hold + 1) / double(span - hold + 1);  // (0, 1)
      w = 1.0 - t * t * (3.0 - 2.0 * t);
    }
    for (size_t i = 0; i < per_frame; ++i) {
      float& value = frames[per_frame * f + i];
      value = static_cast<float>(value + w * (original[per_frame * f + i] - value));
    }
  }
}

std::vector<float> decode_clip_blob(const std::vector<uint8_t>& blob) {
  std::vector<float> out;
  codec::DecodeScratch scratch;
  db::Error err;
  check(codec::decode_all(blob.data(), blob.size(), out, scratch, &err), err);
  return out;
}

// A clip's last frame as the runtime decodes it (only that frame is decoded).
std::vector<float> last_frame(db::Reader& reader, int64_t clip, size_t per_frame) {
  db::ClothClip row;
  db::Error err;
  check(reader.cloth_clip(clip, &row, &err), err);
  std::vector<uint8_t> blob;
  check(reader.clip_blob(clip, &blob, &err), err);
  std::vector<float> out(per_frame);
  codec::DecodeScratch scratch;
  check(
      reader.decode(blob, uint32_t(row.frame_count - 1), 1, out.data(), out.size(), scratch, &err),
      err);
  return out;
}

std::string mm(double metres) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f mm", 1e3 * metres);
  return buf;
}

}  // namespace

EditContext open_edit(const std::string& path, const std::string& scene_file, double epsilon,
                      const std::string& author, const std::string& motions_dir) {
  if (!std::filesystem::exists(path)) fail("cannot open " + path + ": no such file");
  EditContext ctx{path, db::Writer::open(path), {}, {}, 0, author};
  db::Error err;
  check(ctx.reader.open_borrowed(ctx.writer.handle(), ctx.writer.path(), &err), err);
  ctx.scene = load_database_scene(ctx.reader, scene_file, motions_dir);
  db::Garment garment;
  check(ctx.reader.garment(&garment, &err), err);
  if (garment.vertex_count() != static_cast<uint32_t>(ctx.scene.scene.model.vertex_count()))
    fail(path + ": the garment has " + std::to_string(garment.vertex_count()) +
         " vertices, its scene makes " + std::to_string(ctx.scene.scene.model.vertex_count()));
  // The setting the database was simulated with (the scene's, or what --auto chose): what carried
  // forward clips are simulated with, so they match their neighbours.
  try {
    parse_solver_settings_json(garment.solver, path + ": garment solver",
                               &ctx.scene.scene.file.solver, &ctx.scene.scene.file.settings);
  } catch (const std::exception&) {
    // recorded before the full settings were: the scene file's
  }
  ctx.scene.scene.file.settings.threads = 1;
  ctx.epsilon = epsilon > 0 ? epsilon : database_epsilon(ctx.reader);
  return ctx;
}

std::vector<float> read_clip_frames(db::Reader& reader, int64_t clip, db::ClothClip* row) {
  db::Error err;
  if (reader.cloth_clip(clip, row, &err) != db::Status::Ok) fail(err.message);
  std::vector<uint8_t> blob;
  check(reader.clip_blob(clip, &blob, &err), err);
  std::vector<float> out;
  codec::DecodeScratch scratch;
  check(reader.decode_all(blob, &out, scratch, &err), err);  // codec version 1 or 2
  return out;
}

// ---- export / import ----------------------------------------------------------------------------

ExportedClip export_clip(db::Reader& reader, int64_t clip, const std::string& dir,
                         const std::string& scene_file, const std::string& motions_dir,
                         bool with_body) {
  db::ClothClip row;
  const std::vector<float> frames = read_clip_frames(reader, clip, &row);
  db::Garment garment;
  db::ArtistMesh artist;
  db::Error err;
  check(reader.garment(&garment, &err), err);
  check(reader.artist_mesh(&artist, &err), err);
  const int n = static_cast<int>(artist.vertex_count());
  ExportedClip out;
  // The body first: when the scene cannot be rebuilt nothing is written.
  PointCache body;
  int caps = 0;
  std::string body_note;
  double rate = 0;
  try {
    DatabaseScene scene = load_database_scene(reader, scene_file, motions_dir);
    rate = scene.graph.rate;
    const ExploreEdge* edge = nullptr;
    for (const auto& e : scene.graph.edges)
      if (e.db_clip == row.primary_clip) edge = &e;
    if (!edge || static_cast<int>(edge->poses.size()) != row.frame_count)
      fail("its motion graph has no edge of " + std::to_string(row.frame_count) +
           " frames along primary clip " + std::to_string(row.primary_clip));
    if (with_body) {
      const auto capsules = character_space_capsules(scene.scene, edge->poses);
      body.frame_count = row.frame_count;
      for (const auto& at : capsules) append_capsule_mesh_positions(at, body.positions);
      caps = capsules.empty() ? 0 : static_cast<int>(capsules.front().size());
      body.vertex_count =
          static_cast<int>(body.positions.size() / 3 / std::max(1, row.frame_count));
    } else {
      body_note = "not exported (--no-body)";
    }
  } catch (const std::exception& e) {
    if (with_body)
      fail("clip export: " + reader.path() + ": cannot rebuild the scene for the body: " +
           e.what() + " (--no-body exports the cloth alone)");
    body_note = std::string("not exported (--no-body): ") + e.what();
  }
  if (rate <= 0) {
    // Without the scene: the primary clip's recorded rate.
    std::vector<db::PrimaryClip> primaries;
    check(reader.primary_clips(&primaries, &err), err);
    for (const auto& p : primaries)
      if (p.id == row.primary_clip) rate = p.frame_rate;
  }
  make_directories(dir);
  out.cloth_obj = dir + "/cloth.obj";
  out.cloth_pc2 = dir + "/cloth.pc2";
  out.info_json = dir + "/clip.json";
  PointCache cache;
  cache.vertex_count = static_cast<int>(garment.vertex_count());
  cache.frame_count = row.frame_count;
  cache.positions = frames;
  // In the artist's topology (docs/guide/mesh_garments.md): their vertex order, faces and UVs;
  // `clip import` maps it back.
  cache = artist_order(artist, cache);
  write_artist_obj(out.cloth_obj, "cloth_clip_" + std::to_string(clip), cache.positions.data(),
                   artist);
  write_pc2(out.cloth_pc2, cache);
  if (body.vertex_count > 0) {
    out.body_obj = dir + "/body.obj";
    out.body_pc2 = dir + "/body.pc2";
    write_obj(out.body_obj, "body", body.positions.data(), body.vertex_count,
              capsule_mesh_triangles(caps));
    write_pc2(out.body_pc2, body);
  } else {
    // An earlier export's body into the same folder would be read as this clip's (the Blender
    // add-on loads body.obj + body.pc2 when they are there): without a body, none is left.
    for (const char* stale : {"/body.obj", "/body.pc2"}) std::filesystem::remove(dir + stale);
  }
  out.frame_rate = rate;
  out.frames = row.frame_count;
  std::string import =
      "clothdb clip import " + reader.path() + " " + std::to_string(clip) + " " + dir;
  if (!scene_file.empty()) import += " --scene " + scene_file;
  if (!motions_dir.empty()) import += " --motions " + motions_dir;
  nlohmann::json info = {
      {"database", reader.path()},
      {"clip", clip},
      {"primary_clip", row.primary_clip},
      {"start_state", row.start_state},
      {"frames", row.frame_count},
      {"vertices", n},
      {"simulation_vertices", garment.vertex_count()},
      {"topology", artist.source.empty() ? "the simulation mesh (a procedural garment)"
                                         : "the artist's mesh of " + artist.source},
      {"frame_rate", rate},
      {"frame_start", 0},
      {"frame_end", row.frame_count - 1},
      {"space", "character space of each frame (docs/SECONDARY_GRAPH.md), metres, y up"},
      {"codec_bound_m", row.error_bound},
      {"import", import},
  };
  if (!body_note.empty()) info["body"] = body_note;
  write_file_atomic(out.info_json, info.dump(2) + "\n");
  return out;
}

EditedCache read_edited_cache(const std::string& path, const db::ArtistMesh& artist,
                              uint32_t vertex_count, int32_t frame_count, double rate) {
  const std::string file =
      std::filesystem::is_directory(path) ? path + "/cloth.pc2" : std::string(path);
  if (!std::filesystem::exists(file))
    fail(file + ": no such file (a .pc2, or a folder with cloth.pc2)");
  const PointCache cache = read_pc2(file);
  char clip_range[160];
  std::snprintf(clip_range, sizeof clip_range,
                "frames 0-%d at %g fps, as `clip export` wrote them (header start frame 0, "
                "sample rate 1)",
                frame_count - 1, rate);
  // Either topology: the artist's vertex order (what `clip export` writes) or the simulation's.
  if (cache.vertex_count != static_cast<int>(vertex_count) &&
      cache.vertex_count != static_cast<int>(artist.vertex_count()))
    fail(file + ": points: " + std::to_string(cache.vertex_count) + " vertices, the clip has " +
         std::to_string(artist.vertex_count()) +
         (artist.vertex_count() != vertex_count
              ? " in the artist's mesh and " + std::to_string(vertex_count) + " simulated"
              : std::string()) +
         " (the topology changed: keep the vertex order)");
  if (cache.sample_rate != 1.0f) {
    char b[400];
    std::snprintf(b, sizeof b,
                  "%s: header sample rate %g (frames between samples): a retimed or sub-sampled "
                  "export; the clip has one sample per frame (%s). Export every frame, with the "
                  "Mesh Cache's frame scale 1 (docs/guide/blender.md)",
                  file.c_str(), cache.sample_rate, clip_range);
    fail(b);
  }
  if (cache.frame_count != frame_count) {
    char b[500];
    std::snprintf(b, sizeof b,
                  "%s: samples: %d frames, the clip has %d (the clip follows its primary edge "
                  "frame by frame). Its header says frames %g-%g; the clip's are %s: export "
                  "exactly that range (docs/guide/blender.md)",
                  file.c_str(), cache.frame_count, frame_count, cache.start_frame,
                  cache.start_frame + cache.frame_count - 1, clip_range);
    fail(b);
  }
  const size_t n = size_t(cache.vertex_count);
  for (size_t i = 0; i < cache.positions.size(); ++i)
    if (!std::isfinite(cache.positions[i]))
      fail(file + ": frame " + std::to_string(i / 3 / n) + " vertex " + std::to_string(i / 3 % n) +
           ": not a finite coordinate");
  try {
    return {simulation_order(artist, vertex_count, cache, file).positions, cache.start_frame, file};
  } catch (const ExchangeError& e) {
    fail(e.what());
  }
}

std::vector<float> read_edited_frames(const std::string& path, const db::ArtistMesh& artist,
                                      uint32_t vertex_count, int32_t frame_count) {
  return read_edited_cache(path, artist, vertex_count, frame_count, 30).frames;
}

namespace {

// RMS distance between frames `a` and `b` (each per_frame floats) over every `step`-th vertex.
double frame_rms(const float* a, const float* b, size_t per_frame, size_t step) {
  double sum = 0;
  size_t count = 0;
  for (size_t i = 0; i < per_frame; i += 3 * step, ++count)
    for (int k = 0; k < 3; ++k) sum += double(a[i + k] - b[i + k]) * (a[i + k] - b[i + k]);
  return std::sqrt(sum / double(std::max<size_t>(1, count)));
}

// RMS over every frame k of `frames` against the original clip at time offset + scale * k (linear
// between frames, held at either end as Blender's Mesh Cache does).
double timing_rms(const std::vector<float>& frames, const std::vector<float>& original,
                  size_t per_frame, int n, double offset, double scale, size_t step) {
  std::vector<float> at(per_frame);
  double sum = 0;
  for (int k = 0; k < n; ++k) {
    const double t = std::clamp(offset + scale * k, 0.0, double(n - 1));
    const int f0 = std::min(int(t), n - 1), f1 = std::min(f0 + 1, n - 1);
    const float w = float(t - f0);
    const float* a = original.data() + per_frame * f0;
    const float* b = original.data() + per_frame * f1;
    for (size_t i = 0; i < per_frame; i += 3 * step)
      for (int c = 0; c < 3; ++c) at[i + c] = a[i + c] + w * (b[i + c] - a[i + c]);
    const double r = frame_rms(frames.data() + per_frame * k, at.data(), per_frame, step);
    sum += r * r;
  }
  return std::sqrt(sum / n);
}

}  // namespace

// Frames that are not an edit of the clip at all, refused whatever --on-break says
// (docs/guide/blender.md#what-clip-import-checks). In order: a frozen cache (every frame the same
// while the clip moves: an export without the Mesh Cache evaluated); no change (within the codec's
// bound: NoChange); a rigid axis rotation of the whole clip about the origin (what a DCC's axis
// conversion writes, Blender's PC2 export "Convert to Y-up": (x, y, z) -> (x, z, -y)); another
// rigid move, with scale (world space of an object with a transform); the clip shifted by whole
// frames or retimed (a Mesh Cache frame start or frame scale other than the clip's); a change
// that moves most vertices farther than the garment is big.
void refuse_foreign_frames(const std::vector<float>& frames, const std::vector<float>& original,
                           size_t per_frame, double position_bound, float header_start,
                           double rate) {
  const size_t vertices = per_frame / 3, count = original.size() / 3;
  if (vertices == 0 || count == 0) return;
  const int n = static_cast<int>(count / vertices);
  // Every step-th vertex, at most about 512, for the timing and rigid fits (enough to tell).
  const size_t step = std::max<size_t>(1, vertices / 512);
  char b[600];

  double frozen = 0, moving = 0;
  for (int k = 1; k < n; ++k) {
    frozen =
        std::max(frozen, frame_rms(frames.data() + per_frame * k, frames.data(), per_frame, 1));
    moving =
        std::max(moving, frame_rms(original.data() + per_frame * k, original.data(), per_frame, 1));
  }
  if (n > 1 && frozen <= 0.1 * position_bound && moving > 10 * position_bound) {
    std::snprintf(b, sizeof b,
                  "clip import: all %d frames are the same (a frozen cache; the clip moves up to "
                  "%.2f mm RMS from its first frame): the exporter wrote the mesh without its "
                  "animation. In Blender's PC2 export turn on \"Apply Modifiers\" so that the Mesh "
                  "Cache is evaluated (docs/guide/blender.md); refused whatever --on-break says",
                  n, 1e3 * moving);
    fail(b);
  }
  double largest = 0;
  for (size_t i = 0; i < original.size(); ++i)
    largest = std::max(largest, double(std::abs(frames[i] - original[i])));
  if (largest <= position_bound) {
    std::snprintf(b, sizeof b,
                  "clip import: no change: the frames are the stored clip's (largest difference "
                  "%.4f mm, within the codec's bound %.4f mm); nothing written or logged. A "
                  "shape-key edit over a Mesh Cache needs its Deform Mode \"Integrate\" and the "
                  "export's \"Apply Modifiers\" (docs/guide/blender.md)",
                  1e3 * largest, 1e3 * position_bound);
    throw NoChange(b);
  }

  // Garment size: the diagonal of the original first frame's bounding box.
  Vec3 lo = Vec3::Constant(1e300), hi = -lo;
  for (size_t v = 0; v < vertices; ++v) {
    const Vec3 p(original[3 * v], original[3 * v + 1], original[3 * v + 2]);
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const double size = (hi - lo).norm();
  // RMS distance of the import from R * original, over every vertex of every frame.
  auto rms = [&](const Eigen::Matrix3d& r) {
    double sum = 0;
    for (size_t i = 0; i < count; ++i) {
      const Vec3 a(original[3 * i], original[3 * i + 1], original[3 * i + 2]);
      const Vec3 b(frames[3 * i], frames[3 * i + 1], frames[3 * i + 2]);
      sum += (r * a - b).squaredNorm();
    }
    return std::sqrt(sum / double(count));
  };
  const double as_is = rms(Eigen::Matrix3d::Identity());
  if (as_is >= 0.1 * size) {
    // The 23 other rotations that map axes onto axes (signed permutations with determinant +1).
    const int perms[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
    double best = as_is;
    Eigen::Matrix3d best_r = Eigen::Matrix3d::Identity();
    for (const auto& p : perms)
      for (int signs = 0; signs < 8; ++signs) {
        Eigen::Matrix3d r = Eigen::Matrix3d::Zero();
        for (int k = 0; k < 3; ++k) r(k, p[k]) = (signs >> k & 1) ? -1.0 : 1.0;
        if (r.determinant() < 0 || r.isIdentity()) continue;
        const double d = rms(r);
        if (d < best) {
          best = d;
          best_r = r;
        }
      }
    if (best < 0.02 * size) {
      const Eigen::AngleAxisd aa(best_r);
      const Vec3 axis = aa.axis();
      int k = 0;
      axis.cwiseAbs().maxCoeff(&k);
      const bool y_up =
          best_r.isApprox((Eigen::Matrix3d() << 1, 0, 0, 0, 0, 1, 0, -1, 0).finished()) ||
          best_r.isApprox((Eigen::Matrix3d() << 1, 0, 0, 0, 0, -1, 0, 1, 0).finished());
      std::snprintf(b, sizeof b,
                    "clip import: the frames are the clip rotated by %.0f degrees about %s%c (RMS "
                    "%.3g mm from that rotation, %.3g m from the clip): an axis conversion in the "
                    "exporter, not an edit. %s; refused whatever --on-break says",
                    aa.angle() * 180.0 / 3.14159265358979323846, axis[k] < 0 ? "-" : "", "XYZ"[k],
                    1e3 * best, as_is,
                    y_up ? "In Blender's PC2 export (io_export_pc2) turn off \"Convert to Y-up\" "
                           "and export again (docs/guide/blender.md)"
                         : "Export again with the exporter's axis conversion off");
      fail(b);
    }
    // A rigid move with scale of the whole clip (Umeyama 1991, least squares): the object's
    // transform applied, i.e. world space.
    Eigen::Matrix3Xd src(3, 0), dst(3, 0);
    {
      std::vector<double> s_, d_;
      for (int f = 0; f < n; ++f)
        for (size_t v = 0; v < vertices; v += step) {
          const size_t i = 3 * (size_t(f) * vertices + v);
          for (int c = 0; c < 3; ++c) s_.push_back(original[i + c]), d_.push_back(frames[i + c]);
        }
      src = Eigen::Map<Eigen::Matrix3Xd>(s_.data(), 3, Eigen::Index(s_.size() / 3));
      dst = Eigen::Map<Eigen::Matrix3Xd>(d_.data(), 3, Eigen::Index(d_.size() / 3));
    }
    const Eigen::Matrix4d t = Eigen::umeyama(src, dst, true);
    const Eigen::Matrix3d sr = t.topLeftCorner<3, 3>();
    const double scale = std::cbrt(sr.determinant());
    const Eigen::Matrix3Xd fitted = (sr * src).colwise() + t.topRightCorner<3, 1>();
    const double residual = std::sqrt((fitted - dst).colwise().squaredNorm().mean());
    if (scale > 0 && residual < 0.02 * size) {
      const Eigen::AngleAxisd aa(Eigen::Matrix3d(sr / scale));
      // Rounded to the mm printed, without a "-0.000".
      const Vec3 tr =
          (1e3 * t.topRightCorner<3, 1>()).array().round().matrix() * 1e-3 + Vec3::Constant(0.0);
      std::snprintf(b, sizeof b,
                    "clip import: the frames are the clip moved rigidly (translation %.3f %.3f "
                    "%.3f m, rotation %.1f degrees, scale %.3f; RMS %.3g mm from that move, %.3g "
                    "m from the clip): world space, from an object with a transform, not the "
                    "clip's own (local) space. Export in the object's local space, or clear its "
                    "location, rotation and scale (docs/guide/blender.md); refused whatever "
                    "--on-break says",
                    tr.x(), tr.y(), tr.z(), aa.angle() * 180.0 / 3.14159265358979323846, scale,
                    1e3 * residual, as_is);
      fail(b);
    }
  }

  // Timing: the clip at time offset + scale * k in frame k, against the frames as they are.
  if (n >= 4) {
    const double at_once = timing_rms(frames, original, per_frame, n, 0, 1, step);
    double best = at_once, best_offset = 0, best_scale = 1;
    for (int offset = -3; offset <= 3; ++offset)
      for (int sc = 50; sc <= 200; ++sc) {
        if (offset == 0 && sc == 100) continue;
        const double r = timing_rms(frames, original, per_frame, n, offset, sc / 100.0, step);
        if (r < best) best = r, best_offset = offset, best_scale = sc / 100.0;
      }
    if (best < 0.5 * at_once) {
      if (best_scale == 1.0) {
        const int d = static_cast<int>(best_offset);
        std::snprintf(
            b, sizeof b,
            "clip import: the frames are the clip shifted by %d frame%s (frame k holds the clip's "
            "frame k%+d; RMS %.3g mm from that, %.3g mm from the clip as is): exported %s (PC2 "
            "header start frame %g; the clip's frame 0 is at the Mesh Cache's frame start). "
            "Export frames 0-%d with the Mesh Cache's frame start 0 (docs/guide/blender.md); "
            "refused whatever --on-break says",
            std::abs(d), std::abs(d) == 1 ? "" : "s", d, 1e3 * best, 1e3 * at_once,
            d > 0 ? "early: the cache runs ahead of the scene" : "late: the cache lags the scene",
            header_start, n - 1);
      } else {
        std::snprintf(b, sizeof b,
                      "clip import: the frames are the clip retimed by %.2f (frame k holds the "
                      "clip at frame %g + %.2f k; RMS %.3g mm from that, %.3g mm from the clip as "
                      "is): the Mesh Cache's frame scale, or the scene's fps, is not the clip's "
                      "(%g fps). Set frame scale 1 and the scene to %g fps "
                      "(docs/guide/blender.md); refused whatever --on-break says",
                      best_scale, best_offset, best_scale, 1e3 * best, 1e3 * at_once, rate, rate);
      }
      fail(b);
    }
  }

  if (as_is < 0.1 * size) return;  // an edit, large or small: the continuity checks judge it
  // Gross change: most vertices, in some frame, farther from the clip than the garment's size.
  for (size_t f = 0; f < count / vertices; ++f) {
    size_t far = 0;
    for (size_t v = 0; v < vertices; ++v) {
      const size_t i = 3 * (f * vertices + v);
      const Vec3 d(frames[i] - original[i], frames[i + 1] - original[i + 1],
                   frames[i + 2] - original[i + 2]);
      far += d.norm() > size;
    }
    if (2 * far > vertices) {
      std::snprintf(b, sizeof b,
                    "clip import: in frame %zu, %zu of %zu vertices are farther than the garment's "
                    "size (%.3g m) from the clip: not an edit of this clip (another clip, or "
                    "another coordinate frame?); refused whatever --on-break says",
                    f, far, vertices, size);
      fail(b);
    }
  }
}

OnBreak parse_on_break(const std::string& name) {
  if (name == "refuse") return OnBreak::Refuse;
  if (name == "reblend") return OnBreak::Reblend;
  if (name == "ramp") return OnBreak::Ramp;
  fail("--on-break: '" + name + "' is not refuse, reblend or ramp");
}

ImportReport import_clip(EditContext& ctx, int64_t clip, std::vector<float> frames,
                         const ImportOptions& options) {
  db::ClothClip row;
  const std::vector<float> original = read_clip_frames(ctx.reader, clip, &row);
  const ExploreEdge& edge = edge_of_clip(ctx, row, nullptr);
  const size_t per_frame = static_cast<size_t>(ctx.scene.scene.model.vertex_count()) * 3;
  const int n = row.frame_count;
  if (frames.size() != original.size())
    fail("clip import: " + std::to_string(frames.size() / per_frame) + " frames given, clip " +
         std::to_string(clip) + " has " + std::to_string(n));
  const double rate = ctx.scene.graph.rate;
  refuse_foreign_frames(frames, original, per_frame, ctx.writer.codec().position_bound,
                        options.header_start_frame, rate);
  std::vector<db::ClothEdge> all_edges;
  db::Error err;
  check(ctx.reader.cloth_edges(&all_edges, &err), err);
  const std::vector<float> start_x = decode_state(ctx.reader, row.start_state).x;
  // The edges at either end, each with what the clip's end meets there (read once): an out edge's
  // target positions, or the last frame of the clip an edge into the start state comes from.
  struct Neighbour {
    const db::ClothEdge* edge;
    bool out;
    std::vector<float> meets;
  };
  std::vector<Neighbour> neighbours;
  for (const db::ClothEdge& e : all_edges) {
    if (e.from_clip == clip)
      neighbours.push_back({&e, true, decode_state(ctx.reader, e.to_state).x});
    else if (e.to_state == row.start_state)
      neighbours.push_back({&e, false, last_frame(ctx.reader, e.from_clip, per_frame)});
  }

  ImportReport report;
  auto measure = [&] {
    report.start_move = end_move(frames, original, per_frame, 0, std::min(1, n - 1), rate);
    report.end_move = end_move(frames, original, per_frame, n - 1, std::max(0, n - 2), rate);
    report.edges.clear();
    const float* first = frames.data();
    const float* last = frames.data() + per_frame * (n - 1);
    for (const Neighbour& nb : neighbours) {
      const db::ClothEdge& e = *nb.edge;
      EdgeCheck c{e.id, e.from_clip, e.to_state, !nb.out, e.blend_error, 0, 0, false};
      if (nb.out) {
        // An edge back into the clip's own start state sees both ends move.
        c.blend_after = e.blend_error + report.end_move +
                        (e.to_state == row.start_state ? report.start_move : 0.0);
        c.pop = transition_pop(last, nb.meets.data(), per_frame / 3);
      } else {
        c.blend_after = e.blend_error + report.start_move;
        c.pop = std::max(transition_pop(nb.meets.data(), start_x.data(), per_frame / 3),
                         transition_pop(nb.meets.data(), first, per_frame / 3));
      }
      c.broken = c.blend_after > ctx.epsilon;
      report.edges.push_back(c);
    }
  };
  measure();
  const bool start_broken =
      std::any_of(report.edges.begin(), report.edges.end(),
                  [](const EdgeCheck& c) { return c.broken && c.into_start; });
  const bool end_broken = std::any_of(report.edges.begin(), report.edges.end(),
                                      [](const EdgeCheck& c) { return c.broken && !c.into_start; });
  if ((start_broken || end_broken) && options.on_break == OnBreak::Refuse) return report;
  if (options.on_break == OnBreak::Ramp) {
    if (start_broken) ramp_to_original(frames, original, per_frame, n, true, options.ramp_frames);
    if (end_broken) ramp_to_original(frames, original, per_frame, n, false, options.ramp_frames);
    report.ramped_start = start_broken;
    report.ramped_end = end_broken;
    measure();
  }

  // Re-encoded within the file's bound; the metrics are measured on what the runtime decodes.
  double codec_error = 0;
  const std::vector<uint8_t> blob = ctx.writer.encode_clip(
      frames.data(), static_cast<uint32_t>(n), static_cast<uint32_t>(per_frame / 3), &codec_error);
  const std::vector<float> stored = decode_clip_blob(blob);
  ClipQuality quality = measure_clip(ctx.scene.scene, edge.poses, stored);
  quality.halved_steps = -1;  // not simulated: unknown
  report.metrics = to_clip_metrics(quality);
  report.codec_error = codec_error;
  // The stored clip measured as the edit is (its decoded frames), so that before and after differ
  // by the edit alone: the stored metrics were measured on the simulated, unquantised frames.
  ClipQuality before = measure_clip(ctx.scene.scene, edge.poses, original);
  before.halved_steps = -1;
  report.metrics_before = to_clip_metrics(before);
  if (report.metrics.max_strain > 0.10 ||
      report.metrics.max_strain > 2 * report.metrics_before.max_strain) {
    char w[300];
    std::snprintf(w, sizeof w,
                  "max strain %.2f %% after the edit, %.2f %% before (both on the decoded "
                  "frames): above %s; the edit stretches the cloth",
                  100 * report.metrics.max_strain, 100 * report.metrics_before.max_strain,
                  report.metrics.max_strain > 0.10 ? "10 %" : "twice the stored clip's");
    report.strain_warning = w;
  }

  db::Writer::Edit edit(ctx.writer, clip, "import", ctx.author);
  ctx.writer.replace_clip_blob(clip, blob, codec_error, db::ClipStatus::Edited);
  ctx.writer.set_clip_metrics(clip, report.metrics);
  for (const EdgeCheck& c : report.edges) {
    // The clip's own edges: their blend bound and pop with the edited end. Edges into its start
    // state change only when asked to re-blend (their other clips are unchanged).
    if (!c.into_start)
      ctx.writer.set_edge(c.edge, c.to_state, c.blend_after, c.pop);
    else if (options.on_break == OnBreak::Reblend && c.broken)
      ctx.writer.set_edge(c.edge, c.to_state, c.blend_after, c.pop);
  }
  report.edit = edit.commit("imported frames: start moved " + mm(report.start_move) +
                            ", end moved " + mm(report.end_move) +
                            (report.ramped_start || report.ramped_end ? ", ramped" : ""));
  return report;
}

// ---- re-simulation ------------------------------------------------------------------------------

ResimReport resim_clip(EditContext& ctx, int64_t clip, const ResimOptions& options) {
  db::ClothClip row;
  read_clip_frames(ctx.reader, clip, &row);
  int edge_index = 0;
  const ExploreEdge& edge = edge_of_clip(ctx, row, &edge_index);
  const StateData start = decode_state(ctx.reader, row.start_state);
  JobInput job;
  job.edge = edge_index;
  job.x = start.x;
  job.v = start.v;
  job.solver = options.solver;
  job.settings = options.settings;
  job.settings.threads = std::max(1, options.threads);
  job.codec = ctx.writer.codec();
  const JobResult r = run_job(ctx.scene.scene, ctx.scene.graph, job);
  if (!r.stable)
    fail("clip resim: clip " + std::to_string(clip) + " with " + solver_name(options.solver) +
         " is unstable (" + r.message + "); nothing was changed");
  std::vector<float> end_x, end_v;
  {
    codec::DecodeScratch scratch;
    db::Error err;
    check(codec::decode_all(r.end_x_blob.data(), r.end_x_blob.size(), end_x, scratch, &err), err);
    check(codec::decode_all(r.end_v_blob.data(), r.end_v_blob.size(), end_v, scratch, &err), err);
  }
  const double tau = 1.0 / ctx.scene.graph.rate;
  std::vector<db::StoredState> states;
  std::vector<db::ClothEdge> edges;
  db::Error err;
  check(ctx.reader.cloth_states(&states, &err), err);
  check(ctx.reader.cloth_edges(&edges, &err), err);
  int64_t max_state = 0, best_id = 0;
  double best = std::numeric_limits<double>::infinity();
  std::vector<float> best_x;
  for (const auto& s : states) {
    max_state = std::max(max_state, s.id);
    if (node_of_primary_clip(ctx.scene.graph, s.primary_clip) != edge.to_node) continue;
    StateData d = decode_state(ctx.reader, s.id);
    const double dist = db::state_distance(end_x, end_v, d.x, d.v, tau);
    if (dist < best) best = dist, best_id = s.id, best_x = std::move(d.x);
  }
  std::vector<const db::ClothEdge*> out;
  for (const auto& e : edges)
    if (e.from_clip == clip) out.push_back(&e);

  ResimReport report;
  report.metrics = to_clip_metrics(r.quality);
  if (!out.empty()) {
    const StateData old_target = decode_state(ctx.reader, out.front()->to_state);
    report.end_move = db::state_distance(end_x, end_v, old_target.x, old_target.v, tau);
  }
  db::Writer::Edit edit(ctx.writer, clip, "resim", ctx.author);
  ctx.writer.replace_clip_blob(clip, r.clip_blob, r.clip_max_error, db::ClipStatus::Edited);
  ctx.writer.set_clip_metrics(clip, report.metrics);
  const uint32_t vertices = r.vertex_count;
  auto link = [&](int64_t to_state, double blend, const std::vector<float>& target_x) {
    const double pop = transition_pop(r.last.data(), target_x.data(), vertices);
    if (out.empty()) {
      ctx.writer.add_cloth_edge(clip, to_state, blend, pop);
    } else {
      ctx.writer.set_edge(out.front()->id, to_state, blend, pop);
      for (size_t k = 1; k < out.size(); ++k) ctx.writer.set_edge(out[k]->id, to_state, blend, pop);
    }
    report.linked_to = to_state;
    report.blend_error = blend;
  };
  std::string carried;
  if (best_id != 0 && best <= ctx.epsilon) {
    link(best_id, best, best_x);
  } else {
    // A new state: the explorer simulates the clips leaving it (with the database's setting), and
    // so on, only from the states this edit makes.
    report.new_state = true;
    const int64_t id = ctx.writer.add_cloth_state_blobs(
        node_anchor_clip(ctx.scene.graph, edge.to_node), 0, r.end_x_blob, r.end_v_blob, 0, clip);
    link(id, 0.0, end_x);
    ExploreOptions eo;
    eo.epsilon = ctx.epsilon;
    eo.max_frames = options.max_frames;
    eo.batch = options.batch;
    eo.threads = std::max(1, options.threads);
    eo.progress = options.progress;
    eo.min_state_id = id;
    eo.resim_clip = clip;
    const ExploreReport er = explore(ctx.scene.scene, ctx.scene.graph, ctx.writer, eo);
    report.frames_added = er.frames_this_run;
    report.dead_ends_left = er.dead_ends;
    // What the edit added, and how many generations deep (a new state made by a clip that starts
    // at a new state is one generation further).
    std::vector<db::StoredState> now;
    std::vector<db::ClothClip> clips;
    check(ctx.reader.cloth_states(&now, &err), err);
    check(ctx.reader.cloth_clips(&clips, &err), err);
    std::map<int64_t, int64_t> clip_start;
    for (const auto& c : clips) clip_start[c.id] = c.start_state;
    std::map<int64_t, int> depth;
    for (const auto& s : now) {
      if (s.id <= max_state) continue;
      ++report.states_added;
      int d = 1;
      auto from = clip_start.find(s.source_clip);
      if (from != clip_start.end() && depth.count(from->second)) d = depth[from->second] + 1;
      depth[s.id] = d;
      report.depth = std::max(report.depth, d);
    }
    for (const auto& c : clips)
      if (c.start_state > max_state) ++report.clips_added;
    carried = "; carried forward: " + std::to_string(report.states_added) + " new states, " +
              std::to_string(report.clips_added) + " clips, " +
              std::to_string(report.dead_ends_left) + " dead ends left";
  }
  report.edit = edit.commit(std::string("re-simulated with ") + solver_name(options.solver) + " " +
                            solver_settings_json(options.solver, options.settings) +
                            "; end moved " + mm(report.end_move) + carried);
  return report;
}

// ---- flag, delete -------------------------------------------------------------------------------

int64_t set_clip_flag(EditContext& ctx, int64_t clip, bool flagged) {
  db::ClothClip row;
  db::Error err;
  if (ctx.reader.cloth_clip(clip, &row, &err) != db::Status::Ok)
    fail(ctx.path + ": no cloth clip " + std::to_string(clip));
  db::Writer::Edit edit(ctx.writer, clip, flagged ? "flag" : "unflag", ctx.author);
  // Unflagging an edited clip leaves it edited: the flag is about how it looks, not its origin.
  const db::ClipStatus status = flagged                                 ? db::ClipStatus::Flagged
                                : row.status == db::ClipStatus::Flagged ? db::ClipStatus::Ok
                                                                        : row.status;
  ctx.writer.set_clip_status_unlogged(clip, status);
  return edit.commit(std::string(flagged ? "flagged" : "unflagged") + " (was " +
                     db::clip_status_name(row.status) + ")");
}

DeleteReport delete_clip(EditContext& ctx, int64_t clip) {
  db::ClothClip row;
  db::Error err;
  if (ctx.reader.cloth_clip(clip, &row, &err) != db::Status::Ok)
    fail(ctx.path + ": no cloth clip " + std::to_string(clip));
  const ExploreGraph& graph = ctx.scene.graph;
  std::vector<db::StoredState> states;
  std::vector<db::ClothClip> clips;
  std::vector<db::ClothEdge> edges;
  check(ctx.reader.cloth_states(&states, &err), err);
  check(ctx.reader.cloth_clips(&clips, &err), err);
  check(ctx.reader.cloth_edges(&edges, &err), err);
  const StateData start = decode_state(ctx.reader, row.start_state);
  int node = -1;
  for (const auto& s : states)
    if (s.id == row.start_state) node = node_of_primary_clip(graph, s.primary_clip);
  if (row.start_state == start_state_id(states, graph))
    fail(ctx.path + ": clip " + std::to_string(clip) +
         " starts at the start state, where every path begins; re-simulate it (clip resim) or "
         "import a fix instead");
  std::set<std::pair<int64_t, int64_t>> along;  // (state, primary clip) with a clip
  for (const auto& c : clips)
    if (c.id != clip) along.insert({c.start_state, c.primary_clip});
  DeleteReport report;
  report.start_state = row.start_state;
  std::vector<const db::ClothEdge*> into;
  for (const auto& e : edges)
    if (e.to_state == row.start_state && e.from_clip != clip) into.push_back(&e);
  double best = std::numeric_limits<double>::infinity();
  std::vector<float> best_x;
  if (!into.empty()) {
    const double tau = 1.0 / graph.rate;
    for (const auto& s : states) {
      if (s.id == row.start_state || node_of_primary_clip(graph, s.primary_clip) != node) continue;
      bool complete = true;
      for (const auto& e : graph.edges)
        if (e.from_node == node && !along.count({s.id, e.db_clip})) complete = false;
      if (!complete) continue;
      StateData d = decode_state(ctx.reader, s.id);
      const double dist = db::state_distance(start.x, start.v, d.x, d.v, tau);
      if (dist < best) best = dist, report.replacement = s.id, best_x = std::move(d.x);
    }
    if (report.replacement == 0)
      fail(ctx.path + ": clip " + std::to_string(clip) +
           " cannot be deleted: " + std::to_string(into.size()) +
           " edges lead to its start state " + std::to_string(row.start_state) +
           " and no other state at its node has cloth along every way out; re-simulate it "
           "(clip resim) instead");
  }
  // Dead ends linked to this clip (docs/DATABASE.md, "Dead ends and links") continue with the clip
  // of the nearest other state at the node along the same primary clip, so the runtime still never
  // falls back.
  std::vector<db::ClothLink> links, relinked;
  check(ctx.reader.cloth_links(&links, &err), err);
  for (const db::ClothLink& l : links) {
    if (l.to_clip != clip) continue;
    const StateData from = decode_state(ctx.reader, l.from_state);
    db::ClothLink next = l;
    double nearest = std::numeric_limits<double>::infinity();
    for (const auto& c : clips) {
      if (c.id == clip || c.primary_clip != l.primary_clip) continue;
      const StateData to = decode_state(ctx.reader, c.start_state);
      const double d = db::state_distance(from.x, from.v, to.x, to.v, 1.0 / graph.rate);
      if (d < nearest) nearest = d, next.to_clip = c.id;
    }
    if (!std::isfinite(nearest))
      fail(ctx.path + ": clip " + std::to_string(clip) + " cannot be deleted: state " +
           std::to_string(l.from_state) +
           " continues with it through a link and no other clip runs along primary clip " +
           std::to_string(l.primary_clip));
    next.blend_error = nearest;
    relinked.push_back(next);
  }
  const size_t per_frame = start.x.size();
  db::Writer::Edit edit(ctx.writer, clip, "delete", ctx.author);
  ctx.writer.remove_clip(clip);
  for (const db::ClothLink& l : relinked) ctx.writer.add_cloth_link(l);
  for (const db::ClothEdge* e : into) {
    const std::vector<float> from = last_frame(ctx.reader, e->from_clip, per_frame);
    EdgeCheck c{e->id,
                e->from_clip,
                report.replacement,
                true,
                e->blend_error,
                e->blend_error + best,
                transition_pop(from.data(), best_x.data(), per_frame / 3),
                false};
    c.broken = c.blend_after > ctx.epsilon;
    ctx.writer.set_edge(e->id, report.replacement, c.blend_after, c.pop);
    report.rerouted.push_back(c);
  }
  report.edit = edit.commit(
      "deleted clip " + std::to_string(clip) + " (state " + std::to_string(row.start_state) +
      " along primary clip " + std::to_string(row.primary_clip) + "); " +
      std::to_string(into.size()) + " edges into its start state re-routed" +
      (report.replacement ? " to state " + std::to_string(report.replacement) : ""));
  return report;
}

// ---- consistency --------------------------------------------------------------------------------

std::vector<std::string> coverage_gaps(db::Reader& reader, const ExploreGraph& graph) {
  std::vector<db::StoredState> states;
  std::vector<db::ClothClip> clips;
  std::vector<db::ClothEdge> edges;
  db::Error err;
  check(reader.cloth_states(&states, &err), err);
  check(reader.cloth_clips(&clips, &err), err);
  check(reader.cloth_edges(&edges, &err), err);
  std::map<int64_t, int> node;
  for (const auto& s : states) node[s.id] = node_of_primary_clip(graph, s.primary_clip);
  const int64_t start = start_state_id(states, graph);
  std::map<std::pair<int64_t, int64_t>, int64_t> clip_of;  // (state, primary clip) -> clip
  for (const auto& c : clips) clip_of[{c.start_state, c.primary_clip}] = c.id;
  std::map<int64_t, std::vector<int64_t>> next;  // clip -> states
  for (const auto& e : edges) next[e.from_clip].push_back(e.to_state);
  std::vector<std::string> gaps;
  if (start == 0) return {"no state at the start node"};
  std::set<int64_t> seen{start};
  std::deque<int64_t> queue{start};
  while (!queue.empty()) {
    const int64_t s = queue.front();
    queue.pop_front();
    for (const auto& e : graph.edges) {
      if (e.from_node != node[s]) continue;
      auto c = clip_of.find({s, e.db_clip});
      if (c == clip_of.end()) {
        gaps.push_back("state " + std::to_string(s) + " at node " + std::to_string(node[s]) +
                       " has no clip along '" + e.name + "'");
        continue;
      }
      for (int64_t t : next[c->second])
        if (seen.insert(t).second) queue.push_back(t);
    }
  }
  return gaps;
}

}  // namespace clothdb
