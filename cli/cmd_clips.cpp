// `clothdb clips list FILE --worst N --by METRIC [--json]` and `clothdb clip show FILE ID`:
// finding the cloth clips that look wrong (docs/GUIDE.md#fixing-a-bad-clip) from the quality
// metrics the explorer stores (precompute/quality/clip_quality.hpp, docs/DATABASE.md).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "cli_util.hpp"
#include "clips_list.hpp"
#include "cloth/self_intersection.hpp"
#include "commands.hpp"
#include "database/codec/codec.hpp"
#include "database/format/contracts.hpp"
#include "database/store/writer.hpp"
#include "explore/explorer.hpp"
#include "quality/clip_quality.hpp"
#include "render/preview.hpp"
#include "report/output.hpp"
#include "report/svg_plot.hpp"

namespace clothdb::cli {

namespace {

// Everything the two commands show about the clips of one file.
struct ClipTable {
  std::string path;
  std::vector<db::ClothClip> clips;
  std::map<int64_t, std::string> primary_name;
  std::map<int64_t, std::vector<db::ClothEdge>> edges_from;  // clip id -> its out edges
  std::vector<db::StoredState> states;
  // clip id -> how its end was steered (docs/GUIDE.md#the-precompute-kim-et-al-2013, steering)
  std::map<int64_t, db::ClipSteering> steering;
  // clip id -> the most edge-triangle crossings in one of its decoded frames, for the clips that
  // have no stored value (files before schema version 5); filled only when listing by
  // self-intersections (it decodes those clips).
  std::map<int64_t, int> crossings;
  // clip id -> the error contract its codec version 3 blob was encoded within (table
  // codec_contract); clips without one keep the strict per-coordinate bound.
  std::map<int64_t, db::ClipContract> contracts;
};

// A clip's most crossings in one frame: the stored value, else the one measured on its decoded
// frames when listing; -1 if neither.
int clip_crossing_count(const ClipTable& t, const db::ClothClip& c) {
  if (c.self_intersections >= 0) return c.self_intersections;
  auto it = t.crossings.find(c.id);
  return it == t.crossings.end() ? -1 : it->second;
}

// The garment's topology (rest positions zero: only the triangles and edges are used).
ClothMesh garment_topology(db::Reader& reader) {
  db::Garment garment;
  db::Error err;
  if (reader.garment(&garment, &err) != db::Status::Ok) throw std::runtime_error(err.message);
  ClothMesh mesh;
  mesh.rest = Eigen::Matrix3Xd::Zero(3, Eigen::Index(garment.vertex_count()));
  for (size_t k = 0; k + 2 < garment.triangles.size(); k += 3)
    mesh.triangles.push_back(
        {int(garment.triangles[k]), int(garment.triangles[k + 1]), int(garment.triangles[k + 2])});
  build_topology(mesh);
  return mesh;
}

Eigen::Matrix3Xd frame_positions(const std::vector<float>& frames, int f, int n) {
  Eigen::Matrix3Xd m(3, n);
  for (int v = 0; v < n; ++v)
    for (int k = 0; k < 3; ++k)
      m(k, v) = frames[(size_t(f) * size_t(n) + size_t(v)) * 3 + size_t(k)];
  return m;
}

// Edge-triangle crossings of every frame of clip `id` as decoded (cloth/self_intersection.hpp).
std::vector<int> clip_crossings(db::Reader& reader, const ClothMesh& mesh, int64_t id) {
  std::vector<uint8_t> blob;
  std::vector<float> frames;
  codec::DecodeScratch scratch;
  db::Error err;
  if (reader.clip_blob(id, &blob, &err) != db::Status::Ok ||
      reader.decode_all(blob, &frames, scratch, &err) != db::Status::Ok)
    throw std::runtime_error(err.message);
  const int n = mesh.vertex_count();
  const int count = n > 0 ? int(frames.size() / (size_t(n) * 3)) : 0;
  std::vector<int> out;
  for (int f = 0; f < count; ++f)
    out.push_back(count_self_intersections(mesh, frame_positions(frames, f, n)));
  return out;
}

// Fills t.crossings when `metric` is self-intersections, for the clips without a stored value (it
// decodes them).
void measure_crossings_if_listed(db::Reader& reader, ClipTable& t, const char* metric) {
  if (std::string(metric) != "self-intersections") return;
  bool any_unknown = false;
  for (const auto& c : t.clips) any_unknown = any_unknown || c.self_intersections < 0;
  if (!any_unknown) return;
  const ClothMesh mesh = garment_topology(reader);
  for (const auto& c : t.clips) {
    if (c.self_intersections >= 0) continue;
    const std::vector<int> per_frame = clip_crossings(reader, mesh, c.id);
    t.crossings[c.id] =
        per_frame.empty() ? 0 : *std::max_element(per_frame.begin(), per_frame.end());
  }
}

ClipTable read_table(db::Reader& reader) {
  ClipTable t;
  t.path = reader.path();
  db::Error err;
  std::vector<db::PrimaryClip> primary;
  std::vector<db::ClothEdge> edges;
  if (reader.cloth_clips(&t.clips, &err) != db::Status::Ok ||
      reader.primary_clips(&primary, &err) != db::Status::Ok ||
      reader.cloth_edges(&edges, &err) != db::Status::Ok ||
      reader.cloth_states(&t.states, &err) != db::Status::Ok)
    throw std::runtime_error(err.message);
  std::vector<db::ClipSteering> steering;
  if (reader.clip_steering(&steering, &err) != db::Status::Ok)
    throw std::runtime_error(err.message);
  for (const auto& st : steering) t.steering[st.clip] = st;
  for (const auto& p : primary) t.primary_name[p.id] = p.name;
  for (const auto& e : edges) t.edges_from[e.from_clip].push_back(e);
  std::vector<db::ClipContract> contracts;
  if (db::clip_contracts(reader.handle(), reader.path(), &contracts, &err) != db::Status::Ok)
    throw std::runtime_error(err.message);
  for (const auto& c : contracts) t.contracts[c.clip] = c;
  return t;
}

// "0.81/2.90/0.090" (RMS / max / jitter in mm, as measured) or "bound" (strict contract).
std::string contract_cell(const ClipTable& t, int64_t clip) {
  const auto it = t.contracts.find(clip);
  if (it == t.contracts.end()) return "bound";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.2f/%.2f/%.3f", it->second.measured.rms * 1e3,
                it->second.measured.max * 1e3, it->second.measured.jitter * 1e3);
  return buf;
}

// The worst pop over a clip's out edges (NaN if it has none, or none was measured).
double worst_pop(const ClipTable& t, int64_t clip) {
  double worst = db::kUnknownMetric;
  auto it = t.edges_from.find(clip);
  if (it == t.edges_from.end()) return worst;
  for (const auto& e : it->second)
    if (!std::isnan(e.pop)) worst = std::isnan(worst) ? e.pop : std::max(worst, e.pop);
  return worst;
}

// The metrics `--by` accepts, in the order the table shows them.
struct Metric {
  const char* name;  // as given to --by
  const char* json;  // JSON key (unit in the name)
  double scale;      // stored value -> shown value
  double (*get)(const ClipTable&, const db::ClothClip&);
};

const Metric kMetrics[] = {
    {"strain", "max_strain_percent", 100,
     [](const ClipTable&, const db::ClothClip& c) { return c.max_strain; }},
    {"penetration", "max_penetration_mm", 1e3,
     [](const ClipTable&, const db::ClothClip& c) { return c.max_penetration; }},
    {"mean-penetration", "mean_penetration_mm", 1e3,
     [](const ClipTable&, const db::ClothClip& c) { return c.mean_penetration; }},
    {"jitter", "jitter_mm", 1e3, [](const ClipTable&, const db::ClothClip& c) { return c.jitter; }},
    {"halved", "halved_steps", 1,
     [](const ClipTable&, const db::ClothClip& c) {
       return c.halved_steps < 0 ? db::kUnknownMetric : double(c.halved_steps);
     }},
    {"pop", "worst_pop_mm", 1e3,
     [](const ClipTable& t, const db::ClothClip& c) { return worst_pop(t, c.id); }},
    // The largest displacement steering gave a vertex in one frame (0: not steered).
    {"steering", "steering_mm", 1e3,
     [](const ClipTable& t, const db::ClothClip& c) {
       auto it = t.steering.find(c.id);
       return it == t.steering.end() ? 0.0 : it->second.displacement;
     }},
    // The most edge-triangle crossings in one frame (docs/guide/self_collision.md): stored by
    // the precompute, measured on the decoded frames when listing a file from before it was.
    {"self-intersections", "self_intersections", 1,
     [](const ClipTable& t, const db::ClothClip& c) {
       const int k = clip_crossing_count(t, c);
       return k < 0 ? db::kUnknownMetric : double(k);
     }},
};

const Metric& find_metric(const std::string& name) {
  std::string known;
  for (const Metric& m : kMetrics) {
    if (name == m.name) return m;
    known += std::string(known.empty() ? "" : ", ") + m.name;
  }
  throw std::runtime_error("--by: unknown metric '" + name + "' (known: " + known + ")");
}

// A metric as table text: "?" when unknown (a file from before the metrics, or not measured).
std::string cell(double v, const char* fmt) {
  if (std::isnan(v)) return "?";
  char buf[32];
  std::snprintf(buf, sizeof buf, fmt, v);
  return buf;
}

nlohmann::json number_or_null(double v) {
  return std::isnan(v) ? nlohmann::json(nullptr) : nlohmann::json(v);
}

// The clips of `t`, worst `metric` first; unknown values last; ties by id so the listing is
// stable. worst > 0: only that many.
std::vector<const db::ClothClip*> worst_first(const ClipTable& t, const Metric& metric, int worst) {
  std::vector<const db::ClothClip*> order;
  for (const auto& c : t.clips) order.push_back(&c);
  std::stable_sort(order.begin(), order.end(), [&](const db::ClothClip* a, const db::ClothClip* b) {
    const double va = metric.get(t, *a), vb = metric.get(t, *b);
    if (std::isnan(va) != std::isnan(vb)) return std::isnan(vb);
    if (!std::isnan(va) && va != vb) return va > vb;
    return a->id < b->id;
  });
  if (worst > 0 && order.size() > size_t(worst)) order.resize(size_t(worst));
  return order;
}

nlohmann::json list_json(const ClipTable& t, const Metric& metric, int worst) {
  nlohmann::json rows = nlohmann::json::array();
  for (const db::ClothClip* c : worst_first(t, metric, worst)) {
    nlohmann::json row = {
        {"id", c->id},
        {"primary_clip",
         t.primary_name.count(c->primary_clip) ? t.primary_name.at(c->primary_clip) : ""},
        {"primary_clip_id", c->primary_clip},
        {"start_state", c->start_state},
        {"frames", c->frame_count},
        {"status", db::clip_status_name(c->status)}};
    for (const Metric& m : kMetrics) {
      const double v = m.get(t, *c);
      const bool whole =
          std::string(m.name) == "halved" || std::string(m.name) == "self-intersections";
      row[m.json] = whole ? (std::isnan(v) ? nlohmann::json(nullptr) : nlohmann::json(int(v)))
                          : number_or_null(v * m.scale);
    }
    row["worst_frame"] =
        c->worst_frame < 0 ? nlohmann::json(nullptr) : nlohmann::json(c->worst_frame);
    if (const auto k = t.contracts.find(c->id); k != t.contracts.end())
      row["contract_mm"] = {
          {"rms", k->second.measured.rms * 1e3},       {"max", k->second.measured.max * 1e3},
          {"jitter", k->second.measured.jitter * 1e3}, {"rms_cap", k->second.caps.rms * 1e3},
          {"max_cap", k->second.caps.max * 1e3},       {"jitter_cap", k->second.caps.jitter * 1e3}};
    else
      row["contract_mm"] = nullptr;
    rows.push_back(std::move(row));
  }
  return {
      {"file", t.path}, {"by", metric.name}, {"clips_in_file", t.clips.size()}, {"clips", rows}};
}

void list_clips(const std::string& path, int worst, const std::string& by, bool json) {
  const Metric& metric = find_metric(by);
  db::Reader reader = open_reader(path);
  ClipTable t = read_table(reader);
  measure_crossings_if_listed(reader, t, metric.name);
  if (json) {
    std::printf("%s\n", list_json(t, metric, worst).dump(2).c_str());
    return;
  }
  const std::vector<const db::ClothClip*> order = worst_first(t, metric, worst);
  std::printf("%zu of %zu clips in %s, worst %s first (? = not measured)\n", order.size(),
              t.clips.size(), path.c_str(), metric.name);
  std::printf("%6s  %-34s %6s  %-7s %8s %8s %8s %8s %6s %8s %8s %6s %6s  %s\n", "id",
              "primary clip", "frames", "status", "strain%", "pen mm", "mpen mm", "jit mm",
              "halved", "pop mm", "steer mm", "worst", "cross", "codec rms/max/jitter mm");
  for (const db::ClothClip* c : order) {
    std::string name =
        t.primary_name.count(c->primary_clip) ? t.primary_name.at(c->primary_clip) : "?";
    if (name.size() > 34) name = name.substr(0, 31) + "...";
    std::printf(
        "%6lld  %-34s %6d  %-7s %8s %8s %8s %8s %6s %8s %8s %6s %6s  %s\n", (long long)c->id,
        name.c_str(), c->frame_count, db::clip_status_name(c->status),
        cell(100 * c->max_strain, "%.2f").c_str(), cell(1e3 * c->max_penetration, "%.2f").c_str(),
        cell(1e3 * c->mean_penetration, "%.2f").c_str(), cell(1e3 * c->jitter, "%.3f").c_str(),
        c->halved_steps < 0 ? "?" : std::to_string(c->halved_steps).c_str(),
        cell(1e3 * worst_pop(t, c->id), "%.2f").c_str(),
        t.steering.count(c->id) ? cell(1e3 * t.steering.at(c->id).displacement, "%.2f").c_str()
                                : "-",
        c->worst_frame < 0 ? "?" : std::to_string(c->worst_frame).c_str(),
        clip_crossing_count(t, *c) < 0 ? "?" : std::to_string(clip_crossing_count(t, *c)).c_str(),
        contract_cell(t, c->id).c_str());
  }
}

// ---- clip show --------------------------------------------------------------------------------

struct ShowArgs {
  std::string file, png, svg, scene;
  int64_t id = 0;
  int tiles = 12, columns = 4, tile_size = 320;
  bool no_png = false;
};

// Frames for the contact sheet: `count` spread evenly from the first to the last, with the one
// nearest the worst frame replaced by it.
std::vector<int> sheet_frames(int frame_count, int count, int worst) {
  count = std::max(1, std::min(count, frame_count));
  std::vector<int> frames;
  for (int k = 0; k < count; ++k)
    frames.push_back(count == 1 ? 0
                                : int(std::lround(double(k) * (frame_count - 1) / (count - 1))));
  if (worst >= 0 && worst < frame_count) {
    size_t nearest = 0;
    for (size_t k = 1; k < frames.size(); ++k)
      if (std::abs(frames[k] - worst) < std::abs(frames[nearest] - worst)) nearest = k;
    frames[nearest] = worst;
  }
  std::sort(frames.begin(), frames.end());
  frames.erase(std::unique(frames.begin(), frames.end()), frames.end());
  return frames;
}

// The clip's poses and the scene it was simulated in, when the scene can be rebuilt from the
// database (otherwise the reason is printed and the sheet is drawn without the body).
struct ClipScene {
  std::optional<DatabaseScene> scene;
  const ExploreEdge* edge = nullptr;
};

ClipScene clip_scene(db::Reader& reader, const ClipTable& t, const db::ClothClip& c,
                     const std::string& scene_file, uint32_t vertices) {
  ClipScene out;
  try {
    out.scene = load_database_scene(reader, scene_file);
    if (uint32_t(out.scene->scene.model.vertex_count()) != vertices)
      throw std::runtime_error("the scene's garment has " +
                               std::to_string(out.scene->scene.model.vertex_count()) +
                               " vertices, the database's " + std::to_string(vertices));
    for (const auto& e : out.scene->graph.edges)
      if (e.db_clip == c.primary_clip) out.edge = &e;
    if (!out.edge)
      throw std::runtime_error(
          "no edge of its motion graph is primary clip " +
          (t.primary_name.count(c.primary_clip) ? t.primary_name.at(c.primary_clip) : "?"));
    if (int(out.edge->poses.size()) != c.frame_count)
      throw std::runtime_error("primary clip has " + std::to_string(out.edge->poses.size()) +
                               " poses, the cloth clip " + std::to_string(c.frame_count) +
                               " frames");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "clip show: drawing without the body: %s\n", e.what());
    out.scene.reset();
    out.edge = nullptr;
  }
  return out;
}

