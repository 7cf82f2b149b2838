// How cloth is compressed in one file: fixed when the file is made and stored in its meta table
// (codec.*, database/format/meta_keys.hpp). The reader loads it at open; the writer encodes with
// it.
#pragma once

#include <cstdint>

#include "database/codec/codec.hpp"

namespace clothdb::db {

struct CodecSettings {
  double position_bound = codec::kDefaultPositionBound;  // m, max error per coordinate
  double velocity_bound = 0.001;  // m/s; 1 mm/s moves a resumed vertex 0.03 mm in a frame
  uint32_t key_interval = codec::kDefaultKeyInterval;
  int zstd_level = codec::kDefaultZstdLevel;
};

// The codec's settings for encoding with this file's key interval and zstd level at `bound` (the
// position or the velocity bound): what the writer stores, and what a worker encoding a clip for it
// must use.
inline codec::EncodeSettings encode_settings(const CodecSettings& codec, double bound) {
  codec::EncodeSettings s;
  s.bound = bound;
  s.key_interval = codec.key_interval;
  s.zstd_level = codec.zstd_level;
  return s;
}

}  // namespace clothdb::db
