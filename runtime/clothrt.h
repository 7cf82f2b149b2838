/* clothrt: plays back precomputed secondary cloth (a clothdb database) in a game.
 *
 * A database holds the character's primary motion graph (clips between nodes) and the secondary
 * cloth graph of Kim et al. 2013 (docs/SECONDARY_GRAPH.md). A player follows whatever path the
 * game takes through the primary graph: at each node the game names the next primary clip (or lets
 * the player pick at random), the player follows the cloth edge from the clip it just played and
 * continues with the cloth clip that starts there, blending when the edge links back to a
 * different state. Positions come out in character space or, given the character's root transform,
 * in world space, written into a buffer the caller owns (with a stride, so they can go straight
 * into a vertex buffer).
 *
 * Errors: every function that can fail returns an int status (CLOTHRT_OK or a CLOTHRT_ERR_*
 * code); clothrt_db_errmsg / clothrt_player_errmsg give the message of the last failure on that
 * handle, clothrt_last_open_errmsg the one of the last failed clothrt_db_open on this thread. No
 * function throws or aborts on bad data: corrupt or missing cloth gives an error code and the
 * player keeps showing its last good pose.
 *
 * THREADING
 *  - A clothrt_db is shared read-only: any number of players, on any threads, may use one
 *    database handle at the same time. Its decoded-clip cache and its SQLite connections are
 *    protected internally. The clothrt_db_* query functions may be called from any thread.
 *  - A clothrt_player is used by one thread at a time (no internal locking); different players
 *    need no coordination. Moving a player between threads needs the caller's own happens-before
 *    (e.g. the job system's barrier).
 *  - clothrt_db_close must be called after every player of that database has been destroyed and
 *    no other call on it is running.
 *  - With prefetch_threads > 0 the database owns that many background threads (each with its own
 *    read-only SQLite connection) that decode the clips players will need next. With 0, the same
 *    work runs on the callers' threads inside clothrt_player_advance (at most one clip per call).
 *
 *  - The render-mesh functions follow the same rules: clothrt_db_render_* read immutable data of
 *    the database (any thread); clothrt_player_get_render_mesh uses the player's own scratch
 *    buffers (one thread per player at a time, like every player call).
 *
 * MEMORY: decoded clips live in a cache shared by all players of a database, capped by
 * clothrt_db_options.cache_bytes (clips a player is playing or about to play are pinned and may
 * push it over the cap until released). After warm-up, advancing and sampling a player allocate
 * nothing; decoding a new clip reuses the buffer of the clip it evicts.
 */
#ifndef CLOTHRT_H
#define CLOTHRT_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Status codes. */
#define CLOTHRT_OK 0
#define CLOTHRT_ERR_IO 1          /* the file or SQLite failed (cannot open, busy, disk error) */
#define CLOTHRT_ERR_NOT_CLOTHDB 2 /* not a clothdb database */
#define CLOTHRT_ERR_VERSION 3     /* written by a newer clothdb than this library reads */
#define CLOTHRT_ERR_CORRUPT 4     /* inconsistent or damaged data (checksums, sizes, graph) */
#define CLOTHRT_ERR_NOT_FOUND 5   /* no such clip, or no cloth was precomputed for it */
#define CLOTHRT_ERR_INVALID 6     /* invalid argument or call order (e.g. player not started) */
#define CLOTHRT_ERR_NOMEM 7       /* out of memory */

/* "ok", "io", "not-clothdb", "version", "corrupt", "not-found", "invalid", "nomem". */
const char* clothrt_status_name(int status);

typedef struct clothrt_db clothrt_db;
typedef struct clothrt_player clothrt_player;

typedef struct clothrt_db_options {
  /* Cap on the memory of decoded clips, bytes. 0: 64 MiB. */
  size_t cache_bytes;
  /* Background decoding threads owned by the database (0..8). 0: decode on the callers' threads
   * inside clothrt_player_advance. */
  int prefetch_threads;
  /* How long before the end of a clip a player asks for the clips it may continue with. */
  double prefetch_seconds;
} clothrt_db_options;

/* Defaults: 64 MiB cache, 1 prefetch thread, 1 s prefetch window. */
void clothrt_db_options_init(clothrt_db_options* options);

/* Opens a clothdb database read-only and loads its graph. options may be NULL (defaults).
 * On failure *out is NULL and clothrt_last_open_errmsg() says why. The file is read through a
 * memory map (SQLite's mmap_size, up to 1 GiB of it; docs/DATABASE.md): an I/O error on the file
 * while it is read (a disk or network file system failing under it) then arrives as SIGBUS, not as
 * CLOTHRT_ERR_IO. */
int clothrt_db_open(const char* path, const clothrt_db_options* options, clothrt_db** out);
void clothrt_db_close(clothrt_db* db); /* NULL is fine */
const char* clothrt_last_open_errmsg(void);
const char* clothrt_db_errmsg(const clothrt_db* db);

uint32_t clothrt_db_vertex_count(const clothrt_db* db);
uint32_t clothrt_db_triangle_count(const clothrt_db* db);
/* Copies 3 * triangle_count vertex indices into out (capacity in indices). */
int clothrt_db_triangles(const clothrt_db* db, uint32_t* out, size_t capacity);

