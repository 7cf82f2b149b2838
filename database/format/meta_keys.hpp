// Every key of a clothdb file's meta table and what it holds: the only place a key is spelled.
// Typed reads are in database/format/cloth_graph.hpp (meta_text, meta_number, ...), typed writes in
// database/store/writer.hpp.
#pragma once

#include <string>
#include <vector>

namespace clothdb::db {

// Every key of the meta table, and what it holds. Typed accessors below read and write them.
namespace meta {
inline constexpr const char* kFormat = "format";                 // "clothdb"
inline constexpr const char* kFormatVersion = "format_version";  // schema version (integer)
inline constexpr const char* kCreated = "created";               // ISO 8601 UTC
inline constexpr const char* kUnits = "units";                   // text for people
inline constexpr const char* kCodecPositionBound = "codec.position_bound";  // m
inline constexpr const char* kCodecVelocityBound = "codec.velocity_bound";  // m/s
inline constexpr const char* kCodecKeyInterval = "codec.key_interval";
inline constexpr const char* kCodecZstdLevel = "codec.zstd_level";
// The newest blob format version stored in the file (1, 2): set by the writer whenever it stores
// a blob of a newer version, so an older runtime refuses the file at open instead of failing clip
// by clip.
inline constexpr const char* kCodecFormatVersion = "codec.format_version";
// `db recode`: the bound (m) the clips were recoded to, and the basis the recode built.
inline constexpr const char* kCodecRecodedBound = "codec.recoded_bound";
inline constexpr const char* kCodecBasis = "codec.basis";
inline constexpr const char* kScene = "scene";               // the scene file's text
inline constexpr const char* kScenePath = "scene_path";      // as given to precompute
inline constexpr const char* kSceneHash = "scene_hash";      // content_hash of kScene
inline constexpr const char* kMotionGraph = "motion_graph";  // the primary graph, JSON
inline constexpr const char* kStartClip = "start_clip";      // primary clip id (integer)
inline constexpr const char* kAutoSolver = "auto_solver";    // --auto's table (Markdown)
// "1": the explorer linked every dead end when its last run ended (schema 4, ClothLink), so db
// check requires a clip or a link for every way out of every state a cloth edge leads into.
inline constexpr const char* kDeadEndsLinked = "dead_ends_linked";
// The garment's error floor on the motion graph (explore/error_floor.hpp), measured by the
// precompute before it explored: m (a number), and the measurement's detail (JSON: pairwise
// distances in mm, histories, options). An epsilon below the floor cannot link clip ends.
inline constexpr const char* kErrorFloor = "error_floor";
inline constexpr const char* kErrorFloorDetail = "error_floor_detail";
// The explorer's forecast of the CPU-hours to converge, made when its last run ended
// (precompute/explore/forecast.hpp): text as `db info` shows it after "forecast  ".
inline constexpr const char* kForecast = "forecast";
// The value of kFormat in every clothdb file.
inline constexpr const char* kFormatName = "clothdb";
// The keys a file may hold; `db check` reports any other.
const std::vector<std::string>& known_keys();
}  // namespace meta

}  // namespace clothdb::db
