#include "bench/character_bench.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <limits>
#include <map>
#include <memory>
#include <sstream>
#include <stdexcept>

#include "bench/strain_study.hpp"
#include "cloth/self_intersection.hpp"
#include "report/stats.hpp"

namespace clothdb {

CapsuleSpeed fastest_capsule(const CharacterScene& scene, const MotionClip& clip, int frames) {
  CapsuleSpeed best;
  frames = std::min(frames, clip.frame_count);
  for (int f = 1; f < frames; ++f) {
    const auto caps =
        body_capsules(scene.body, scene.skeleton, clip_pose(clip, f - 1), clip_pose(clip, f));
    for (const auto& c : caps) {
      const double speed = std::max((c.a - c.a_start).norm(), (c.b - c.b_start).norm()) * clip.rate;
      if (speed > best.speed)
        best = {speed, c.radius, f, scene.skeleton.names[static_cast<size_t>(c.bone)]};
    }
  }
  return best;
}

namespace {

// Sub-steps for one run: see CharacterBenchOptions::substeps.
int substeps_for(SolverKind kind, int requested, const CharacterScene& scene, double dt) {
  if (kind == SolverKind::MassSpring) {
    const int stable = static_cast<int>(std::ceil(dt / mass_spring_critical_dt(scene.model)));
    return std::max(requested, stable);
  }
  if (requested > 0) return requested;
  if (kind == SolverKind::Newton) return 1;
  return scene.file.settings.substeps;
}

// Fills the row's worst-edge fields for edge `edge` at frame f (see CharacterBenchRow).
void locate_edge(const CharacterScene& scene, const MotionClip& clip, int f,
                 const Eigen::Matrix3Xd& x, const std::array<int, 2>& edge,
                 CharacterBenchRow& row) {
  const Eigen::Matrix3Xd& rest = scene.model.mesh.rest;
  const double top = rest.row(1).maxCoeff(), bottom = rest.row(1).minCoeff();
  const double mid_y = 0.5 * (rest(1, edge[0]) + rest(1, edge[1]));
  row.worst_edge_depth = top > bottom ? (top - mid_y) / (top - bottom) : 0.0;
  const auto caps =
      body_capsules(scene.body, scene.skeleton, clip_pose(clip, f - 1), clip_pose(clip, f));
  row.worst_edge_gap = std::numeric_limits<double>::infinity();
  row.worst_edge_bone.clear();
  for (int end : edge) {
    const Vec3 p = x.col(end);
    for (const auto& c : caps) {
      const Vec3 ab = c.b - c.a;
      const double t = std::clamp((p - c.a).dot(ab) / std::max(ab.squaredNorm(), 1e-30), 0.0, 1.0);
      const double gap = (p - (c.a + t * ab)).norm() - c.radius;
      if (gap < row.worst_edge_gap) {
        row.worst_edge_gap = gap;
        row.worst_edge_bone = c.bone >= 0 ? scene.skeleton.names[static_cast<size_t>(c.bone)] : "?";
      }
    }
  }
}

// One run of the clip with one setting, a frame at a time, so that several runs can take their
// frames in turn (run_interleaved).
struct BenchRun {
  CharacterScene& scene;
  const MotionClip& clip;
  ColliderMotion motion;
  std::unique_ptr<Solver> solver;
  CharacterBenchRow row;
  ClothState state;
  std::vector<Eigen::Matrix3Xd>* positions = nullptr;
  double wall = 0, cpu = 0;
  long iterations = 0, factorizations = 0, limit_passes = 0;
  std::vector<double> strains;  // every edge at every frame, for the percentile
  int substeps = 0;

  BenchRun(CharacterScene& s, const MotionClip& c, SolverKind kind, const SolverSettings& settings,
           ColliderMotion m, std::vector<Eigen::Matrix3Xd>* p)
      : scene(s), clip(c), motion(m), positions(p), substeps(settings.substeps) {
    scene.env.collider_motion = motion;
    solver = make_scene_solver(scene, kind, settings);
    row.solver = solver->describe();
    row.threads = settings.threads;
    row.collider_motion = motion;
    row.self_collision_mm = settings.self_collision_thickness_mm;
    row.vertices = scene.model.vertex_count();
    row.capsules = static_cast<int>(scene.body.capsules.size());
    state = settle_garment(scene, *solver, clip_pose(clip, 0));
    if (positions != nullptr) positions->assign(1, state.x);
  }