/* THE RENDER MESH. A game draws the artist's garment mesh, not the welded, triangulated
 * simulation mesh above: the artist's vertex order, their UVs, vertices split where UV or normal
 * seams run (docs/DATABASE.md, "The artist's mesh"). Render vertex i < the artist's vertex count
 * is artist vertex i; each further (vertex, UV, normal) combination a seam makes follows, so a
 * seam vertex appears once per side. A database of a procedural garment (or one written before
 * the artist's mesh was stored) has the simulation mesh as its render mesh (the identity map, no
 * UVs). Vertex count, index buffer (3 indices per triangle, the artist's faces fanned from their
 * first corner, in face order) and UVs are fixed for the database: read them once. */
uint32_t clothrt_db_render_vertex_count(const clothrt_db* db);
uint32_t clothrt_db_render_triangle_count(const clothrt_db* db);
/* Copies 3 * render_triangle_count indices into out (capacity in indices). */
int clothrt_db_render_triangles(const clothrt_db* db, uint32_t* out, size_t capacity);
/* 1 when the render mesh has UVs (then clothrt_player_get_render_mesh can give tangents). */
int clothrt_db_render_has_uvs(const clothrt_db* db);
/* Writes render_vertex_count UVs (2 floats each) at out, out + stride_bytes, ... (stride_bytes >=
 * 8, a multiple of 4). CLOTHRT_ERR_NOT_FOUND when the mesh has none. A vertex without a UV gets (0,
 * 0). */
int clothrt_db_render_uvs(const clothrt_db* db, float* out, size_t stride_bytes);
/* Copies, per render vertex, the artist's vertex it is (its index in the artist's file) into out
 * (capacity in indices). */
int clothrt_db_render_source_vertices(const clothrt_db* db, uint32_t* out, size_t capacity);

/* Where clothrt_player_get_render_mesh writes, per render vertex: 3 floats at each stride. A NULL
 * pointer skips that output. Strides are in bytes, multiples of 4, >= 12 (>= 16 for tangents). */
typedef struct clothrt_render_output {
  float* positions;
  size_t position_stride;
  /* Unit normals, area-weighted over the simulation mesh's triangles around each vertex, so both
   * copies of a seam vertex get the same normal (hard edges of the artist's normals are not kept).
   */
  float* normals;
  size_t normal_stride;
  /* 4 floats: unit tangent along +u (orthogonal to the normal) and w = +-1, the bitangent's sign
   * (bitangent = w * cross(normal, tangent)), per render vertex, from the triangles around it in
   * UV space (Lengyel 2001). Only when the mesh has UVs (CLOTHRT_ERR_INVALID otherwise). */
  float* tangents;
  size_t tangent_stride;
} clothrt_render_output;

/* Samples the player like clothrt_player_get_positions and writes the render mesh's positions
 * (seam copies duplicated), and normals and tangents if asked, computed from the sampled frame.
 * root_transform as for clothrt_player_get_positions (NULL: character space); normals and
 * tangents are turned by its upper 3x3 and renormalised (exact for rotations and uniform scale).
 * After warm-up it allocates nothing. */
int clothrt_player_get_render_mesh(clothrt_player* player, const clothrt_render_output* out,
                                   const float* root_transform);

typedef struct clothrt_clip_info {
  int64_t id;          /* primary clip id */
  const char* name;    /* valid while the database is open */
  int32_t frame_count; /* poses, frame 0 at the source node, the last at the target node */
  double frame_rate;   /* Hz */
  uint32_t successor_count;
  int has_cloth; /* some cloth clip was precomputed along this primary clip */
} clothrt_clip_info;

size_t clothrt_db_clip_count(const clothrt_db* db);
/* Primary clips in id order: index 0 .. clothrt_db_clip_count - 1. */
int clothrt_db_clip_info(const clothrt_db* db, size_t index, clothrt_clip_info* out);
/* The primary clip named `name`; CLOTHRT_ERR_NOT_FOUND if none. */
int clothrt_db_find_clip(const clothrt_db* db, const char* name, int64_t* id);
/* Primary clips that may follow `clip` (those leaving its target node), in id order. Writes up to
 * capacity ids and the total number into *count. */
int clothrt_db_successors(const clothrt_db* db, int64_t clip, int64_t* out, size_t capacity,
                          size_t* count);
/* The primary clip whose source node is the start of the graph (meta start_clip). */
int64_t clothrt_db_start_clip(const clothrt_db* db);

/* Counters of a database and all its players, for profiling. Times in nanoseconds, summed over
 * threads. */
