// The edit log's exact undo (Writer::Edit, Writer::undo_last): the only unit that uses SQLite's
// session extension, so only the store side needs a SQLite built with it (Debian's libsqlite3 is:
// SQLITE_ENABLE_SESSION and SQLITE_ENABLE_PREUPDATE_HOOK). The runtime never links this.
#define SQLITE_ENABLE_SESSION 1
#define SQLITE_ENABLE_PREUPDATE_HOOK 1
#include <sqlite3.h>

#include <string>

#include "database/sqlite/statement.hpp"
#include "database/store/writer.hpp"

namespace clothdb::db {

using sql::Stmt;

// ----------------------------------------------------------------------------------- Edits

Writer::Edit::Edit(Writer& writer, int64_t clip, const std::string& action,
                   const std::string& author)
    : writer_(&writer), clip_(clip), action_(action), author_(author), tx_(writer) {
  // Opened inside the transaction, so it records exactly this edit's changes.
  if (sqlite3session_create(writer.db_, "main", &session_) != SQLITE_OK)
    writer.throw_sql("starting an edit's change record (sqlite3session_create)");
  for (const TableInfo& table : tables())
    if (table.undoable && sqlite3session_attach(session_, table.name) != SQLITE_OK) {
      sqlite3session_delete(session_);
      session_ = nullptr;
      writer.throw_sql("attaching a table to an edit's change record");
    }
}

Writer::Edit::~Edit() {
  if (session_) sqlite3session_delete(session_);
}

int64_t Writer::Edit::commit(const std::string& description) {
  int size = 0;
  void* changes = nullptr;
  if (sqlite3session_changeset(session_, &size, &changes) != SQLITE_OK)
    writer_->throw_sql("reading an edit's changes (sqlite3session_changeset)");
  sqlite3session_delete(session_);  // before the log row: the log is not part of the edit
  session_ = nullptr;
  Stmt log(writer_->db_, (std::string("INSERT INTO edit_log(time, author, clip, action, "
                                      "description, changeset) VALUES(") +
                          sql::kNow + ", ?, ?, ?, ?, ?)")
                             .c_str());
  log.bind(1, author_).bind(2, clip_).bind(3, action_).bind(4, description);
  log.bind_blob(5, changes, size_t(size));
  const int rc = log.ok() ? log.step() : log.rc();
  sqlite3_free(changes);
  if (rc != SQLITE_DONE) writer_->throw_sql("logging an edit");
  const int64_t id = sqlite3_last_insert_rowid(writer_->db_);
  tx_.commit();
  return id;
}

namespace {

// Applying an inverted changeset: any conflict means the rows are not as the edit left them.
struct UndoConflicts {
  int count = 0;
  int kind = 0;
};

int abort_on_conflict(void* context, int kind, sqlite3_changeset_iter*) {
  auto* c = static_cast<UndoConflicts*>(context);
  ++c->count;
  c->kind = kind;
  return SQLITE_CHANGESET_ABORT;
}

const char* conflict_name(int kind) {
  switch (kind) {
    case SQLITE_CHANGESET_DATA:
      return "a row it changed has changed again";
    case SQLITE_CHANGESET_NOTFOUND:
      return "a row it changed is gone";
    case SQLITE_CHANGESET_CONFLICT:
      return "a row it removed has been added again";
    case SQLITE_CHANGESET_CONSTRAINT:
      return "restoring a row breaks a constraint";
    case SQLITE_CHANGESET_FOREIGN_KEY:
      return "newer rows refer to rows it added";
  }
  return "conflict";
}

}  // namespace

EditLogEntry Writer::undo_last(const std::string& author) {
  Transaction t(*this);
  Stmt last(db_,
            "SELECT id, clip, action, description, changeset IS NOT NULL FROM edit_log "
            "WHERE action != 'undo' AND id NOT IN "
            "(SELECT undoes FROM edit_log WHERE undoes IS NOT NULL) ORDER BY id DESC LIMIT 1");
  if (!last.ok()) throw_sql("reading the edit log");
  const int rc = last.step();
  if (rc == SQLITE_DONE)
    throw ClothdbError(Status::NotFound, path_ + ": the edit log has nothing left to undo");
  if (rc != SQLITE_ROW) throw_sql("reading the edit log");
  EditLogEntry undone;
  undone.id = last.i64(0);
  undone.clip = last.i64(1);
  undone.action = last.text(2);
  undone.description = last.text(3);
  undone.has_changeset = last.i64(4) != 0;
  if (!undone.has_changeset)
    throw ClothdbError(Status::InvalidArgument,
                       path_ + ": edit " + std::to_string(undone.id) + " ('" + undone.action +
                           "') was logged without a changeset by an early build; it cannot be "
                           "undone exactly");
  Stmt blob(db_, "SELECT changeset FROM edit_log WHERE id = ?");
  if (!blob.ok() || blob.bind(1, undone.id).step() != SQLITE_ROW)
    throw_sql("reading an edit's changeset");
  int inverse_size = 0;
  void* inverse = nullptr;
  if (sqlite3changeset_invert(int(blob.bytes(0)),
                              const_cast<void*>(sqlite3_column_blob(blob.get(), 0)), &inverse_size,
                              &inverse) != SQLITE_OK)
    throw ClothdbError(Status::Corrupt, path_ + ": edit " + std::to_string(undone.id) +
                                            ": its changeset does not read back");
  UndoConflicts conflicts;
  const int applied =
      sqlite3changeset_apply(db_, inverse_size, inverse, nullptr, abort_on_conflict, &conflicts);
  if (applied != SQLITE_OK) {
    sqlite3_free(inverse);
    if (conflicts.count > 0)
      throw ClothdbError(Status::InvalidArgument,
                         path_ + ": cannot undo edit " + std::to_string(undone.id) + " (" +
                             undone.action + " of clip " + std::to_string(undone.clip) +
                             ") exactly: " + conflict_name(conflicts.kind) +
                             " since (written outside the edit log, e.g. by a precompute run); "
                             "nothing was changed");
    throw_sql("undoing an edit");
  }
  Stmt log(db_, (std::string("INSERT INTO edit_log(time, author, clip, action, description, "
                             "undoes, changeset) VALUES(") +
                 sql::kNow + ", ?, ?, 'undo', ?, ?, ?)")
                    .c_str());
  log.bind(1, author).bind(2, undone.clip);
  log.bind(3, "undo of edit " + std::to_string(undone.id) + " (" + undone.action + ")");
  log.bind(4, undone.id).bind_blob(5, inverse, size_t(inverse_size));
  const int logged = log.ok() ? log.step() : log.rc();
  sqlite3_free(inverse);
  if (logged != SQLITE_DONE) throw_sql("logging an undo");
  t.commit();
  return undone;
}

}  // namespace clothdb::db
