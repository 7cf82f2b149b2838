#include "compress/recode.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <stdexcept>

#include "compress/subspace.hpp"
#include "database/codec/codec.hpp"
#include "database/store/basis_store.hpp"
#include "database/store/contract_store.hpp"
#include "database/store/writer.hpp"

namespace clothdb {
namespace {

void check(db::Status st, const db::Error& err) {
  if (st != db::Status::Ok) throw ClothdbError(st, err.message);
}

uint64_t file_bytes(const std::string& path) {
  std::error_code ec;
  uint64_t bytes = std::filesystem::file_size(path, ec);
  if (ec) bytes = 0;
  const auto wal = std::filesystem::file_size(path + "-wal", ec);
  if (!ec) bytes += wal;
  return bytes;
}

std::string text(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

}  // namespace

BuiltBasis build_basis_from_clips(db::Reader& reader, const std::vector<db::ClothClip>& clips,
                                  uint32_t vertex_count, uint32_t modes, uint32_t sample_frames,
                                  const BodyAnchors* anchors) {
  const size_t n = size_t(vertex_count) * 3;
  db::Error err;
  codec::DecodeScratch scratch;
  std::vector<uint8_t> blob;
  std::vector<float> frames, sample;
  uint64_t total = 0;
  for (const auto& c : clips) total += uint64_t(c.frame_count);
  const uint64_t stride = std::max<uint64_t>(1, total / std::max<uint32_t>(1, sample_frames));
  uint64_t index = 0;
  for (const auto& c : clips) {
    check(reader.clip_blob(c.id, &blob, &err), err);
    check(reader.decode_all(blob, &frames, scratch, &err), err);
    if (frames.size() != size_t(c.frame_count) * n)
      throw ClothdbError(db::Status::Corrupt, "clip " + std::to_string(c.id) + " decodes to " +
                                                  std::to_string(frames.size() / n) +
                                                  " frames, its row says " +
                                                  std::to_string(c.frame_count));
    for (int32_t f = 0; f < c.frame_count; ++f, ++index)
      if (index % stride == 0)
        sample.insert(sample.end(), frames.begin() + ptrdiff_t(size_t(f) * n),
                      frames.begin() + ptrdiff_t(size_t(f + 1) * n));
  }
  if (sample.empty()) throw std::invalid_argument("the database has no cloth frames");
  const uint32_t sampled = uint32_t(sample.size() / n);
  if (anchors)
    to_body_frame(sample.data(), sampled, vertex_count,
                  fit_body_frames(sample.data(), sampled, vertex_count, *anchors).data());
  const Subspace s = build_subspace(sample, uint32_t(n), modes);
  BuiltBasis out;
  out.basis = codec::make_basis(0, vertex_count, s.mean.data(), s.basis.data(), s.modes);
  out.frames = total;
  out.sampled = sample.size() / n;
  out.sample_rms = s.sample_rms;
  out.residual_rms = s.residual_rms;
  char source[256];
  std::snprintf(
      source, sizeof source,
      "PCA of %llu of %llu frames (every %llu-th)%s, %u modes, sample RMS %.3g m, "
      "residual RMS %.3g m",
      (unsigned long long)out.sampled, (unsigned long long)total, (unsigned long long)stride,
      anchors ? (" in the body frame of " + std::to_string(anchors->vertices.size()) + " anchors")
                    .c_str()
              : "",
      s.modes, s.sample_rms, s.residual_rms);
  out.source = source;
  return out;
}

RecodeReport recode_database(const std::string& path, const RecodeOptions& o) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  auto say = [&](const std::string& line) {
    if (o.progress) o.progress(line);
  };
  if (o.codec < 1 || o.codec > 3)
    throw std::invalid_argument("recode: --codec must be v1, v2 or v3");
  const bool v3 = o.codec == 3;
  if (v3 && !(o.contract.rms > 0 && o.contract.max > 0 && o.contract.jitter > 0))
    throw std::invalid_argument("recode: codec v3 needs positive RMS, max and jitter caps");
  if (o.batch == 0) throw std::invalid_argument("recode: batch must be at least 1");
  RecodeReport report;
  report.file_bytes_before = file_bytes(path);

