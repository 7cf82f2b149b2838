#include "database/check.hpp"

#include <sqlite3.h>

#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <set>

#include "database/cloth_graph.hpp"
#include "database/codec.hpp"

namespace clothdb::db {
namespace {

std::string format(const char* fmt, ...) __attribute__((format(printf, 1, 2)));
std::string format(const char* fmt, ...) {
  char buf[512];
  va_list args;
  va_start(args, fmt);
  std::vsnprintf(buf, sizeof buf, fmt, args);
  va_end(args);
  return buf;
}

// Runs a query whose rows each describe one problem (first column text) or a count.
void collect(sqlite3* db, const char* sql, CheckReport& report, const char* prefix) {
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db, sql, -1, &s, nullptr) != SQLITE_OK) {
    report.problems.push_back(format("%s: cannot run check: %s", prefix, sqlite3_errmsg(db)));
    return;
  }
  int rc;
  while ((rc = sqlite3_step(s)) == SQLITE_ROW) {
    const unsigned char* t = sqlite3_column_text(s, 0);
    report.problems.push_back(std::string(prefix) + ": " +
                              (t ? reinterpret_cast<const char*>(t) : "?"));
  }
  if (rc != SQLITE_DONE)
    report.problems.push_back(format("%s: check failed: %s", prefix, sqlite3_errmsg(db)));
  sqlite3_finalize(s);
}

// One check of a blob against its row. `frames`/`vertices`: what the row says (0: unknown).
// Returns the blob's header (version 0 if it could not be read).
codec::BlobInfo check_blob(const void* data, size_t size, const std::string& what, int64_t frames,
                           int64_t vertices, Reader& reader, codec::DecodeScratch& scratch,
                           CheckReport& report) {
  ++report.blobs_checked;
  const uint8_t* p = static_cast<const uint8_t*>(data);
  Error err;
  codec::BlobInfo info;
  const codec::Basis* basis = nullptr;  // codec version 2: the basis the blob names
  if (codec::read_info(p, size, &info, &err) != Status::Ok ||
      reader.basis_for(p, size, &basis, &err) != Status::Ok ||
      codec::verify(p, size, scratch, &err, basis) != Status::Ok) {
    report.problems.push_back(what + ": " + err.message);
    return codec::BlobInfo{};
  }
  if (frames > 0 && info.frame_count != frames)
    report.problems.push_back(format("%s: blob holds %u frames, the row says %lld", what.c_str(),
                                     info.frame_count, (long long)frames));
  if (vertices > 0 && info.vertex_count != vertices)
    report.problems.push_back(format("%s: blob holds %u vertices, expected %lld", what.c_str(),
                                     info.vertex_count, (long long)vertices));
  return info;
}

uint64_t count(sqlite3* db, const char* sql) {
  sqlite3_stmt* s = nullptr;
  uint64_t n = 0;
  if (sqlite3_prepare_v2(db, sql, -1, &s, nullptr) == SQLITE_OK && sqlite3_step(s) == SQLITE_ROW)
    n = uint64_t(sqlite3_column_int64(s, 0));
  sqlite3_finalize(s);
  return n;
}