typedef struct clothrt_stats {
  size_t cache_bytes;    /* decoded clips held (including reusable buffers) */
  size_t cache_cap;      /* the cap set at open */
  size_t metadata_bytes; /* the graph index loaded at open */
  uint32_t clips_cached;
  uint64_t clip_loads; /* clips decoded */
  uint64_t clip_evictions;
  uint64_t load_failures;
  uint64_t stalls; /* transitions that had to wait for (or do) a load */
  uint64_t fallbacks_resolved;
  uint64_t sqlite_ns;     /* fetching blobs and cloth states */
  uint64_t decode_ns;     /* codec::decode_frames: zstd and prediction */
  uint64_t repack_ns;     /* storing decoded frames in the cache's 16-bit form */
  uint64_t sample_ns;     /* players: interpolating, blending, transforming, writing out */
  uint64_t transition_ns; /* players: following edges, setting up blends */
  uint64_t frames_sampled;
} clothrt_stats;

int clothrt_db_stats(const clothrt_db* db, clothrt_stats* out);
/* Times players record (sample_ns, transition_ns) are off by default: turning them on costs two
 * clock reads per call. */
void clothrt_db_set_timing(clothrt_db* db, int enabled);
void clothrt_db_reset_stats(clothrt_db* db);

/* Players. */
int clothrt_player_create(clothrt_db* db, clothrt_player** out);
void clothrt_player_destroy(clothrt_player* player); /* NULL is fine */
const char* clothrt_player_errmsg(const clothrt_player* player);
/* Bytes the player holds (pose buffers), not counting the shared cache. */
size_t clothrt_player_memory(const clothrt_player* player);

/* Frames over which a transition into a different state is blended (default 8, 0: snap). A blend
 * interrupted by the next transition continues from the pose shown at that moment. A transition
 * through a dead end that the precompute closed with a link to the nearest state (schema 4) blends
 * over its recorded error / 1 mm frames instead when that is longer, at most 60. */
int clothrt_player_set_blend_frames(clothrt_player* player, double frames);

/* Starts at the source node of primary clip `clip` (0: the graph's start clip), in the first cloth
 * state stored at that node that has cloth along it. */
int clothrt_player_start(clothrt_player* player, int64_t clip);
/* Starts at frame 0 of a given cloth clip (e.g. to resume, or to spread players over clips). */
int clothrt_player_start_cloth_clip(clothrt_player* player, int64_t cloth_clip);

/* Names the primary clip to take at the next node (must be a successor of the current primary
 * clip and have cloth: CLOTHRT_ERR_INVALID / CLOTHRT_ERR_NOT_FOUND otherwise). May be called any
 * time during the current clip; the latest call wins. When the node is reached with nothing named,
 * random mode picks one, otherwise the lowest-id successor with cloth is taken. */
int clothrt_player_set_next(clothrt_player* player, int64_t clip);
/* Random mode (for testing): at each node pick a successor with cloth uniformly, from `seed`. */
int clothrt_player_set_random(clothrt_player* player, int enabled, uint64_t seed);

/* Advances by dt seconds (any finite step >= 0; positions are interpolated between stored frames).
 * Returns an error when a clip needed for a transition cannot be read or decoded: the player then
 * holds the last good pose while the primary clip plays on, and restarts at the next node.
 * Long steps cost bounded work, whatever dt is: at most 4,096 nodes are passed in one call, and
 * clips the step passes whole are not loaded (only the one it ends in), so no blend carries across
 * them. Without random mode the walk is a cycle after the first node, and whole turns of it are
 * skipped: the step lands exactly where stepping in small steps would (for cycles found within
 * the 4,096 nodes, i.e. through up to about 1,000 clips). In random mode those nodes are passed
 * with the same random draws as small steps would make. Past the cap the rest of the step is
 * taken modulo the length of the next clip (a place reached in bounded time, not the exact one).
 * Steps beyond 1e250 s count as 1e250 s. transitions/fallbacks in clothrt_frame_info count
 * skipped turns too. */
int clothrt_player_advance(clothrt_player* player, double dt_seconds);

/* Writes vertex_count positions (3 floats each) at out, out + stride_bytes, ... (stride_bytes >= 12
 * and a multiple of 4). root_transform: the character's root transform of this frame as a 4x4
 * column-major matrix (OpenGL order; world = M * [x y z 1]) to get world space, or NULL for
 * character space (docs/SECONDARY_GRAPH.md). */
int clothrt_player_get_positions(clothrt_player* player, float* out, size_t stride_bytes,
                                 const float* root_transform);

typedef struct clothrt_frame_info {
  int64_t primary_clip; /* the primary clip being played */
  double primary_frame; /* fractional frame within it */
  int64_t cloth_clip;   /* 0 while holding after an error */
  int64_t cloth_state;  /* the state the cloth clip starts from */
  int64_t next_clip;    /* the primary clip that will follow (named or chosen), 0: not decided */
  int blending;         /* a blend into the current clip is in progress */
  double blend_weight;  /* 0 at the start of a blend .. 1 when done (1 when not blending) */
  int fallback;         /* the current clip was reached by a fallback to the nearest state */
  int holding;          /* showing the last good pose after an error */
  uint64_t transitions; /* nodes passed since start */
  uint64_t fallbacks;   /* fallbacks since start */
  uint64_t interrupted_blends; /* transitions that came while a blend was in progress */
} clothrt_frame_info;

int clothrt_player_info(const clothrt_player* player, clothrt_frame_info* out);

#ifdef __cplusplus
}
#endif

#endif /* CLOTHRT_H */
