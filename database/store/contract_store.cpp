#include "database/store/contract_store.hpp"

#include "database/format/contracts.hpp"
#include "database/sqlite/statement.hpp"

namespace clothdb::db {

using sql::Stmt;

void store_clip_contract(Writer& writer, int64_t clip, const codec::ContractFigures& m,
                         const codec::Contract& caps) {
  Writer::Transaction t(writer);
  writer.ensure_table("codec_contract");
  Stmt s(writer.handle(),
         "INSERT OR REPLACE INTO codec_contract(clip, rms, max, jitter, rms_cap, max_cap, "
         "jitter_cap) VALUES(?, ?, ?, ?, ?, ?, ?)");
  s.bind(1, clip).bind(2, m.rms).bind(3, m.max).bind(4, m.jitter);
  s.bind(5, caps.rms).bind(6, caps.max).bind(7, caps.jitter);
  if (!s.ok() || s.step() != SQLITE_DONE) writer.throw_sql("storing a clip's contract");
  t.commit();
}

void set_clip_error_bound(Writer& writer, int64_t clip, double error_bound) {
  Stmt s(writer.handle(), "UPDATE cloth_clip SET error_bound = ? WHERE id = ?");
  if (!s.ok() || s.bind(1, error_bound).bind(2, clip).step() != SQLITE_DONE)
    writer.throw_sql("setting a clip's error bound");
}

void remove_clip_contract(Writer& writer, int64_t clip) {
  Stmt t(writer.handle(),
         "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'codec_contract'");
  if (!t.ok() || t.step() != SQLITE_ROW) return;
  Stmt s(writer.handle(), "DELETE FROM codec_contract WHERE clip = ?");
  if (!s.ok() || s.bind(1, clip).step() != SQLITE_DONE)
    writer.throw_sql("removing a clip's contract");
}

}  // namespace clothdb::db
