// `clothdb db recode`: re-encodes every cloth clip and state of a database with codec version 2
// (a subspace built from the database's own frames plus a residual layer; docs/DATABASE.md,
// "clothdb db recode") or version 1, in place, in batches of rows, each batch one transaction: a
// process killed at any moment leaves a file whose every blob is either the old or the new one, and
// which checks and plays.
#pragma once

#include <cstdint>
#include <functional>
#include <string>

#include "compress/body_frame.hpp"
#include "database/codec/codec.hpp"
#include "database/store/writer.hpp"

namespace clothdb {

// A garment subspace (codec version 2) from a database's own clip frames: up to sample_frames
// frames taken evenly over every clip (in id order, each decoded as stored), their principal
// components (compress/subspace.hpp), quantised as stored (codec::make_basis; id 0 until stored).
// Shared by `db recode` and the explorer (ExploreOptions::subspace_modes), so both build a basis
// the same way. Throws std::invalid_argument when there is no frame, ClothdbError on a bad blob.
struct BuiltBasis {
  codec::Basis basis;
  std::string source;  // what it was built from, for codec_basis.source
  uint64_t frames = 0, sampled = 0;
  double sample_rms = 0, residual_rms = 0;  // m
};
// With anchors, the sampled frames are first taken into the body frame (compress/body_frame.hpp),
// as codec version 2 with a body frame predicts them.
BuiltBasis build_basis_from_clips(db::Reader& reader, const std::vector<db::ClothClip>& clips,
                                  uint32_t vertex_count, uint32_t modes, uint32_t sample_frames,
                                  const BodyAnchors* anchors = nullptr);

struct RecodeOptions {
  int codec = 2;                 // frame format to write: 1, 2 or 3
  double bound = 0;              // m per coordinate against the stored frames; 0: the file's bound
  double velocity_bound = 0;     // m/s for state velocities; 0: the file's velocity bound
  uint32_t modes = 64;           // basis modes (codec 2)
  uint32_t basis_frames = 3000;  // frames sampled evenly from all clips to build the basis
  double coefficient_step_factor = 2.0;
  // Codec 2: cloth relative to the body (a rigid frame fitted to the garment's highest 5 %, its
  // pinned band; compress/body_frame.hpp), for the basis and every position blob.
  bool body_frame = false;
  // Codec 3: the error contract every clip is encoded within (codec/contract.hpp), measured
  // against the clip's stored frames; all three caps positive. States keep their blobs (a
  // resumed simulation starts from them, so they keep the strict bound).
  codec::Contract contract;
  uint32_t batch = 32;  // rows per transaction
  bool always = false;  // replace every blob, even where the new encoding is larger
  bool vacuum = true;   // give the freed pages back to the file system at the end
  std::function<void(const std::string&)> progress;  // one line per step
  // Called after each batch commits (tests end the process here to stand in for a kill).
  std::function<void(uint64_t batches_committed)> after_batch;
};

struct RecodeReport {
  int64_t basis_id = 0;  // 0: codec 1
  uint32_t basis_modes = 0;
  double basis_seconds = 0;
  double sample_rms = 0, residual_rms = 0;  // m, of the basis's sample
  uint64_t clips = 0, clips_replaced = 0, states = 0, states_replaced = 0;
  uint64_t blob_bytes_before = 0, blob_bytes_after = 0;  // clip and state blobs
  uint64_t raw_bytes = 0;                                // the same as float32
  double max_error = 0;  // m, largest measured |new - stored| over every replaced clip coordinate
  codec::ContractFigures worst;  // codec 3: the worst figure of each kind over the clips recoded
  uint64_t clips_with_residual = 0;  // codec 3
  uint64_t clips_already_v3 = 0;     // codec 3: kept as they were (a rerun after a kill)
  uint64_t file_bytes_before = 0, file_bytes_after = 0;
  double seconds = 0;
};

// Throws ClothdbError (file problems) or std::exception. Blobs are replaced only when the new
// encoding is smaller; each replaced clip's error_bound and max_error become the old ones plus the
// new encoding's (the bound against the original simulation adds up, by the triangle inequality).
// Codec 3 records each replaced clip's contract (table codec_contract) in the same transaction as
// its blob; its max_error and error_bound then add the measured and the capped vertex distance
// (a coordinate's error is at most its vertex's distance). Clips already of version 3 are kept.
RecodeReport recode_database(const std::string& path, const RecodeOptions& options);

}  // namespace clothdb
