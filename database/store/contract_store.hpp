// Storing the error contract of a codec version 3 clip (table codec_contract, created by the first
// row, so files without one are unchanged). Reading is database/format/contracts.hpp.
#pragma once

#include <cstdint>

#include "database/codec/contract.hpp"
#include "database/store/writer.hpp"

namespace clothdb::db {

// Records (or replaces) clip's measured figures and caps. Joins the writer's transaction if one is
// open, so a recode writes a clip's blob and its contract together. Throws ClothdbError.
void store_clip_contract(Writer& writer, int64_t clip, const codec::ContractFigures& measured,
                         const codec::Contract& caps);

// Sets a version 3 clip's recorded per-coordinate bound (cloth_clip.error_bound): a contract has
// none of its own, and a coordinate's error is at most its vertex's distance, so the precompute
// records the max cap. Throws ClothdbError.
void set_clip_error_bound(Writer& writer, int64_t clip, double error_bound);

// Removes clip's contract row, if any (its blob is no longer a version 3 one).
void remove_clip_contract(Writer& writer, int64_t clip);

}  // namespace clothdb::db
