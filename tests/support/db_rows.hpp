// Every row of every table of a clothdb file, as text (blobs by checksum), for tests that compare
// two files made two ways (resumed, threaded, MPI, undone): the comparison covers tables a test
// did not think of, and what legitimately differs is named, table by table and key by key.
#pragma once

#include <gtest/gtest.h>
#include <sqlite3.h>

#include <set>
#include <string>
#include <utility>
#include <vector>

#include "database/format/checksum.hpp"

namespace clothdb::test {

// What two runs of the same content may legitimately differ in, each by its exact name.
struct RowsLeftOut {
  std::set<std::string> tables;                           // whole tables
  std::set<std::pair<std::string, std::string>> columns;  // (table, column)
  std::set<std::string> meta_keys;                        // rows of meta
};

// The run bookkeeping: when, where, how long and with how many threads a run went, and which
// run made a row (a resumed file has two runs, an uninterrupted one).
inline RowsLeftOut run_bookkeeping() {
  RowsLeftOut out;
  out.tables = {"run"};
  out.columns = {{"cloth_state", "run"},
                 {"cloth_clip", "run"},
                 {"cloth_link", "run"},
                 {"codec_basis", "created"}};
  // The forecast is made from CPU times, which differ from run to run like the run table.
  out.meta_keys = {"created", "forecast"};
  return out;
}

// "table: col=value col=value ..." per row, tables by name, rows by primary key (meta by key).
inline std::vector<std::string> every_row(const std::string& path, const RowsLeftOut& left_out) {
  std::vector<std::string> out;
  sqlite3* db = nullptr;
  if (sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr) != SQLITE_OK) {
    ADD_FAILURE() << path << ": cannot open: " << sqlite3_errmsg(db);
    sqlite3_close(db);
    return out;
  }
  std::vector<std::string> tables;
  sqlite3_stmt* s = nullptr;
  sqlite3_prepare_v2(db,
                     "SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE "
                     "'sqlite_%' ORDER BY name",
                     -1, &s, nullptr);
  while (sqlite3_step(s) == SQLITE_ROW)
    tables.push_back(reinterpret_cast<const char*>(sqlite3_column_text(s, 0)));
  sqlite3_finalize(s);
  for (const std::string& t : tables) {
    out.push_back("table " + t);
    if (left_out.tables.count(t)) continue;
    const std::string sql = "SELECT * FROM \"" + t + "\" ORDER BY 1";
    if (sqlite3_prepare_v2(db, sql.c_str(), -1, &s, nullptr) != SQLITE_OK) {
      ADD_FAILURE() << path << ": " << sql << ": " << sqlite3_errmsg(db);
      continue;
    }
    while (sqlite3_step(s) == SQLITE_ROW) {
      if (t == "meta" &&
          left_out.meta_keys.count(reinterpret_cast<const char*>(sqlite3_column_text(s, 0))))
        continue;
      std::string row = t + ":";
      for (int c = 0; c < sqlite3_column_count(s); ++c) {
        const std::string column = sqlite3_column_name(s, c);
        if (left_out.columns.count({t, column})) continue;
        row += " " + column + "=";
        switch (sqlite3_column_type(s, c)) {
          case SQLITE_NULL:
            row += "NULL";
            break;
          case SQLITE_BLOB:
            row += "blob:" + std::to_string(db::xxh64(sqlite3_column_blob(s, c),
                                                      size_t(sqlite3_column_bytes(s, c))));
            break;
          default:
            row += reinterpret_cast<const char*>(sqlite3_column_text(s, c));
        }
      }
      out.push_back(row);
    }
    sqlite3_finalize(s);
  }
  sqlite3_close(db);
  return out;
}

// Expects the two files to hold the same rows; names the first few that differ.
inline void expect_same_rows(const std::string& a, const std::string& b,
                             const RowsLeftOut& left_out = run_bookkeeping()) {
  const std::vector<std::string> ra = every_row(a, left_out), rb = every_row(b, left_out);
  EXPECT_GT(ra.size(), 0u) << a;
  int shown = 0;
  for (size_t i = 0; i < std::max(ra.size(), rb.size()) && shown < 5; ++i) {
    const std::string x = i < ra.size() ? ra[i] : "(none)", y = i < rb.size() ? rb[i] : "(none)";
    if (x == y) continue;
    ++shown;
    ADD_FAILURE() << "row " << i << " differs:\n  " << a << ": " << x.substr(0, 200) << "\n  " << b
                  << ": " << y.substr(0, 200);
  }
  EXPECT_EQ(ra.size(), rb.size()) << a << " vs " << b;
}

}  // namespace clothdb::test