// A clip whose end became a new state (an edge with blend error 0) must end where that state is:
// both were encoded from the same simulated frame, so they differ by at most the codec bound per
// coordinate each, 2 sqrt(3) bound per vertex. Measured with the contract's state distance
// (database/cloth_graph.hpp) on positions alone.
void check_new_state_ends(Reader& reader, CheckReport& report) {
  Error err;
  std::vector<ClothEdge> edges;
  std::vector<ClothClip> clips;
  if (reader.cloth_edges(&edges, &err) != Status::Ok ||
      reader.cloth_clips(&clips, &err) != Status::Ok)
    return;  // reported by the row checks above
  std::map<int64_t, const ClothClip*> clip_by_id;
  for (const ClothClip& c : clips) clip_by_id[c.id] = &c;
  codec::DecodeScratch scratch;
  std::vector<uint8_t> blob;
  std::vector<float> last, x, v;
  for (const ClothEdge& e : edges) {
    if (e.blend_error != 0) continue;
    const auto c = clip_by_id.find(e.from_clip);
    if (c == clip_by_id.end() || c->second->frame_count < 1) continue;
    // The clip's recorded bound composes with any recode (`db recode` adds its own); the state
    // went through the same codec.
    const double bound = std::max(reader.codec().position_bound, c->second->error_bound);
    const double tolerance = 2 * std::sqrt(3.0) * bound * (1 + 1e-6);
    if (reader.clip_blob(e.from_clip, &blob, &err) != Status::Ok ||
        reader.read_state(e.to_state, &x, &v, scratch, &err) != Status::Ok)
      continue;  // a blob that does not decode is reported by check_blob
    last.resize(x.size());
    if (codec::decode_frames(blob.data(), blob.size(), uint32_t(c->second->frame_count - 1), 1,
                             last.data(), last.size(), scratch, &err) != Status::Ok)
      continue;
    const std::vector<float> still(x.size(), 0.0f);
    const double d = state_distance(last, still, x, still, 0.0);
    if (d > tolerance)
      report.problems.push_back(format(
          "cloth edge %lld: clip %lld ends %.3f mm RMS from state %lld, which its end made (blend "
          "error 0; at most %.3f mm allowed by the codec bound)",
          (long long)e.id, (long long)e.from_clip, 1e3 * d, (long long)e.to_state,
          1e3 * tolerance));
  }
}

// Lists the first findings of one kind and then how many more there were.
struct Findings {
  std::vector<std::string>* out;
  std::string kind;
  int count = 0;
  static constexpr int kMax = 20;
  Findings(std::vector<std::string>* o, std::string k) : out(o), kind(std::move(k)) {}
  void add(const std::string& what) {
    if (++count <= kMax) out->push_back(kind + ": " + what);
  }
  ~Findings() {
    if (count > kMax) out->push_back(format("%s: ... and %d more", kind.c_str(), count - kMax));
  }
};

int find_root(std::vector<int>& parent, int i) {
  while (parent[size_t(i)] != i) i = parent[size_t(i)] = parent[size_t(parent[size_t(i)])];
  return i;
}

// The garment row and its arrays, as the runtime reads them.
void check_garment(sqlite3* db, CheckReport& report) {
  Findings f(&report.problems, "garment");
  const uint64_t rows = count(db, "SELECT count(*) FROM garment");
  if (rows != 1) {
    f.add(rows == 0 ? "no garment row: the runtime cannot open this file"
                    : format("%llu garment rows, expected one", (unsigned long long)rows));
    if (rows == 0) return;
  }
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db,
                         "SELECT vertex_count, triangle_count, triangles, "
                         "length(rest_positions) FROM garment LIMIT 1",
                         -1, &s, nullptr) != SQLITE_OK ||
      sqlite3_step(s) != SQLITE_ROW) {
    f.add(std::string("cannot read: ") + sqlite3_errmsg(db));
    sqlite3_finalize(s);
    return;
  }
  const int64_t vertices = sqlite3_column_int64(s, 0), triangles = sqlite3_column_int64(s, 1);
  const uint8_t* tri = static_cast<const uint8_t*>(sqlite3_column_blob(s, 2));
  const int64_t tri_bytes = sqlite3_column_bytes(s, 2), rest_bytes = sqlite3_column_int64(s, 3);
  if (vertices <= 0) f.add(format("vertex_count %lld", (long long)vertices));
  if (triangles < 0) f.add(format("triangle_count %lld", (long long)triangles));
  if (rest_bytes != vertices * 12)
    f.add(format("rest positions hold %lld bytes, %lld vertices need %lld", (long long)rest_bytes,
                 (long long)vertices, (long long)vertices * 12));
  if (tri_bytes != triangles * 12) {
    f.add(format("triangle array holds %lld bytes, %lld triangles need %lld (truncated?)",
                 (long long)tri_bytes, (long long)triangles, (long long)triangles * 12));
  } else if (tri) {
    Findings bad(&report.problems, "garment triangle");
    for (int64_t t = 0; t < triangles; ++t)
      for (int k = 0; k < 3; ++k) {
        uint32_t v;
        std::memcpy(&v, tri + 12 * t + 4 * k, 4);
        if (int64_t(v) >= vertices)
          bad.add(format("triangle %lld: vertex index %u is out of range (%lld vertices)",
                         (long long)t, v, (long long)vertices));
      }
  }
  sqlite3_finalize(s);
}

