/* Plays a few seconds of cloth from a clothdb database through the C API of clothrt, the way a
 * game loop would: one shared database, one player per character, a random path through the
 * motion graph, positions written into an interleaved vertex buffer in world space.
 *
 *   clothrt_play_example FILE.clothdb [SECONDS]
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "clothrt.h"

/* An interleaved vertex as a renderer would upload it: position, then a normal the renderer fills
 * in itself. */
typedef struct vertex {
  float position[3];
  float normal[3];
} vertex;

int main(int argc, char** argv) {
  clothrt_db_options options;
  clothrt_db* db = NULL;
  clothrt_player* player = NULL;
  vertex* vertices = NULL;
  double seconds = 3.0;
  const double dt = 1.0 / 60.0; /* the game runs at 60 Hz, the cloth was stored at 30 */
  int frame, frames, rc, status = 1;
  uint32_t count;
  clothrt_frame_info info;
  clothrt_stats stats;

  if (argc < 2) {
    fprintf(stderr, "usage: %s FILE.clothdb [SECONDS]\n", argv[0]);
    return 2;
  }
  if (argc > 2) seconds = atof(argv[2]);

  clothrt_db_options_init(&options);
  options.cache_bytes = (size_t)16 << 20;
  rc = clothrt_db_open(argv[1], &options, &db);
  if (rc != CLOTHRT_OK) {
    fprintf(stderr, "cannot open %s: %s (%s)\n", argv[1], clothrt_last_open_errmsg(),
            clothrt_status_name(rc));
    return 1;
  }
  count = clothrt_db_vertex_count(db);
  vertices = (vertex*)calloc(count, sizeof(vertex));
  if (!vertices) goto done;

  if (clothrt_player_create(db, &player) != CLOTHRT_OK) goto done;
  clothrt_player_set_random(player, 1, 42);
  rc = clothrt_player_start(player, 0);
  if (rc != CLOTHRT_OK) {
    fprintf(stderr, "start: %s\n", clothrt_player_errmsg(player));
    goto done;
  }

  frames = (int)(seconds / dt + 0.5);
  for (frame = 0; frame < frames; ++frame) {
    /* The character walks along +x and turns slowly: its root transform, column-major. */
    const float heading = (float)(0.2 * frame * dt);
    const float c = cosf(heading), s = sinf(heading);
    const float root[16] = {c, 0, -s, 0, 0, 1, 0, 0, s, 0, c, 0, (float)(1.2 * frame * dt),
                            0, 0, 1};
    rc = clothrt_player_advance(player, dt);
    if (rc != CLOTHRT_OK)
      fprintf(stderr, "frame %d: %s (showing the last good pose)\n", frame,
              clothrt_player_errmsg(player));
    rc = clothrt_player_get_positions(player, vertices[0].position, sizeof(vertex), root);
    if (rc != CLOTHRT_OK) {
      fprintf(stderr, "frame %d: %s\n", frame, clothrt_player_errmsg(player));
      goto done;
    }
    if (!isfinite(vertices[count - 1].position[1])) {
      fprintf(stderr, "frame %d: non-finite position\n", frame);
      goto done;
    }
  }
  clothrt_player_info(player, &info);
  clothrt_db_stats(db, &stats);
  printf(
      "played %d frames (%.1f s): %llu transitions, %llu fallbacks, %u clips decoded, "
      "cache %.1f MB; last vertex at (%.3f, %.3f, %.3f)\n",
      frames, seconds, (unsigned long long)info.transitions, (unsigned long long)info.fallbacks,
      (unsigned)stats.clip_loads, stats.cache_bytes / 1048576.0, vertices[count - 1].position[0],
      vertices[count - 1].position[1], vertices[count - 1].position[2]);
  status = 0;

done:
  clothrt_player_destroy(player);
  clothrt_db_close(db);
  free(vertices);
  return status;
}
