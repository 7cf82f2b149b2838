#include "explore/codec_schedule.hpp"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "compress/recode.hpp"
#include "database/format/bases.hpp"
#include "database/store/basis_store.hpp"

namespace clothdb {

void check_codec_schedule_options(const ExploreOptions& options) {
  if (options.subspace_modes > 0 &&
      (options.subspace_first_frames < 1 || !(options.subspace_growth > 1.0) ||
       options.subspace_sample_frames < 2))
    throw std::invalid_argument(
        "explore: codec v2 needs subspace_first_frames >= 1, subspace_growth > 1 and "
        "subspace_sample_frames >= 2");
}

CodecSchedule load_codec_schedule(db::Reader& reader, const std::string& path,
                                  const ExploreOptions& options, uint32_t vertex_count) {
  CodecSchedule schedule;
  db::Error err;
  if (options.subspace_modes > 0 && options.subspace_body_frame) {
    // From the file's garment row, as `db recode` takes them.
    db::Garment garment;
    if (reader.garment(&garment, &err) != db::Status::Ok)
      throw std::runtime_error(path + ": " + std::string(err.message));
    schedule.body = std::make_shared<const BodyAnchors>(body_anchors(garment.rest_positions));
  }
  if (options.subspace_modes > 0) {
    // A resumed run continues from the file's newest basis.
    std::vector<db::BasisRow> bases;
    if (db::list_bases(reader.handle(), path, &bases, &err) != db::Status::Ok)
      throw std::runtime_error(path + ": " + std::string(err.message));
    schedule.bases_in_file = static_cast<int>(bases.size());
    if (!bases.empty()) {
      auto newest = std::make_shared<codec::Basis>();
      if (db::load_basis(reader.handle(), path, bases.back().id, newest.get(), &err) !=
          db::Status::Ok)
        throw std::runtime_error(path + ": " + std::string(err.message));
      if (newest->vertex_count == vertex_count) schedule.basis = std::move(newest);
    }
  }
  return schedule;
}

void maybe_build_basis(CodecSchedule& schedule, db::Reader& reader, db::Writer& writer,
                       const ExploreOptions& options, uint32_t vertex_count,
                       ExploreReport& report) {
  if (options.subspace_modes == 0) return;
  const double due = static_cast<double>(options.subspace_first_frames) *
                     std::pow(options.subspace_growth, schedule.bases_in_file);
  if (static_cast<double>(report.frames) < due) return;
  const auto t0 = std::chrono::steady_clock::now();
  db::Error err;
  std::vector<db::ClothClip> clips;
  if (reader.cloth_clips(&clips, &err) != db::Status::Ok)
    throw std::runtime_error(writer.path() + ": " + std::string(err.message));
  BuiltBasis built = build_basis_from_clips(reader, clips, vertex_count, options.subspace_modes,
                                            options.subspace_sample_frames, schedule.body.get());
  built.basis.id = db::store_basis(writer, built.basis, "explore: " + built.source);
  schedule.bases_built.insert(built.basis.id);
  ++schedule.bases_in_file;
  ++report.bases_built;
  if (options.progress)
    std::fprintf(stderr, "\nexplore: basis %lld of %u modes from %llu stored frames in %.1f s\n",
                 static_cast<long long>(built.basis.id), built.basis.mode_count,
                 static_cast<unsigned long long>(built.frames),
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  schedule.basis = std::make_shared<const codec::Basis>(std::move(built.basis));
}

std::set<int64_t> unchosen_bases(db::Reader& reader, const std::string& path,
                                 const std::set<int64_t>& built) {
  db::Error err;
  auto check = [&](db::Status status, const std::string& what) {
    if (status != db::Status::Ok)
      throw std::runtime_error(
          path + ": reading " + what +
          " to find the bases no blob names (nothing removed): " + std::string(err.message));
  };
  std::vector<db::BasisRow> bases;
  std::vector<db::EditLogEntry> edits;
  check(db::list_bases(reader.handle(), path, &bases, &err), "codec_basis");
  check(reader.edit_log(&edits, &err), "edit_log");
  std::set<int64_t> candidates;
  for (const db::BasisRow& b : bases)
    if (built.count(b.id) || (edits.empty() && b.source.rfind("explore: ", 0) == 0))
      candidates.insert(b.id);
  if (candidates.empty()) return {};
  std::set<int64_t> named;
  auto name = [&](const std::vector<uint8_t>& blob, const std::string& what) {
    codec::BlobInfo info;
    check(codec::read_info(blob.data(), blob.size(), &info, &err), what);
    if (info.version >= codec::kFormatVersionV2) named.insert(info.basis_id);
  };
  std::vector<db::ClothClip> clips;
  std::vector<db::StoredState> states;
  check(reader.cloth_clips(&clips, &err), "cloth_clip");
  check(reader.cloth_states(&states, &err), "cloth_state");
  std::vector<uint8_t> blob, velocities;
  for (const db::ClothClip& c : clips) {
    const std::string what = "cloth clip " + std::to_string(c.id);
    check(reader.clip_blob(c.id, &blob, &err), what);
    name(blob, what);
  }
  for (const db::StoredState& st : states) {
    const std::string what = "cloth state " + std::to_string(st.id);
    check(reader.state_blobs(st.id, &blob, &velocities, &err), what);
    name(blob, what + " positions");
    name(velocities, what + " velocities");
  }
  std::set<int64_t> unchosen;
  for (int64_t id : candidates)
    if (!named.count(id)) unchosen.insert(id);
  return unchosen;
}

}  // namespace clothdb