// The primary and cloth graphs as the runtime joins them (runtime/db.cpp): nodes are the classes
// of clip ends joined by transitions.
void check_graph(Reader& reader, CheckReport& report) {
  std::vector<PrimaryClip> pcs;
  std::vector<PrimaryTransition> transitions;
  std::vector<StoredState> states;
  std::vector<ClothClip> clips;
  std::vector<ClothEdge> edges;
  Error err;
  if (reader.primary_clips(&pcs, &err) != Status::Ok ||
      reader.primary_transitions(&transitions, &err) != Status::Ok ||
      reader.cloth_states(&states, &err) != Status::Ok ||
      reader.cloth_clips(&clips, &err) != Status::Ok ||
      reader.cloth_edges(&edges, &err) != Status::Ok) {
    report.problems.push_back(std::string("graph: cannot read: ") + err.message);
    return;
  }
  std::map<int64_t, int> primary;
  for (size_t i = 0; i < pcs.size(); ++i) primary[pcs[i].id] = int(i);
  {
    Findings f(&report.problems, "primary clip");
    for (const PrimaryClip& p : pcs)
      if (p.frame_count < 2 || !(p.frame_rate > 0) || !std::isfinite(p.frame_rate))
        f.add(format("%lld: %d frames at %g Hz (needs >= 2 frames at a positive rate)",
                     (long long)p.id, p.frame_count, p.frame_rate));
  }
  const int np = int(pcs.size());
  std::vector<int> parent(size_t(2 * np));
  for (int i = 0; i < 2 * np; ++i) parent[size_t(i)] = i;
  std::set<std::pair<int, int>> joined;
  {
    Findings f(&report.problems, "primary transition");
    for (const PrimaryTransition& t : transitions) {
      auto a = primary.find(t.from_clip), b = primary.find(t.to_clip);
      if (a == primary.end() || b == primary.end()) continue;  // reported above
      const PrimaryClip& from = pcs[size_t(a->second)];
      if (t.from_frame != from.frame_count - 1 || t.to_frame != 0)
        f.add(
            format("%lld: joins frame %d of clip %lld (last %d) to frame %d of clip %lld; "
                   "transitions join a clip's last frame to the next clip's first",
                   (long long)t.id, t.from_frame, (long long)t.from_clip, from.frame_count - 1,
                   t.to_frame, (long long)t.to_clip));
      parent[size_t(find_root(parent, 2 * a->second + 1))] = find_root(parent, 2 * b->second);
      joined.insert({a->second, b->second});
    }
  }
  auto src = [&](int p) { return find_root(parent, 2 * p); };
  auto tgt = [&](int p) { return find_root(parent, 2 * p + 1); };
  std::map<int, std::vector<int>> into, out_of;  // node -> primary clips
  for (int i = 0; i < np; ++i) {
    into[tgt(i)].push_back(i);
    out_of[src(i)].push_back(i);
  }
  {
    // A node is where every clip into it may continue with every clip out of it; a missing pair
    // means a transition row was lost.
    Findings f(&report.problems, "primary transition");
    for (const auto& [node, ins] : into)
      for (int a : ins)
        for (int b : out_of[node])
          if (!joined.count({a, b}))
            f.add(format("missing from clip %lld to clip %lld (both meet at one node)",
                         (long long)pcs[size_t(a)].id, (long long)pcs[size_t(b)].id));
  }
  std::map<int64_t, int> state_node;  // state id -> node
  for (const StoredState& s : states) {
    auto p = primary.find(s.primary_clip);
    if (p != primary.end()) state_node[s.id] = src(p->second);
  }
  std::map<int64_t, size_t> clip_index;
  std::set<std::pair<int64_t, int>> explored;  // (state, primary index)
  std::set<int> with_cloth;                    // primary indices with some cloth clip
  {
    Findings f(&report.problems, "cloth clip");
    for (size_t i = 0; i < clips.size(); ++i) {
      const ClothClip& c = clips[i];
      clip_index[c.id] = i;
      auto p = primary.find(c.primary_clip);
      auto s = state_node.find(c.start_state);
      if (p == primary.end() || s == state_node.end()) continue;  // reported above
      const PrimaryClip& pc = pcs[size_t(p->second)];
      if (c.first_frame != 0 || c.frame_count != pc.frame_count)
        f.add(format(
            "%lld: covers frames %d..+%d of primary clip %lld (%d frames); clips span "
            "whole primary clips",
            (long long)c.id, c.first_frame, c.frame_count, (long long)pc.id, pc.frame_count));
      if (s->second != src(p->second))
        f.add(
            format("%lld: starts from state %lld, which is not at primary clip %lld's source "
                   "node",
                   (long long)c.id, (long long)c.start_state, (long long)pc.id));
      explored.insert({c.start_state, p->second});
      with_cloth.insert(p->second);
    }
  }
  std::set<int64_t> has_edge;
  {
    Findings f(&report.problems, "cloth edge");
    for (const ClothEdge& e : edges) {
      auto c = clip_index.find(e.from_clip);
      auto s = state_node.find(e.to_state);
      if (c == clip_index.end() || s == state_node.end()) continue;  // reported above
      has_edge.insert(e.from_clip);
      auto p = primary.find(clips[c->second].primary_clip);
      if (p != primary.end() && s->second != tgt(p->second))
        f.add(
            format("%lld: leads to state %lld, which is not at the end node of clip %lld "
                   "(primary clip %lld)",
                   (long long)e.id, (long long)e.to_state, (long long)e.from_clip,
                   (long long)pcs[size_t(p->second)].id));
    }
  }
  {
    Findings f(&report.problems, "cloth clip");
    for (const ClothClip& c : clips) {
      auto p = primary.find(c.primary_clip);
      if (p == primary.end() || has_edge.count(c.id)) continue;
      bool way_on = false;
      for (int b : out_of[tgt(p->second)]) way_on |= with_cloth.count(b) > 0;
      if (way_on)
        f.add(
            format("%lld: has no cloth edge out, though its end node has clips with cloth "
                   "leaving it",
                   (long long)c.id));
    }
  }
  // Schema 4: every dead end must have a link (ClothLink), so the runtime never searches for a
  // fallback (issue 16). Older files have no links: their dead ends are warnings, as before.
  std::vector<ClothLink> links;
  if (reader.cloth_links(&links, &err) != Status::Ok) {
    report.problems.push_back(std::string("cloth link: cannot read: ") + err.message);
    return;
  }
  std::set<std::pair<int64_t, int>> linked;  // (state, primary index)
  {
    Findings f(&report.problems, "cloth link");
    for (const ClothLink& l : links) {
      auto s = state_node.find(l.from_state);
      auto p = primary.find(l.primary_clip);
      auto c = clip_index.find(l.to_clip);
      if (s == state_node.end() || p == primary.end() || c == clip_index.end()) {
        f.add(format("%lld: names a missing state %lld, primary clip %lld or cloth clip %lld",
                     (long long)l.id, (long long)l.from_state, (long long)l.primary_clip,
                     (long long)l.to_clip));
        continue;
      }
      if (clips[c->second].primary_clip != l.primary_clip)
        f.add(format("%lld: continues with cloth clip %lld, which is not along primary clip %lld",
                     (long long)l.id, (long long)l.to_clip, (long long)l.primary_clip));
      if (s->second != src(p->second))
        f.add(format("%lld: from state %lld, which is not at primary clip %lld's source node",
                     (long long)l.id, (long long)l.from_state, (long long)l.primary_clip));
      if (!(l.blend_error >= 0) || !std::isfinite(l.blend_error))
        f.add(
            format("%lld: blend error %g is not a finite length", (long long)l.id, l.blend_error));
      if (explored.count({l.from_state, p->second}))
        f.add(format("%lld: state %lld already has a clip along primary clip %lld", (long long)l.id,
                     (long long)l.from_state, (long long)l.primary_clip));
      linked.insert({l.from_state, p->second});
    }
  }
  {
    // Once the explorer has linked the dead ends (meta dead_ends_linked), every way out of every
    // state the runtime can reach through a cloth edge must have a clip or a link: the runtime
    // never falls back. Before that (older files, hand-made ones) they are warnings.
    std::string flag;
    const bool required = reader.schema_version() >= 4 &&
                          reader.meta(meta::kDeadEndsLinked, &flag, &err) == Status::Ok &&
                          flag == "1";
    std::set<int64_t> reached;
    for (const ClothEdge& e : edges) reached.insert(e.to_state);
    Findings f(required ? &report.problems : &report.warnings,
               required ? "dead end" : "unexplored");
    for (const StoredState& s : states) {
      auto n = state_node.find(s.id);
      if (n == state_node.end()) continue;
      if (required && !reached.count(s.id)) continue;
      for (int b : out_of[n->second])
        if (with_cloth.count(b) && !explored.count({s.id, b}) && !linked.count({s.id, b}))
          f.add(required
                    ? format("state %lld has neither a clip nor a link along primary clip %lld "
                             "(the runtime would have to fall back; run `clothdb precompute` "
                             "again on this database to link its dead ends)",
                             (long long)s.id, (long long)pcs[size_t(b)].id)
                    : format("state %lld has no clip along primary clip %lld (the runtime falls "
                             "back to the nearest state that has one)",
                             (long long)s.id, (long long)pcs[size_t(b)].id));
    }
  }
  std::string start;
  if (reader.meta("start_clip", &start, &err) == Status::Ok) {
    bool found = false;
    for (const PrimaryClip& p : pcs) found |= std::to_string(p.id) == start || p.name == start;
    if (!found) report.problems.push_back("meta: start_clip '" + start + "' names no primary clip");
  }
  // The error floor the precompute measured (explore/error_floor.hpp): a distance, so a finite
  // number >= 0; the precompute compares every resumed run's epsilon with it.
  std::string floor;
  if (reader.meta(meta::kErrorFloor, &floor, &err) == Status::Ok) {
    char* end = nullptr;
    const double metres = std::strtod(floor.c_str(), &end);
    if (floor.empty() || *end != '\0' || !std::isfinite(metres) || metres < 0)
      report.problems.push_back("meta: error_floor '" + floor +
                                "' is not a distance in metres (a finite number >= 0)");
  }
}

}  // namespace

