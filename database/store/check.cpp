#include "database/store/check.hpp"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <set>

#include "database/codec/codec.hpp"
#include "database/format/cloth_graph.hpp"
#include "database/format/contracts.hpp"
#include "database/format/graph_index.hpp"
#include "database/format/message.hpp"
#include "database/format/meta_keys.hpp"
#include "database/sqlite/statement.hpp"

namespace clothdb::db {
namespace {

using sql::Stmt;

// Runs a query whose rows each describe one problem (first column text) or a count.
void collect(sqlite3* db, const char* sql, CheckReport& report, const char* prefix) {
  Stmt s(db, sql);
  if (!s.ok()) {
    report.problems.push_back(
        format_message("%s: cannot run check: %s", prefix, sqlite3_errmsg(db)));
    return;
  }
  int rc;
  while ((rc = s.step()) == SQLITE_ROW)
    report.problems.push_back(std::string(prefix) + ": " + (s.is_null(0) ? "?" : s.text(0)));
  if (rc != SQLITE_DONE)
    report.problems.push_back(format_message("%s: check failed: %s", prefix, sqlite3_errmsg(db)));
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
    report.problems.push_back(format_message("%s: blob holds %u frames, the row says %lld",
                                             what.c_str(), info.frame_count, (long long)frames));
  if (vertices > 0 && info.vertex_count != vertices)
    report.problems.push_back(format_message("%s: blob holds %u vertices, expected %lld",
                                             what.c_str(), info.vertex_count, (long long)vertices));
  return info;
}

uint64_t count(sqlite3* db, const std::string& sql) {
  Stmt s(db, sql);
  return s.ok() && s.step() == SQLITE_ROW ? uint64_t(s.i64(0)) : 0;
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
      report.problems.push_back(format_message(
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
    if (count > kMax)
      out->push_back(format_message("%s: ... and %d more", kind.c_str(), count - kMax));
  }
};

// The garment row and its arrays, as the runtime reads them.
void check_garment(sqlite3* db, CheckReport& report) {
  Findings f(&report.problems, "garment");
  const uint64_t rows = count(db, "SELECT count(*) FROM garment");
  if (rows != 1) {
    // `graph build --db` makes such a file on purpose, before the precompute fills it.
    f.add(rows == 0 ? "no garment row: the runtime cannot open this file (a file holding only a "
                      "motion graph: `clothdb precompute SCENE --db FILE` explores into it)"
                    : format_message("%llu garment rows, expected one", (unsigned long long)rows));
    if (rows == 0) return;
  }
  Stmt s(db,
         "SELECT vertex_count, triangle_count, triangles, length(rest_positions) FROM garment "
         "LIMIT 1");
  if (!s.ok() || s.step() != SQLITE_ROW) {
    f.add(std::string("cannot read: ") + sqlite3_errmsg(db));
    return;
  }
  const int64_t vertices = s.i64(0), triangles = s.i64(1);
  const uint8_t* tri = static_cast<const uint8_t*>(s.blob(2));
  const int64_t tri_bytes = int64_t(s.bytes(2)), rest_bytes = s.i64(3);
  if (vertices <= 0) f.add(format_message("vertex_count %lld", (long long)vertices));
  if (triangles < 0) f.add(format_message("triangle_count %lld", (long long)triangles));
  if (rest_bytes != vertices * 12)
    f.add(format_message("rest positions hold %lld bytes, %lld vertices need %lld",
                         (long long)rest_bytes, (long long)vertices, (long long)vertices * 12));
  if (tri_bytes != triangles * 12) {
    f.add(format_message("triangle array holds %lld bytes, %lld triangles need %lld (truncated?)",
                         (long long)tri_bytes, (long long)triangles, (long long)triangles * 12));
  } else if (tri) {
    Findings bad(&report.problems, "garment triangle");
    for (int64_t t = 0; t < triangles; ++t)
      for (int k = 0; k < 3; ++k) {
        uint32_t v;
        std::memcpy(&v, tri + 12 * t + 4 * k, 4);
        if (int64_t(v) >= vertices)
          bad.add(format_message("triangle %lld: vertex index %u is out of range (%lld vertices)",
                                 (long long)t, v, (long long)vertices));
      }
  }
}

// The primary and cloth graphs by the rules the runtime refuses a file on (GraphIndex, shared
// with runtime/db.cpp), then what only the check asks: every clip with a way on has an edge, and
// every way out of a state has a clip or a link.
void check_graph(Reader& reader, CheckReport& report) {
  GraphRows rows;
  Error err;
  if (rows.read(reader, &err) != Status::Ok) {
    report.problems.push_back(std::string("graph: cannot read: ") + err.message);
    return;
  }
  std::map<std::string, std::unique_ptr<Findings>> by_kind;
  auto findings = [&](const std::string& kind) -> Findings& {
    auto& f = by_kind[kind];
    if (!f) f = std::make_unique<Findings>(&report.problems, kind);
    return *f;
  };
  GraphIndex index;
  index.build(rows, [&](const GraphFinding& f) {
    // Rows naming missing rows are reported by the SQL checks above (clearer messages), links
    // excepted, which those do not cover.
    if (!f.dangling || std::string(f.kind) == "cloth link") findings(f.kind).add(f.message);
    return true;  // collect them all
  });
  by_kind.clear();  // flushes the "... and N more" lines in kind order
  std::set<std::pair<int, int>> explored, linked;  // (state, primary) with a clip / a link
  std::set<int> with_cloth;                        // primary indices with some cloth clip
  for (const GraphIndex::Clip& c : index.clips) {
    explored.insert({c.state, c.primary});
    with_cloth.insert(c.primary);
  }
  for (const GraphIndex::Link& l : index.links) linked.insert({l.state, l.primary});
  {
    Findings f(&report.problems, "cloth clip");
    for (const GraphIndex::Clip& c : index.clips) {
      if (c.to_state >= 0) continue;
      bool way_on = false;
      for (int b : index.leaving[size_t(index.primaries[size_t(c.primary)].tgt_node)])
        way_on |= with_cloth.count(b) > 0;
      if (way_on)
        f.add(
            format_message("%lld: has no cloth edge out, though its end node has clips with cloth "
                           "leaving it",
                           (long long)c.id));
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
    std::set<int> reached;
    for (const GraphIndex::Clip& c : index.clips)
      if (c.to_state >= 0) reached.insert(c.to_state);
    Findings f(required ? &report.problems : &report.warnings,
               required ? "dead end" : "unexplored");
    for (size_t s = 0; s < index.states.size(); ++s) {
      if (required && !reached.count(int(s))) continue;
      for (int b : index.leaving[size_t(index.states[s].node)])
        if (with_cloth.count(b) && !explored.count({int(s), b}) && !linked.count({int(s), b}))
          f.add(required
                    ? format_message(
                          "state %lld has neither a clip nor a link along primary clip %lld "
                          "(the runtime would have to fall back; run `clothdb precompute` "
                          "again on this database to link its dead ends)",
                          (long long)index.states[s].id, (long long)index.primaries[size_t(b)].id)
                    : format_message(
                          "state %lld has no clip along primary clip %lld (the runtime falls "
                          "back to the nearest state that has one)",
                          (long long)index.states[s].id, (long long)index.primaries[size_t(b)].id));
    }
  }
  const std::vector<PrimaryClip>& pcs = rows.primary_clips;
  std::string start;
  if (reader.meta(meta::kStartClip, &start, &err) == Status::Ok) {
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

// The error contracts of codec version 3 clips (docs/DATABASE.md, "codec_contract"): every
// version 3 clip has one, every row names a version 3 clip, and the figures measured when it was
// encoded lie within its caps. (The original frames are gone after a recode, so the figures are
// checked as recorded; the blob itself is checked by decoding it above.)
static void check_contracts(sqlite3* db, const std::string& path,
                            const std::map<int64_t, uint32_t>& clip_versions, CheckReport& report) {
  std::vector<ClipContract> rows;
  Error err;
  if (clip_contracts(db, path, &rows, &err) != Status::Ok) {
    report.problems.push_back(err.message);
    return;
  }
  std::set<int64_t> with_row;
  for (const ClipContract& c : rows) {
    with_row.insert(c.clip);
    const auto v = clip_versions.find(c.clip);
    if (v == clip_versions.end()) {
      report.problems.push_back(
          format_message("codec_contract: clip %lld does not exist", (long long)c.clip));
      continue;
    }
    if (v->second != codec::kFormatVersionV3 && v->second != 0)
      report.problems.push_back(format_message(
          "cloth clip %lld: a codec_contract row, but its blob is codec version %u (the contract "
          "is version 3's)",
          (long long)c.clip, v->second));
    if (!(c.caps.rms > 0 && c.caps.max > 0 && c.caps.jitter > 0))
      report.problems.push_back(format_message(
          "cloth clip %lld: codec_contract caps must be positive", (long long)c.clip));
    else if (!codec::within(c.measured, c.caps, 1e-9))
      report.problems.push_back(format_message(
          "cloth clip %lld: contract %s exceeds its caps (RMS %g / max %g / jitter %g mm)",
          (long long)c.clip, codec::describe(c.measured).c_str(), c.caps.rms * 1e3,
          c.caps.max * 1e3, c.caps.jitter * 1e3));
  }
  for (const auto& [id, version] : clip_versions)
    if (version == codec::kFormatVersionV3 && !with_row.count(id))
      report.problems.push_back(format_message(
          "cloth clip %lld: codec version 3 blob without a codec_contract row", (long long)id));
}

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
      Stmt s(db, "PRAGMA integrity_check(20)");
      while (s.ok() && s.step() == SQLITE_ROW)
        if (s.text(0) != "ok") report.problems.push_back("sqlite integrity_check: " + s.text(0));
    }
    sqlite3_close_v2(db);
    return report;
  }
  sqlite3* db = reader.handle();
  // Everything below reads one consistent snapshot even while a writer commits.
  sqlite3_exec(db, "BEGIN", nullptr, nullptr, nullptr);

  {
    Stmt ic(db, "PRAGMA integrity_check(100)");
    if (ic.ok()) {
      while (ic.step() == SQLITE_ROW) {
        const std::string row = ic.is_null(0) ? "?" : ic.text(0);
        if (row != "ok") report.problems.push_back("sqlite integrity_check: " + row);
      }
    } else {
      report.problems.push_back(std::string("sqlite integrity_check: ") + sqlite3_errmsg(db));
    }
  }

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
  {
    // The artist's mesh and its map (the runtime refuses a file whose map names a vertex the
    // garment lacks): the reader's own check, db::check_artist_mesh.
    ArtistMesh mesh;
    Error mesh_err;
    if (count(db, "SELECT count(*) FROM garment") == 1 &&
        reader.artist_mesh(&mesh, &mesh_err) != Status::Ok)
      report.problems.push_back(std::string("garment mesh: ") + mesh_err.message);
  }
  check_graph(reader, report);
  report.rows_checked = count(db,
                              "SELECT (SELECT count(*) FROM cloth_edge) + "
                              "(SELECT count(*) FROM cloth_clip) + "
                              "(SELECT count(*) FROM cloth_state) + "
                              "(SELECT count(*) FROM primary_transition)");

  const int64_t garment_vertices = int64_t(count(db, "SELECT vertex_count FROM garment"));
  codec::DecodeScratch scratch;
  std::map<int64_t, uint32_t> clip_versions;  // for the contracts below
  {
    Stmt s(db,
           "SELECT id, frame_count, vertex_count, frames, error_bound, max_error FROM cloth_clip");
    while (s.ok() && s.step() == SQLITE_ROW) {
      const int64_t id = s.i64(0);
      const int64_t vertices = s.i64(2);
      const std::string what = format_message("cloth clip %lld", (long long)id);
      if (garment_vertices > 0 && vertices != garment_vertices)
        report.problems.push_back(format_message("%s: %lld vertices, the garment has %lld",
                                                 what.c_str(), (long long)vertices,
                                                 (long long)garment_vertices));
      const codec::BlobInfo info =
          check_blob(s.blob(3), s.bytes(3), what, s.i64(1), vertices, reader, scratch, report);
      clip_versions[id] = info.version;
      // The bound: the blob's codec bound and the error measured when it was encoded must lie
      // within the clip's recorded bound (after `db recode`, the old bound plus the new one).
      // Without the simulation's own frames this is what can be checked; the decoder itself
      // range-checks every value against the blob's grid.
      const double bound = s.f64(4), max_error = s.f64(5);
      const double slack = 1 + 1e-9;
      if (info.version != 0 && !s.is_null(4) && info.bound > bound * slack)
        report.problems.push_back(
            format_message("%s: blob bound %g m exceeds the recorded bound %g m", what.c_str(),
                           info.bound, bound));
      if (!s.is_null(4) && !s.is_null(5) && !(max_error <= bound * slack))
        report.problems.push_back(
            format_message("%s: measured error %g m exceeds the recorded bound %g m", what.c_str(),
                           max_error, bound));
    }
  }
  check_contracts(db, path, clip_versions, report);
  {
    Stmt s(db, "SELECT id, vertex_count, positions, velocities FROM cloth_state");
    while (s.ok() && s.step() == SQLITE_ROW) {
      const int64_t id = s.i64(0);
      const int64_t vertices = s.i64(1);
      if (garment_vertices > 0 && vertices != garment_vertices)
        report.problems.push_back(
            format_message("cloth state %lld: %lld vertices, the garment has %lld", (long long)id,
                           (long long)vertices, (long long)garment_vertices));
      for (int col : {2, 3}) {
        const std::string what = format_message("cloth state %lld %s", (long long)id,
                                                col == 2 ? "positions" : "velocities");
        check_blob(s.blob(col), s.bytes(col), what, 1, vertices, reader, scratch, report);
      }
    }
  }
  {
    Stmt s(db, "SELECT id, old_frames FROM edit_log WHERE old_frames IS NOT NULL");
    while (s.ok() && s.step() == SQLITE_ROW)
      check_blob(s.blob(1), s.bytes(1), format_message("edit %lld old frames", (long long)s.i64(0)),
                 0, garment_vertices, reader, scratch, report);
  }
  check_new_state_ends(reader, report);
  sqlite3_exec(db, "COMMIT", nullptr, nullptr, nullptr);
  return report;
}

DatabaseInfo read_database_info(const std::string& path) {
  Reader reader;
  Error err;
  throw_if_error(reader.open(path, &err), err);
  DatabaseInfo info;
  info.path = path;
  std::error_code ec;
  info.file_bytes = std::filesystem::file_size(path, ec);
  const auto wal = std::filesystem::file_size(path + "-wal", ec);
  if (!ec) info.file_bytes += wal;
  info.schema_version = reader.schema_version();
  info.codec = reader.codec();
  throw_if_error(reader.all_meta(&info.meta, &err), err);
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
  info.clips_v2 = count(db, "SELECT count(*) FROM cloth_clip WHERE " +
                                codec::version_is_sql("frames", codec::kFormatVersionV2));
  info.clips_v3 = count(db, "SELECT count(*) FROM cloth_clip WHERE " +
                                codec::version_is_sql("frames", codec::kFormatVersionV3));
  info.clips_v1 = info.cloth_clips - info.clips_v2 - info.clips_v3;
  {
    std::vector<ClipContract> rows;
    throw_if_error(clip_contracts(db, path, &rows, &err), err);
    info.contracts = rows.size();
    for (const auto& c : rows) {
      info.worst_contract.rms = std::max(info.worst_contract.rms, c.measured.rms);
      info.worst_contract.max = std::max(info.worst_contract.max, c.measured.max);
      info.worst_contract.jitter = std::max(info.worst_contract.jitter, c.measured.jitter);
      info.loosest_caps.rms = std::max(info.loosest_caps.rms, c.caps.rms);
      info.loosest_caps.max = std::max(info.loosest_caps.max, c.caps.max);
      info.loosest_caps.jitter = std::max(info.loosest_caps.jitter, c.caps.jitter);
    }
  }
  info.states_v2 = count(db, "SELECT count(*) FROM cloth_state WHERE " +
                                 codec::version_is_sql("positions", codec::kFormatVersionV2));
  info.states_v1 = info.cloth_states - info.states_v2;
  throw_if_error(list_bases(db, path, &info.bases, &err), err);
  {
    Stmt s(db,
           "SELECT (SELECT max(max_error) FROM cloth_clip), (SELECT total(cpu_seconds) FROM run)");
    if (s.ok() && s.step() == SQLITE_ROW) {
      info.max_clip_error = s.f64(0);
      info.run_cpu_seconds = s.f64(1);
    }
  }
  if (info.schema_version >= 4) {
    Stmt s(db,
           "SELECT count(*), coalesce(avg(blend_error), 0), coalesce(max(blend_error), 0) FROM "
           "cloth_link");
    if (s.ok() && s.step() == SQLITE_ROW) {
      info.cloth_links = uint64_t(s.i64(0));
      info.mean_link_error = s.f64(1);
      info.max_link_error = s.f64(2);
    }
  }
  {
    Stmt s(db,
           "SELECT (SELECT count(*) FROM cloth_clip c WHERE c.primary_clip = p.id) FROM "
           "primary_clip p");
    while (s.ok() && s.step() == SQLITE_ROW) {
      const auto k = size_t(s.i64(0));
      if (info.clips_per_edge.size() <= k) info.clips_per_edge.resize(k + 1, 0);
      ++info.clips_per_edge[k];
    }
  }
  {
    Stmt s(db, "SELECT notes FROM run WHERE notes != '' ORDER BY id DESC LIMIT 1");
    if (s.ok() && s.step() == SQLITE_ROW) info.last_run_notes = s.text(0);
  }
  {
    Stmt s(db, "SELECT id, started, finished IS NULL FROM run ORDER BY id DESC LIMIT 1");
    if (s.ok() && s.step() == SQLITE_ROW) {
      info.last_run_id = s.i64(0);
      info.last_run_started = s.text(1);
      info.last_run_unfinished = s.i64(2) != 0;
    }
  }
  sqlite3_exec(db, "COMMIT", nullptr, nullptr, nullptr);
  return info;
}

}  // namespace clothdb::db
