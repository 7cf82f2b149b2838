// explore_run DB THREADS TOTAL_FRAMES CACHE_BYTES: the state store test's exploration
// (explore_fixture.hpp: tiny_scene on tiny_graph) as a process of its own, so that
// tests/test_state_store.cpp can SIGKILL it mid-run and run the same command again.
// TOTAL_FRAMES is a budget for the file: the frames it already holds count against it, so a run
// resumed after a kill stops where an uninterrupted run stops. Prints the state store's figures.
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <string>

#include "database/format/reader.hpp"
#include "support/explore_fixture.hpp"

using namespace clothdb;

int main(int argc, char** argv) {
  if (argc != 5) {
    std::fprintf(stderr, "usage: %s DB THREADS TOTAL_FRAMES CACHE_BYTES\n", argv[0]);
    return 2;
  }
  try {
    const std::string path = argv[1];
    const long total = std::atol(argv[3]);
    long stored = 0;
    if (std::filesystem::exists(path)) {
      db::Reader reader;
      db::Error err;
      std::vector<db::ClothClip> clips;
      if (reader.open(path, &err) != db::Status::Ok ||
          reader.cloth_clips(&clips, &err) != db::Status::Ok) {
        std::fprintf(stderr, "%s: %s\n", path.c_str(), err.message);
        return 1;
      }
      for (const db::ClothClip& c : clips) stored += c.frame_count;
    }
    const CharacterScene scene = test::tiny_scene();
    ExploreGraph graph = test::tiny_graph(scene);
    db::Writer writer =
        std::filesystem::exists(path) ? db::Writer::open(path) : db::Writer::create(path);
    prepare_database(writer, scene, graph, "{}");
    if (stored >= total) {
      std::printf("budget spent: %ld of %ld frames stored\n", stored, total);
      return 0;
    }
    const ExploreReport r = explore(scene, graph, writer,
                                    test::many_states_options(std::atoi(argv[2]), total - stored,
                                                              std::strtoull(argv[4], nullptr, 10)));
    std::printf(
        "states %d bytes_per_state %zu cache_capacity %zu peak_alive %zu resumed %d exact %ld "
        "reads %ld\n",
        r.states, r.bytes_per_state, r.state_cache.capacity, r.state_cache.peak_alive_bytes,
        r.resumed ? 1 : 0, r.exact_evaluations, r.state_cache.reads);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "explore_run: %s\n", e.what());
    return 1;
  }
}