CheckReport check_database(const std::string& path) {
  CheckReport report;
  Reader reader;
  Error err;
  if (reader.open(path, &err) != Status::Ok) {
    report.problems.push_back(err.message);
    // A damaged file may still answer SQLite's own check, which says more than "cannot read".
    sqlite3* db = nullptr;
    if (err.status != Status::NotClothdb && err.status != Status::NewerVersion &&
        sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr) == SQLITE_OK) {
      sqlite3_stmt* s = nullptr;
      if (sqlite3_prepare_v2(db, "PRAGMA integrity_check(20)", -1, &s, nullptr) == SQLITE_OK) {
        while (sqlite3_step(s) == SQLITE_ROW) {
          const std::string row = reinterpret_cast<const char*>(sqlite3_column_text(s, 0));
          if (row != "ok") report.problems.push_back("sqlite integrity_check: " + row);
        }
      }
      sqlite3_finalize(s);
    }
    sqlite3_close_v2(db);
    return report;
  }
  sqlite3* db = reader.handle();
  // Everything below reads one consistent snapshot even while a writer commits.
  sqlite3_exec(db, "BEGIN", nullptr, nullptr, nullptr);

  sqlite3_stmt* ic = nullptr;
  if (sqlite3_prepare_v2(db, "PRAGMA integrity_check(100)", -1, &ic, nullptr) == SQLITE_OK) {
    while (sqlite3_step(ic) == SQLITE_ROW) {
      const unsigned char* t = sqlite3_column_text(ic, 0);
      const std::string row = t ? reinterpret_cast<const char*>(t) : "?";
      if (row != "ok") report.problems.push_back("sqlite integrity_check: " + row);
    }
  } else {
    report.problems.push_back(std::string("sqlite integrity_check: ") + sqlite3_errmsg(db));
  }
  sqlite3_finalize(ic);

  collect(db,
          "SELECT printf('%s row %d: %s references a missing row', \"table\", rowid, parent) "
          "FROM pragma_foreign_key_check",
          report, "foreign key");
  // Explicit graph checks (the same as the foreign keys for the graph, with clearer messages,
  // and they do not depend on the tables having been created with those constraints).
  collect(db,
          "SELECT printf('cloth edge %d: from clip %d does not exist', e.id, e.from_clip) "
          "FROM cloth_edge e LEFT JOIN cloth_clip c ON c.id = e.from_clip WHERE c.id IS NULL "
          "UNION ALL "
          "SELECT printf('cloth edge %d: to state %d does not exist', e.id, e.to_state) "
          "FROM cloth_edge e LEFT JOIN cloth_state s ON s.id = e.to_state WHERE s.id IS NULL",
          report, "graph");
  collect(db,
          "SELECT printf('cloth clip %d: start state %d does not exist', c.id, c.start_state) "
          "FROM cloth_clip c LEFT JOIN cloth_state s ON s.id = c.start_state WHERE s.id IS NULL "
          "UNION ALL "
          "SELECT printf('cloth clip %d: primary clip %d does not exist', c.id, c.primary_clip) "
          "FROM cloth_clip c LEFT JOIN primary_clip p ON p.id = c.primary_clip WHERE p.id IS NULL "
          "UNION ALL "
          "SELECT printf('cloth state %d: primary clip %d does not exist', s.id, s.primary_clip) "
          "FROM cloth_state s LEFT JOIN primary_clip p ON p.id = s.primary_clip "
          "WHERE p.id IS NULL "
          "UNION ALL "
          "SELECT printf('cloth state %d: frame %d outside primary clip %d (%d frames)', s.id, "
          "s.frame, p.id, p.frame_count) FROM cloth_state s JOIN primary_clip p "
          "ON p.id = s.primary_clip WHERE s.frame < 0 OR s.frame > p.frame_count "
          "UNION ALL "
          "SELECT printf('primary transition %d: clip %d or %d does not exist', t.id, "
          "t.from_clip, t.to_clip) FROM primary_transition t "
          "WHERE t.from_clip NOT IN (SELECT id FROM primary_clip) "
          "OR t.to_clip NOT IN (SELECT id FROM primary_clip) "
          "UNION ALL "
          "SELECT printf('cloth clip %d: status ''%s'' is not ok, flagged or edited', id, status) "
          "FROM cloth_clip WHERE status NOT IN ('ok', 'flagged', 'edited')",
          report, "graph");
  // Quality metrics are lengths and counts: never negative (NULL: not measured). Version 1 files
  // have only the first two.
  collect(db,
          reader.schema_version() >= 2
              ? "SELECT printf('cloth clip %d: negative quality metric (strain %g, penetration "
                "%g, mean penetration %g, jitter %g)', id, max_strain, max_penetration, "
                "mean_penetration, jitter) FROM cloth_clip WHERE max_strain < 0 OR "
                "max_penetration < 0 OR mean_penetration < 0 OR jitter < 0 "
                "UNION ALL SELECT printf('cloth edge %d: negative pop %g', id, pop) FROM "
                "cloth_edge WHERE pop < 0"
              : "SELECT printf('cloth clip %d: negative quality metric (strain %g, penetration "
                "%g)', id, max_strain, max_penetration) FROM cloth_clip WHERE max_strain < 0 OR "
                "max_penetration < 0",
          report, "metrics");
  check_garment(db, report);
  check_graph(reader, report);
  report.rows_checked = count(db,
                              "SELECT (SELECT count(*) FROM cloth_edge) + "
                              "(SELECT count(*) FROM cloth_clip) + "
                              "(SELECT count(*) FROM cloth_state) + "
                              "(SELECT count(*) FROM primary_transition)");

  const int64_t garment_vertices = int64_t(count(db, "SELECT vertex_count FROM garment"));
  codec::DecodeScratch scratch;
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db,
                         "SELECT id, frame_count, vertex_count, frames, error_bound, max_error "
                         "FROM cloth_clip",
                         -1, &s, nullptr) == SQLITE_OK) {
    while (sqlite3_step(s) == SQLITE_ROW) {
      const int64_t id = sqlite3_column_int64(s, 0);
      const int64_t vertices = sqlite3_column_int64(s, 2);
      const std::string what = format("cloth clip %lld", (long long)id);
      if (garment_vertices > 0 && vertices != garment_vertices)
        report.problems.push_back(format("%s: %lld vertices, the garment has %lld", what.c_str(),
                                         (long long)vertices, (long long)garment_vertices));
      const codec::BlobInfo info =
          check_blob(sqlite3_column_blob(s, 3), size_t(sqlite3_column_bytes(s, 3)), what,
                     sqlite3_column_int64(s, 1), vertices, reader, scratch, report);
      // The bound: the blob's codec bound and the error measured when it was encoded must lie
      // within the clip's recorded bound (after `db recode`, the old bound plus the new one).
      // Without the simulation's own frames this is what can be checked; the decoder itself
      // range-checks every value against the blob's grid.
      const double bound = sqlite3_column_double(s, 4), max_error = sqlite3_column_double(s, 5);
      const double slack = 1 + 1e-9;
      if (info.version != 0 && sqlite3_column_type(s, 4) != SQLITE_NULL &&
          info.bound > bound * slack)
        report.problems.push_back(format("%s: blob bound %g m exceeds the recorded bound %g m",
                                         what.c_str(), info.bound, bound));
      if (sqlite3_column_type(s, 4) != SQLITE_NULL && sqlite3_column_type(s, 5) != SQLITE_NULL &&
          !(max_error <= bound * slack))
        report.problems.push_back(format("%s: measured error %g m exceeds the recorded bound %g m",
                                         what.c_str(), max_error, bound));
    }
  }
  sqlite3_finalize(s);
  if (sqlite3_prepare_v2(db, "SELECT id, vertex_count, positions, velocities FROM cloth_state", -1,
                         &s, nullptr) == SQLITE_OK) {
    while (sqlite3_step(s) == SQLITE_ROW) {
      const int64_t id = sqlite3_column_int64(s, 0);
      const int64_t vertices = sqlite3_column_int64(s, 1);
      if (garment_vertices > 0 && vertices != garment_vertices)
        report.problems.push_back(format("cloth state %lld: %lld vertices, the garment has %lld",
                                         (long long)id, (long long)vertices,
                                         (long long)garment_vertices));
      for (int col : {2, 3}) {
        const std::string what =
            format("cloth state %lld %s", (long long)id, col == 2 ? "positions" : "velocities");
        check_blob(sqlite3_column_blob(s, col), size_t(sqlite3_column_bytes(s, col)), what, 1,
                   vertices, reader, scratch, report);
      }
    }
  }
  sqlite3_finalize(s);
  if (sqlite3_prepare_v2(db, "SELECT id, old_frames FROM edit_log WHERE old_frames IS NOT NULL", -1,
                         &s, nullptr) == SQLITE_OK) {
    while (sqlite3_step(s) == SQLITE_ROW) {
      check_blob(sqlite3_column_blob(s, 1), size_t(sqlite3_column_bytes(s, 1)),
                 format("edit %lld old frames", (long long)sqlite3_column_int64(s, 0)), 0,
                 garment_vertices, reader, scratch, report);
    }
  }
  sqlite3_finalize(s);
  check_new_state_ends(reader, report);
  sqlite3_exec(db, "COMMIT", nullptr, nullptr, nullptr);
  return report;
}

