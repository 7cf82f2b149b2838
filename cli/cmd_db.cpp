// `clothdb db info FILE` and `clothdb db check FILE`.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "cli_util.hpp"
#include "commands.hpp"
#include "compress/recode.hpp"
#include "database/format/cloth_graph.hpp"
#include "database/store/check.hpp"
#include "graph/motion_graph.hpp"

namespace clothdb::cli {

namespace {

// Primary clips by how many cloth clips run along them, in power-of-two buckets, with a bar: a
// run that spent its budget going round one loop shows a few edges in the top bucket.
void print_clips_per_edge(const std::vector<uint64_t>& per_edge) {
  uint64_t edges = 0, most = 0;
  for (uint64_t n : per_edge) edges += n;
  std::vector<std::pair<std::string, uint64_t>> buckets;
  for (size_t lo = 0; lo < per_edge.size(); lo = lo == 0 ? 1 : 2 * lo) {
    const size_t hi = lo == 0 ? 0 : std::min(per_edge.size() - 1, 2 * lo - 1);
    uint64_t n = 0;
    for (size_t k = lo; k <= hi; ++k) n += per_edge[k];
    buckets.push_back(
        {lo == hi ? std::to_string(lo) : std::to_string(lo) + "-" + std::to_string(hi), n});
    most = std::max(most, n);
  }
  std::printf("clips per edge  of %llu primary clips, how many have k cloth clips along them:\n",
              (unsigned long long)edges);
  for (const auto& [label, n] : buckets)
    std::printf("  k = %-9s %5llu %s\n", label.c_str(), (unsigned long long)n,
                std::string(most ? size_t(40 * n / most) : 0, '#').c_str());
}

// The garment's error floor the precompute measured (meta error_floor, m, and its detail JSON).
void print_error_floor(const db::DatabaseInfo& i) {
  std::string floor, detail;
  for (const auto& [key, value] : i.meta) {
    if (key == db::meta::kErrorFloor) floor = value;
    if (key == db::meta::kErrorFloorDetail) detail = value;
  }
  if (floor.empty()) return;
  char* end = nullptr;
  const double metres = std::strtod(floor.c_str(), &end);
  if (*end != '\0' || !std::isfinite(metres)) {
    std::printf("error floor     '%s' (not a number)\n", floor.c_str());
    return;
  }
  std::printf("error floor     %.2f mm", 1e3 * metres);
  const nlohmann::json j = nlohmann::json::parse(detail, nullptr, false);
  if (j.is_object() && j.contains("walked_mm") && j.contains("held_median_mm") &&
      j.contains("histories"))
    std::printf(" (median of %zu pairwise distances between %zu histories; held still %.2f mm)",
                j["walked_mm"].size(), j["histories"].size(), j["held_median_mm"].get<double>());
  std::printf(": an epsilon below it cannot link clip ends\n");
}

// The stored motion graph's coverage (graph/motion_graph.hpp: graph_coverage), if it holds one.
void print_graph_coverage(const db::DatabaseInfo& i) {
  for (const auto& [key, value] : i.meta) {
    if (key != db::meta::kMotionGraph) continue;
    const nlohmann::json j = nlohmann::json::parse(value, nullptr, false);
    try {
      std::printf("%s",
                  coverage_text(motion_graph_from_json(j, i.path + ": meta motion_graph")).c_str());
    } catch (const GraphError& e) {
      std::printf("coverage: not shown: %s\n", e.what());
    }
  }
}

// The explorer's forecast of the CPU-hours to converge (meta forecast), as its last run made it.
void print_forecast(const db::DatabaseInfo& i) {
  for (const auto& [key, value] : i.meta)
    if (key == db::meta::kForecast) std::printf("forecast  %s\n", value.c_str());
}

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
  print_graph_coverage(i);
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
  std::printf(
      "frame codec     %s: %llu clip blobs of version 1, %llu of version 2, %llu of version 3; "
      "states %llu of version 1, %llu of version 2\n",
      i.clips_v3 > 0                        ? "v3 (contract)"
      : i.clips_v2 == 0 && i.states_v2 == 0 ? "v1"
      : i.clips_v1 == 0 && i.states_v1 == 0 ? "v2"
                                            : "v1 and v2",
      (unsigned long long)i.clips_v1, (unsigned long long)i.clips_v2,
      (unsigned long long)i.clips_v3, (unsigned long long)i.states_v1,
      (unsigned long long)i.states_v2);
  if (i.contracts)
    std::printf(
        "error contract  %llu clips: worst %s within caps of RMS %g / max %g / jitter %g "
        "mm (against the frames they were encoded from)\n",
        (unsigned long long)i.contracts, codec::describe(i.worst_contract).c_str(),
        i.loosest_caps.rms * 1e3, i.loosest_caps.max * 1e3, i.loosest_caps.jitter * 1e3);
  for (const auto& b : i.bases)
    std::printf("codec basis %-4lld %u modes x %u vertices, %.2f MB, %s: %s\n", (long long)b.id,
                b.mode_count, b.vertex_count, b.bytes / 1e6, b.created.c_str(), b.source.c_str());
  std::printf("cloth states    %.2f MB encoded\n", i.state_blob_bytes / 1e6);
  if (i.cloth_edges)
    std::printf(
        "linked          %llu of %llu clip ends (%.1f %%) link back to a state their clip "
        "did not make\n",
        (unsigned long long)i.linked_edges, (unsigned long long)i.cloth_edges,
        100.0 * double(i.linked_edges) / double(i.cloth_edges));
  if (i.schema_version >= 4)
    std::printf(
        "dead ends       %llu linked to the nearest state's clip (blend error mean %.2f mm, worst "
        "%.2f mm); the runtime needs no fallback search when db check passes\n",
        (unsigned long long)i.cloth_links, 1e3 * i.mean_link_error, 1e3 * i.max_link_error);
  if (!i.clips_per_edge.empty()) print_clips_per_edge(i.clips_per_edge);
  std::printf("runs            %llu, %.1f CPU s; %llu edits logged\n", (unsigned long long)i.runs,
              i.run_cpu_seconds, (unsigned long long)i.edits);
  if (i.last_run_unfinished) {
    // A killed precompute left no summary: say so, rather than show an earlier run's as the last.
    std::printf(
        "last run        run %lld (started %s) did not finish: killed, or still running; its "
        "committed batches are kept, and the same command resumes it\n",
        (long long)i.last_run_id, i.last_run_started.c_str());
    if (!i.last_run_notes.empty()) std::printf("last finished   %s\n", i.last_run_notes.c_str());
  } else if (!i.last_run_notes.empty()) {
    std::printf("last run        %s\n", i.last_run_notes.c_str());
  }
  print_error_floor(i);
  print_forecast(i);
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