  // Frame f (from f - 1); only the simulation's own call is timed, not the metrics.
  void step(int f) {
    if (!row.stable) return;  // stopped at the frame that went unstable
    scene.env.collider_motion = motion;
    const Eigen::Matrix3Xd x0 = state.x;
    const std::clock_t c0 = std::clock();
    const PoseRun run = simulate_poses(scene, *solver, {clip_pose(clip, f - 1), clip_pose(clip, f)},
                                       clip.rate, state);
    cpu += static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC;
    if (!run.stable) {
      row.stable = false;
      row.message = "frame " + std::to_string(f) + ": " + run.message;
      return;
    }
    wall += run.seconds;
    ++row.frames;
    if (positions != nullptr) positions->push_back(state.x);
    row.step_halvings += run.step_halvings;
    const FrameMetrics& m = run.metrics.front();
    iterations += m.iterations;
    factorizations += m.factorizations;
    limit_passes += m.strain_limit_passes;
    row.strain_limit_capped += m.strain_limit_capped;
    row.max_strain = std::max(row.max_strain, m.max_strain);
    const EdgeStrainMax frame_worst = append_edge_strains(scene.model, state.x, strains);
    if (frame_worst.strain >= row.max_strain && frame_worst.strain > 0.0) {
      row.worst_frame = f;
      locate_edge(scene, clip, f, state.x, scene.model.mesh.edges[frame_worst.edge], row);
    }
    row.max_penetration = std::max(row.max_penetration, m.max_penetration);
    const int crossings = count_self_intersections(scene.model.mesh, state.x);
    if (crossings > 0) ++row.self_intersection_frames;
    if (crossings > row.self_intersections) {
      row.self_intersections = crossings;
      row.self_intersection_frame = f;
    }
    row.mean_penetration = std::max(row.mean_penetration, m.mean_penetration);
    const auto caps =
        body_capsules(scene.body, scene.skeleton, clip_pose(clip, f - 1), clip_pose(clip, f));
    for (Eigen::Index i = 0; i < state.x.cols(); ++i) {
      if (scene.model.inv_mass[i] <= 0.0) continue;
      double deepest = 0.0;
      for (const auto& c : caps)
        deepest = std::max(deepest, path_depth_fraction(x0.col(i), state.x.col(i), c));
      row.deepest_path = std::max(row.deepest_path, deepest);
      if (deepest > 0.5) ++row.tunnelled;
    }
  }

