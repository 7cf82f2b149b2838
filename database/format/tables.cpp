#include "database/format/tables.hpp"

namespace clothdb::db {

const std::vector<TableInfo>& tables() {
  static const std::vector<TableInfo> list = {
      {"meta", 1, true, false},
      {"garment", 1, false, false},
      {"garment_mesh", 5, false, false},
      {"garment_group", 5, false, false},
      {"motion_file", 1, false, false},
      {"source_file", 5, false, false},
      {"primary_clip", 1, false, false},
      {"primary_transition", 1, false, false},
      {"run", 1, true, false},
      {"cloth_state", 1, true, false},
      {"cloth_clip", 1, true, false},
      {"cloth_edge", 1, true, false},
      {"cloth_link", 4, true, false},
      {"cloth_clip_steering", 4, true, false},
      {"edit_log", 1, false, false},
      {"codec_basis", 4, false, true},
      // The error contract each codec version 3 clip was encoded within, and what it measured.
      {"codec_contract", 4, false, true},
  };
  return list;
}

const TableInfo* find_table(std::string_view name) {
  for (const TableInfo& t : tables())
    if (name == t.name) return &t;
  return nullptr;
}

}  // namespace clothdb::db
