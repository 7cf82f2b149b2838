// `clothdb simulate SCENE --clip NAME --out DIR`: one clip of a character scene, written for
// Blender (OBJ + PC2 point cache, cloth and body), with per-frame metrics and PNG previews.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "character_scene/character_scene.hpp"
#include "cli_util.hpp"
#include "cloth/self_intersection.hpp"
#include "commands.hpp"
#include "exchange/body_mesh.hpp"
#include "exchange/point_cache.hpp"
#include "render/preview.hpp"
#include "report/output.hpp"

namespace clothdb::cli {

namespace {

void append_floats(const Eigen::Matrix3Xd& x, std::vector<float>& out) {
  for (Eigen::Index i = 0; i < x.cols(); ++i)
    for (int k = 0; k < 3; ++k) out.push_back(static_cast<float>(x(k, i)));
}

}  // namespace

void register_simulate(CLI::App& app) {
  struct Args {
    std::string scene, clip, out, solver, linear_solver;
    int frames = 0, preview_every = 30, substeps = 0, iterations = 0, threads = 0, width = 480,
        height = 360;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "simulate",
      "Simulates one clip of a scene and writes DIR/garment.obj + DIR/cloth.pc2 on the artist's "
      "mesh (its vertex order, faces, UVs and normals; Blender: import the OBJ, add a Mesh Cache "
      "modifier with the PC2), DIR/body.obj + DIR/body.pc2 (the colliding "
      "capsules), DIR/metrics.csv, DIR/summary.json and PNG previews in DIR/previews/.");
  cmd->add_option("SCENE", args->scene, "Scene file (JSON), e.g. motions/skirt_walk.json")
      ->required();
  cmd->add_option("--clip", args->clip, "Clip name (default: the scene's first clip)");
  cmd->add_option("--out", args->out, "Output directory")->required();
  cmd->add_option("--frames", args->frames, "Simulate only the first N frames (0: all)")
      ->capture_default_str()
      ->check(number_in(0, 1e9));
  cmd->add_option("--preview-every", args->preview_every, "A PNG preview every N frames (0: none)")
      ->capture_default_str()
      ->check(number_in(0, 1e9));
  cmd->add_option("--solver", args->solver,
                  "Override the scene's solver: mass-spring | pbd | xpbd | newton");
  cmd->add_option("--substeps", args->substeps, "Override the scene's sub-steps")
      ->check(number_in(0, kMaxSubsteps));
  cmd->add_option("--iterations", args->iterations, "Override the scene's iterations")
      ->check(number_in(0, kMaxIterations));
  cmd->add_option(
      "--linear-solver", args->linear_solver,
      "Override Newton's linear solver: ldlt | cholmod | cholmod-supernodal | pcg | pcg-ic");
  cmd->add_option("--threads", args->threads, "Override the scene's OpenMP threads")
      ->check(number_in(0, max_solver_threads()));
  cmd->add_option("--width", args->width, "Preview width")
      ->capture_default_str()
      ->check(number_in(16, 8192));
  cmd->add_option("--height", args->height, "Preview height")
      ->capture_default_str()
      ->check(number_in(16, 8192));
  cmd->callback([args] {
    SceneFile file = load_scene_file(args->scene);
    if (!args->solver.empty()) file.solver = parse_solver_kind(args->solver);
    if (args->substeps > 0) file.settings.substeps = args->substeps;
    if (args->iterations > 0) file.settings.iterations = args->iterations;
    if (args->threads > 0) file.settings.threads = args->threads;
    if (!args->linear_solver.empty())
      file.settings.linear_solver = parse_linear_solver_kind(args->linear_solver);
    const CharacterScene scene = build_character_scene(file);
    const MotionClip& clip = scene.clips[args->clip.empty() ? 0 : scene.clip_index(args->clip)];
    auto solver = make_scene_solver(scene, file.solver, file.settings);
    std::fprintf(
        stderr,
        "%s: %s, %d cloth vertices, %zu colliding capsules, clip '%s' (%d frames at %g Hz), %s\n",
        file.path.c_str(), scene.garment.name.c_str(), scene.model.vertex_count(),
        scene.body.capsules.size(), clip.name.c_str(), clip.frame_count, clip.rate,
        solver->describe().c_str());
    for (const std::string& line : placement_lines(scene.placement))
      std::fprintf(stderr, "  %s\n", line.c_str());

    // Before any work: a bad --out is refused now, and nothing is left half-written in it.
    Staging stage(args->out, "simulate");
    ClothState state = settle_garment(scene, *solver, clip_pose(clip, 0));
    const int frames =
        args->frames > 0 ? std::min(args->frames, clip.frame_count) : clip.frame_count;
    std::vector<float> cloth, body;
    append_floats(state.x, cloth);
    auto capsules_at = [&](int f) {
      return body_capsules(scene.body, scene.skeleton, clip_pose(clip, std::max(f - 1, 0)),
                           clip_pose(clip, f));
    };
    append_capsule_mesh_positions(capsules_at(0), body);
    Body whole_skeleton;  // previews: every bone, thinner than the colliders
    whole_skeleton.capsules = all_bone_capsules(scene.skeleton);
    for (BoneCapsule& c : whole_skeleton.capsules) c.radius *= 0.6;
    std::ostringstream csv;
    csv << "frame,max_strain,max_penetration_mm,mean_penetration_mm,kinetic_energy_J,step_"
           "halvings,self_intersections\n";
    // Edge-triangle crossings (cloth/self_intersection.hpp): per frame, the worst, and how many
    // frames have any (docs/guide/self_collision.md).
    int worst_crossings = count_self_intersections(scene.model.mesh, state.x);
    int worst_crossing_frame = 0, crossing_frames = worst_crossings > 0 ? 1 : 0;
    FrameMetrics worst;
    const auto start = std::chrono::steady_clock::now();
    double solver_seconds = 0;
    std::vector<std::pair<int, Eigen::Matrix3Xd>> preview_frames;
    if (args->preview_every > 0) preview_frames.push_back({0, state.x});
    for (int f = 1; f < frames; ++f) {
      const PoseRun run = simulate_poses(
          scene, *solver, {clip_pose(clip, f - 1), clip_pose(clip, f)}, clip.rate, state);
      if (!run.stable)
        throw std::runtime_error(clip.name + ": frame " + std::to_string(f) + ": " + run.message);
      solver_seconds += run.seconds;
      const FrameMetrics& m = run.metrics.front();
      csv << f << ',' << m.max_strain << ',' << 1e3 * m.max_penetration << ','
          << 1e3 * m.mean_penetration << ',' << m.kinetic_energy << ',' << m.step_halvings;
      const int crossings = count_self_intersections(scene.model.mesh, state.x);
      csv << ',' << crossings << '\n';
      if (crossings > 0) ++crossing_frames;
      if (crossings > worst_crossings) worst_crossings = crossings, worst_crossing_frame = f;
      worst.max_strain = std::max(worst.max_strain, m.max_strain);
      worst.max_penetration = std::max(worst.max_penetration, m.max_penetration);
      worst.mean_penetration = std::max(worst.mean_penetration, m.mean_penetration);
      worst.step_halvings += m.step_halvings;
      append_floats(state.x, cloth);
      append_capsule_mesh_positions(capsules_at(f), body);
      if (args->preview_every > 0 && f % args->preview_every == 0)
        preview_frames.push_back({f, state.x});
      const double elapsed =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      std::fprintf(stderr,
                   "\r  frame %d/%d  %.1f ms/frame  max strain %.2f%%  max penetration %.2f mm  "
                   "ETA %.0f s   ",
                   f + 1, frames, 1e3 * solver_seconds / f, 100 * m.max_strain,
                   1e3 * m.max_penetration, elapsed / f * (frames - 1 - f));
    }
    std::fprintf(stderr, "\n");

    PointCache pc;
    pc.vertex_count = scene.model.vertex_count();
    pc.frame_count = frames;
    pc.positions = std::move(cloth);
    // The artist's topology (docs/guide/mesh_garments.md): their vertex order, faces, UVs.
    const db::ArtistMesh artist = artist_mesh_of(scene.garment);
    const PointCache artist_pc = artist_order(artist, pc);
    write_artist_obj(stage.path("garment.obj"), scene.garment.name, artist_pc.positions.data(),
                     artist);
    write_pc2(stage.path("cloth.pc2"), artist_pc);
    PointCache bc;
    bc.vertex_count = static_cast<int>(body.size() / 3 / frames);
    bc.frame_count = frames;
    bc.positions = std::move(body);
    write_obj(stage.path("body.obj"), "body", bc.positions.data(), bc.vertex_count,
              capsule_mesh_triangles(static_cast<int>(scene.body.capsules.size())));
    write_pc2(stage.path("body.pc2"), bc);
    write_file_atomic(stage.path("metrics.csv"), csv.str());
    std::vector<std::string> written = {"garment.obj", "cloth.pc2",   "body.obj",
                                        "body.pc2",    "metrics.csv", "summary.json"};
    if (!preview_frames.empty()) {
      make_directories(stage.path("previews"));
      written.push_back("previews");
      Eigen::Matrix3Xd all(3, 0);
      for (const auto& [f, x] : preview_frames) {
        all.conservativeResize(3, all.cols() + x.cols());
        all.rightCols(x.cols()) = x;
        // The whole figure in view, not only the cloth: previews show a person.
        for (const CapsuleCollider& c : body_capsules(whole_skeleton, scene.skeleton,
                                                      clip_pose(clip, f), clip_pose(clip, f))) {
          all.conservativeResize(3, all.cols() + 2);
          all.col(all.cols() - 2) = c.a + Vec3(0, c.radius, 0);
          all.col(all.cols() - 1) = c.b + Vec3(0, c.radius, 0);
        }
      }
      PreviewCamera cam = frame_points(all, 1.25);
      for (const auto& [f, x] : preview_frames) {
        PreviewScene ps;
        ps.cloth = &x;
        ps.triangles = &scene.model.mesh.triangles;
        ps.capsules = capsules_at(f);
        ps.skeleton =
            body_capsules(whole_skeleton, scene.skeleton, clip_pose(clip, f), clip_pose(clip, f));
        ps.floor_height = 0.0;
        char name[64];
        std::snprintf(name, sizeof name, "/previews/frame_%04d.png", f);
        write_png(stage.dir.string() + name, render_preview(ps, cam, args->width, args->height),
                  args->width, args->height);
      }
    }
    nlohmann::json summary = {{"scene", file.path.string()},
                              {"clip", clip.name},
                              {"solver", solver->describe()},
                              {"vertices", scene.model.vertex_count()},
                              {"capsules", scene.body.capsules.size()},
                              {"frames", frames},
                              {"rate", clip.rate},
                              {"ms_per_frame", 1e3 * solver_seconds / std::max(frames - 1, 1)},
                              {"max_strain", worst.max_strain},
                              {"max_penetration_mm", 1e3 * worst.max_penetration},
                              {"max_mean_penetration_mm", 1e3 * worst.mean_penetration},
                              {"thickness_mm", 1e3 * file.material.thickness},
                              {"step_halvings", worst.step_halvings},
                              {"self_intersections_max", worst_crossings},
                              {"self_intersections_worst_frame", worst_crossing_frame},
                              {"frames_with_self_intersections", crossing_frames}};
    write_file_atomic(stage.path("summary.json"), summary.dump(2) + "\n");
    stage.commit(written);
    std::printf(
        "%s\nwrote %s/{garment.obj,cloth.pc2,body.obj,body.pc2,metrics.csv,summary.json} and %zu "
        "previews\n",
        summary.dump(2).c_str(), args->out.c_str(), preview_frames.size());
  });
}

}  // namespace clothdb::cli
