// Hand-editing the cloth clips of a database (docs/GUIDE.md#fixing-a-bad-clip): export a clip for
// Blender and import it back, re-simulate it with other settings, flag or delete it. Every change
// is one db::Writer::Edit (one transaction, logged with its changeset), so `clothdb undo` reverts
// it exactly and a failed edit writes nothing.
//
// Continuity. A clip starts at its start state S (its frame 0 is S's positions) and ends in a cloth
// edge to a state T whose blend error (the explorer's state distance, explore/explorer.hpp) is at
// most epsilon. An edit "moves" an end by the state distance between the new and the old end,
// velocities taken as the frame-to-frame displacement times the rate, so an import of the
// unchanged export moves nothing but the codec's rounding. By the triangle inequality the edge's
// blend error is then at most its old one plus the move, and an end whose bound exceeds epsilon
// breaks continuity: the edges into S (start) and the clip's own out edges (end) are reported.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "database/store/writer.hpp"
#include "explore/explorer.hpp"

namespace clothdb {

// What every edit needs: the database, the scene and motion graph it was made from, its error
// bound and the solver setting it was simulated with.
struct EditContext {
  std::string path;
  db::Writer writer;
  db::Reader reader;
  DatabaseScene scene;  // scene.scene.file.solver/settings: the database's recorded setting
  double epsilon = 0;   // m: the newest run's, unless given
  std::string author;
};

// scene_file, motions_dir: as for load_database_scene ("" = the scene the database stores).
// epsilon <= 0: the newest run's (run settings "epsilon_m"). Throws std::runtime_error naming the
// file and what is missing.
EditContext open_edit(const std::string& path, const std::string& scene_file, double epsilon,
                      const std::string& author, const std::string& motions_dir = "");

// The frames of a clip as stored (decoded), frame_count * V * 3 floats in character space.
std::vector<float> read_clip_frames(db::Reader& reader, int64_t clip, db::ClothClip* row);

// ---- export / import

struct ExportedClip {
  std::string cloth_obj, cloth_pc2, body_obj, body_pc2, info_json;  // body_*: "" without body
  double frame_rate = 0;                                            // Hz
  int frames = 0;
};
// Writes DIR/cloth.obj (frame 0) + DIR/cloth.pc2 (every frame; header start frame 0 and sample
// rate 1, the clip's frame k at frame k), DIR/body.obj + DIR/body.pc2 (the colliding capsules),
// all in the clip's character space (the space the database stores, so an import is exact up to
// float rounding), and DIR/clip.json (frames, rate, the import command). The body needs the scene
// (load_database_scene with scene_file and motions_dir); when it cannot be rebuilt the export
// fails naming why, unless with_body is false.
ExportedClip export_clip(db::Reader& reader, int64_t clip, const std::string& dir,
                         const std::string& scene_file, const std::string& motions_dir = "",
                         bool with_body = true);

// Reads PATH (a .pc2 file, or a folder holding cloth.pc2) in the artist's vertex order (what
// export_clip writes) or the simulation's, checks it has the clip's frame count, a sample rate of 1
// (one sample per frame) and only finite coordinates, and returns the frames in simulation order
// (vertex_count vertices); throws std::runtime_error naming the file, and for a wrong frame count
// the header's frame range and the clip's (`rate`: the clip's fps, for the message).
struct EditedCache {
  std::vector<float> frames;
  float start_frame = 0;  // the PC2 header's (`clip export` writes 0)
  std::string file;
};
EditedCache read_edited_cache(const std::string& path, const db::ArtistMesh& artist,
                              uint32_t vertex_count, int32_t frame_count, double rate);
std::vector<float> read_edited_frames(const std::string& path, const db::ArtistMesh& artist,
                                      uint32_t vertex_count, int32_t frame_count);

// An import whose frames are the stored clip's within the codec's bound: nothing to write and
// nothing logged (`clothdb clip import` exits with kNoChangeExitStatus).
struct NoChange : std::runtime_error {
  using std::runtime_error::runtime_error;
};
inline constexpr int kNoChangeExitStatus = 3;

enum class OnBreak {
  Refuse,   // a broken end: nothing is written
  Reblend,  // record the larger blend errors so the runtime blends across the jump
  Ramp,     // ramp the edited frames back to the original ones over the blend frames at that end
};
OnBreak parse_on_break(const std::string& name);  // "refuse", "reblend", "ramp"

struct EdgeCheck {
  int64_t edge = 0, from_clip = 0, to_state = 0;
  bool into_start = false;  // an edge into the clip's start state (else one of its out edges)
  double blend_before = 0;  // m, as recorded
  double blend_after = 0;   // m, the bound: blend_before + the end's move
  double pop = 0;           // m, the jump at the edge after the edit (transition_pop)
  bool broken = false;      // blend_after > epsilon
};

struct ImportOptions {
  OnBreak on_break = OnBreak::Refuse;
  int ramp_frames = 8;
  float header_start_frame = 0;  // the PC2 header's, named when the frames are shifted
};

struct ImportReport {
  int64_t edit = 0;                     // 0: nothing written (refused)
  double start_move = 0, end_move = 0;  // m
  std::vector<EdgeCheck> edges;
  bool ramped_start = false, ramped_end = false;
  db::ClipMetrics metrics;         // measured on the re-encoded frames (what the runtime plays)
  db::ClipMetrics metrics_before;  // the stored clip measured the same way (decoded frames)
  double codec_error = 0;          // m, the re-encoded clip's largest error
  // Non-empty when the edit's max strain is above 10 % or above twice the stored clip's.
  std::string strain_warning;
};
// Before any continuity check, whatever options.on_break says, frames that are no edit of the
// clip are refused naming the cause (docs/guide/blender.md#what-clip-import-checks): every frame
// the same (a frozen cache), the clip shifted by whole frames or retimed (frame scale, fps), the
// clip under an axis conversion (Y-up) or a rigid move (world space instead of the object's local
// space), or a change larger than the garment. Frames equal to the stored clip within the codec's
// bound throw NoChange.
ImportReport import_clip(EditContext& ctx, int64_t clip, std::vector<float> frames,
                         const ImportOptions& options);

// ---- re-simulation

struct ResimOptions {
  SolverKind solver = SolverKind::Xpbd;
  SolverSettings settings;
  // Budget of the carried-forward exploration (frames simulated beyond the clip itself; 0: none).
  long max_frames = 0;
  int batch = 8;
  int threads = 1;
  bool progress = false;
};

struct ResimReport {
  int64_t edit = 0;
  double end_move = 0;    // m, the new end against the state the clip's edge led to
  int64_t linked_to = 0;  // the state its edge now leads to
  double blend_error = 0;
  bool new_state = false;  // the end moved by more than epsilon from every state at its node
  int states_added = 0, clips_added = 0, dead_ends_left = 0;
  long frames_added = 0;
  int depth = 0;  // generations of new states the change was carried through
  db::ClipMetrics metrics;
};
// Re-simulates the clip from its start state with the given solver setting. When its new end is
// within epsilon of a state at its node, the clip's edge links there (no propagation). Otherwise
// the end becomes a new state and the explorer simulates the clips leaving it, and onwards from
// every further new state, until every new end links back within epsilon or the budget runs out
// (the clips that started from the old end state stay: other edges still lead there).
ResimReport resim_clip(EditContext& ctx, int64_t clip, const ResimOptions& options);

// ---- flag, delete

int64_t set_clip_flag(EditContext& ctx, int64_t clip, bool flagged);

struct DeleteReport {
  int64_t edit = 0;
  int64_t start_state = 0;
  int64_t replacement = 0;  // the state the edges into start_state now lead to (0: none needed)
  std::vector<EdgeCheck> rerouted;
};
// Deletes the clip and its out edges. Its start state S then lacks cloth along the clip's edge,
// so every edge into S is re-routed to the nearest other state at S's node that has clips along
// every edge leaving the node (blend error bound: the old one plus the distance between the two
// states). Refused when there is no such state, or when S is the start state.
DeleteReport delete_clip(EditContext& ctx, int64_t clip);

// ---- consistency

// Every state reachable from the start state through cloth edges that lacks a clip along some
// primary edge leaving its node, as "state N at node M has no clip along 'edge'" (empty: every
// way the game can move has cloth from every state it can be in).
std::vector<std::string> coverage_gaps(db::Reader& reader, const ExploreGraph& graph);

}  // namespace clothdb
