// `clothdb db dump FILE`: every row of the cloth graph tables as text, blobs as their size and
// xxh64, so two databases can be compared with diff (the MPI tests compare a multi-rank run with a
// single-process one this way).
#include <sqlite3.h>

#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "cli_util.hpp"
#include "commands.hpp"
#include "database/checksum.hpp"

namespace clothdb::cli {

namespace {

void dump_table(sqlite3* db, const std::string& path, const std::string& table) {
  sqlite3_stmt* raw = nullptr;
  const std::string sql = "SELECT * FROM " + table + " ORDER BY rowid";
  if (sqlite3_prepare_v2(db, sql.c_str(), -1, &raw, nullptr) != SQLITE_OK)
    throw std::runtime_error(path + ": table " + table + ": " + sqlite3_errmsg(db));
  std::unique_ptr<sqlite3_stmt, int (*)(sqlite3_stmt*)> stmt(raw, sqlite3_finalize);
  const int columns = sqlite3_column_count(raw);
  std::printf("[%s]", table.c_str());
  for (int c = 0; c < columns; ++c) std::printf(" %s", sqlite3_column_name(raw, c));
  std::printf("\n");
  int rc;
  while ((rc = sqlite3_step(raw)) == SQLITE_ROW) {
    for (int c = 0; c < columns; ++c) {
      std::printf(c ? " " : "");
      switch (sqlite3_column_type(raw, c)) {
        case SQLITE_NULL:
          std::printf("null");
          break;
        case SQLITE_INTEGER:
          std::printf("%lld", static_cast<long long>(sqlite3_column_int64(raw, c)));
          break;
        case SQLITE_FLOAT:
          std::printf("%.17g", sqlite3_column_double(raw, c));
          break;
        case SQLITE_TEXT:
          std::printf("'%s'", reinterpret_cast<const char*>(sqlite3_column_text(raw, c)));
          break;
        default: {
          const void* blob = sqlite3_column_blob(raw, c);
          const size_t n = static_cast<size_t>(sqlite3_column_bytes(raw, c));
          std::printf("blob:%zu:%016llx", n, static_cast<unsigned long long>(db::xxh64(blob, n)));
        }
      }
    }
    std::printf("\n");
  }
  if (rc != SQLITE_DONE)
    throw std::runtime_error(path + ": table " + table + ": " + sqlite3_errmsg(db));
}

}  // namespace

void register_db_dump(CLI::App& app) {
  CLI::App& db = command_group(app, "db", "Inspect and check clothdb database files");
  struct Args {
    std::string file;
    std::string tables = "cloth_state,cloth_clip,cloth_edge";
  };
  auto args = std::make_shared<Args>();
  CLI::App* dump = db.add_subcommand(
      "dump",
      "Prints every row of the cloth graph tables (blobs as size and xxh64), in id order, for "
      "comparing two databases with diff");
  dump->add_option("FILE", args->file, "clothdb database")->required()->check(CLI::ExistingFile);
  dump->add_option("--tables", args->tables, "Comma-separated tables to print")
      ->capture_default_str();
  dump->callback([args] {
    sqlite3* raw = nullptr;
    const int rc = sqlite3_open_v2(args->file.c_str(), &raw, SQLITE_OPEN_READONLY, nullptr);
    std::unique_ptr<sqlite3, int (*)(sqlite3*)> db(raw, sqlite3_close);
    if (rc != SQLITE_OK)
      throw std::runtime_error(args->file + ": cannot open: " + sqlite3_errstr(rc));
    for (const std::string& table : split_list(args->tables)) dump_table(raw, args->file, table);
  });
}

}  // namespace clothdb::cli
