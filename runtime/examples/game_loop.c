/* A fixed-timestep game loop driving two characters' cloth through the C API of clothrt
 * (runtime/clothrt.h), the way an engine would:
 *  - the game logic runs at a fixed 60 Hz, decoupled from a render rate that varies from frame
 *    to frame (the classic accumulator loop); the cloth players advance with the logic;
 *  - both characters share one database (one cache, one prefetch thread) and write their cloth
 *    on the render mesh (the artist's vertex order, seam vertices split, their UVs), in world
 *    space, into ONE interleaved vertex buffer (position, normal, uv: 32-byte stride), character 0
 *    in the first half and character 1 in the second: positions and normals straight from
 *    clothrt_player_get_render_mesh, UVs copied in once;
 *  - at the end it prints the runtime's counters, `stalls` among them (transitions that had to
 *    wait for a clip to be decoded), and checks what it drew.
 *
 *   clothrt_game_loop FILE.clothdb [SECONDS]
 *
 * Exit 0 when every frame was finite, the normals unit length, seam copies of a vertex at one place
 * with one normal, and the two characters apart.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clothrt.h"

#define CHARACTERS 2

/* What the renderer uploads: 32 bytes per vertex. */
typedef struct vertex {
  float position[3];
  float normal[3];
  float uv[2];
} vertex;

/* The character's root transform at game time t: walking along its own line, turning slowly.
 * Column-major 4x4 (clothrt_player_get_positions). */
static void root_transform(int character, double t, float out[16]) {
  const float heading = (float)(0.3 * t + 1.5 * character);
  const float c = cosf(heading), s = sinf(heading);
  const float m[16] = {
      c, 0, -s, 0, 0, 1, 0, 0, s, 0, c, 0, (float)(1.1 * t), 0, (float)(3.0 * character), 1};
  memcpy(out, m, sizeof m);
}

