#include "explore/explorer.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <stdexcept>

#include "character_scene/character_space.hpp"
#include "database/codec/codec.hpp"
#include "database/format/checksum.hpp"
#include "database/store/basis_store.hpp"
#include "database/store/contract_store.hpp"
#include "explore/codec_schedule.hpp"
#include "explore/dead_ends.hpp"
#include "explore/forecast.hpp"
#include "explore/jobs.hpp"
#include "explore/primary_graph.hpp"
#include "explore/progress.hpp"
#include "explore/scene_sources.hpp"
#include "explore/secondary_graph.hpp"
#include "graph/motion_graph.hpp"
#include "quality/clip_quality.hpp"

// Where the parts are: explore() below is Kim et al. 2013's loop, and integrate_batch its step.
// The secondary graph (states per node, nearest state) is in explore/secondary_graph, the dead-end
// queue and the closing links in explore/dead_ends, jobs and steering in explore/jobs, the codec
// version 2 schedule in explore/codec_schedule, the curve and progress bar in explore/progress.

namespace clothdb {

namespace {

// Kim et al.'s step, for a batch's results in batch order, in one transaction: each clip is stored
// and its end either links to the nearest state at its end node (distance <= epsilon: a cloth edge
// with that blend error) or becomes a new state (a new dead end per way out of that node). This
// project's additions: unstable jobs are left as dead ends (not retried in this run), steering is
// recorded, and the clip ends that linked are counted (the curve's share linked).
void integrate_batch(SecondaryGraph& sg, db::Writer& writer, const ExploreGraph& graph,
                     const std::vector<Job>& batch, const std::vector<JobResult>& results,
                     int64_t run_id, const ExploreOptions& options, FailedDeadEnds& failed,
                     ExploreReport& report) {
  const auto t0 = std::chrono::steady_clock::now();
  codec::DecodeScratch scratch;
  db::Writer::Transaction tx(writer);
  for (size_t b = 0; b < batch.size(); ++b) {
    const Job& job = batch[b];
    const JobResult& r = results[b];
    report.cpu_seconds += r.cpu_seconds;
    const int64_t start_id = sg.states[static_cast<size_t>(job.state)].id;
    const ExploreEdge& edge = graph.edges[static_cast<size_t>(job.edge)];
    if (!r.stable) {
      failed.insert({start_id, job.edge});
      std::fprintf(stderr,
                   "\nexplore: state %lld along '%s' is unstable (%s); left as a dead end\n",
                   static_cast<long long>(start_id), edge.name.c_str(), r.message.c_str());
      continue;
    }
    db::NewClothClip clip;
    clip.set_metrics(to_clip_metrics(r.quality));
    clip.start_state = start_id;
    clip.primary_clip = edge.db_clip;
    clip.first_frame = 0;
    clip.run = run_id;
    const int64_t clip_id = writer.add_cloth_clip_blob(clip, r.clip_blob, r.clip_max_error);
    if (r.has_contract) {
      db::store_clip_contract(writer, clip_id, r.contract, options.subspace_contract);
      db::set_clip_error_bound(writer, clip_id, options.subspace_contract.max);
    }
    {
      codec::BlobInfo info;
      db::Error info_err;
      if (codec::read_info(r.clip_blob.data(), r.clip_blob.size(), &info, &info_err) ==
              db::Status::Ok &&
          info.version == codec::kFormatVersionV2)
        ++report.clips_v2;
      report.clips_v3 += r.has_contract;
    }
    if (r.steer_target != 0) {
      writer.set_clip_steering(
          {clip_id, r.steer_target, r.steer_distance, r.steer_displacement, r.steer_acceleration});
      ++report.steered;
      report.worst_steering = std::max(report.worst_steering, r.steer_displacement);
    }
    record_clip(sg, start_id, job.edge, clip_id);
    report.frames += r.frame_count;
    report.frames_this_run += r.frame_count;
    // The end as it is stored (and as a resumed run reads it), then the nearest state at the end
    // node.
    std::vector<float> end_x, end_v;
    db::Error err;
    if (codec::decode_all(r.end_x_blob.data(), r.end_x_blob.size(), end_x, scratch, &err) !=
            db::Status::Ok ||
        codec::decode_all(r.end_v_blob.data(), r.end_v_blob.size(), end_v, scratch, &err) !=
            db::Status::Ok)
      throw std::runtime_error("explore: the end state of state " + std::to_string(start_id) +
                               " along '" + edge.name + "' does not decode: " + err.message);
    const Nearest nearest = nearest_state(sg, edge.to_node, end_x, end_v);
    ++sg.clips;
    if (nearest.state >= 0 && nearest.distance <= options.epsilon) {
      // Kim et al.: within epsilon, the clip's end continues as that state (blend error recorded).
      ++sg.linked;
      const StateRec& to = sg.states[static_cast<size_t>(nearest.state)];
      const ExactStatePtr to_exact = sg.state(nearest.state);
      writer.add_cloth_edge(clip_id, to.id, nearest.distance,
                            transition_pop(r.last.data(), to_exact->x.data(), r.vertex_count));
      report.worst_blend_error = std::max(report.worst_blend_error, nearest.distance);
    } else {
      // Kim et al.: otherwise the end is a new state, with a dead end per way out of its node.
      StateRec rec;
      rec.node = edge.to_node;
      rec.id = writer.add_cloth_state_blobs(node_anchor_clip(graph, rec.node), 0, r.end_x_blob,
                                            r.end_v_blob, run_id, clip_id);
      writer.add_cloth_edge(clip_id, rec.id, 0.0,
                            transition_pop(r.last.data(), end_x.data(), r.vertex_count));
      add_state(sg, std::move(rec), ExactState{std::move(end_x), std::move(end_v)}, nearest);
    }
  }
  tx.commit();
  report.jobs_this_run += static_cast<long>(batch.size());
  report.integrate_seconds +=
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Simulation CPU seconds of the file's earlier runs (a killed run recorded none).
double earlier_cpu_seconds(db::Reader& reader, const std::string& path) {
  std::vector<db::Run> runs;
  db::Error err;
  if (reader.runs(&runs, &err) != db::Status::Ok)
    throw std::runtime_error(path + ": reading run to resume: " + std::string(err.message));
  double seconds = 0;
  for (const db::Run& r : runs) seconds += r.cpu_seconds;
  return seconds;
}

// The CPU the run has used, for the budget: the process's (every thread, the error floor and the
// set-up included), and at least what the simulations reported (MPI workers run elsewhere).
double run_cpu_seconds(const ExploreOptions& options, double explore_start) {
  const double start = options.process_cpu_start >= 0 ? options.process_cpu_start : explore_start;
  return process_cpu_seconds() - start;
}

bool budget_spent(const ExploreOptions& options, ExploreReport& report, double explore_start) {
  report.budget_cpu_seconds = std::max(run_cpu_seconds(options, explore_start),
                                       options.cpu_seconds_spent + report.cpu_seconds);
  return (options.cpu_hours > 0 && report.budget_cpu_seconds >= options.cpu_hours * 3600) ||
         (options.max_frames > 0 && report.frames_this_run >= options.max_frames);
}

// The end of a run, after its last batch: the closing links, the unchosen bases removed, the run's
// notes, and the file compacted when bases were removed.
void close_run(SecondaryGraph& sg, const ExploreGraph& graph, db::Writer& writer,
               db::Reader& reader, const CodecSchedule& bases, const ExploreOptions& options,
               int64_t run_id, size_t dead_ends_left, ExploreReport& report) {
  // This project's: a basis no blob chose (version 1 was smaller every time) costs bytes and the
  // runtime's memory for nothing. Only once the exploration has converged: until then a resumed
  // run must find every basis an uninterrupted one would have, to choose as it would. Found
  // (reads only) before this run's end is written, so a read failure leaves no half-finished end.
  const std::set<int64_t> unchosen = options.subspace_modes > 0 && dead_ends_left == 0
                                         ? unchosen_bases(reader, writer.path(), bases.bases_built)
                                         : std::set<int64_t>{};
  // This project's: no runtime fallback, so every dead end left links to the nearest explored
  // state's clip.
  const std::vector<db::ClothLink> links = link_dead_ends(sg, graph, run_id);
  writer.replace_cloth_links(links);
  db::set_meta_text(writer, db::meta::kDeadEndsLinked, "1");
  for (int64_t id : unchosen) db::remove_basis(writer, id);
  report.bases_removed = static_cast<int>(unchosen.size());
  report.links = static_cast<int>(links.size());
  for (const db::ClothLink& l : links) {
    report.worst_link_error = std::max(report.worst_link_error, l.blend_error);
    report.mean_link_error += l.blend_error / static_cast<double>(links.size());
  }
  // This project's: the forecast of the CPU time to converge, from this run's curve (an edit's
  // exploration from its own states says nothing about the file's).
  report.forecast = forecast_convergence(report.curve, report.cpu_seconds_before);
  if (options.min_state_id == 0)
    db::set_meta_text(writer, db::meta::kForecast, forecast_text(report.forecast));
  writer.finish_run(run_id, report.cpu_seconds, run_notes(report, dead_ends_left));
  if (report.bases_removed > 0) {
    // The removed bases' pages (a few MB each) would otherwise stay in the file as free pages.
    reader.close();
    std::string why;
    if (!db::compact_file(writer, &why))
      std::fprintf(stderr, "explore: %s: not compacted after removing unused bases: %s\n",
                   writer.path().c_str(), why.c_str());
  }
}

}  // namespace

double process_cpu_seconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
}

std::vector<db::NodeEdge> node_edges(const ExploreGraph& graph) {
  std::vector<db::NodeEdge> out;
  out.reserve(graph.edges.size());
  for (const ExploreEdge& e : graph.edges) out.push_back({e.from_node, e.to_node, e.db_clip});
  return out;
}

int64_t node_anchor_clip(const ExploreGraph& graph, int node) {
  const int64_t clip = db::node_anchor_clip(node_edges(graph), node);
  if (clip == 0)
    throw std::runtime_error("explore: node " + std::to_string(node) + " has no edge leaving it");
  return clip;
}

int node_of_primary_clip(const ExploreGraph& graph, int64_t primary_clip) {
  return db::node_of_primary_clip(node_edges(graph), primary_clip);
}

ExploreGraph explore_graph(const CharacterScene& scene, const MotionGraph& graph,
                           const std::string& where) {
  return make_explore_graph(graph, scene.clips, where);
}

DatabaseScene load_database_scene(db::Reader& reader, const std::string& scene_file,
                                  const std::string& motions_dir) {
  const std::string& path = reader.path();
  db::Error err;
  auto meta = [&](const char* key) {
    std::string value;
    if (reader.meta(key, &value, &err) != db::Status::Ok)
      throw std::runtime_error(path + ": no meta '" + key +
                               "': not made by `clothdb precompute`, so its scene is unknown");
    return value;
  };
  std::vector<db::MotionFile> motion_files;
  db::throw_if_error(reader.motion_files(&motion_files, &err), err);
  DatabaseScene out;
  if (scene_file.empty() && has_stored_scene(reader)) {
    // The scene, manifest and garment mesh the database stores: the same scene from anywhere.
    out.scene = build_stored_scene(reader, motions_dir);
  } else {
    const std::string stored_path = meta(db::meta::kScenePath);
    const std::string scene_path = scene_file.empty() ? stored_path : scene_file;
    const std::string scene_hash = meta(db::meta::kSceneHash);
    if (!std::filesystem::exists(scene_path))
      throw std::runtime_error(
          scene_file.empty()
              ? path +
                    ": made before databases stored their scene's manifest and mesh "
                    "(docs/DATABASE.md#stored-sources), and its scene file " +
                    stored_path +
                    " does not exist from here (a relative path is relative to where `precompute` "
                    "ran): give the scene file with --scene"
              : path + ": --scene " + scene_path + ": no such file");
    SceneFile file = load_scene_file(scene_path);
    if (const std::string now = content_hash(file.text); now != scene_hash) {
      const std::string field = json_difference(meta(db::meta::kScene), file.text);
      throw std::runtime_error(path + ": the scene file " + scene_path +
                               " is not the one this database was made from (" +
                               (field.empty() ? scene_hash + ", now " + now : field) + ")");
    }
    if (const std::string d = scene_difference(reader, file); !d.empty())
      throw std::runtime_error(d);
    relocate_motion_files(file, motion_files, motions_dir, path);
    out.scene = build_character_scene(file);
  }
  nlohmann::json graph_json;
  try {
    graph_json = nlohmann::json::parse(meta(db::meta::kMotionGraph));
  } catch (const nlohmann::json::parse_error& e) {
    throw std::runtime_error(path + ": meta motion_graph: not valid JSON: " + e.what());
  }
  const MotionGraph graph = motion_graph_from_json(graph_json, path + ": meta motion_graph");
  out.graph = explore_graph(out.scene, graph, path + ": meta motion_graph");
  std::vector<db::PrimaryClip> clips;
  if (reader.primary_clips(&clips, &err) != db::Status::Ok) throw std::runtime_error(err.message);
  std::map<std::string, int64_t> ids;
  for (const auto& c : clips) ids[c.name] = c.id;
  for (auto& e : out.graph.edges) {
    if (!ids.count(e.name))
      throw std::runtime_error(path + ": has no primary clip '" + e.name +
                               "' of its own motion graph");
    e.db_clip = ids[e.name];
  }
  return out;
}

void prepare_database(db::Writer& writer, const CharacterScene& scene, ExploreGraph& graph,
                      const std::string& graph_json) {
  db::Reader reader;
  db::Error err;
  if (reader.open(writer.path(), &err) != db::Status::Ok)
    throw std::runtime_error(writer.path() + ": " + std::string(err.message));
  const std::string scene_hash = content_hash(scene.file.text);
  const bool has_graph = attach_primary_graph(reader, graph, graph_json);
  check_motion_files(reader, scene_motion_files(scene.file));

  db::Garment existing;
  if (reader.garment(&existing, &err) == db::Status::Ok) {
    // Resuming: the scene must be the one this database was made from.
    // Named by its first differing field (the stored scene, manifest and mesh against these).
    std::string stored;
    if (reader.meta(db::meta::kSceneHash, &stored, &err) == db::Status::Ok &&
        stored != scene_hash) {
      std::string stored_text;
      std::string field;
      if (reader.meta(db::meta::kScene, &stored_text, &err) == db::Status::Ok)
        field = json_difference(stored_text, scene.file.text);
      throw std::runtime_error(
          writer.path() + ": was made from another version of " + scene.file.path.string() + " (" +
          (field.empty() ? "scene hash " + stored + ", now " + scene_hash : field) +
          "); use a new --db, or give the scene it was made from");
    }
    if (const std::string d = scene_difference(reader, scene.file); !d.empty())
      throw std::runtime_error(d + "; use a new --db, or give the files it was made from");
    if (existing.vertex_count() != static_cast<uint32_t>(scene.model.vertex_count()))
      throw std::runtime_error(
          writer.path() + ": garment has " + std::to_string(existing.vertex_count()) +
          " vertices, the scene makes " + std::to_string(scene.model.vertex_count()));
    if (!has_graph) throw std::runtime_error(writer.path() + ": has a garment but no motion graph");
    std::vector<db::SourceFile> stored_sources;
    db::throw_if_error(reader.source_files(&stored_sources, &err), err);
    if (stored_sources.empty()) {
      // Made before the sources were stored: the scene is the stored one, so store them now.
      reader.close();
      db::Writer::Transaction tx(writer);
      for (const db::SourceFile& f : scene_sources(scene.file)) writer.add_source_file(f);
      tx.commit();
    }
    return;
  }
  db::Writer::Transaction tx(writer);
  if (!has_graph) write_primary_graph(writer, graph, graph_json, scene_motion_files(scene.file));
  for (const db::SourceFile& f : scene_sources(scene.file)) writer.add_source_file(f);
  db::Garment g;
  for (const auto& t : scene.model.mesh.triangles)
    for (int k = 0; k < 3; ++k) g.triangles.push_back(static_cast<uint32_t>(t[k]));
  const std::vector<float> rest =
      to_character_space(scene.model.mesh.rest, Eigen::Isometry3d::Identity(), false);
  g.rest_positions = rest;
  const Material& m = scene.file.material;
  char mat[256];
  std::snprintf(mat, sizeof mat,
                "{\"density\": %g, \"youngs_modulus\": %g, \"poisson\": %g, \"thickness\": %g, "
                "\"bending_stiffness\": %g, \"damping\": %g}",
                m.density, m.youngs_modulus, m.poisson, m.thickness, m.bending_rigidity(),
                m.damping);
  g.material = mat;
  g.solver = solver_settings_json(scene.file.solver, scene.file.settings);
  writer.put_garment(g);
  // The artist's mesh and its map, for a garment made from a file (a procedural one reads back as
  // its own simulation mesh).
  if (scene.garment.artist.vertex_count() > 0) writer.put_artist_mesh(scene.garment.artist);
  db::set_meta_text(writer, db::meta::kUnits,
                    "metres, seconds; cloth in character space (docs/SECONDARY_GRAPH.md)");
  db::set_meta_text(writer, db::meta::kScene, scene.file.text);
  db::set_meta_text(writer, db::meta::kScenePath, scene.file.path.string());
  db::set_meta_text(writer, db::meta::kSceneHash, scene_hash);
  tx.commit();
}

db::RunSettings make_run_settings(const CharacterScene& scene, const ExploreOptions& options,
                                  const db::CodecSettings& codec) {
  db::RunSettings run;
  run.epsilon = options.epsilon;
  run.solver = scene.file.solver;
  run.settings = scene.file.settings;
  run.codec = codec;
  run.cpu_hours = options.cpu_hours;
  run.max_frames = options.max_frames;
  run.threads = options.threads;
  run.batch = options.batch;
  run.auto_solver = options.auto_solver;
  run.resim_clip = options.resim_clip;
  run.subspace_modes = options.subspace_modes;
  run.subspace_body_frame = options.subspace_body_frame;
  db::validate_run_settings(run, "run settings");
  return run;
}

ExploreReport explore(const CharacterScene& scene, const ExploreGraph& graph, db::Writer& writer,
                      const ExploreOptions& options, const BatchRunner& given_runner) {
  const double explore_start = process_cpu_seconds();
  int batches = 0;
  const db::RunSettings run = make_run_settings(scene, options, writer.codec());
  check_codec_schedule_options(options);
  const BatchRunner runner =
      given_runner ? given_runner : openmp_runner(scene, graph, options.threads);
  const uint32_t vertex_count = static_cast<uint32_t>(scene.model.vertex_count());
  ExploreReport report;
  // Everything the file holds is read before anything is written, so that a read failure ends the
  // run with the file as it was. Through the writer's connection, so an edit that explores from a
  // state it has just added (clip resim) sees it.
  db::Reader reader;
  db::Error err;
  if (reader.open_borrowed(writer.handle(), writer.path(), &err) != db::Status::Ok)
    throw std::runtime_error(writer.path() + ": " + std::string(err.message));
  SecondaryGraph sg =
      load_secondary_graph(reader, writer.path(), graph, vertex_count, options.state_cache_bytes,
                           &report.frames, &report.worst_blend_error);
  report.resumed = !sg.states.empty();
  report.cpu_seconds_before = earlier_cpu_seconds(reader, writer.path());
  CodecSchedule bases = load_codec_schedule(reader, writer.path(), options, vertex_count);
  const int64_t run_id = writer.begin_run(db::run_settings_json(run));
  if (sg.states.empty()) add_start_state(scene, graph, writer, run_id, sg);

  FailedDeadEnds failed;
  const ProgressBar progress(options);
  std::vector<Job> queue = dead_ends(sg, graph, options.min_state_id);
  add_curve_point(report, curve_point(sg, graph, queue, report));
  while (true) {
    // Kim et al.: the dead ends whose unresolved error is largest (this project: times the edge's
    // reach, and a batch of fixed size, so the result does not depend on the thread count).
    const std::vector<Job> batch = choose_batch(sg, failed, queue, options.batch);
    const double spent_before = report.budget_cpu_seconds;
    const bool spent = budget_spent(options, report, explore_start);
    if (batches > 0)  // the CPU from the last check to this one: that batch's
      report.largest_batch_cpu_seconds =
          std::max(report.largest_batch_cpu_seconds, report.budget_cpu_seconds - spent_before);
    if (batch.empty() || spent) break;
    ++batches;
    // Kim et al.: simulate each along its edge from its state (this project: steered ends).
    std::vector<JobResult> results(batch.size());
    runner(job_inputs(scene, graph, sg, batch, options, writer.codec(), bases.basis, bases.body),
           results);
    // Kim et al.'s step: link each end to the nearest state within epsilon, or make a new state.
    integrate_batch(sg, writer, graph, batch, results, run_id, options, failed, report);
    // This project's: codec version 2 bases built from the clips stored so far.
    maybe_build_basis(bases, reader, writer, options, vertex_count, report);
    queue = dead_ends(sg, graph, options.min_state_id);
    const Forecast forecast = add_curve_point(report, curve_point(sg, graph, queue, report));
    progress.update(report, forecast, sg.done.size(), queue.size());
  }
  progress.end();

  close_run(sg, graph, writer, reader, bases, options, run_id, queue.size(), report);
  report.states = static_cast<int>(sg.states.size());
  report.clips = static_cast<int>(sg.done.size());
  report.dead_ends = static_cast<int>(queue.size());
  report.edges = report.clips;
  report.worst_error = report.curve.back().worst_error;
  report.weighted_worst_error = report.curve.back().weighted_worst_error;
  report.linked_fraction = report.curve.back().linked_fraction;
  report.converged = queue.empty();
  report.bytes_per_state = bytes_per_state(sg);
  report.state_cache = sg.exact->stats();
  report.exact_evaluations = sg.exact_evaluations;
  return report;
}

}  // namespace clothdb