  CharacterBenchRow finish() {
    if (!strains.empty()) row.p99_strain = report::percentile(std::move(strains), 0.99);
    if (row.frames > 0) {
      row.ms_per_frame = 1e3 * wall / row.frames;
      row.cpu_ms_per_frame = 1e3 * cpu / row.frames;
      row.iterations_per_frame = static_cast<double>(iterations) / row.frames;
      row.factorizations_per_frame = static_cast<double>(factorizations) / row.frames;
      row.strain_limit_passes_per_substep =
          static_cast<double>(limit_passes) / (static_cast<double>(row.frames) * substeps);
    }
    return row;
  }
};

// Runs the settings side by side, frame by frame in turn (each settled first), so that a change
// in the machine's speed during the runs (another process, a slowed core: single runs of the same
// binary on the 12k skirt read 1.41x and 1.58x minutes apart, docs/notebook/self_collision.md,
// "Seventeenth round") falls on all of them alike and their CPU per frame compares.
std::vector<CharacterBenchRow> run_interleaved(
    CharacterScene& scene, const MotionClip& clip, SolverKind kind,
    const std::vector<SolverSettings>& settings, ColliderMotion motion, int frames,
    const std::function<void(const std::string&)>& progress,
    std::vector<std::vector<Eigen::Matrix3Xd>>* positions = nullptr) {
  if (positions != nullptr) positions->assign(settings.size(), {});
  std::vector<std::unique_ptr<BenchRun>> runs;
  for (std::size_t k = 0; k < settings.size(); ++k)
    runs.push_back(std::make_unique<BenchRun>(scene, clip, kind, settings[k], motion,
                                              positions ? &(*positions)[k] : nullptr));
  const auto start = std::chrono::steady_clock::now();
  for (int f = 1; f < frames; ++f) {
    for (auto& run : runs) run->step(f);
    if (progress && (f % 10 == 0 || f + 1 == frames)) {
      const double elapsed =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      std::ostringstream line;
      line << "  " << runs.front()->row.solver;
      if (runs.size() > 1) line << " and " << runs.size() - 1 << " more, frame by frame in turn,";
      line << " threads=" << runs.front()->row.threads << ' ' << collider_motion_name(motion)
           << ": frame " << f + 1 << '/' << frames << ", ETA "
           << std::lround(elapsed / f * (frames - 1 - f)) << " s";
      progress(line.str());
    }
  }
  std::vector<CharacterBenchRow> rows;
  for (auto& run : runs) rows.push_back(run->finish());
  return rows;
}

CharacterBenchRow run_one(CharacterScene& scene, const MotionClip& clip, SolverKind kind,
                          const SolverSettings& settings, ColliderMotion motion, int frames,
                          const std::function<void(const std::string&)>& progress,
                          std::vector<Eigen::Matrix3Xd>* positions = nullptr) {
  std::vector<std::vector<Eigen::Matrix3Xd>> out;
  CharacterBenchRow row = run_interleaved(scene, clip, kind, {settings}, motion, frames, progress,
                                          positions ? &out : nullptr)
                              .front();
  if (positions != nullptr) *positions = std::move(out.front());
  return row;
}

std::string fixed(double v, int digits) {
  std::ostringstream out;
  out.setf(std::ios::fixed);
  out.precision(digits);
  out << v;
  return out.str();
}

std::string worst_edge_text(const CharacterBenchRow& r) {
  if (r.worst_frame < 0) return "-";
  return "frame " + std::to_string(r.worst_frame) + ", " + fixed(100 * r.worst_edge_depth, 0) +
         " % down, " + fixed(1e3 * r.worst_edge_gap, 1) + " mm from " + r.worst_edge_bone;
}

std::string cheapest_text(const std::vector<double>& targets) {
  std::string out;
  for (double t : targets) out += (out.empty() ? "**" : ", **") + fixed(100 * t, 2) + " %**";
  return out.empty() ? "-" : out;
}

}  // namespace

std::vector<CharacterBenchRow> run_character_bench(
    const SceneFile& file, const CharacterBenchOptions& options,
    const std::function<void(const std::string&)>& progress) {
  std::vector<CharacterBenchRow> rows;
  std::vector<SolverKind> solvers = options.solvers;
  if (solvers.empty()) solvers.push_back(file.solver);
  for (SolverKind kind : solvers) {
    SceneFile f = file;
    f.solver = kind;
    CharacterScene scene = build_character_scene(f);
    const MotionClip& clip =
        scene.clips[options.clip.empty() ? 0 : static_cast<size_t>(scene.clip_index(options.clip))];
    const int frames = std::min(options.frames, clip.frame_count);
    // The reference runs by their solver's description, so that runs sharing a reference (a
    // coarse-driven run and the garment's own at the same setting: scene_reference drops
    // coarse_vertices) are compared with the same one, run once.
    std::map<std::string, std::pair<CharacterBenchRow, std::vector<Eigen::Matrix3Xd>>> references;
    for (int requested : options.substeps) {
      SolverSettings settings = file.settings;
      settings.substeps = substeps_for(kind, requested, scene, 1.0 / clip.rate);
      if (options.iterations > 0) settings.iterations = options.iterations;
      if (options.stretch_iterations >= 0) settings.stretch_iterations = options.stretch_iterations;
      if (options.strain_limit >= 0.0) settings.strain_limit = options.strain_limit;
      if (options.strain_limit_iterations > 0)
        settings.strain_limit_iterations = options.strain_limit_iterations;
      if (options.contact_rounds >= 0)
        settings.strain_limit_contact_rounds = options.contact_rounds;
      if (options.strain_limit_relaxation > 0.0)
        settings.strain_limit_relaxation = options.strain_limit_relaxation;
      if (options.chebyshev_rho >= 0.0) settings.chebyshev_rho = options.chebyshev_rho;
      if (options.tethers >= 0) settings.tethers = options.tethers != 0;
      std::vector<int> coarse_counts = options.coarse_vertices;
      if (coarse_counts.empty()) coarse_counts.push_back(file.settings.coarse_vertices);
      std::vector<double> self_mm = options.self_collision_mm;
      if (self_mm.empty()) {
        self_mm.push_back(file.settings.self_collision_thickness_mm);
        if (self_mm.front() > 0.0) self_mm.push_back(0.0);
      }
      for (int threads : options.threads) {
        settings.threads = threads;
        std::vector<ColliderMotion> motions = options.collider_motions;
        if (motions.empty()) motions.push_back(file.collider_motion);
        for (ColliderMotion motion : motions) {
          // Every self-collision thickness and coarse count at this setting, frame by frame in
          // turn (run_interleaved): the "CPU vs off" column compares runs made in the same
          // minutes.
          std::vector<SolverSettings> side_by_side;
          for (double mm : self_mm)
            for (int coarse : coarse_counts) {
              settings.self_collision_thickness_mm = mm;
              settings.coarse_vertices = coarse;
              side_by_side.push_back(settings);
            }
          std::vector<std::vector<Eigen::Matrix3Xd>> positions;
          std::vector<CharacterBenchRow> made =
              run_interleaved(scene, clip, kind, side_by_side, motion, frames, progress,
                              options.reference ? &positions : nullptr);
          for (std::size_t k = 0; k < made.size(); ++k) {
            settings = side_by_side[k];
            const std::vector<Eigen::Matrix3Xd> run_positions =
                options.reference ? std::move(positions[k]) : std::vector<Eigen::Matrix3Xd>{};
            rows.push_back(std::move(made[k]));
            CharacterBenchRow& r = rows.back();
            if (options.reference && r.stable) {
              const SolverCandidate ref = scene_reference(kind, settings);
              const std::string key = make_scene_solver(scene, kind, ref.settings)->describe() +
                                      " " + collider_motion_name(motion);
              if (references.count(key) == 0) {
                std::vector<Eigen::Matrix3Xd> ref_positions;
                CharacterBenchRow rr = run_one(scene, clip, kind, ref.settings, motion, frames,
                                               progress, &ref_positions);
                references[key] = {std::move(rr), std::move(ref_positions)};
              }
              const CharacterBenchRow& rr = references[key].first;
              const std::vector<Eigen::Matrix3Xd>& ref_positions = references[key].second;
              r.reference = rr.solver;
              if (rr.stable && rr.frames > 0) {
                const FrameErrors e = compare_frames(run_positions, ref_positions, 1);
                r.reference_rms_mm = 1e3 * e.rms;
                r.reference_max_mm = 1e3 * e.max;
                r.reference_cpu_ms_per_frame = rr.cpu_ms_per_frame;
                for (std::size_t window : {5, 15, 30}) {
                  if (run_positions.size() <= window) continue;
                  const std::vector<Eigen::Matrix3Xd> a(run_positions.begin(),
                                                        run_positions.begin() + window + 1);
                  const FrameErrors w = compare_frames(a, ref_positions, 1);
                  if (progress)
                    progress("  frames 1-" + std::to_string(window) + ": " + fixed(1e3 * w.rms, 2) +
                             " / " + fixed(1e3 * w.max, 2) + " mm RMS / max from the reference");
                }
              } else {
                r.reference += " (unstable: " + rr.message + ")";
              }
            }
            if (progress)
              progress(r.solver + " threads=" + std::to_string(threads) + " " +
                       collider_motion_name(motion) + ": " + fixed(r.ms_per_frame, 2) +
                       " ms/frame (CPU " + fixed(r.cpu_ms_per_frame, 2) + "), strain p99 " +
                       fixed(100 * r.p99_strain, 2) + " % max " + fixed(100 * r.max_strain, 2) +
                       " %, max penetration " + fixed(1e3 * r.max_penetration, 2) +
                       " mm, tunnelled " + std::to_string(r.tunnelled) + ", worst edge " +
                       worst_edge_text(r) + ", self-intersections max " +
                       std::to_string(r.self_intersections) + " in " +
                       std::to_string(r.self_intersection_frames) + " frames" +
                       (settings.strain_limit > 0.0
                            ? ", strain-limit passes per sub-step " +
                                  fixed(r.strain_limit_passes_per_substep, 2) + " (capped " +
                                  std::to_string(r.strain_limit_capped) + ")"
                            : std::string()) +
                       (std::isfinite(r.reference_rms_mm)
                            ? ", " + fixed(r.reference_rms_mm, 2) + " / " +
                                  fixed(r.reference_max_mm, 2) + " mm RMS / max from 8x sub-steps"
                            : std::string()) +
                       (r.stable ? "" : ", UNSTABLE: " + r.message));
          }
        }
      }
    }
  }
  for (double target : options.strain_targets) {
    CharacterBenchRow* best = nullptr;
    for (CharacterBenchRow& row : rows)
      if (row.stable && meets_strain_target(row.max_strain, target) &&
          (best == nullptr || row.cpu_ms_per_frame < best->cpu_ms_per_frame))
        best = &row;
    if (best != nullptr) best->cheapest_for.push_back(target);
  }
  return rows;
}

std::vector<SettleRow> run_settle_bench(const SceneFile& file, const std::string& clip_name,
                                        int every,
                                        const std::function<void(const std::string&)>& progress) {
  if (every < 1) throw std::invalid_argument("settle bench: every must be at least 1");
  const CharacterScene scene = build_character_scene(file);
  const MotionClip& clip =
      scene.clips[clip_name.empty() ? 0 : static_cast<size_t>(scene.clip_index(clip_name))];
  std::vector<SettleRow> rows;
  for (int f = 0; f < clip.frame_count; f += every) {
    auto solver = make_scene_solver(scene, file.solver, file.settings);
    const auto pose = clip_pose(clip, f);
    const ClothState state = settle_garment(scene, *solver, pose);
    Environment env = scene.env;
    env.capsules = body_capsules(scene.body, scene.skeleton, pose, pose);
    rows.push_back({f, max_edge_strain(scene.model, state.x),
                    max_penetration(state.x, scene.model.inv_mass, env)});
    if (progress)
      progress("  settled from frame " + std::to_string(f) + ": max strain " +
               fixed(100 * rows.back().max_strain, 2) + " %");
  }
  return rows;
}

std::string character_rows_markdown(const std::vector<CharacterBenchRow>& rows) {
  std::ostringstream out;
  out << "| solver | threads | colliders | verts | capsules | frames | ms/frame | CPU ms/frame | "
         "p99 strain | max strain "
         "| max pen. mm | mean pen. mm | tunnelled | deepest path | it./frame | fact./frame "
         "| halvings | worst edge | self-col. mm | CPU vs off | crossings max (frame) | frames "
         "crossing | RMS / max mm from 8x sub-steps | ref. CPU ms/frame | cheapest within | "
         "stable |\n"
         "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
         "---|---|---|---|\n";
  for (const auto& r : rows) {
    // The cost of self-collision: CPU per frame over that of the same run without it (same
    // sub-steps, threads and colliders), when the table has one.
    std::string ratio = "-";
    for (const auto& off : rows)
      if (r.self_collision_mm > 0.0 && off.self_collision_mm == 0.0 && off.threads == r.threads &&
          off.collider_motion == r.collider_motion && off.frames == r.frames &&
          off.cpu_ms_per_frame > 0.0 &&
          r.solver.rfind(off.solver, 0) == 0)  // describe() appends self_collision=...
        ratio = fixed(r.cpu_ms_per_frame / off.cpu_ms_per_frame, 2) + "x";
    out << "| " << r.solver << " | " << r.threads << " | "
        << collider_motion_name(r.collider_motion) << " | " << r.vertices << " | " << r.capsules
        << " | " << r.frames << " | " << fixed(r.ms_per_frame, 2) << " | "
        << fixed(r.cpu_ms_per_frame, 2) << " | " << fixed(100 * r.p99_strain, 2) << "% | "
        << fixed(100 * r.max_strain, 2) << "% | " << fixed(1e3 * r.max_penetration, 2) << " | "
        << fixed(1e3 * r.mean_penetration, 2) << " | " << r.tunnelled << " | "
        << fixed(r.deepest_path, 2) << " | " << fixed(r.iterations_per_frame, 2) << " | "
        << fixed(r.factorizations_per_frame, 2) << " | " << r.step_halvings << " | "
        << worst_edge_text(r) << " | " << fixed(r.self_collision_mm, 1) << " | " << ratio << " | "
        << r.self_intersections << " ("
        << (r.self_intersection_frame < 0 ? std::string("-")
                                          : std::to_string(r.self_intersection_frame))
        << ") | " << r.self_intersection_frames << " | "
        << (std::isfinite(r.reference_rms_mm)
                ? fixed(r.reference_rms_mm, 2) + " / " + fixed(r.reference_max_mm, 2)
                : std::string("-"))
        << " | "
        << (std::isfinite(r.reference_cpu_ms_per_frame) ? fixed(r.reference_cpu_ms_per_frame, 2)
                                                        : std::string("-"))
        << " | " << cheapest_text(r.cheapest_for) << " | "
        << (r.stable ? "yes" : "no: " + r.message) << " |\n";
  }
  return out.str();
}

}  // namespace clothdb
