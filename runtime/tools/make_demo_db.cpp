// Writes the synthetic demo database (runtime/tools/synthetic_db.hpp) that the C example and
// `ctest` play: make_demo_db OUT.clothdb [SIDE]. Replaces OUT if it exists.
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>

#include "runtime/tools/synthetic_db.hpp"

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s OUT.clothdb [SIDE]\n", argv[0]);
    return 2;
  }
  const int side = argc > 2 ? std::atoi(argv[2]) : 24;
  if (side < 2 || side > 1000) {
    std::fprintf(stderr, "%s: SIDE must be 2..1000\n", argv[0]);
    return 2;
  }
  try {
    for (const char* suffix : {"", "-wal", "-shm"})
      std::filesystem::remove(std::string(argv[1]) + suffix);
    // With an artist's mesh (quads, a UV seam), so the examples draw a render mesh.
    clothdb::synthetic::Spec spec = clothdb::synthetic::demo_spec(uint32_t(side));
    spec.artist_mesh = true;
    const auto built = clothdb::synthetic::build(argv[1], spec);
    std::printf("wrote %s: %u vertices, %zu primary clips, %zu cloth clips\n", argv[1],
                built.vertices, built.primary.size(), built.clip.size());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: %s\n", argv[0], e.what());
    return 1;
  }
  return 0;
}
