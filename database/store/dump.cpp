#include "database/store/dump.hpp"

#include <algorithm>

#include "database/format/checksum.hpp"
#include "database/format/reader.hpp"
#include "database/format/tables.hpp"
#include "database/sqlite/statement.hpp"

namespace clothdb::db {
namespace {

using sql::Stmt;

bool table_exists(sqlite3* db, const std::string& table) {
  Stmt s(db, "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?");
  return s.ok() && s.bind(1, table).step() == SQLITE_ROW;
}

bool is_masked(const DumpOptions& o, const std::string& table, const std::string& column,
               const std::string& meta_key) {
  for (const std::string& m : o.masked) {
    if (m == table + "." + column) return true;
    if (table == "meta" && column == "value" && m == "meta." + meta_key) return true;
  }
  return false;
}

void dump_table(sqlite3* db, const std::string& path, const std::string& table,
                const DumpOptions& o, std::FILE* out) {
  // Ordered by the table's key: rowid, or the key of a WITHOUT ROWID table (meta).
  Stmt s(db, "SELECT * FROM \"" + table + "\" ORDER BY " + (table == "meta" ? "key" : "rowid"));
  if (!s.ok())
    throw ClothdbError(sql::status_of(s.rc()),
                       path + ": table " + table + ": " + sqlite3_errmsg(db));
  const int columns = sqlite3_column_count(s.get());
  std::fprintf(out, "[%s]", table.c_str());
  for (int c = 0; c < columns; ++c) std::fprintf(out, " %s", sqlite3_column_name(s.get(), c));
  std::fprintf(out, "\n");
  int rc;
  while ((rc = s.step()) == SQLITE_ROW) {
    const std::string meta_key = table == "meta" ? s.text(0) : "";
    for (int c = 0; c < columns; ++c) {
      std::fprintf(out, c ? " " : "");
      if (is_masked(o, table, sqlite3_column_name(s.get(), c), meta_key)) {
        std::fprintf(out, "masked");
        continue;
      }
      switch (sqlite3_column_type(s.get(), c)) {
        case SQLITE_NULL:
          std::fprintf(out, "null");
          break;
        case SQLITE_INTEGER:
          std::fprintf(out, "%lld", static_cast<long long>(s.i64(c)));
          break;
        case SQLITE_FLOAT:
          std::fprintf(out, "%.17g", s.f64(c));
          break;
        case SQLITE_TEXT:
          std::fprintf(out, "'%s'", s.text(c).c_str());
          break;
        default:
          std::fprintf(out, "blob:%zu:%016llx", s.bytes(c),
                       static_cast<unsigned long long>(xxh64(s.blob(c), s.bytes(c))));
      }
    }
    std::fprintf(out, "\n");
  }
  if (rc != SQLITE_DONE)
    throw ClothdbError(sql::status_of(rc), path + ": table " + table + ": " + sqlite3_errmsg(db));
}

}  // namespace

void dump_database(const std::string& path, const DumpOptions& options, std::FILE* out) {
  for (const std::string& m : options.masked) {
    const size_t dot = m.find('.');
    if (dot == std::string::npos || dot == 0 || dot + 1 == m.size() ||
        !find_table(m.substr(0, dot)))
      throw ClothdbError(Status::InvalidArgument,
                         "--mask " + m +
                             ": expected TABLE.COLUMN or meta.KEY with a table of the "
                             "registry (docs/DATABASE.md)");
  }
  Reader reader;  // recognises the file: a non-clothdb file is refused, naming it
  Error err;
  throw_if_error(reader.open(path, &err), err);
  sqlite3* db = reader.handle();
  std::vector<std::string> names = options.tables;
  if (names.empty()) {
    for (const TableInfo& t : tables())
      if (table_exists(db, t.name)) names.emplace_back(t.name);
  } else {
    for (const std::string& t : names)
      if (!table_exists(db, t))
        throw ClothdbError(Status::NotFound, path + ": no table " + t +
                                                 (find_table(t) ? " in this file (created later)"
                                                                : " (not a clothdb table)"));
  }
  for (const std::string& t : names) dump_table(db, path, t, options, out);
}

}  // namespace clothdb::db