  db::Writer writer = db::Writer::open(path);
  db::Reader reader;  // reads through the writer's connection: sees each batch as written
  db::Error err;
  check(reader.open_borrowed(writer.handle(), writer.path(), &err), err);
  const db::CodecSettings file_codec = writer.codec();
  const double bound = o.bound > 0 ? o.bound : file_codec.position_bound;
  const double velocity_bound = o.velocity_bound > 0 ? o.velocity_bound : file_codec.velocity_bound;
  db::Garment garment;
  check(reader.garment(&garment, &err), err);
  const uint32_t V = garment.vertex_count();
  std::vector<db::ClothClip> clips;
  std::vector<db::StoredState> states;
  check(reader.cloth_clips(&clips, &err), err);
  check(reader.cloth_states(&states, &err), err);
  report.clips = clips.size();
  report.states = states.size();
  codec::DecodeScratch scratch;
  std::vector<uint8_t> blob, pos_blob, vel_blob;
  std::vector<float> frames, x, v;

  // The basis: principal components of frames sampled evenly over every clip.
  codec::Basis basis;
  const bool body = o.codec == 2 && o.body_frame;
  const BodyAnchors anchors = body ? body_anchors(garment.rest_positions) : BodyAnchors{};
  if (o.codec >= 2) {
    const auto t0 = Clock::now();
    say("basis: sampling up to " + std::to_string(o.basis_frames) + " frames, " +
        std::to_string(o.modes) + " modes ...");
    BuiltBasis built = build_basis_from_clips(reader, clips, V, o.modes, o.basis_frames,
                                              body ? &anchors : nullptr);
    basis = std::move(built.basis);
    basis.id = db::store_basis(writer, basis, built.source);  // committed before any blob names it
    report.basis_id = basis.id;
    report.basis_modes = basis.mode_count;
    report.sample_rms = built.sample_rms;
    report.residual_rms = built.residual_rms;
    report.basis_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    say(std::string("basis ") + std::to_string(basis.id) + ": " + built.source);
  }

  const codec::EncodeSettings position_settings = db::encode_settings(file_codec, bound);
  const codec::EncodeSettings velocity_settings = db::encode_settings(file_codec, velocity_bound);
  codec::SubspaceSettings sub;
  sub.coefficient_step_factor = o.coefficient_step_factor;
  auto encode = [&](const std::vector<float>& data, uint32_t count, bool velocities,
                    codec::EncodeStats* stats) {
    const auto& settings = velocities ? velocity_settings : position_settings;
    if (o.codec == 1 || (v3 && velocities))
      return codec::encode(data.data(), count, V, settings, stats);
    codec::SubspaceSettings s = sub;
    s.use_mean = !velocities;
    std::vector<float> transforms;
    if (body && !velocities) {
      transforms = fit_body_frames(data.data(), count, V, anchors);
      s.body_frames = transforms.data();
    }
    return codec::encode_v2(data.data(), count, V, basis, settings, s, stats);
  };

