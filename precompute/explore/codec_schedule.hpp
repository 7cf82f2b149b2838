// The codec-v2 schedule (this project's addition to Kim et al.; ExploreOptions::subspace_modes):
// when the explorer builds a garment subspace from the clips stored so far, which basis the jobs
// encode with, and which bases are removed once the exploration converges. The schedule is a
// function of the file (bases stored, frames stored), so a resumed run decides as an
// uninterrupted one did.
#pragma once

#include <cstdint>
#include <memory>
#include <set>

#include "compress/body_frame.hpp"
#include "database/codec/codec.hpp"
#include "database/store/writer.hpp"
#include "explore/explorer.hpp"

namespace clothdb {

struct CodecSchedule {
  // The newest basis (null until one is built or loaded), how many bases the file holds, and the
  // ids of those this run built.
  std::shared_ptr<const codec::Basis> basis;
  int bases_in_file = 0;
  std::set<int64_t> bases_built;
  // With subspace_body_frame: the garment's body anchors, from the file's garment row.
  std::shared_ptr<const BodyAnchors> body;
};

// Throws std::invalid_argument for schedule options that cannot work.
void check_codec_schedule_options(const ExploreOptions& options);

// The schedule as the file leaves it (the newest basis, for a resumed run). Reads only; throws
// std::runtime_error naming `path` when a read fails.
CodecSchedule load_codec_schedule(db::Reader& reader, const std::string& path,
                                  const ExploreOptions& options, uint32_t vertex_count);

// After a batch: a new basis when the stored frames have reached
// first_frames x growth^(bases in the file).
void maybe_build_basis(CodecSchedule& schedule, db::Reader& reader, db::Writer& writer,
                       const ExploreOptions& options, uint32_t vertex_count, ExploreReport& report);

// The bases explorer runs built (source "explore: ...") that no clip or state blob names. With
// edits in the file, only those of this run (`built`): an edit's undo record may hold a blob of an
// older basis that no row names any more. Reads only; throws std::runtime_error naming `path`
// when any read fails (a basis a blob names that could not be read must never be removed).
std::set<int64_t> unchosen_bases(db::Reader& reader, const std::string& path,
                                 const std::set<int64_t>& built);

}  // namespace clothdb