DatabaseInfo read_database_info(const std::string& path) {
  Reader reader;
  Error err;
  if (reader.open(path, &err) != Status::Ok) throw ClothdbError(err.status, err.message);
  DatabaseInfo info;
  info.path = path;
  std::error_code ec;
  info.file_bytes = std::filesystem::file_size(path, ec);
  const auto wal = std::filesystem::file_size(path + "-wal", ec);
  if (!ec) info.file_bytes += wal;
  info.schema_version = reader.schema_version();
  info.codec = reader.codec();
  if (reader.all_meta(&info.meta, &err) != Status::Ok) throw ClothdbError(err.status, err.message);
  sqlite3* db = reader.handle();
  sqlite3_exec(db, "BEGIN", nullptr, nullptr, nullptr);
  info.garment_vertices = uint32_t(count(db, "SELECT vertex_count FROM garment"));
  info.garment_triangles = uint32_t(count(db, "SELECT triangle_count FROM garment"));
  info.motion_files = count(db, "SELECT count(*) FROM motion_file");
  info.primary_clips = count(db, "SELECT count(*) FROM primary_clip");
  info.primary_transitions = count(db, "SELECT count(*) FROM primary_transition");
  info.cloth_states = count(db, "SELECT count(*) FROM cloth_state");
  info.cloth_clips = count(db, "SELECT count(*) FROM cloth_clip");
  info.cloth_edges = count(db, "SELECT count(*) FROM cloth_edge");
  info.runs = count(db, "SELECT count(*) FROM run");
  info.edits = count(db, "SELECT count(*) FROM edit_log");
  // A clip end that linked back: its edge goes into a state that its own clip did not make.
  info.linked_edges = count(db,
                            "SELECT count(*) FROM cloth_edge e JOIN cloth_state s ON s.id = "
                            "e.to_state WHERE s.source_clip IS NULL OR s.source_clip != "
                            "e.from_clip");
  info.clips_ok = count(db, "SELECT count(*) FROM cloth_clip WHERE status = 'ok'");
  info.clips_flagged = count(db, "SELECT count(*) FROM cloth_clip WHERE status = 'flagged'");
  info.clips_edited = count(db, "SELECT count(*) FROM cloth_clip WHERE status = 'edited'");
  info.cloth_frames = count(db, "SELECT total(frame_count) FROM cloth_clip");
  info.clip_blob_bytes = count(db, "SELECT total(length(frames)) FROM cloth_clip");
  info.clip_raw_bytes = count(db, "SELECT total(frame_count * vertex_count * 12) FROM cloth_clip");
  info.state_blob_bytes =
      count(db, "SELECT total(length(positions) + length(velocities)) FROM cloth_state");
  info.clips_v2 = count(db, "SELECT count(*) FROM cloth_clip WHERE substr(frames, 5, 1) = x'02'");
  info.clips_v1 = info.cloth_clips - info.clips_v2;
  info.states_v2 =
      count(db, "SELECT count(*) FROM cloth_state WHERE substr(positions, 5, 1) = x'02'");
  info.states_v1 = info.cloth_states - info.states_v2;
  if (list_bases(db, path, &info.bases, &err) != Status::Ok)
    throw ClothdbError(err.status, err.message);
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db,
                         "SELECT (SELECT max(max_error) FROM cloth_clip), "
                         "(SELECT total(cpu_seconds) FROM run)",
                         -1, &s, nullptr) == SQLITE_OK &&
      sqlite3_step(s) == SQLITE_ROW) {
    info.max_clip_error = sqlite3_column_double(s, 0);
    info.run_cpu_seconds = sqlite3_column_double(s, 1);
  }
  sqlite3_finalize(s);
  if (info.schema_version >= 4 &&
      sqlite3_prepare_v2(db,
                         "SELECT count(*), coalesce(avg(blend_error), 0), "
                         "coalesce(max(blend_error), 0) FROM cloth_link",
                         -1, &s, nullptr) == SQLITE_OK &&
      sqlite3_step(s) == SQLITE_ROW) {
    info.cloth_links = uint64_t(sqlite3_column_int64(s, 0));
    info.mean_link_error = sqlite3_column_double(s, 1);
    info.max_link_error = sqlite3_column_double(s, 2);
  }
  sqlite3_finalize(s);
  if (sqlite3_prepare_v2(db,
                         "SELECT (SELECT count(*) FROM cloth_clip c WHERE c.primary_clip = p.id) "
                         "FROM primary_clip p",
                         -1, &s, nullptr) == SQLITE_OK) {
    while (sqlite3_step(s) == SQLITE_ROW) {
      const auto k = size_t(sqlite3_column_int64(s, 0));
      if (info.clips_per_edge.size() <= k) info.clips_per_edge.resize(k + 1, 0);
      ++info.clips_per_edge[k];
    }
  }
  sqlite3_finalize(s);
  if (sqlite3_prepare_v2(db, "SELECT notes FROM run WHERE notes != '' ORDER BY id DESC LIMIT 1", -1,
                         &s, nullptr) == SQLITE_OK &&
      sqlite3_step(s) == SQLITE_ROW && sqlite3_column_text(s, 0))
    info.last_run_notes = reinterpret_cast<const char*>(sqlite3_column_text(s, 0));
  sqlite3_finalize(s);
  sqlite3_exec(db, "COMMIT", nullptr, nullptr, nullptr);
  return info;
}

}  // namespace clothdb::db
