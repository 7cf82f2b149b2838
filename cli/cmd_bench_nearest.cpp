// `clothdb bench nearest`: the nearest-state search with and without its pruning steps
// (bench/nearest_bench.hpp).
#include <cstdio>
#include <memory>
#include <stdexcept>
#include <string>

#include "bench/nearest_bench.hpp"
#include "cli_util.hpp"
#include "commands.hpp"
#include "explore/secondary_graph.hpp"

namespace clothdb::cli {

void register_bench_nearest(CLI::App& bench) {
  struct Args {
    std::string db;
    size_t synthetic = 0;
    uint32_t vertices = 100;
    int clusters = 4;
    uint32_t seed = 1;
    size_t modes = kMotionModes;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "nearest",
      "The explorer's nearest-state search and priority updates, adding every state as a resume "
      "does: as before (every candidate's reduced bound, sorted), then adding early exit, the "
      "coarse bound first and the motion basis (all: as the explorer runs): CPU time (one thread) "
      "and state distances "
      "begun, and whether every answer is the same (it must be)");
  cmd->add_option("--db", args->db, "A database: its cloth states, in the order they were added")
      ->check(CLI::ExistingFile);
  cmd->add_option("--synthetic", args->synthetic,
                  "Instead, this many synthetic states clustered at one node")
      ->check(number_in(1, 1e7));
  cmd->add_option("--vertices", args->vertices, "Synthetic: vertices per state")
      ->capture_default_str()
      ->check(CLI::Range(8u, 100000u));
  cmd->add_option("--clusters", args->clusters, "Synthetic: clusters")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  cmd->add_option("--seed", args->seed, "Synthetic: random seed")->capture_default_str();
  cmd->add_option("--modes", args->modes, "Modes of the motion basis (the explorer's by default)")
      ->capture_default_str()
      ->check(CLI::Range(size_t(1), size_t(256)));
  cmd->callback([args] {
    if (args->db.empty() == (args->synthetic == 0))
      throw std::runtime_error("bench nearest: give --db FILE or --synthetic N (one of them)");
    const NearestBenchResult r =
        args->db.empty() ? bench_nearest_synthetic(args->synthetic, args->vertices, args->clusters,
                                                   args->seed, args->modes)
                         : bench_nearest_file(args->db, args->modes);
    std::printf("states                   %zu of %u vertices at %zu nodes (largest %zu)\n",
                r.states, r.vertices, r.nodes, r.largest_node);
    std::printf("reduced bound alone      %.3f CPU s, %ld state distances measured\n",
                r.reduced_only.cpu_seconds, r.reduced_only.exact_evaluations);
    std::printf("+ early exit             %.3f CPU s, %ld state distances begun\n",
                r.early_exit.cpu_seconds, r.early_exit.exact_evaluations);
    std::printf("+ coarse                 %.3f CPU s, %ld state distances begun\n",
                r.coarse.cpu_seconds, r.coarse.exact_evaluations);
    std::printf("+ motion basis (%zu modes, the explorer) %.3f CPU s, %ld state distances begun\n",
                r.motion_modes, r.motion.cpu_seconds, r.motion.exact_evaluations);
    std::printf("answers                  %s\n",
                r.identical ? "identical (nearest state, distance, priority)" : "DIFFER");
    if (!r.identical) throw std::runtime_error("bench nearest: the answers differ");
  });
}

}  // namespace clothdb::cli