int main(int argc, char** argv) {
  const double step = 1.0 / 60.0; /* the game logic's fixed step */
  double seconds = 5.0, game_time = 0, accumulator = 0;
  clothrt_db_options options;
  clothrt_db* db = NULL;
  clothrt_player* players[CHARACTERS] = {NULL, NULL};
  vertex* buffer = NULL;
  uint32_t* tri = NULL;
  uint32_t* source = NULL;
  uint32_t count, triangles, i;
  unsigned long render_frames = 0, logic_steps = 0, rng = 12345;
  int c, rc, status = 1;
  float nearest = 1e30f;
  clothrt_stats stats;
  clothrt_frame_info info[CHARACTERS];

  if (argc < 2) {
    fprintf(stderr, "usage: %s FILE.clothdb [SECONDS]\n", argv[0]);
    return 2;
  }
  if (argc > 2) seconds = atof(argv[2]);
  if (!(seconds > 0 && seconds < 3600)) {
    fprintf(stderr, "%s: SECONDS must be in (0, 3600)\n", argv[0]);
    return 2;
  }

  clothrt_db_options_init(&options);
  rc = clothrt_db_open(argv[1], &options, &db);
  if (rc != CLOTHRT_OK) {
    fprintf(stderr, "cannot open %s: %s (%s)\n", argv[1], clothrt_last_open_errmsg(),
            clothrt_status_name(rc));
    return 1;
  }
  /* The render mesh: fixed for the database, read once (the index buffer is the same for both
   * characters, offset by count for the second). */
  count = clothrt_db_render_vertex_count(db);
  triangles = clothrt_db_render_triangle_count(db);
  buffer = (vertex*)calloc((size_t)count * CHARACTERS, sizeof(vertex));
  tri = (uint32_t*)malloc((size_t)triangles * 3 * sizeof(uint32_t));
  source = (uint32_t*)malloc((size_t)count * sizeof(uint32_t));
  if (!buffer || !tri || !source ||
      clothrt_db_render_triangles(db, tri, (size_t)triangles * 3) != CLOTHRT_OK ||
      clothrt_db_render_source_vertices(db, source, count) != CLOTHRT_OK)
    goto done;
  if (clothrt_db_render_has_uvs(db))
    for (c = 0; c < CHARACTERS; ++c)
      if (clothrt_db_render_uvs(db, buffer[(size_t)c * count].uv, sizeof(vertex)) != CLOTHRT_OK)
        goto done;

  for (c = 0; c < CHARACTERS; ++c) {
    if (clothrt_player_create(db, &players[c]) != CLOTHRT_OK) goto done;
    /* Each character walks its own random path through the motion graph. */
    clothrt_player_set_random(players[c], 1, (uint64_t)(17 + c));
    rc = clothrt_player_start(players[c], 0);
    if (rc != CLOTHRT_OK) {
      fprintf(stderr, "start: %s\n", clothrt_player_errmsg(players[c]));
      goto done;
    }
  }

  while (game_time < seconds) {
    /* The render rate varies (8..40 ms per frame, a fixed pseudo-random sequence): the logic
     * catches up in whole fixed steps. */
    rng = rng * 1103515245ul + 12345ul;
    accumulator += 0.008 + 0.032 * (double)((rng >> 16) % 1000) / 1000.0;
    while (accumulator >= step) {
      for (c = 0; c < CHARACTERS; ++c) {
        rc = clothrt_player_advance(players[c], step);
        if (rc != CLOTHRT_OK)
          fprintf(stderr, "step %lu, character %d: %s (showing the last good pose)\n", logic_steps,
                  c, clothrt_player_errmsg(players[c]));
      }
      game_time += step;
      accumulator -= step;
      ++logic_steps;
    }
    /* Render: each character's cloth into its half of the one buffer, with the stride. */
    for (c = 0; c < CHARACTERS; ++c) {
      float root[16];
      vertex* half = buffer + (size_t)c * count;
      clothrt_render_output out;
      memset(&out, 0, sizeof out);
      out.positions = half[0].position;
      out.position_stride = sizeof(vertex);
      out.normals = half[0].normal;
      out.normal_stride = sizeof(vertex);
      root_transform(c, game_time, root);
      rc = clothrt_player_get_render_mesh(players[c], &out, root);
      if (rc != CLOTHRT_OK) {
        fprintf(stderr, "character %d: %s\n", c, clothrt_player_errmsg(players[c]));
        goto done;
      }
    }
    for (i = 0; i < count * CHARACTERS; ++i) {
      const float* p = buffer[i].position;
      const float* n = buffer[i].normal;
      if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]) ||
          fabsf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2] - 1) > 1e-3f) {
        fprintf(stderr, "render frame %lu: vertex %u is not finite or its normal not unit\n",
                render_frames, i);
        goto done;
      }
    }
    /* A vertex on a UV seam is drawn once per side: both render copies of one artist vertex at
     * one place with one normal. */
    for (i = 1; i < count; ++i) {
      const uint32_t first = source[i];
      if (first < i && source[first] == first) {
        const float* p = buffer[i].position;
        const float* q = buffer[first].position;
        if (memcmp(p, q, 3 * sizeof(float)) != 0 ||
            memcmp(buffer[i].normal, buffer[first].normal, 3 * sizeof(float)) != 0) {
          fprintf(stderr, "render frame %lu: seam copy %u of vertex %u drawn apart\n",
                  render_frames, i, first);
          goto done;
        }
      }
    }
    {
      /* The characters are 3 m apart: their cloth must not be drawn on top of each other. */
      const float* a = buffer[0].position;
      const float* b = buffer[count].position;
      const float d = sqrtf((a[0] - b[0]) * (a[0] - b[0]) + (a[2] - b[2]) * (a[2] - b[2]));
      if (d < nearest) nearest = d;
    }
    ++render_frames;
  }

  clothrt_db_stats(db, &stats);
  for (c = 0; c < CHARACTERS; ++c) clothrt_player_info(players[c], &info[c]);
  printf(
      "%.1f s of game time: %lu logic steps at 60 Hz, %lu render frames; %u render vertices "
      "(%u simulated, %u triangles) x %d characters in one %u-byte-stride buffer\n",
      game_time, logic_steps, render_frames, count, clothrt_db_vertex_count(db), triangles,
      CHARACTERS, (unsigned)sizeof(vertex));
  for (c = 0; c < CHARACTERS; ++c)
    printf("character %d: %llu transitions, %llu fallbacks, now primary clip %lld frame %.1f\n", c,
           (unsigned long long)info[c].transitions, (unsigned long long)info[c].fallbacks,
           (long long)info[c].primary_clip, info[c].primary_frame);
  printf("runtime: stalls %llu, clip loads %llu, load failures %llu, cache %.1f MB\n",
         (unsigned long long)stats.stalls, (unsigned long long)stats.clip_loads,
         (unsigned long long)stats.load_failures, stats.cache_bytes / 1048576.0);
  if (nearest < 1.0f) {
    fprintf(stderr, "the two characters' cloth came within %.2f m: buffer halves overlap\n",
            nearest);
    goto done;
  }
  if (info[0].transitions == 0 || info[1].transitions == 0) {
    fprintf(stderr, "a character never passed a node in %.1f s\n", game_time);
    goto done;
  }
  status = 0;

done:
  for (c = 0; c < CHARACTERS; ++c) clothrt_player_destroy(players[c]);
  clothrt_db_close(db);
  free(buffer);
  free(tri);
  free(source);
  return status;
}
