// Reading the error contracts of codec version 3 clips (table codec_contract, docs/DATABASE.md
// "codec_contract"): per clip, the caps it was encoded within and the figures the encoder measured
// against the frames it was given. Writing them is database/store/contract_store.hpp.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "database/codec/contract.hpp"
#include "database/format/status.hpp"

struct sqlite3;

namespace clothdb::db {

struct ClipContract {
  int64_t clip = 0;
  codec::ContractFigures measured;  // m
  codec::Contract caps;             // m
};

// Every row, by clip id (empty when the file has no codec_contract table).
Status clip_contracts(sqlite3* db, const std::string& path, std::vector<ClipContract>* out,
                      Error* err);

}  // namespace clothdb::db