// Each frame's defects relative to the level where they show (what worst_frame maximises).
void write_frame_plot(const std::string& path, int64_t id, const std::vector<FrameQuality>& q) {
  PlotSpec spec;
  spec.title = "Cloth clip " + std::to_string(id) + ": defects per frame (decoded frames)";
  spec.x_label = "frame";
  spec.y_label = "relative to visible: strain / 10 %, penetration / 5 mm, jitter / 1 mm";
  const char* names[3] = {"strain", "max penetration", "jitter"};
  for (int k = 0; k < 3; ++k) {
    PlotSeries s;
    s.label = names[k];
    s.color = palette_color(size_t(k));
    s.line = true;
    for (size_t f = 0; f < q.size(); ++f) {
      s.x.push_back(double(f));
      s.y.push_back(k == 0   ? q[f].strain / kVisibleStrain
                    : k == 1 ? q[f].max_penetration / kVisiblePenetration
                             : q[f].jitter / kVisibleJitter);
    }
    spec.series.push_back(std::move(s));
  }
  write_file_atomic(path, render_svg(spec));
}

void show_clip(const ShowArgs& a) {
  db::Reader reader = open_reader(a.file);
  const ClipTable t = read_table(reader);
  auto it = std::find_if(t.clips.begin(), t.clips.end(),
                         [&](const db::ClothClip& c) { return c.id == a.id; });
  if (it == t.clips.end()) {
    std::string range = t.clips.empty() ? "it has none"
                                        : "ids " + std::to_string(t.clips.front().id) + " .. " +
                                              std::to_string(t.clips.back().id);
    throw std::runtime_error(a.file + ": no cloth clip " + std::to_string(a.id) + " (" + range +
                             ")");
  }
  const db::ClothClip& c = *it;
  const std::string name =
      t.primary_name.count(c.primary_clip) ? t.primary_name.at(c.primary_clip) : "?";
  std::printf("clip %lld of %s: %d frames along primary clip %lld '%s', status %s, run %lld\n",
              (long long)c.id, a.file.c_str(), c.frame_count, (long long)c.primary_clip,
              name.c_str(), db::clip_status_name(c.status), (long long)c.run);
  std::printf("  max strain        %s %%\n", cell(100 * c.max_strain, "%.3f").c_str());
  std::printf("  max penetration   %s mm\n", cell(1e3 * c.max_penetration, "%.3f").c_str());
  std::printf("  mean penetration  %s mm (over penetrating vertex-frames)\n",
              cell(1e3 * c.mean_penetration, "%.3f").c_str());
  std::printf("  jitter            %s mm (RMS normalised 4th difference, world space)\n",
              cell(1e3 * c.jitter, "%.4f").c_str());
  std::printf("  halved steps      %s\n",
              c.halved_steps < 0 ? "?" : std::to_string(c.halved_steps).c_str());
  std::printf("  worst frame       %s\n",
              c.worst_frame < 0 ? "?" : std::to_string(c.worst_frame).c_str());
  std::printf("  self-intersections %s (most edge-triangle crossings in one frame, as simulated)\n",
              c.self_intersections < 0 ? "?" : std::to_string(c.self_intersections).c_str());
  std::printf("  codec             bound %.3g mm, max error %.3g mm, %zu bytes\n",
              1e3 * c.error_bound, 1e3 * c.max_error, c.blob_bytes);
  for (const auto& s : t.states)
    if (s.id == c.start_state) {
      std::printf("start state %lld at primary clip %lld frame %d, ", (long long)s.id,
                  (long long)s.primary_clip, s.frame);
      if (s.source_clip)
        std::printf("the end of clip %lld\n", (long long)s.source_clip);
      else
        std::printf("the settled rest state\n");
    }
  auto edges = t.edges_from.find(c.id);
  if (edges == t.edges_from.end()) {
    std::printf("out edges: none\n");
  } else {
    std::printf("out edges:\n");
    for (const auto& e : edges->second)
      std::printf("  edge %lld -> state %lld: blend error %.3f mm, pop %s mm%s\n", (long long)e.id,
                  (long long)e.to_state, 1e3 * e.blend_error, cell(1e3 * e.pop, "%.3f").c_str(),
                  e.blend_error > 0 ? " (blended)" : " (its own end: no blend)");
  }
  if (a.no_png) return;

  // The frames as stored (decoded), and the body at each.
  std::vector<uint8_t> blob;
  std::vector<float> frames;
  codec::DecodeScratch scratch;
  db::Error err;
  if (reader.clip_blob(c.id, &blob, &err) != db::Status::Ok ||
      reader.decode_all(blob, &frames, scratch, &err) != db::Status::Ok)
    throw std::runtime_error(err.message);
  db::Garment garment;
  if (reader.garment(&garment, &err) != db::Status::Ok) throw std::runtime_error(err.message);
  const int n = int(garment.vertex_count());
  const ClipScene cs = clip_scene(reader, t, c, a.scene, garment.vertex_count());
  std::vector<std::vector<CapsuleCollider>> body, skeleton;
  if (cs.edge) {
    body = character_space_capsules(cs.scene->scene, cs.edge->poses);
    skeleton = character_space_skeleton(cs.scene->scene, cs.edge->poses);
    std::vector<FrameQuality> per_frame;
    measure_clip(cs.scene->scene, cs.edge->poses, frames, &per_frame);
    write_frame_plot(a.svg, c.id, per_frame);
    std::printf("per-frame plot %s\n", a.svg.c_str());
  }
  std::vector<std::array<int, 3>> triangles(garment.triangles.size() / 3);
  for (size_t k = 0; k < triangles.size(); ++k)
    triangles[k] = {int(garment.triangles[3 * k]), int(garment.triangles[3 * k + 1]),
                    int(garment.triangles[3 * k + 2])};

  // Frames where the cloth passes through itself (docs/guide/self_collision.md): framed in orange
  // on the sheet.
  const std::vector<int> crossings = clip_crossings(reader, garment_topology(reader), c.id);
  int crossing_frames = 0, most = 0;
  for (int k : crossings) crossing_frames += k > 0 ? 1 : 0, most = std::max(most, k);
  std::printf(
      "  decoded frames    %d with edge-triangle crossings, at most %d in one (as stored)\n",
      crossing_frames, most);
  const std::vector<int> shown = sheet_frames(c.frame_count, a.tiles, c.worst_frame);
  auto frame_matrix = [&](int f) {
    Eigen::Matrix3Xd m(3, n);
    for (int v = 0; v < n; ++v)
      for (int k = 0; k < 3; ++k) m(k, v) = frames[(size_t(f) * n + v) * 3 + k];
    return m;
  };
  // One camera for every tile (so motion reads as motion), framing the cloth of the shown frames.
  Eigen::Matrix3Xd all(3, 0);
  for (int f : shown) {
    const Eigen::Matrix3Xd m = frame_matrix(f);
    all.conservativeResize(3, all.cols() + m.cols());
    all.rightCols(m.cols()) = m;
  }
  double floor = all.row(1).minCoeff();
  for (int f : shown)
    for (const auto* caps : {&body, &skeleton})
      for (const auto& cap : caps->empty() ? std::vector<CapsuleCollider>{} : (*caps)[size_t(f)]) {
        floor = std::min({floor, cap.a.y() - cap.radius, cap.b.y() - cap.radius});
        all.conservativeResize(3, all.cols() + 2);
        all.col(all.cols() - 2) = cap.a;
        all.col(all.cols() - 1) = cap.b;
      }
  const PreviewCamera cam = frame_points(all, 1.15);
  std::vector<std::vector<uint8_t>> tiles;
  const int size = a.tile_size;
  for (int f : shown) {
    const Eigen::Matrix3Xd m = frame_matrix(f);
    PreviewScene scene;
    scene.cloth = &m;
    scene.triangles = &triangles;
    if (!body.empty()) scene.capsules = body[size_t(f)];
    if (!skeleton.empty()) scene.skeleton = skeleton[size_t(f)];
    scene.floor_height = floor - 0.01;
    std::vector<uint8_t> tile = render_preview(scene, cam, size, size);
    const bool worst = f == c.worst_frame;
    if (size_t(f) < crossings.size() && crossings[size_t(f)] > 0)
      draw_border(tile, size, size, std::max(6, size / 20), {255, 140, 0});
    if (worst) draw_border(tile, size, size, std::max(3, size / 40), {220, 20, 20});
    draw_number(tile, size, size, size / 40 + 4, size / 40 + 4, f, std::max(2, size / 100),
                worst ? std::array<uint8_t, 3>{220, 20, 20} : std::array<uint8_t, 3>{40, 40, 40});
    tiles.push_back(std::move(tile));
  }
  const int columns = std::max(1, std::min(a.columns, int(tiles.size())));
  const int rows = int((tiles.size() + columns - 1) / columns);
  write_png(a.png, contact_sheet(tiles, size, size, columns), size * columns, size * rows);
  std::string list;
  for (int f : shown) list += (list.empty() ? "" : " ") + std::to_string(f);
  std::printf(
      "contact sheet %s: frames %s%s; worst frame %d framed in red, frames where the cloth "
      "crosses itself in orange\n",
      a.png.c_str(), list.c_str(), body.empty() ? " (without the body)" : " with the body capsules",
      c.worst_frame);
}

}  // namespace

