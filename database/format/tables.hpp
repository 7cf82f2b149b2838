// The one list of a clothdb file's tables: what each holds is in docs/DATABASE.md, its columns in
// database/store/writer.cpp (the only place that creates them). Everything that walks the tables
// (the writer creating a file, the edit log recording an edit, `db dump`, `db check`) walks this
// list, so a new table is added here once.
#pragma once

#include <cstdint>
#include <string_view>
#include <vector>

namespace clothdb::db {

// Version 2 added the quality metrics (cloth_clip: mean_penetration, jitter, halved_steps,
// worst_frame; cloth_edge: pop). Version 3: the edit log keeps each edit's changeset (exact undo
// of edits that touch many rows) and the actions flag, unflag, import, resim, delete. Version 4:
// the cloth_link and cloth_clip_steering tables. Version 5: the source_file table (the scene's
// manifest and garment mesh, so a file rebuilds its scene from any directory), the artist's mesh
// (garment_mesh, garment_group; a file without one reads as a procedural garment, identity map)
// and cloth_clip's self_intersections. Writer::open migrates older files in one transaction; the
// Reader reads them as they are.
constexpr int kSchemaVersion = 5;
constexpr int32_t kApplicationId = 0x434C4442;  // "CLDB"

struct TableInfo {
  const char* name;
  int since_version;  // the schema version that added it
  // An edit (Writer::Edit) records its changes to this table and undo restores them.
  bool undoable;
  // Created when first needed (codec_basis, by the first basis stored), not with the file: a file
  // may lack it at any version.
  bool on_demand;
};

// Every table, in dependency order (a table only refers to tables before it, except the deferred
// cloth_state.source_clip).
const std::vector<TableInfo>& tables();
// The entry of `name`, or null.
const TableInfo* find_table(std::string_view name);

}  // namespace clothdb::db
