#include "database/sqlite/statement.hpp"

#include <cstdio>
#include <cstdlib>

namespace clothdb::db::sql {

Status status_of(int sqlite_code) {
  switch (sqlite_code & 0xff) {
    case SQLITE_CONSTRAINT:
      return Status::InvalidArgument;
    case SQLITE_CORRUPT:
    case SQLITE_NOTADB:
      return Status::Corrupt;
    default:
      return Status::IoError;
  }
}

Stmt::Stmt(sqlite3* db, const char* sql) {
  rc_ = sqlite3_prepare_v2(db, sql, -1, &s_, nullptr);
  if (rc_ != SQLITE_OK) {
    sqlite3_finalize(s_);
    s_ = nullptr;
  } else if (s_ == nullptr) {
    rc_ = SQLITE_MISUSE;  // empty SQL: nothing to run
  }
}

std::string Stmt::text(int c) {
  const unsigned char* t = sqlite3_column_text(s_, c);
  return t ? std::string(reinterpret_cast<const char*>(t), size_t(sqlite3_column_bytes(s_, c)))
           : std::string();
}

int prepare_persistent(sqlite3* db, const char* sql, sqlite3_stmt** out) {
  return sqlite3_prepare_v3(db, sql, -1, SQLITE_PREPARE_PERSISTENT, out, nullptr);
}

std::string to_text(double v) {
  char buf[40];
  for (int precision = 6; precision <= 17; ++precision) {
    std::snprintf(buf, sizeof buf, "%.*g", precision, v);
    if (std::strtod(buf, nullptr) == v) break;
  }
  return buf;
}

}  // namespace clothdb::db::sql
