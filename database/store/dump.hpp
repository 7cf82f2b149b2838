// `clothdb db dump`: every row of a clothdb file's tables as text, blobs as their size and xxh64,
// so two files can be compared with diff (the MPI and resume tests compare runs this way; the
// undo walk-through in docs/GUIDE.md#fixing-a-bad-clip compares dumps with cmp).
#pragma once

#include <cstdio>
#include <string>
#include <vector>

namespace clothdb::db {

struct DumpOptions {
  // Tables to print, in this order; empty: every table of the registry (database/format/
  // tables.hpp) that the file has, in registry order.
  std::vector<std::string> tables;
  // Columns printed as `masked`: "table.column", or "meta.KEY" for the value of one meta row.
  // For comparing runs whose times, hosts or CPU seconds differ by nature.
  std::vector<std::string> masked;
};

// Writes the dump to `out`. Throws ClothdbError naming the file (and the table) when it cannot be
// read, a named table does not exist, or a mask names no table of the registry.
void dump_database(const std::string& path, const DumpOptions& options, std::FILE* out);

}  // namespace clothdb::db
