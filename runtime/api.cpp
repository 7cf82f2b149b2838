// The C entry points: argument checks, error codes and messages, and no exception ever crossing
// the C boundary (allocation failures become CLOTHRT_ERR_NOMEM).
#include <cmath>
#include <cstdio>
#include <cstring>
#include <new>

#include "internal.hpp"

struct clothrt_db {
  clothrt::Db impl;
};

struct clothrt_player {
  explicit clothrt_player(clothrt::Db* db) : impl(db) {}
  clothrt::Player impl;
};

namespace {

thread_local char open_message[sizeof(clothrt::Error::message)] = "";

void set_open_message(const char* text) {
  std::snprintf(open_message, sizeof open_message, "%s", text);
}

int db_fail(const clothrt_db* db, int code, const char* text) {
  clothrt::Error e;
  e.set(
      code == CLOTHRT_ERR_NOT_FOUND ? clothrt::Status::NotFound : clothrt::Status::InvalidArgument,
      "%s", text);
  const_cast<clothrt_db*>(db)->impl.set_error(e);
  return code;
}

int clip_index(const clothrt_db* db, int64_t id) {
  auto it = db->impl.primary_by_id.find(id);
  return it == db->impl.primary_by_id.end() ? -1 : it->second;
}

}  // namespace

extern "C" {

const char* clothrt_status_name(int status) {
  switch (status) {
    case CLOTHRT_OK:
      return "ok";
    case CLOTHRT_ERR_IO:
      return "io";
    case CLOTHRT_ERR_NOT_CLOTHDB:
      return "not-clothdb";
    case CLOTHRT_ERR_VERSION:
      return "version";
    case CLOTHRT_ERR_CORRUPT:
      return "corrupt";
    case CLOTHRT_ERR_NOT_FOUND:
      return "not-found";
    case CLOTHRT_ERR_INVALID:
      return "invalid";
    case CLOTHRT_ERR_NOMEM:
      return "nomem";
  }
  return "unknown";
}

void clothrt_db_options_init(clothrt_db_options* options) {
  if (!options) return;
  options->cache_bytes = size_t(64) << 20;
  options->prefetch_threads = 1;
  options->prefetch_seconds = 1.0;
}

int clothrt_db_open(const char* path, const clothrt_db_options* options, clothrt_db** out) {
  if (!out) {
    set_open_message("clothrt_db_open: out is NULL");
    return CLOTHRT_ERR_INVALID;
  }
  *out = nullptr;
  if (!path) {
    set_open_message("clothrt_db_open: path is NULL");
    return CLOTHRT_ERR_INVALID;
  }
  clothrt_db_options opts;
  clothrt_db_options_init(&opts);
  if (options) {
    if (options->cache_bytes > 0) opts.cache_bytes = options->cache_bytes;
    opts.prefetch_threads = options->prefetch_threads;
    if (std::isfinite(options->prefetch_seconds) && options->prefetch_seconds >= 0)
      opts.prefetch_seconds = options->prefetch_seconds;
  }
  try {
    auto* db = new clothrt_db;
    clothrt::Error err;
    const clothrt::Status st = db->impl.open(path, opts, &err);
    if (st != clothrt::Status::Ok) {
      set_open_message(err.message);
      delete db;
      return clothrt::to_code(st);
    }
    set_open_message("");
    *out = db;
    return CLOTHRT_OK;
  } catch (const std::bad_alloc&) {
    set_open_message("clothrt_db_open: out of memory");
    return CLOTHRT_ERR_NOMEM;
  } catch (const std::exception& e) {
    // std::thread creation failing (system_error) and the like.
    std::snprintf(open_message, sizeof open_message, "clothrt_db_open: %s", e.what());
    return CLOTHRT_ERR_IO;
  }
}

void clothrt_db_close(clothrt_db* db) {
  delete db;
}

const char* clothrt_last_open_errmsg(void) {
  return open_message;
}

const char* clothrt_db_errmsg(const clothrt_db* db) {
  return db ? db->impl.error.message : "clothrt: database handle is NULL";
}

uint32_t clothrt_db_vertex_count(const clothrt_db* db) {
  return db ? db->impl.vertex_count : 0;
}

uint32_t clothrt_db_triangle_count(const clothrt_db* db) {
  return db ? uint32_t(db->impl.triangles.size() / 3) : 0;
}

int clothrt_db_triangles(const clothrt_db* db, uint32_t* out, size_t capacity) {
  if (!db) return CLOTHRT_ERR_INVALID;
  if (!out || capacity < db->impl.triangles.size())
    return db_fail(db, CLOTHRT_ERR_INVALID, "clothrt_db_triangles: output buffer too small");
  std::memcpy(out, db->impl.triangles.data(), db->impl.triangles.size() * sizeof(uint32_t));
  return CLOTHRT_OK;
}

uint32_t clothrt_db_render_vertex_count(const clothrt_db* db) {
  return db ? db->impl.render_vertex_count : 0;
}

uint32_t clothrt_db_render_triangle_count(const clothrt_db* db) {
  return db ? uint32_t(db->impl.render_triangles.size() / 3) : 0;
}

int clothrt_db_render_triangles(const clothrt_db* db, uint32_t* out, size_t capacity) {
  if (!db) return CLOTHRT_ERR_INVALID;
  const auto& t = db->impl.render_triangles;
  if (!out || capacity < t.size())
    return db_fail(db, CLOTHRT_ERR_INVALID, "clothrt_db_render_triangles: output buffer too small");
  if (!t.empty()) std::memcpy(out, t.data(), t.size() * sizeof(uint32_t));
  return CLOTHRT_OK;
}

int clothrt_db_render_has_uvs(const clothrt_db* db) {
  return db && !db->impl.render_uvs.empty();
}

int clothrt_db_render_uvs(const clothrt_db* db, float* out, size_t stride_bytes) {
  if (!db) return CLOTHRT_ERR_INVALID;
  if (!out || stride_bytes < 2 * sizeof(float) || stride_bytes % sizeof(float) != 0)
    return db_fail(db, CLOTHRT_ERR_INVALID,
                   "clothrt_db_render_uvs: need an output buffer and a stride >= 8 that is a "
                   "multiple of 4");
  if (db->impl.render_uvs.empty())
    return db_fail(db, CLOTHRT_ERR_NOT_FOUND, "clothrt_db_render_uvs: the render mesh has no UVs");
  const size_t s = stride_bytes / sizeof(float);
  for (size_t r = 0; r < db->impl.render_vertex_count; ++r) {
    out[r * s] = db->impl.render_uvs[2 * r];
    out[r * s + 1] = db->impl.render_uvs[2 * r + 1];
  }
  return CLOTHRT_OK;
}

int clothrt_db_render_source_vertices(const clothrt_db* db, uint32_t* out, size_t capacity) {
  if (!db) return CLOTHRT_ERR_INVALID;
  const auto& v = db->impl.render_source;
  if (!out || capacity < v.size())
    return db_fail(db, CLOTHRT_ERR_INVALID,
                   "clothrt_db_render_source_vertices: output buffer too small");
  std::memcpy(out, v.data(), v.size() * sizeof(uint32_t));
  return CLOTHRT_OK;
}

size_t clothrt_db_clip_count(const clothrt_db* db) {
  return db ? db->impl.primaries.size() : 0;
}

int clothrt_db_clip_info(const clothrt_db* db, size_t index, clothrt_clip_info* out) {
  if (!db || !out) return CLOTHRT_ERR_INVALID;
  if (index >= db->impl.primaries.size())
    return db_fail(db, CLOTHRT_ERR_NOT_FOUND, "clothrt_db_clip_info: index out of range");
  const clothrt::PrimaryInfo& p = db->impl.primaries[index];
  out->id = p.id;
  out->name = p.name.c_str();
  out->frame_count = p.frames;
  out->frame_rate = p.rate;
  out->successor_count = p.succ_end - p.succ_begin;
  out->has_cloth = p.cand_end > p.cand_begin;
  return CLOTHRT_OK;
}

int clothrt_db_find_clip(const clothrt_db* db, const char* name, int64_t* id) {
  if (!db || !name || !id) return CLOTHRT_ERR_INVALID;
  for (const clothrt::PrimaryInfo& p : db->impl.primaries)
    if (p.name == name) {
      *id = p.id;
      return CLOTHRT_OK;
    }
  return db_fail(db, CLOTHRT_ERR_NOT_FOUND, "clothrt_db_find_clip: no primary clip of that name");
}

int clothrt_db_successors(const clothrt_db* db, int64_t clip, int64_t* out, size_t capacity,
                          size_t* count) {
  if (!db || !count || (capacity > 0 && !out)) return CLOTHRT_ERR_INVALID;
  const int i = clip_index(db, clip);
  if (i < 0)
    return db_fail(db, CLOTHRT_ERR_NOT_FOUND, "clothrt_db_successors: no such primary clip");
  const clothrt::PrimaryInfo& p = db->impl.primaries[size_t(i)];
  *count = p.succ_end - p.succ_begin;
  for (size_t k = 0; k < *count && k < capacity; ++k)
    out[k] = db->impl.primaries[size_t(db->impl.successors[p.succ_begin + k])].id;
  return CLOTHRT_OK;
}

int64_t clothrt_db_start_clip(const clothrt_db* db) {
  return db ? db->impl.primaries[size_t(db->impl.start_primary)].id : 0;
}

int clothrt_db_stats(const clothrt_db* db, clothrt_stats* out) {
  if (!db || !out) return CLOTHRT_ERR_INVALID;
  const_cast<clothrt_db*>(db)->impl.fill_stats(out);
  return CLOTHRT_OK;
}

void clothrt_db_set_timing(clothrt_db* db, int enabled) {
  if (db) db->impl.timing.store(enabled != 0);
}

void clothrt_db_reset_stats(clothrt_db* db) {
  if (db) db->impl.reset_stats();
}

int clothrt_player_create(clothrt_db* db, clothrt_player** out) {
  if (!out) return CLOTHRT_ERR_INVALID;
  *out = nullptr;
  if (!db) return CLOTHRT_ERR_INVALID;
  try {
    *out = new clothrt_player(&db->impl);
    return CLOTHRT_OK;
  } catch (const std::bad_alloc&) {
    return db_fail(db, CLOTHRT_ERR_NOMEM, "clothrt_player_create: out of memory");
  }
}

void clothrt_player_destroy(clothrt_player* player) {
  delete player;
}

const char* clothrt_player_errmsg(const clothrt_player* player) {
  return player ? player->impl.error.message : "clothrt: player handle is NULL";
}

size_t clothrt_player_memory(const clothrt_player* player) {
  return player ? player->impl.memory() : 0;
}

int clothrt_player_set_blend_frames(clothrt_player* player, double frames) {
  if (!player) return CLOTHRT_ERR_INVALID;
  if (!(frames >= 0) || !std::isfinite(frames)) {
    player->impl.error.set(clothrt::Status::InvalidArgument,
                           "set_blend_frames: %g is not a finite non-negative number", frames);
    return CLOTHRT_ERR_INVALID;
  }
  player->impl.blend_frames = frames;
  return CLOTHRT_OK;
}

int clothrt_player_start(clothrt_player* player, int64_t clip) {
  if (!player) return CLOTHRT_ERR_INVALID;
  clothrt::Db& db = *player->impl.db;
  const int i = clip == 0 ? db.start_primary : [&] {
    auto it = db.primary_by_id.find(clip);
    return it == db.primary_by_id.end() ? -1 : it->second;
  }();
  if (i < 0) {
    player->impl.error.set(clothrt::Status::NotFound, "start: no primary clip %lld",
                           (long long)clip);
    return CLOTHRT_ERR_NOT_FOUND;
  }
  const clothrt::PrimaryInfo& p = db.primaries[size_t(i)];
  if (p.cand_begin == p.cand_end) {
    player->impl.error.set(clothrt::Status::NotFound,
                           "start: no cloth was precomputed along primary clip %lld",
                           (long long)p.id);
    return CLOTHRT_ERR_NOT_FOUND;
  }
  return player->impl.start_clip(db.candidates[p.cand_begin]);
}

int clothrt_player_start_cloth_clip(clothrt_player* player, int64_t cloth_clip) {
  if (!player) return CLOTHRT_ERR_INVALID;
  clothrt::Db& db = *player->impl.db;
  auto it = db.clip_by_id.find(cloth_clip);
  if (it == db.clip_by_id.end()) {
    player->impl.error.set(clothrt::Status::NotFound, "start: no cloth clip %lld",
                           (long long)cloth_clip);
    return CLOTHRT_ERR_NOT_FOUND;
  }
  return player->impl.start_clip(it->second);
}

int clothrt_player_set_next(clothrt_player* player, int64_t clip) {
  if (!player) return CLOTHRT_ERR_INVALID;
  clothrt::Db& db = *player->impl.db;
  auto it = db.primary_by_id.find(clip);
  if (it == db.primary_by_id.end()) {
    player->impl.error.set(clothrt::Status::NotFound, "set_next: no primary clip %lld",
                           (long long)clip);
    return CLOTHRT_ERR_NOT_FOUND;
  }
  return player->impl.set_next(it->second);
}

int clothrt_player_set_random(clothrt_player* player, int enabled, uint64_t seed) {
  if (!player) return CLOTHRT_ERR_INVALID;
  player->impl.set_random(enabled != 0, seed);
  return CLOTHRT_OK;
}

int clothrt_player_advance(clothrt_player* player, double dt_seconds) {
  if (!player) return CLOTHRT_ERR_INVALID;
  return player->impl.advance(dt_seconds);
}

int clothrt_player_get_positions(clothrt_player* player, float* out, size_t stride_bytes,
                                 const float* root_transform) {
  if (!player) return CLOTHRT_ERR_INVALID;
  return player->impl.positions(out, stride_bytes, root_transform);
}

int clothrt_player_get_render_mesh(clothrt_player* player, const clothrt_render_output* out,
                                   const float* root_transform) {
  if (!player) return CLOTHRT_ERR_INVALID;
  if (!out) {
    player->impl.error.set(clothdb::Status::InvalidArgument, "get_render_mesh: output is NULL");
    return CLOTHRT_ERR_INVALID;
  }
  return player->impl.render(*out, root_transform);
}

int clothrt_player_info(const clothrt_player* player, clothrt_frame_info* out) {
  if (!player || !out) return CLOTHRT_ERR_INVALID;
  player->impl.info(out);
  return CLOTHRT_OK;
}

}  // extern "C"