nlohmann::json clips_list_json(db::Reader& reader, const std::string& by, int worst) {
  const Metric& metric = find_metric(by);
  ClipTable t = read_table(reader);
  measure_crossings_if_listed(reader, t, metric.name);
  return list_json(t, metric, worst);
}

std::vector<ClipMetricName> clip_metrics() {
  std::vector<ClipMetricName> names;
  for (const Metric& m : kMetrics) names.push_back({m.name, m.json});
  return names;
}

void register_clip_quality_commands(CLI::App& app) {
  struct ListArgs {
    std::string file, by = "strain";
    int worst = 20;
    bool json = false;
  };
  auto la = std::make_shared<ListArgs>();
  CLI::App& clips = command_group(app, "clips", "Cloth clips of a database, by quality");
  CLI::App* list = clips.add_subcommand(
      "list",
      "Table of the worst cloth clips by a quality metric measured at precompute time "
      "(docs/DATABASE.md): strain (max edge strain, %), penetration (max depth into the body, mm), "
      "mean-penetration (mean depth of penetrating vertex-frames, mm), jitter (RMS normalised 4th "
      "difference, mm), halved (solver step halvings), pop (largest jump at its out edges, mm), "
      "self-intersections (most edge-triangle crossings in one frame, as simulated; files from "
      "before it was stored: measured on the decoded frames when listing by it)");
  list->add_option("FILE", la->file, "clothdb database")->required();
  list->add_option("--worst", la->worst, "Show the N worst clips (0: all)")
      ->capture_default_str()
      ->check(non_negative_number());
  list->add_option("--by", la->by,
                   "strain | penetration | mean-penetration | jitter | halved | pop | steering "
                   "(the largest pull steering gave a vertex in one frame; 0: not steered) | "
                   "self-intersections (decodes every clip)")
      ->capture_default_str();
  list->add_flag("--json", la->json, "Print JSON (lengths in mm, strain in %; null: not measured)");
  list->callback([la] { list_clips(la->file, la->worst, la->by, la->json); });

  auto sa = std::make_shared<ShowArgs>();
  CLI::App& clip = command_group(app, "clip", "Inspect and edit single cloth clips");
  CLI::App* show = clip.add_subcommand(
      "show",
      "One cloth clip's quality metrics, start state and out edges (with their pops), and a PNG "
      "contact sheet of its frames with the body capsules, the worst frame framed in red and "
      "frames where the cloth crosses itself framed in orange");
  show->add_option("FILE", sa->file, "clothdb database")->required();
  show->add_option("ID", sa->id, "Cloth clip id (see `clothdb clips list`)")->required();
  show->add_option("--png", sa->png, "Write the contact sheet here (default: FILE.clip<ID>.png)");
  show->add_flag("--no-png", sa->no_png, "Print only; no contact sheet or plot");
  show->add_option("--svg", sa->svg,
                   "Write the per-frame plot of the defects here (default: the PNG's path with "
                   ".svg; needs the scene)");
  show->add_option(
      "--scene", sa->scene,
      "Scene file the database was made from, for the body (default: the one the database "
      "stores; needed only for files made before scenes were stored)");
  show->add_option("--tiles", sa->tiles, "Frames on the sheet")
      ->capture_default_str()
      ->check(number_in(1, 64));
  show->add_option("--columns", sa->columns, "Tiles per row")
      ->capture_default_str()
      ->check(number_in(1, 16));
  show->add_option("--tile-size", sa->tile_size, "Tile width and height, pixels")
      ->capture_default_str()
      ->check(number_in(64, 1024));
  show->callback([sa] {
    ShowArgs a = *sa;
    if (a.png.empty()) a.png = a.file + ".clip" + std::to_string(a.id) + ".png";
    if (a.svg.empty()) {
      const bool ext = a.png.size() > 4 && a.png.substr(a.png.size() - 4) == ".png";
      a.svg = a.png.substr(0, a.png.size() - (ext ? 4 : 0)) + ".svg";
    }
    show_clip(a);
  });
}

}  // namespace clothdb::cli