  struct RecodeArgs {
    std::string file, codec = "v2";
    double bound_mm = 0, velocity_bound_mm_s = 0;
    ContractOptions contract;
    RecodeOptions options;
  };
  auto rargs = std::make_shared<RecodeArgs>();
  CLI::App* recode = db->add_subcommand(
      "recode",
      "Re-encode every cloth clip and state in place (docs/DATABASE.md, codec version 2): v2 "
      "builds "
      "a garment subspace (PCA of the file's own frames) and codes each frame as subspace "
      "coefficients plus a residual that keeps the per-coordinate bound; v1 re-encodes with the "
      "version 1 codec. Rows are rewritten in batches, one transaction each, so a killed recode "
      "leaves a valid file; a blob is replaced only if the new one is smaller. The bound applies "
      "to the stored frames, so each clip's bound against the simulation becomes its old bound "
      "plus this one (recorded per clip). v3 keeps an error contract in what a player sees "
      "instead of a bound (docs/DATABASE.md, \"The error contract\"): each clip's worst-frame "
      "RMS vertex distance, largest vertex distance and jitter (second difference in time of the "
      "error) within --rms-mm, --max-mm and --jitter-mm, measured against the stored frames and "
      "recorded per clip (table codec_contract); states keep their blobs.");
  recode->add_option("FILE", rargs->file, "clothdb database")->required();
  recode->add_option("--codec", rargs->codec, "Frame format to write: v3, v2 or v1")
      ->capture_default_str()
      ->check(CLI::IsMember({"v1", "v2", "v3"}));
  rargs->contract.add_to(*recode);
  recode
      ->add_option("--bound-mm", rargs->bound_mm,
                   "Position bound in mm per coordinate, against the stored frames (default: "
                   "the file's codec.position_bound)")
      ->check(number_in(1e-6, 1e3));
  recode
      ->add_option("--velocity-bound-mm-s", rargs->velocity_bound_mm_s,
                   "State velocity bound in mm/s (default: the file's codec.velocity_bound)")
      ->check(positive_number());
  recode->add_option("--modes", rargs->options.modes, "Basis modes (v2, v3)")
      ->capture_default_str()
      ->check(CLI::Range(1u, codec::kMaxBasisModes));
  recode
      ->add_option("--basis-frames", rargs->options.basis_frames,
                   "Frames sampled evenly over all clips to build the basis (v2)")
      ->capture_default_str()
      ->check(CLI::Range(2u, 1000000u));
  recode
      ->add_option("--coefficient-step", rargs->options.coefficient_step_factor,
                   "Coefficient quantisation step as a multiple of the bound (v2)")
      ->capture_default_str()
      ->check(positive_number());
  recode->add_option("--batch", rargs->options.batch, "Rows per transaction")
      ->capture_default_str()
      ->check(CLI::Range(1u, 100000u));
  recode->add_flag("--body-frame", rargs->options.body_frame,
                   "v2: code the cloth relative to a rigid body frame fitted to the garment's "
                   "highest 5 % (its pinned band) in every frame, and build the basis in it");
  recode->add_flag("--always", rargs->options.always,
                   "Replace every blob even where the new encoding is larger (for measuring)");
  recode->add_flag("!--no-vacuum", rargs->options.vacuum,
                   "Keep the freed pages in the file (skip VACUUM at the end)");
  recode->callback([rargs] {
    RecodeOptions o = rargs->options;
    o.codec = rargs->codec == "v1" ? 1 : rargs->codec == "v2" ? 2 : 3;
    if (o.codec == 3 && rargs->bound_mm > 0)
      throw CLI::ValidationError("--bound-mm",
                                 "v3 keeps an error contract, not a per-coordinate bound: "
                                 "give --rms-mm, --max-mm and --jitter-mm");
    o.contract = rargs->contract.resolved(o.codec == 3);
    o.bound = rargs->bound_mm * 1e-3;
    o.velocity_bound = rargs->velocity_bound_mm_s * 1e-3;
    o.progress = [](const std::string& line) { std::fprintf(stderr, "%s\n", line.c_str()); };
    const RecodeReport r = recode_database(rargs->file, o);
    std::printf("recoded %s to codec %s in %.1f s", rargs->file.c_str(), rargs->codec.c_str(),
                r.seconds);
    if (r.basis_id)
      std::printf(" (basis %lld: %u modes in %.1f s, sample RMS %.2f mm, residual RMS %.2f mm)",
                  (long long)r.basis_id, r.basis_modes, r.basis_seconds, r.sample_rms * 1e3,
                  r.residual_rms * 1e3);
    std::printf(
        "\nclips %llu (%llu replaced), states %llu (%llu replaced); blobs %.2f MB -> %.2f MB "
        "(%.1f:1 against float32 -> %.1f:1); largest new error %.3f mm; file %.2f MB -> %.2f MB\n",
        (unsigned long long)r.clips, (unsigned long long)r.clips_replaced,
        (unsigned long long)r.states, (unsigned long long)r.states_replaced,
        r.blob_bytes_before / 1e6, r.blob_bytes_after / 1e6,
        double(r.raw_bytes) / double(std::max<uint64_t>(1, r.blob_bytes_before)),
        double(r.raw_bytes) / double(std::max<uint64_t>(1, r.blob_bytes_after)), r.max_error * 1e3,
        r.file_bytes_before / 1e6, r.file_bytes_after / 1e6);
    if (o.codec == 3)
      std::printf(
          "contract: worst over the recoded clips %s (caps %s); %llu clips needed a "
          "residual, %llu were already v3\n",
          codec::describe(r.worst).c_str(),
          codec::describe({o.contract.rms, o.contract.max, o.contract.jitter}).c_str(),
          (unsigned long long)r.clips_with_residual, (unsigned long long)r.clips_already_v3);
  });

  CLI::App* check = db->add_subcommand(
      "check",
      "Integrity check: SQLite's own check and foreign keys, every blob's checksums "
      "(by decoding it, codec version 2 with its basis), blob sizes against their rows, each "
      "clip's codec bound and measured error within its recorded bound, every edge, clip and "
      "state pointing at rows that exist, and everything the runtime relies on (garment arrays "
      "and triangle indices, transitions complete at every node, cloth edges landing at their "
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
