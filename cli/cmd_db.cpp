// `clothdb db info FILE` and `clothdb db check FILE`.
#include <cstdio>
#include <memory>
#include <string>

#include "cli_util.hpp"
#include "commands.hpp"
#include "database/check.hpp"

namespace clothdb::cli {

namespace {

void print_info(const db::DatabaseInfo& i) {
  std::printf("file            %s (%.2f MB with WAL)\n", i.path.c_str(), i.file_bytes / 1e6);
  std::printf("schema version  %d\n", i.schema_version);
  std::printf(
      "codec           positions +-%g m, velocities +-%g m/s, key frame every %u, zstd %d\n",
      i.codec.position_bound, i.codec.velocity_bound, i.codec.key_interval, i.codec.zstd_level);
  if (i.garment_vertices)
    std::printf("garment         %u vertices, %u triangles\n", i.garment_vertices,
                i.garment_triangles);
  else
    std::printf("garment         none stored\n");
  std::printf("motion          %llu files, %llu primary clips, %llu transitions\n",
              (unsigned long long)i.motion_files, (unsigned long long)i.primary_clips,
              (unsigned long long)i.primary_transitions);
  std::printf(
      "cloth graph     %llu states, %llu clips (%llu ok, %llu flagged, %llu edited), "
      "%llu edges\n",
      (unsigned long long)i.cloth_states, (unsigned long long)i.cloth_clips,
      (unsigned long long)i.clips_ok, (unsigned long long)i.clips_flagged,
      (unsigned long long)i.clips_edited, (unsigned long long)i.cloth_edges);
  std::printf("cloth frames    %llu: %.2f MB encoded, %.2f MB as float32",
              (unsigned long long)i.cloth_frames, i.clip_blob_bytes / 1e6, i.clip_raw_bytes / 1e6);
  if (i.clip_blob_bytes) std::printf(" (%.1f:1)", double(i.clip_raw_bytes) / i.clip_blob_bytes);
  std::printf(", largest codec error %.3g m\n", i.max_clip_error);
  std::printf("cloth states    %.2f MB encoded\n", i.state_blob_bytes / 1e6);
  if (i.cloth_edges)
    std::printf(
        "linked          %llu of %llu clip ends (%.1f %%) link back to a state their clip "
        "did not make\n",
        (unsigned long long)i.linked_edges, (unsigned long long)i.cloth_edges,
        100.0 * double(i.linked_edges) / double(i.cloth_edges));
  std::printf("runs            %llu, %.1f CPU s; %llu edits logged\n", (unsigned long long)i.runs,
              i.run_cpu_seconds, (unsigned long long)i.edits);
  if (!i.last_run_notes.empty()) std::printf("last run        %s\n", i.last_run_notes.c_str());
  for (const auto& [key, value] : i.meta) {
    // Long values (the scene file) are shown by their first line only.
    const std::string first = value.substr(0, std::min(value.find('\n'), size_t(100)));
    std::printf("meta %-18s %s%s\n", key.c_str(), first.c_str(),
                first.size() < value.size() ? " ..." : "");
  }
}

}  // namespace

void register_db_commands(CLI::App& app) {
  CLI::App* db = &command_group(app, "db", "Inspect and check clothdb database files");

  auto file = std::make_shared<std::string>();
  CLI::App* info = db->add_subcommand(
      "info",
      "Summary of a clothdb database: format and codec settings, garment, motion and "
      "cloth graph sizes, compression, runs");
  info->add_option("FILE", *file, "clothdb database")->required();
  info->callback([file] { print_info(db::read_database_info(*file)); });

  CLI::App* check = db->add_subcommand(
      "check",
      "Integrity check: SQLite's own check and foreign keys, every blob's checksums "
      "(by decoding it), blob sizes against their rows, every edge, clip and state "
      "pointing at rows that exist, and everything the runtime relies on (garment arrays and "
      "triangle indices, transitions complete at every node, cloth edges landing at their "
      "clip's end node, meta versions). Exits 1 on any problem, listing each; states without a "
      "clip along some way out of their node are listed as warnings (the runtime falls back), "
      "an error with --strict.");
  check->add_option("FILE", *file, "clothdb database")->required();
  auto strict = std::make_shared<bool>(false);
  check->add_flag("--strict", *strict, "Treat warnings (unexplored ways out) as problems");
  check->callback([file, strict] {
    const db::CheckReport report = db::check_database(*file);
    for (const auto& p : report.problems) std::printf("problem: %s\n", p.c_str());
    for (const auto& w : report.warnings) std::printf("warning: %s\n", w.c_str());
    if (!report.ok() || (*strict && !report.warnings.empty()))
      throw std::runtime_error(*file + ": " + std::to_string(report.problems.size()) +
                               " problem(s), " + std::to_string(report.warnings.size()) +
                               " warning(s) found");
    std::printf("%s: ok (%llu blobs decoded, %llu graph rows checked, %zu warning(s))\n",
                file->c_str(), (unsigned long long)report.blobs_checked,
                (unsigned long long)report.rows_checked, report.warnings.size());
  });
}

}  // namespace clothdb::cli
