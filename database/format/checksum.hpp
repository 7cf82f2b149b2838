// XXH64 (Yann Collet's xxHash, 64-bit variant, seed 0 by default). zstd uses it internally but
// does not export it, so it is reimplemented here; tests check it against the low 32 bits that
// zstd writes as its frame checksum. Fast (several GB/s), so checking every blob on every decode
// costs a few percent of decoding at most.
#pragma once

#include <cstddef>
#include <cstdint>

namespace clothdb {

uint64_t xxh64(const void* data, size_t size, uint64_t seed = 0);

namespace db {
using ::clothdb::xxh64;
}  // namespace db

}  // namespace clothdb