  // Clips, then states, in batches of rows; each batch one transaction.
  uint64_t batches = 0;
  const size_t rows = clips.size() + states.size();
  const auto rows_start = Clock::now();
  for (size_t b0 = 0; b0 < rows; b0 += o.batch) {
    db::Writer::Transaction t(writer);
    for (size_t r = b0; r < std::min(rows, b0 + o.batch); ++r) {
      if (r < clips.size()) {
        const db::ClothClip& c = clips[r];
        check(reader.clip_blob(c.id, &blob, &err), err);
        if (v3) {
          codec::BlobInfo old;
          check(codec::read_info(blob.data(), blob.size(), &old, &err), err);
          if (old.version == codec::kFormatVersionV3) {  // recoded before a kill: kept
            report.blob_bytes_before += blob.size();
            report.blob_bytes_after += blob.size();
            report.raw_bytes += size_t(c.frame_count) * V * 3 * sizeof(float);
            ++report.clips_already_v3;
            continue;
          }
        }
        check(reader.decode_all(blob, &frames, scratch, &err), err);
        if (v3) {
          codec::V3Settings vs;
          vs.contract = o.contract;
          vs.zstd_level = file_codec.zstd_level;
          codec::V3Stats stats;
          const auto fresh =
              codec::encode_v3(frames.data(), uint32_t(c.frame_count), V, basis, vs, &stats);
          report.blob_bytes_before += blob.size();
          report.raw_bytes += frames.size() * sizeof(float);
          if (o.always || fresh.size() < blob.size()) {
            db::recode_clip_blob(writer, c.id, fresh, c.error_bound + o.contract.max,
                                 c.max_error + stats.figures.max);
            db::store_clip_contract(writer, c.id, stats.figures, o.contract);
            report.worst.rms = std::max(report.worst.rms, stats.figures.rms);
            report.worst.max = std::max(report.worst.max, stats.figures.max);
            report.worst.jitter = std::max(report.worst.jitter, stats.figures.jitter);
            report.max_error = std::max(report.max_error, stats.figures.max);
            report.clips_with_residual += stats.residual_interval > 0;
            report.blob_bytes_after += fresh.size();
            ++report.clips_replaced;
          } else {
            report.blob_bytes_after += blob.size();
          }
          continue;
        }
        codec::EncodeStats stats;
        const auto fresh = encode(frames, uint32_t(c.frame_count), false, &stats);
        report.blob_bytes_before += blob.size();
        report.raw_bytes += frames.size() * sizeof(float);
        if (o.always || fresh.size() < blob.size()) {
          db::recode_clip_blob(writer, c.id, fresh, c.error_bound + bound,
                               c.max_error + stats.max_error);
          report.max_error = std::max(report.max_error, stats.max_error);
          report.blob_bytes_after += fresh.size();
          ++report.clips_replaced;
        } else {
          report.blob_bytes_after += blob.size();
        }
      } else {
        const db::StoredState& s = states[r - clips.size()];
        if (v3) continue;  // states keep the strict bound (see RecodeOptions::contract)
        check(reader.state_blobs(s.id, &pos_blob, &vel_blob, &err), err);
        check(reader.decode_all(pos_blob, &x, scratch, &err), err);
        check(reader.decode_all(vel_blob, &v, scratch, &err), err);
        auto fresh_x = encode(x, 1, false, nullptr);
        auto fresh_v = encode(v, 1, true, nullptr);
        report.blob_bytes_before += pos_blob.size() + vel_blob.size();
        report.raw_bytes += (x.size() + v.size()) * sizeof(float);
        const bool replace_x = o.always || fresh_x.size() < pos_blob.size();
        const bool replace_v = o.always || fresh_v.size() < vel_blob.size();
        if (!replace_x) fresh_x = pos_blob;
        if (!replace_v) fresh_v = vel_blob;
        if (replace_x || replace_v) {
          db::recode_state_blobs(writer, s.id, fresh_x, fresh_v);
          ++report.states_replaced;
        }
        report.blob_bytes_after += fresh_x.size() + fresh_v.size();
      }
    }
    if (b0 + o.batch >= rows) {
      // The last batch also records what the file now uses (meta keys are read by `db info`). A
      // basis no blob took is removed again: it would only cost its bytes.
      const bool basis_used = report.clips_replaced + report.states_replaced > 0;
      if (v3 && basis_used) {
        // codec.format_version was raised by the first version 3 blob (note_blob_version).
        writer.set_meta(db::meta::kCodecBasis, std::to_string(basis.id));
      } else if (o.codec == 1 || basis_used) {
        writer.set_meta(db::meta::kCodecFormatVersion, std::to_string(o.codec));
        writer.set_meta(db::meta::kCodecRecodedBound, text(bound));
      }
      if (o.codec == 2 && basis_used)
        writer.set_meta(db::meta::kCodecBasis, std::to_string(basis.id));
      if (o.codec >= 2 && !basis_used) {
        db::remove_basis(writer, basis.id);
        say("no blob got smaller with the subspace: basis " + std::to_string(basis.id) +
            " removed, the file keeps its blobs");
        report.basis_id = 0;
      }
    }
    t.commit();
    ++batches;
    if (batches % 8 == 0 || b0 + o.batch >= rows) {
      // The time left at the pace so far; clips come first and cost more than states, so it errs
      // long.
      const size_t done = std::min(rows, b0 + o.batch);
      const double seconds = std::chrono::duration<double>(Clock::now() - rows_start).count();
      char left[48] = "";
      if (done < rows)
        std::snprintf(left, sizeof left, ", about %.0f s left",
                      seconds / double(done) * double(rows - done));
      say("recoded " + std::to_string(done) + " of " + std::to_string(rows) + " rows" + left);
    }
    if (o.after_batch) o.after_batch(batches);
  }
  reader.close();
  if (o.vacuum) {
    std::string why;
    if (!db::compact_file(writer, &why)) say("vacuum skipped: " + why);
  }
  report.file_bytes_after = file_bytes(path);
  report.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  return report;
}

}  // namespace clothdb
