// `clothdb bench character SCENE`: time per frame, strain, penetration and tunnelling of a
// character scene's clip for several solvers, sub-steps, thread counts and collider motions.
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <string>

#include "bench/character_bench.hpp"
#include "cli_util.hpp"
#include "commands.hpp"
#include "report/output.hpp"

namespace clothdb::cli {

namespace {

std::vector<int> int_list(const std::string& text, const std::string& option) {
  std::vector<int> out;
  for (double v : number_list(option, text, 0, 1e9, true)) out.push_back(static_cast<int>(v));
  return out;
}

std::string load_average() {
  std::ifstream in("/proc/loadavg");
  std::string one, five, fifteen;
  in >> one >> five >> fifteen;
  return one + " " + five + " " + fifteen;
}

}  // namespace

void register_bench_character(CLI::App& bench) {
  struct Args {
    std::string scene, solvers, substeps = "0", threads = "1", motions, self_collision, out,
                                strain_targets, coarse_vertices;
    int vertices = 0, settle_every = 0;
    CharacterBenchOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand("character",
                                       "Runs one clip of a character scene with each listed "
                                       "solver, sub-step count, thread count and "
                                       "collider motion, and prints a markdown table: ms per frame "
                                       "(wall and CPU), largest edge strain, "
                                       "largest and mean penetration into the body capsules, and "
                                       "tunnelling (vertex-frames whose path "
                                       "crossed more than half a capsule's radius into a moving "
                                       "limb). Also prints the fastest capsule "
                                       "speed in the clip, the CPU model and the load average.");
  cmd->add_option("SCENE", args->scene, "Scene file (JSON), e.g. motions/skirt_walk.json")
      ->required();
  cmd->add_option("--clip", args->options.clip, "Clip name (default: the scene's first clip)");
  cmd->add_option("--frames", args->options.frames, "Frames of the clip to simulate after settling")
      ->capture_default_str()
      ->check(number_in(2, 1000000));
  cmd->add_option("--vertices", args->vertices,
                  "Override the procedural garment's vertex count (skirt, cape)");
  cmd->add_option("--solvers", args->solvers, "Comma-separated solvers (default: the scene's)");
  cmd->add_option(
         "--substeps", args->substeps,
         "Comma-separated sub-step counts; 0: the solver's default (scene's for PBD/XPBD, 1 for "
         "Newton, the stability limit for mass-spring, which is never run below it)")
      ->capture_default_str();
  cmd->add_option("--iterations", args->options.iterations,
                  "Constraint iterations (PBD, XPBD); 0: the scene's")
      ->capture_default_str();
  cmd->add_option("--stretch-iterations", args->options.stretch_iterations,
                  "XPBD stretch sweeps per sub-step; 0: as --iterations; default: the scene's");
  cmd->add_option("--strain-limit", args->options.strain_limit,
                  "XPBD strain limit, e.g. 0.03 for 3 %; 0: off; default: the scene's");
  cmd->add_option("--strain-limit-iterations", args->options.strain_limit_iterations,
                  "XPBD strain-limit passes per sub-step; default: the scene's");
  cmd->add_option("--contact-rounds", args->options.contact_rounds,
                  "XPBD rounds of strain limit and frictionless collision after the collision "
                  "pass; 0: off; default: the scene's");
  cmd->add_option("--strain-limit-relaxation", args->options.strain_limit_relaxation,
                  "XPBD over-relaxation of the strain limit's passes in [1, 2), 1: off; default: "
                  "the scene's (docs/guide/resolution.md)")
      ->check(number_in(1.0, 1.99));
  cmd->add_option("--chebyshev-rho", args->options.chebyshev_rho,
                  "XPBD Chebyshev acceleration of the stretch sweeps (Wang 2015): spectral radius "
                  "estimate in [0, 1), 0: off; default: the scene's (docs/guide/resolution.md)")
      ->check(number_in(0.0, 0.999));
  cmd->add_option("--coarse-vertices", args->coarse_vertices,
                  "Comma-separated solver.coarse_vertices to run: 0, the garment solved itself; "
                  "N, the garment made with N vertices solved and driving it, e.g. 0,3000 "
                  "(docs/guide/resolution.md); default: the scene's");
  cmd->add_option("--tethers", args->options.tethers,
                  "XPBD long-range attachments to the pins: 1 on, 0 off; default: the scene's")
      ->check(CLI::Range(0, 1));
  cmd->add_option("--threads", args->threads, "Comma-separated OpenMP thread counts, e.g. 1,2")
      ->capture_default_str();
  cmd->add_option(
      "--collider-motion", args->motions,
      "Comma-separated: end-pose | interpolated | swept (see cloth/collision.hpp); default: "
      "the scene's colliders.motion");
  cmd->add_option("--self-collision", args->self_collision,
                  "Comma-separated XPBD self-collision thicknesses in mm, 0: off, e.g. 0,4; "
                  "default: the scene's, and when that is on also a run without it (the table's "
                  "'CPU vs off' column is its cost). The runs of one setting take their frames "
                  "in turn, so a change in the machine's speed falls on all of them alike");
  cmd->add_flag("--reference", args->options.reference,
                "Also run each setting at 8x the sub-steps (the converged run of the same model) "
                "over the same frames and report the RMS and largest vertex distance to it");
  cmd->add_option("--strain-targets", args->strain_targets,
                  "Comma-separated largest-strain targets in percent, e.g. 5,2.5: the cheapest run "
                  "(CPU per frame) whose largest strain meets each is marked");
  cmd->add_option("--settle-every", args->settle_every,
                  "Instead of the clip run: settle the garment from every N-th frame of the clip "
                  "and print each settled state's largest edge strain and penetration");
  cmd->add_option("--out", args->out, "Also write DIR/character.md");
  cmd->callback([args] {
    SceneFile file = load_scene_file(args->scene);
    CharacterBenchOptions options = args->options;
    for (const auto& s : split_list(args->solvers)) options.solvers.push_back(parse_solver_kind(s));
    options.substeps = int_list(args->substeps, "--substeps");
    options.threads = int_list(args->threads, "--threads");
    if (!args->coarse_vertices.empty())
      for (int v : int_list(args->coarse_vertices, "--coarse-vertices")) {
        if (v != 0 && v < 16)
          throw std::invalid_argument("--coarse-vertices: expected 0 or at least 16, got " +
                                      std::to_string(v));
        options.coarse_vertices.push_back(v);
      }
    for (int t : options.threads)
      if (t < 1) throw std::invalid_argument("--threads: expected thread counts >= 1");
    for (const auto& m : split_list(args->motions))
      options.collider_motions.push_back(parse_collider_motion(m));
    for (const auto& t : split_list(args->self_collision)) {
      std::size_t used = 0;
      double mm = -1.0;
      try {
        mm = std::stod(t, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used != t.size() || !(mm >= 0.0 && mm <= 50.0))
        throw std::invalid_argument(
            "--self-collision: expected thicknesses in mm in [0, 50], got '" + t + "'");
      options.self_collision_mm.push_back(mm);
    }
    if (!args->strain_targets.empty())
      for (double t : number_list("--strain-targets", args->strain_targets, 0.0, 100.0, false))
        options.strain_targets.push_back(t / 100.0);
    if (args->vertices > 0) {
      if (file.garment_kind == GarmentKind::Mesh)
        throw std::invalid_argument(args->scene +
                                    ": --vertices: the garment is a mesh file, not procedural");
      file.skirt.vertices = file.cape.vertices = args->vertices;
    }
    {
      const CharacterScene scene = build_character_scene(file);
      const MotionClip& clip =
          scene.clips[options.clip.empty() ? 0
                                           : static_cast<size_t>(scene.clip_index(options.clip))];
      const CapsuleSpeed fast = fastest_capsule(scene, clip, options.frames);
      std::printf("scene %s, clip %s (%d frames at %g Hz), %s\n", file.path.c_str(),
                  clip.name.c_str(), std::min(options.frames, clip.frame_count), clip.rate,
                  cpu_model().c_str());
      for (const std::string& line : placement_lines(scene.placement))
        std::printf("  %s\n", line.c_str());
      std::printf(
          "fastest capsule: %s at %.2f m/s (%.1f mm per frame, radius %.1f mm) arriving at frame "
          "%d\n",
          fast.bone.c_str(), fast.speed, 1e3 * fast.speed / clip.rate, 1e3 * fast.radius,
          fast.frame);
      std::printf("load average before: %s\n", load_average().c_str());
    }
    if (args->settle_every > 0) {
      const auto settled = run_settle_bench(
          file, options.clip, args->settle_every,
          [](const std::string& line) { std::fprintf(stderr, "%s\n", line.c_str()); });
      double worst = 0.0;
      std::printf("| start frame | max strain | max pen. mm |\n|---|---|---|\n");
      for (const auto& r : settled) {
        std::printf("| %d | %.2f%% | %.2f |\n", r.frame, 100 * r.max_strain,
                    1e3 * r.max_penetration);
        worst = std::max(worst, r.max_strain);
      }
      std::printf("largest over %zu start frames: %.2f%%\n", settled.size(), 100 * worst);
      return;
    }
    const auto rows = run_character_bench(
        file, options, [](const std::string& line) { std::fprintf(stderr, "%s\n", line.c_str()); });
    const std::string md = character_rows_markdown(rows);
    std::printf("load average after: %s\n%s", load_average().c_str(), md.c_str());
    if (!args->out.empty()) {
      make_directories(args->out);
      write_file_atomic(args->out + "/character.md", md);
      std::printf("wrote %s/character.md\n", args->out.c_str());
    }
  });
}

}  // namespace clothdb::cli
