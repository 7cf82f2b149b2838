// The rows of a clothdb file as plain structs: what the Reader returns and the Writer takes. One
// definition per row; docs/DATABASE.md describes the columns, database/format/tables.hpp lists the
// tables.
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace clothdb::db {

enum class ClipStatus { Ok, Flagged, Edited };
const char* clip_status_name(ClipStatus status);  // "ok", "flagged", "edited"
bool parse_clip_status(const std::string& name, ClipStatus* status);

struct Garment {
  std::vector<uint32_t> triangles;    // 3 vertex indices per triangle
  std::vector<float> rest_positions;  // 3 floats per vertex, m
  std::string material;               // material settings as given (JSON text)
  std::string solver;                 // solver settings as given (JSON text)
  uint32_t vertex_count() const { return uint32_t(rest_positions.size() / 3); }
};

// A group of the artist's faces (an OBJ `g`/`o`, a glTF or FBX mesh), with the material its
// faces use ("" when none). Its vertices are the corners of its faces: a pin rule's vertex group.
struct ArtistGroup {
  std::string name;
  std::string material;
  std::vector<uint32_t> faces;  // indices into ArtistMesh::face_sizes
};

// The artist's garment mesh as given, the triangulation an engine draws, and the map to the
// simulation mesh (docs/DATABASE.md, "The artist's mesh"; database/format/artist_mesh.hpp builds
// and checks it). "Artist vertices" are the file's vertices in its order (an OBJ's `v` lines, what
// Blender's vertex order and a PC2 follow); a face corner names an artist vertex and, separately,
// a UV and a normal, so UV and normal seams split corners, not vertices. "Render vertices" are
// what an engine's vertex buffer holds: render vertex i < vertex_count() is artist vertex i (with
// the UV and normal of its first corner); each further (vertex, UV, normal) combination a seam
// makes is appended after them, in order of first use.
constexpr uint32_t kNoAttribute = 0xFFFFFFFFu;  // a corner or render vertex without a UV/normal
struct ArtistMesh {
  std::string source;  // the garment file (resolved against the scene's folder); "" if procedural
  std::vector<float> positions;          // 3 per artist vertex: rest, bind space, metres
  std::vector<uint32_t> face_sizes;      // corners per face (3 or more), faces in file order
  std::vector<uint32_t> corners;         // artist vertex per corner, face by face
  std::vector<float> uvs;                // 2 per UV; empty: the mesh has none
  std::vector<uint32_t> corner_uvs;      // per corner (kNoAttribute: none); empty: no UVs
  std::vector<float> normals;            // 3 per normal as given; empty: none
  std::vector<uint32_t> corner_normals;  // per corner; empty: no normals
  std::vector<ArtistGroup> groups;
  // The engine's mesh: per render vertex (artist vertex, UV, normal), and 3 render vertices per
  // triangle (each face fanned from its first corner, in face order).
  std::vector<uint32_t> render_vertices;
  std::vector<uint32_t> render_triangles;
  // Per artist vertex: the simulation vertices and weights its position is made of (3 of each).
  // An index where the weld merged vertices or a seam split them: (v, v, v) with (1, 0, 0);
  // barycentric on a simulation triangle where the simulation mesh differs from the artist's.
  std::vector<uint32_t> map_vertices;
  std::vector<float> map_weights;

  uint32_t vertex_count() const { return uint32_t(positions.size() / 3); }
  uint32_t face_count() const { return uint32_t(face_sizes.size()); }
  uint32_t render_vertex_count() const { return uint32_t(render_vertices.size() / 3); }
  uint32_t render_triangle_count() const { return uint32_t(render_triangles.size() / 3); }
};

struct MotionFile {
  int64_t id = 0;
  std::string path;          // as given in the scene file
  std::string content_hash;  // e.g. "sha256:..." of the file's bytes
};

// A file the scene was built from, stored at precompute so that the database rebuilds its scene
// from any directory (docs/DATABASE.md#stored-sources): the motion manifest, the garment's mesh
// file (and a glTF's external buffers). The scene file itself is meta `scene`.
struct SourceFile {
  int64_t id = 0;
  std::string role;          // "manifest", "garment_mesh", "garment_mesh_part"
  std::string path;          // as the referencing file spells it (relative to it, or absolute)
  std::string content_hash;  // xxh64 of the bytes, as motion_file's
  std::vector<uint8_t> bytes;
};

struct PrimaryClip {
  int64_t id = 0;
  std::string name;
  int64_t motion_file = 0;  // 0: none
  int32_t first_frame = 0;  // in the motion file
  int32_t frame_count = 0;
  double frame_rate = 30;
};

struct PrimaryTransition {
  int64_t id = 0;
  int64_t from_clip = 0;
  int32_t from_frame = 0;
  int64_t to_clip = 0;
  int32_t to_frame = 0;
  int32_t blend_frames = 0;
  double cost = 0;
};

// A cloth state: positions and velocities of the garment at a point (primary clip, frame).
struct StoredState {
  int64_t id = 0;
  int64_t primary_clip = 0;
  int32_t frame = 0;
  int64_t source_clip = 0;  // the cloth clip whose end produced it; 0: initial / dead-end seed
  int64_t run = 0;          // 0: none
  size_t positions_bytes = 0;
  size_t velocities_bytes = 0;
};

// A metric that was not measured (a file of schema version 1, or a clip written without it) is
// NaN (doubles) or -1 (counts) in memory and NULL in the file.
constexpr double kUnknownMetric = std::numeric_limits<double>::quiet_NaN();

// Quality of a cloth clip; precompute/quality/clip_quality.hpp defines and measures each one
// (docs/DATABASE.md). Lengths in metres.
struct ClipMetrics {
  double max_strain = 0;                     // max (l - l0) / l0 over edges and frames
  double max_penetration = 0;                // m, deepest free vertex inside a body capsule
  double mean_penetration = kUnknownMetric;  // m, mean over penetrating vertex-frames
  double jitter = kUnknownMetric;            // m, RMS high-pass (4th difference) motion
  int32_t halved_steps = -1;                 // times the solver halved its step
  int32_t worst_frame = -1;                  // frame of the clip where it looks worst
  int32_t self_intersections = -1;           // most edge-triangle crossings in one frame
};

// A cloth clip: frames simulated from a cloth state along one primary clip.
struct ClothClip {
  int64_t id = 0;
  int64_t start_state = 0;
  int64_t primary_clip = 0;
  int32_t first_frame = 0;  // primary clip frame of the clip's first frame
  int32_t frame_count = 0;
  double error_bound = 0;      // codec bound the frames were stored with, m
  double max_error = 0;        // largest codec error actually measured, m
  double max_strain = 0;       // the quality metrics: ClipMetrics
  double max_penetration = 0;  // m
  ClipStatus status = ClipStatus::Ok;
  int64_t run = 0;
  size_t blob_bytes = 0;
  double mean_penetration = kUnknownMetric;  // m
  double jitter = kUnknownMetric;            // m
  int32_t halved_steps = -1;
  int32_t worst_frame = -1;
  int32_t self_intersections = -1;

  ClipMetrics metrics() const {
    return {max_strain,   max_penetration, mean_penetration,  jitter,
            halved_steps, worst_frame,     self_intersections};
  }
};

// The end of a cloth clip continues into a cloth state (possibly a blend from a different one).
struct ClothEdge {
  int64_t id = 0;
  int64_t from_clip = 0;
  int64_t to_state = 0;
  double blend_error = 0;  // m, state distance between the clip's end and the state (explorer)
  // m: the jump the runtime's offset blend absorbs at this edge, max over vertices of
  // |clip's last frame - state's positions| (clip_quality.hpp); kUnknownMetric if not measured.
  double pop = kUnknownMetric;
};

// A dead end closed without simulating it: state `from_state` has no clip along `primary_clip`,
// so the game continues with clip `to_clip` (along the same primary clip, from the nearest state
// at the same node that has one), blending away `blend_error` (m, db::state_distance of the two
// states). Written by the explorer when its budget ends; the runtime needs no fallback search.
struct ClothLink {
  int64_t id = 0;
  int64_t from_state = 0;
  int64_t primary_clip = 0;
  int64_t to_clip = 0;
  double blend_error = 0;
  int64_t run = 0;  // 0: none recorded
};

// A clip whose end was steered onto a state (docs/DATABASE.md, "Dead ends and links";
// SceneFile::steering in the precompute): how far its unsteered end was from that state (m,
// db::state_distance) and how hard the pull was (the largest displacement of a vertex in one frame,
// m, and that over dt^2, m/s^2).
struct ClipSteering {
  int64_t clip = 0;
  int64_t target_state = 0;
  double distance = 0;
  double displacement = 0;
  double acceleration = 0;
};

struct Run {
  int64_t id = 0;
  std::string started;   // ISO 8601 UTC
  std::string finished;  // empty while running (or if the run was killed)
  std::string settings;  // what was simulated and how (JSON text as given)
  double cpu_seconds = 0;
  std::string host;
  std::string notes;
};

struct EditLogEntry {
  int64_t id = 0;
  std::string time;
  std::string author;
  int64_t clip = 0;
  // "set-status", "replace-frames" (early builds, no changeset), "undo", or an Edit's:
  // "flag", "unflag", "import", "resim", "delete"
  std::string action;
  std::string description;
  std::string old_status, new_status;
  bool has_old_frames = false;  // the previous blob is kept, so the edit can be undone
  int64_t undoes = 0;           // for "undo": the edit it reverted
  bool has_changeset = false;   // an Edit's: every row it changed, as an SQLite changeset
};

struct NewClothClip {
  int64_t start_state = 0;
  int64_t primary_clip = 0;
  int32_t first_frame = 0;
  double max_strain = 0;  // the quality metrics: ClipMetrics
  double max_penetration = 0;
  ClipStatus status = ClipStatus::Ok;
  int64_t run = 0;
  double mean_penetration = kUnknownMetric;  // m
  double jitter = kUnknownMetric;            // m
  int32_t halved_steps = -1;
  int32_t worst_frame = -1;
  int32_t self_intersections = -1;

  void set_metrics(const ClipMetrics& m) {
    max_strain = m.max_strain;
    max_penetration = m.max_penetration;
    mean_penetration = m.mean_penetration;
    jitter = m.jitter;
    halved_steps = m.halved_steps;
    worst_frame = m.worst_frame;
    self_intersections = m.self_intersections;
  }
};

}  // namespace clothdb::db
