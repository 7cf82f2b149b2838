// The database handle: the graph index built at open, the shared cache of decoded clips, and the
// jobs (decoding, nearest-state searches) that background threads or callers run.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <new>
#include <numeric>

#include "database/format/bases.hpp"
#include "database/format/cloth_graph.hpp"
#include "database/format/graph_index.hpp"
#include "internal.hpp"

namespace clothrt {

namespace {

using Clock = std::chrono::steady_clock;

uint64_t ns_since(Clock::time_point t) {
  return uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now() - t).count());
}

// Decoded floats back to the codec's integers. The decoder produced x = origin + q * step, so
// (x - origin) / step is within float rounding of an integer and rounds back to q exactly.
void repack(const float* x, size_t n, const float origin[3], float step, uint16_t* q) {
  const float inv = 1.0f / step;
  float base[12];
  for (int j = 0; j < 12; ++j) base[j] = origin[j % 3];
  size_t i = 0;
  for (; i + 12 <= n; i += 12)
    for (size_t j = 0; j < 12; ++j) {
      const float v = (x[i + j] - base[j]) * inv + 0.5f;
      q[i + j] = uint16_t(std::clamp(v, 0.0f, 65535.0f));
    }
  for (; i < n; ++i) {
    const float v = (x[i] - base[i % 12]) * inv + 0.5f;
    q[i] = uint16_t(std::clamp(v, 0.0f, 65535.0f));
  }
}

// The triangles around each vertex as compressed rows, ascending (a counting sort over the
// corners, so a triangle that names a vertex twice is listed twice, as a scatter would add it),
// only those `keep` accepts. Each entry is the triangle's offset in a buffer of `row_floats` floats
// per triangle; each vertex's list is padded to an even length with the row after the last
// triangle (n * row_floats), which the player keeps at zero: adding +0 to a sum that started at +0
// changes no bit, and pairs let the gather loop run two rows per turn. Indices were checked
// against `vertices` by the caller.
template <typename Keep>
void adjacency(const std::vector<uint32_t>& tri, uint32_t vertices, Keep keep, uint32_t row_floats,
               std::vector<uint32_t>* begin, std::vector<uint32_t>* faces) {
  const size_t n = tri.size() / 3;
  std::vector<uint32_t> count(vertices, 0);
  for (size_t t = 0; t < n; ++t)
    if (keep(t))
      for (int k = 0; k < 3; ++k) ++count[tri[3 * t + size_t(k)]];
  begin->assign(size_t(vertices) + 1, 0);
  for (size_t v = 0; v < vertices; ++v) (*begin)[v + 1] = (*begin)[v] + (count[v] + 1) / 2 * 2;
  faces->assign((*begin)[vertices], uint32_t(n) * row_floats);
  std::vector<uint32_t> next(begin->begin(), begin->end() - 1);
  for (size_t t = 0; t < n; ++t)
    if (keep(t))
      for (int k = 0; k < 3; ++k)
        (*faces)[next[tri[3 * t + size_t(k)]]++] = uint32_t(t) * row_floats;
}

}  // namespace

int to_code(Status status) {
  switch (status) {
    case Status::Ok:
      return CLOTHRT_OK;
    case Status::InvalidArgument:
    case Status::OutputTooSmall:
      return CLOTHRT_ERR_INVALID;
    case Status::NotClothdb:
      return CLOTHRT_ERR_NOT_CLOTHDB;
    case Status::NewerVersion:
      return CLOTHRT_ERR_VERSION;
    case Status::Truncated:
    case Status::Corrupt:
    case Status::ChecksumMismatch:
      return CLOTHRT_ERR_CORRUPT;
    case Status::NotFound:
      return CLOTHRT_ERR_NOT_FOUND;
    case Status::IoError:
      return CLOTHRT_ERR_IO;
  }
  return CLOTHRT_ERR_CORRUPT;
}

bool allocate_buffer(Buffer* buffer, size_t bytes) {
  void* p = ::operator new(bytes, std::align_val_t(64), std::nothrow);
  if (!p) return false;
  buffer->data = p;
  buffer->capacity = bytes;
  return true;
}

void free_buffer(Buffer* buffer) {
  if (buffer->data) ::operator delete(buffer->data, std::align_val_t(64));
  buffer->data = nullptr;
  buffer->capacity = 0;
}

Db::~Db() {
  {
    std::lock_guard<std::mutex> lk(mu);
    stopping = true;
  }
  work_cv.notify_all();
  for (std::thread& t : workers) t.join();
  for (Entry& e : entries) free_buffer(&e.buffer);
  for (Buffer& b : pool) free_buffer(&b);
}

Status Db::open(const std::string& file, const clothrt_db_options& opts, Error* err) {
  using namespace clothdb::db;
  path = file;
  options = opts;
  if (Status st = reader.open(file, err); st != Status::Ok) return st;
  Garment garment;
  if (Status st = reader.garment(&garment, err); st != Status::Ok) return st;
  vertex_count = garment.vertex_count();
  triangles = std::move(garment.triangles);
  if (vertex_count == 0)
    return err->set(Status::Corrupt, "%s: the garment has no vertices", file.c_str());
  if (vertex_count > clothdb::codec::kMaxVertices)
    return err->set(Status::Corrupt, "%s: garment of %u vertices", file.c_str(), vertex_count);
  // clothrt_db_triangles hands these to the game's index buffer: never an index out of range.
  for (size_t i = 0; i < triangles.size(); ++i)
    if (triangles[i] >= vertex_count)
      return err->set(Status::Corrupt,
                      "%s: garment triangle %zu has vertex index %u (the garment has %u vertices)",
                      file.c_str(), i / 3, triangles[i], vertex_count);

  // The render mesh: the artist's (checked by the reader against the garment) or, for a
  // procedural garment, the simulation mesh itself.
  {
    ArtistMesh artist;
    if (Status st = reader.artist_mesh(&artist, err); st != Status::Ok) return st;
    render_vertex_count = artist.render_vertex_count();
    render_triangles = std::move(artist.render_triangles);
    render_sim.resize(size_t(render_vertex_count) * 3);
    render_weights.resize(size_t(render_vertex_count) * 3);
    render_source.resize(render_vertex_count);
    const bool uvs = !artist.uvs.empty();
    if (uvs) render_uvs.assign(size_t(render_vertex_count) * 2, 0.0f);
    for (uint32_t r = 0; r < render_vertex_count; ++r) {
      const uint32_t v = artist.render_vertices[3 * r], uv = artist.render_vertices[3 * r + 1];
      render_source[r] = v;
      for (size_t k = 0; k < 3; ++k) {
        render_sim[3 * r + k] = artist.map_vertices[3 * size_t(v) + k];
        render_weights[3 * r + k] = artist.map_weights[3 * size_t(v) + k];
      }
      all_indexed = all_indexed && render_weights[3 * r] == 1.0f;
      if (uvs && uv != kNoAttribute) {
        render_uvs[2 * r] = artist.uvs[2 * size_t(uv)];
        render_uvs[2 * r + 1] = artist.uvs[2 * size_t(uv) + 1];
      }
    }
  }

  // The triangles around each vertex (internal.hpp, vertex_faces): simulation mesh, and with UVs
  // the render triangles that carry a tangent.
  adjacency(
      triangles, vertex_count, [](size_t) { return true; }, 4, &vertex_faces_begin, &vertex_faces);
  if (!render_uvs.empty()) {
    const size_t rt = render_triangles.size() / 3;
    render_uv_edges.resize(rt * 5);
    for (size_t t = 0; t < rt; ++t) {
      const uint32_t* i = &render_triangles[3 * t];
      const float* uv = render_uvs.data();
      float* e = &render_uv_edges[5 * t];
      e[0] = uv[2 * i[1]] - uv[2 * i[0]];
      e[1] = uv[2 * i[1] + 1] - uv[2 * i[0] + 1];
      e[2] = uv[2 * i[2]] - uv[2 * i[0]];
      e[3] = uv[2 * i[2] + 1] - uv[2 * i[0] + 1];
      const float det = e[0] * e[3] - e[2] * e[1];
      e[4] = det == 0 ? 0.0f : 1.0f / det;
    }
    // A triangle degenerate in UV space contributes no tangent.
    adjacency(
        render_triangles, render_vertex_count,
        [&](size_t t) { return render_uv_edges[5 * t + 4] != 0; }, 8, &render_faces_begin,
        &render_faces);
  }

  // Codec version 2 bases: every blob that names one decodes with it (normally one per file).
  std::vector<BasisRow> basis_rows;
  if (Status st = list_bases(reader.handle(), file, &basis_rows, err); st != Status::Ok) return st;
  bases.resize(basis_rows.size());
  for (size_t i = 0; i < basis_rows.size(); ++i)
    if (Status st = load_basis(reader.handle(), file, basis_rows[i].id, &bases[i], err);
        st != Status::Ok)
      return st;

  GraphRows rows;
  if (Status st = rows.read(reader, err); st != Status::Ok) return st;
  if (rows.primary_clips.empty())
    return err->set(Status::NotFound, "%s: no primary clips", file.c_str());
  if (rows.clips.empty()) return err->set(Status::NotFound, "%s: no cloth clips", file.c_str());
  // The graph's rules (database/format/graph_index.hpp): the first broken one refuses the file.
  GraphIndex index;
  if (!index.build(rows, [&](const GraphFinding& f) {
        err->set(Status::Corrupt, "%s: %s %s", file.c_str(), f.kind, f.message.c_str());
        return false;
      }))
    return Status::Corrupt;

  const int np = int(index.primaries.size());
  primaries.resize(size_t(np));
  for (int i = 0; i < np; ++i) {
    const GraphIndex::Primary& g = index.primaries[size_t(i)];
    PrimaryInfo& p = primaries[size_t(i)];
    p.id = g.id;
    p.name = rows.primary_clips[size_t(i)].name;
    p.frames = g.frames;
    p.rate = g.rate;
    p.src_node = g.src_node;
    p.tgt_node = g.tgt_node;
    p.succ_begin = uint32_t(successors.size());
    successors.insert(successors.end(), g.successors.begin(), g.successors.end());
    p.succ_end = uint32_t(successors.size());
    max_successors = std::max(max_successors, p.succ_end - p.succ_begin);
  }
  primary_by_id = index.primary_by_id;
  clip_by_id = index.clip_by_id;
  states.resize(index.states.size());
  for (size_t i = 0; i < states.size(); ++i)
    states[i] = {index.states[i].id, index.states[i].primary};
  clips.resize(index.clips.size());
  for (size_t i = 0; i < clips.size(); ++i) {
    const GraphIndex::Clip& g = index.clips[i];
    clips[i].id = g.id;
    clips[i].state = g.state;
    clips[i].primary = g.primary;
    clips[i].frames = g.frames;
    clips[i].to_state = g.to_state;
    clips[i].blend_error = g.blend_error;
  }

  // Clips along each primary clip, by start state id (states are listed in id order, clips too).
  std::vector<std::vector<int>> along(static_cast<size_t>(np));
  std::unordered_map<uint64_t, int> by_state_primary;
  for (size_t i = 0; i < clips.size(); ++i) {
    along[size_t(clips[i].primary)].push_back(int(i));
    by_state_primary.emplace(uint64_t(clips[i].state) << 32 | uint32_t(clips[i].primary), int(i));
  }
  for (int i = 0; i < np; ++i) {
    std::vector<int>& a = along[size_t(i)];
    std::stable_sort(a.begin(), a.end(),
                     [&](int x, int y) { return clips[size_t(x)].state < clips[size_t(y)].state; });
    primaries[size_t(i)].cand_begin = uint32_t(candidates.size());
    candidates.insert(candidates.end(), a.begin(), a.end());
    primaries[size_t(i)].cand_end = uint32_t(candidates.size());
  }

  // A dead end's precomputed continuation (schema 4, ClothLink): state and primary clip -> the
  // clip to take and the blend it needs.
  std::unordered_map<uint64_t, std::pair<int, double>> link_of;
  for (const GraphIndex::Link& l : index.links)
    link_of[uint64_t(l.state) << 32 | uint32_t(l.primary)] = {l.clip, l.blend_error};

  // Slots: where each clip continues for each successor, known now unless a fallback search is
  // needed.
  for (ClipInfo& c : clips) {
    c.slot_begin = uint32_t(slot_count);
    const PrimaryInfo& p = primaries[size_t(c.primary)];
    slot_count += p.succ_end - p.succ_begin;
  }
  slots.reset(new std::atomic<int32_t>[slot_count == 0 ? 1 : slot_count]);
  slot_blend.assign(slot_count, 0.0f);
  for (const ClipInfo& c : clips) {
    const PrimaryInfo& p = primaries[size_t(c.primary)];
    for (uint32_t k = 0; k < p.succ_end - p.succ_begin; ++k) {
      const int b = successors[p.succ_begin + k];
      int32_t v = kSlotUnresolved;
      const PrimaryInfo& pb = primaries[size_t(b)];
      if (pb.cand_begin == pb.cand_end) {
        v = kSlotNone;
      } else if (c.to_state >= 0) {
        const uint64_t key = uint64_t(c.to_state) << 32 | uint32_t(b);
        auto it = by_state_primary.find(key);
        if (it != by_state_primary.end()) {
          v = int32_t(it->second) << 1;
        } else if (auto l = link_of.find(key); l != link_of.end()) {
          v = int32_t(l->second.first) << 1;
          slot_blend[c.slot_begin + k] = float(l->second.second);
        }
      }
      slots[c.slot_begin + k].store(v, std::memory_order_relaxed);
    }
  }

  // The start clip (database/cloth_graph.hpp: the start-clip rule and how meta holds it).
  start_primary = 0;
  std::string start;
  Error ignore;
  if (reader.meta(clothdb::db::meta::kStartClip, &start, &ignore) == Status::Ok) {
    const int i = clothdb::db::parse_start_clip(start, rows.primary_clips);
    if (i >= 0) start_primary = i;
  }

  entries.resize(clips.size());
  queue.assign(clips.size() + slot_count + 1, 0);
  queue_seen.assign(clips.size(), 0);
  pool.reserve(clips.size());
  players.reserve(64);
  metadata_bytes =
      primaries.size() * sizeof(PrimaryInfo) + successors.size() * sizeof(int) +
      candidates.size() * sizeof(int) + states.size() * sizeof(StateInfo) +
      clips.size() * (sizeof(ClipInfo) + sizeof(Entry)) +
      slot_count * (sizeof(int32_t) + sizeof(float)) + queue.size() * sizeof(int64_t) +
      triangles.size() * sizeof(uint32_t) +
      (render_triangles.size() + render_sim.size() + render_source.size()) * sizeof(uint32_t) +
      (render_weights.size() + render_uvs.size()) * sizeof(float) +
      (vertex_faces_begin.size() + vertex_faces.size() + render_faces_begin.size() +
       render_faces.size()) *
          sizeof(uint32_t) +
      render_uv_edges.size() * sizeof(float) + (primary_by_id.size() + clip_by_id.size()) * 32;
  for (const PrimaryInfo& p : primaries) metadata_bytes += p.name.size();
  for (const auto& b : bases) metadata_bytes += b.memory_bytes();

  sync_loader.reader = &reader;
  const int threads = std::clamp(options.prefetch_threads, 0, 8);
  for (int i = 0; i < threads; ++i) {
    auto r = std::make_unique<Reader>();
    if (Status st = r->open(file, err); st != Status::Ok) return st;
    auto l = std::make_unique<Loader>();
    l->reader = r.get();
    worker_readers.push_back(std::move(r));
    worker_loaders.push_back(std::move(l));
  }
  for (auto& l : worker_loaders) workers.emplace_back([this, p = l.get()] { worker_main(p); });
  return Status::Ok;
}

void Db::set_error(const Error& e) {
  std::lock_guard<std::mutex> lk(error_mu);
  error = e;
}

// ---- cache ----------------------------------------------------------------------------------

void Db::lru_remove(int c) {
  Entry& e = entries[size_t(c)];
  if (!e.in_lru) return;
  if (e.lru_prev >= 0)
    entries[size_t(e.lru_prev)].lru_next = e.lru_next;
  else
    lru_head = e.lru_next;
  if (e.lru_next >= 0)
    entries[size_t(e.lru_next)].lru_prev = e.lru_prev;
  else
    lru_tail = e.lru_prev;
  e.lru_prev = e.lru_next = -1;
  e.in_lru = false;
}

void Db::lru_push_front(int c) {
  Entry& e = entries[size_t(c)];
  lru_remove(c);
  e.lru_next = lru_head;
  e.lru_prev = -1;
  if (lru_head >= 0) entries[size_t(lru_head)].lru_prev = c;
  lru_head = c;
  if (lru_tail < 0) lru_tail = c;
  e.in_lru = true;
}

void Db::trim_to_cap() {
  while (cache_bytes > options.cache_bytes && !pool.empty()) {
    cache_bytes -= pool.back().capacity;
    free_buffer(&pool.back());
    pool.pop_back();
  }
  for (int c = lru_tail; c >= 0 && cache_bytes > options.cache_bytes;) {
    Entry& e = entries[size_t(c)];
    const int prev = e.lru_prev;
    if (e.pins == 0) {
      lru_remove(c);
      e.state = EntryState::Absent;
      cache_bytes -= e.buffer.capacity;
      free_buffer(&e.buffer);
      e.bytes = 0;
      evictions.fetch_add(1, std::memory_order_relaxed);
    }
    c = prev;
  }
}

bool Db::take_buffer(size_t bytes, Buffer* out) {
  auto take_fitting = [&]() {
    int best = -1;
    for (size_t i = 0; i < pool.size(); ++i)
      if (pool[i].capacity >= bytes && (best < 0 || pool[i].capacity < pool[size_t(best)].capacity))
        best = int(i);
    if (best < 0) return false;
    *out = pool[size_t(best)];
    pool[size_t(best)] = pool.back();
    pool.pop_back();
    return true;
  };
  if (take_fitting()) return true;
  // Evict least recently used clips nobody is playing; their buffers may fit this clip.
  for (int c = lru_tail; c >= 0 && cache_bytes + bytes > options.cache_bytes;) {
    Entry& e = entries[size_t(c)];
    const int prev = e.lru_prev;
    if (e.pins == 0) {
      lru_remove(c);
      e.state = EntryState::Absent;
      e.bytes = 0;
      evictions.fetch_add(1, std::memory_order_relaxed);
      pool.push_back(e.buffer);
      e.buffer = Buffer{};
      if (take_fitting()) return true;
    }
    c = prev;
  }
  while (cache_bytes + bytes > options.cache_bytes && !pool.empty()) {
    cache_bytes -= pool.back().capacity;
    free_buffer(&pool.back());
    pool.pop_back();
  }
  if (!allocate_buffer(out, bytes)) return false;
  cache_bytes += bytes;
  return true;
}

Status Db::load(int clip, Loader& loader, Error* err) {
  // Growing a loader buffer is the only thing here that can throw; a throw must not leave the
  // entry Loading forever.
  try {
    const Status st = load_impl(clip, loader, err);
    // Codec errors name neither the file nor the clip: say which clip of which file is damaged.
    if (st != Status::Ok && std::strncmp(err->message, path.c_str(), path.size()) != 0) {
      char what[sizeof err->message];
      std::snprintf(what, sizeof what, "%s", err->message);
      err->set(st, "%s: cloth clip %lld: %s", path.c_str(), (long long)clips[size_t(clip)].id,
               what);
    }
    return st;
  } catch (const std::bad_alloc&) {
    return err->set(Status::IoError, "%s: out of memory decoding cloth clip %lld", path.c_str(),
                    (long long)clips[size_t(clip)].id);
  }
}

Status Db::load_impl(int clip, Loader& loader, Error* err) {
  const ClipInfo& ci = clips[size_t(clip)];
  Entry& entry = entries[size_t(clip)];
  auto t0 = Clock::now();
  Status st = loader.reader->clip_blob(ci.id, &loader.blob, err);
  sqlite_ns.fetch_add(ns_since(t0), std::memory_order_relaxed);
  if (st != Status::Ok) return st;
  clothdb::codec::BlobInfo info;
  if ((st = clothdb::codec::read_info(loader.blob.data(), loader.blob.size(), &info, err)) !=
      Status::Ok)
    return st;
  if (info.vertex_count != vertex_count || info.frame_count != uint32_t(ci.frames))
    return err->set(Status::Corrupt,
                    "%s: cloth clip %lld holds %u frames of %u vertices, expected %d of %u",
                    path.c_str(), (long long)ci.id, info.frame_count, info.vertex_count, ci.frames,
                    vertex_count);
  // Frames on a grid (a per-coordinate bound: versions 1 and 2) of at most 65536 steps per axis are
  // kept as uint16; a blob within an error contract instead (bound 0: version 3) has no grid.
  const bool quantised =
      info.bound > 0 && info.qmax[0] <= 65535 && info.qmax[1] <= 65535 && info.qmax[2] <= 65535;
  const size_t n = size_t(vertex_count) * 3;
  const size_t floats = n * info.frame_count;
  const size_t bytes = floats * (quantised ? sizeof(uint16_t) : sizeof(float));
  {
    std::lock_guard<std::mutex> lk(mu);
    if (entry.buffer.capacity < bytes) {
      if (entry.buffer.data) pool.push_back(entry.buffer);
      entry.buffer = Buffer{};
      if (!take_buffer(bytes, &entry.buffer))
        return err->set(Status::IoError, "%s: out of memory for cloth clip %lld (%zu bytes)",
                        path.c_str(), (long long)ci.id, bytes);
    }
  }
  ClipView view;
  view.quantised = quantised;
  view.frames = info.frame_count;
  view.data = entry.buffer.data;
  if (!quantised) {
    t0 = Clock::now();
    st = clothdb::codec::decode_frames(loader.blob.data(), loader.blob.size(), 0, info.frame_count,
                                       static_cast<float*>(entry.buffer.data), floats,
                                       loader.scratch, err, basis_for(info));
    decode_ns.fetch_add(ns_since(t0), std::memory_order_relaxed);
    if (st != Status::Ok) return st;
  } else {
    for (int a = 0; a < 3; ++a) view.origin[a] = float(info.origin[a]);
    view.step = float(info.step);
    // Decode one key-frame chunk at a time (each chunk is decoded from its key frame once), then
    // repack it, so the float staging buffer stays one chunk long.
    const uint32_t k = std::max<uint32_t>(1, info.key_interval);
    loader.chunk.resize(size_t(k) * n);
    uint16_t* q = static_cast<uint16_t*>(entry.buffer.data);
    for (uint32_t f = 0; f < info.frame_count; f += k) {
      const uint32_t count = std::min(k, info.frame_count - f);
      t0 = Clock::now();
      st = clothdb::codec::decode_frames(loader.blob.data(), loader.blob.size(), f, count,
                                         loader.chunk.data(), loader.chunk.size(), loader.scratch,
                                         err, basis_for(info));
      decode_ns.fetch_add(ns_since(t0), std::memory_order_relaxed);
      if (st != Status::Ok) return st;
      t0 = Clock::now();
      repack(loader.chunk.data(), size_t(count) * n, view.origin, view.step, q + size_t(f) * n);
      repack_ns.fetch_add(ns_since(t0), std::memory_order_relaxed);
    }
  }
  entry.view = view;
  entry.bytes = bytes;
  return Status::Ok;
}

void Db::push_job(int64_t job) {
  // A clip is queued only while Queued and a slot only while Resolving, so live jobs never exceed
  // clips + slots, one less than the ring. Jobs a caller took over by decoding the clip itself
  // stay in the ring until popped; if they ever fill it, drop them.
  if (queue_size == queue.size()) {
    size_t kept = 0;
    std::fill(queue_seen.begin(), queue_seen.end(), 0);
    for (size_t i = 0; i < queue_size; ++i) {
      const int64_t j = queue[(queue_head + i) % queue.size()];
      if (j >= 0 && (entries[size_t(j)].state != EntryState::Queued || queue_seen[size_t(j)]))
        continue;
      if (j >= 0) queue_seen[size_t(j)] = 1;
      queue[(queue_head + kept++) % queue.size()] = j;
    }
    queue_size = kept;
  }
  queue[(queue_head + queue_size) % queue.size()] = job;
  ++queue_size;
  queued.store(queue_size, std::memory_order_relaxed);
}

bool Db::pop_job(int64_t* job) {
  if (queue_size == 0) return false;
  *job = queue[queue_head];
  queue_head = (queue_head + 1) % queue.size();
  --queue_size;
  queued.store(queue_size, std::memory_order_relaxed);
  return true;
}

void Db::pin(int clip) {
  std::lock_guard<std::mutex> lk(mu);
  Entry& e = entries[size_t(clip)];
  ++e.pins;
  if (e.state == EntryState::Absent) {
    e.state = EntryState::Queued;
    push_job(clip);
    work_cv.notify_one();
  } else if (e.state == EntryState::Ready) {
    lru_push_front(clip);
  }
}

void Db::unpin(int clip) {
  std::lock_guard<std::mutex> lk(mu);
  --entries[size_t(clip)].pins;
}

Status Db::acquire(int clip, ClipView* view, bool* stalled, Error* err) {
  std::unique_lock<std::mutex> lk(mu);
  Entry& e = entries[size_t(clip)];
  ++e.pins;
  for (;;) {
    switch (e.state) {
      case EntryState::Ready:
        lru_push_front(clip);
        *view = e.view;
        return Status::Ok;
      case EntryState::Failed:
        --e.pins;
        return err->set(e.failure, "%s: cloth clip %lld cannot be played: %s", path.c_str(),
                        (long long)clips[size_t(clip)].id, clothdb::status_name(e.failure));
      case EntryState::Absent:
      case EntryState::Queued: {
        // Nobody is decoding it yet (a queued job finds it taken and skips it): do it here.
        *stalled = true;
        e.state = EntryState::Loading;
        lk.unlock();
        Error load_err;
        Status st;
        {
          std::lock_guard<std::mutex> io(io_mu);
          st = load(clip, sync_loader, &load_err);
        }
        lk.lock();
        finish_load(clip, st);
        if (st != Status::Ok) {
          --e.pins;
          loaded_cv.notify_all();
          *err = load_err;
          return st;
        }
        loaded_cv.notify_all();
        break;
      }
      case EntryState::Loading:
        *stalled = true;
        loaded_cv.wait(lk);
        break;
    }
  }
}

void Db::finish_load(int clip, Status st) {
  Entry& e = entries[size_t(clip)];
  if (st == Status::Ok) {
    e.state = EntryState::Ready;
    loads.fetch_add(1, std::memory_order_relaxed);
    lru_push_front(clip);
    trim_to_cap();
  } else {
    e.state = EntryState::Failed;
    e.failure = st;
    failures.fetch_add(1, std::memory_order_relaxed);
    if (e.buffer.data) pool.push_back(e.buffer);
    e.buffer = Buffer{};
  }
}

void Db::run_job(int64_t job, Loader& loader) {
  if (job >= 0) {
    const int clip = int(job);
    Entry& e = entries[size_t(clip)];
    {
      std::lock_guard<std::mutex> lk(mu);
      if (e.state != EntryState::Queued) return;
      e.state = EntryState::Loading;
    }
    Error err;
    const Status st = load(clip, loader, &err);
    std::lock_guard<std::mutex> lk(mu);
    finish_load(clip, st);
    loaded_cv.notify_all();
    return;
  }
  const size_t slot = size_t(~job);
  // The clip owning the slot: slots are laid out clip by clip.
  auto it = std::upper_bound(clips.begin(), clips.end(), slot,
                             [](size_t s, const ClipInfo& c) { return s < c.slot_begin; });
  const int clip = int(it - clips.begin()) - 1;
  const int32_t v = search_nearest(clip, uint32_t(slot - clips[size_t(clip)].slot_begin), loader);
  std::lock_guard<std::mutex> lk(mu);
  slots[slot].store(v, std::memory_order_release);
  loaded_cv.notify_all();
}

int32_t Db::search_nearest(int clip, uint32_t k, Loader& loader) {
  try {
    return search_impl(clip, k, loader);
  } catch (const std::bad_alloc&) {
    // Without memory to compare states, the first state with cloth along the edge will do.
    const ClipInfo& c = clips[size_t(clip)];
    const PrimaryInfo& next =
        primaries[size_t(successors[primaries[size_t(c.primary)].succ_begin + k])];
    return next.cand_begin == next.cand_end ? kSlotNone
                                            : int32_t(candidates[next.cand_begin]) << 1 | 1;
  }
}

int32_t Db::search_impl(int clip, uint32_t k, Loader& loader) {
  const ClipInfo& c = clips[size_t(clip)];
  const PrimaryInfo& next =
      primaries[size_t(successors[primaries[size_t(c.primary)].succ_begin + k])];
  if (next.cand_begin == next.cand_end) return kSlotNone;
  fallbacks.fetch_add(1, std::memory_order_relaxed);
  int best = candidates[next.cand_begin];
  if (next.cand_end - next.cand_begin == 1) return int32_t(best) << 1 | 1;
  const size_t n = size_t(vertex_count) * 3;
  Error err;
  auto t0 = Clock::now();
  // The state the cloth is in: the edge's target, or (a dead-end clip) the clip's own end with the
  // velocity of its last frame.
  bool have_reference = false;
  if (c.to_state >= 0) {
    have_reference =
        read_state(loader, states[size_t(c.to_state)].id, &loader.x, &loader.v, &err) == Status::Ok;
  } else if (loader.reader->clip_blob(c.id, &loader.blob, &err) == Status::Ok) {
    loader.chunk.resize(2 * n);
    clothdb::codec::BlobInfo info;
    have_reference =
        clothdb::codec::read_info(loader.blob.data(), loader.blob.size(), &info, &err) ==
            Status::Ok &&
        clothdb::codec::decode_frames(
            loader.blob.data(), loader.blob.size(), uint32_t(c.frames - 2), 2, loader.chunk.data(),
            loader.chunk.size(), loader.scratch, &err, basis_for(info)) == Status::Ok;
    if (have_reference) {
      const double rate = primaries[size_t(c.primary)].rate;
      loader.x.assign(loader.chunk.begin() + ptrdiff_t(n), loader.chunk.end());
      loader.v.resize(n);
      for (size_t i = 0; i < n; ++i)
        loader.v[i] = float((loader.chunk[n + i] - loader.chunk[i]) * rate);
    }
  }
  if (have_reference && loader.x.size() == n && loader.v.size() == n) {
    const double tau = 1.0 / next.rate;
    double best_d = INFINITY;
    for (uint32_t i = next.cand_begin; i < next.cand_end; ++i) {
      const int cand = candidates[i];
      if (read_state(loader, states[size_t(clips[size_t(cand)].state)].id, &loader.sx, &loader.sv,
                     &err) != Status::Ok ||
          loader.sx.size() != n || loader.sv.size() != n)
        continue;
      const double d = clothdb::db::state_distance(loader.x, loader.v, loader.sx, loader.sv, tau);
      if (d < best_d) {
        best_d = d;
        best = cand;
      }
    }
  }
  sqlite_ns.fetch_add(ns_since(t0), std::memory_order_relaxed);
  return int32_t(best) << 1 | 1;
}

const clothdb::codec::Basis* Db::basis_for(const clothdb::codec::BlobInfo& info) const {
  for (const auto& b : bases)
    if (b.id == info.basis_id) return &b;
  return nullptr;  // version 1, or a basis the file lacks: the decoder says which
}

Status Db::read_state(Loader& loader, int64_t state, std::vector<float>* x, std::vector<float>* v,
                      Error* err) {
  if (Status st = loader.reader->state_blobs(state, &loader.pos_blob, &loader.vel_blob, err);
      st != Status::Ok)
    return st;
  for (auto [blob, out] : {std::pair{&loader.pos_blob, x}, std::pair{&loader.vel_blob, v}}) {
    clothdb::codec::BlobInfo info;
    if (Status st = clothdb::codec::read_info(blob->data(), blob->size(), &info, err);
        st != Status::Ok)
      return st;
    if (Status st = clothdb::codec::decode_all(blob->data(), blob->size(), *out, loader.scratch,
                                               err, basis_for(info));
        st != Status::Ok)
      return st;
  }
  return Status::Ok;
}

int32_t Db::resolve_now(int clip, uint32_t k) {
  std::atomic<int32_t>& slot = slots[clips[size_t(clip)].slot_begin + k];
  for (;;) {
    int32_t v = slot.load(std::memory_order_acquire);
    if (v >= 0 || v == kSlotNone) return v;
    if (v == kSlotUnresolved && slot.compare_exchange_strong(v, kSlotResolving)) {
      int32_t r;
      {
        std::lock_guard<std::mutex> io(io_mu);
        r = search_nearest(clip, k, sync_loader);
      }
      std::lock_guard<std::mutex> lk(mu);
      slot.store(r, std::memory_order_release);
      loaded_cv.notify_all();
      return r;
    }
    // Queued or under way elsewhere. Without prefetch threads nobody else may get to it: run
    // queued jobs here until it is done.
    if (workers.empty() && queued.load(std::memory_order_relaxed) > 0) {
      service_one();
      continue;
    }
    std::unique_lock<std::mutex> lk(mu);
    loaded_cv.wait_for(lk, std::chrono::milliseconds(1), [&] {
      const int32_t w = slot.load(std::memory_order_acquire);
      return w >= 0 || w == kSlotNone;
    });
  }
}

void Db::request_resolve(int clip, uint32_t k) {
  const size_t s = clips[size_t(clip)].slot_begin + k;
  int32_t expected = kSlotUnresolved;
  if (!slots[s].compare_exchange_strong(expected, kSlotResolving)) return;
  std::lock_guard<std::mutex> lk(mu);
  push_job(~int64_t(s));
  work_cv.notify_one();
}

void Db::service_one() {
  if (queued.load(std::memory_order_relaxed) == 0) return;
  int64_t job;
  {
    std::lock_guard<std::mutex> lk(mu);
    if (!pop_job(&job)) return;
  }
  std::lock_guard<std::mutex> io(io_mu);
  run_job(job, sync_loader);
}

void Db::worker_main(Loader* loader) {
  for (;;) {
    int64_t job;
    {
      std::unique_lock<std::mutex> lk(mu);
      work_cv.wait(lk, [&] { return stopping || queue_size > 0; });
      if (stopping) return;
      pop_job(&job);
    }
    run_job(job, *loader);
  }
}

void Db::fill_stats(clothrt_stats* out) {
  std::memset(out, 0, sizeof *out);
  std::lock_guard<std::mutex> lk(mu);
  out->cache_bytes = cache_bytes;
  out->cache_cap = options.cache_bytes;
  out->metadata_bytes = metadata_bytes;
  for (const Entry& e : entries) out->clips_cached += e.state == EntryState::Ready;
  out->clip_loads = loads.load();
  out->clip_evictions = evictions.load();
  out->load_failures = failures.load();
  out->stalls = stalls.load();
  out->fallbacks_resolved = fallbacks.load();
  out->sqlite_ns = sqlite_ns.load();
  out->decode_ns = decode_ns.load();
  out->repack_ns = repack_ns.load();
  out->sample_ns = retired_sample_ns.load();
  out->transition_ns = retired_transition_ns.load();
  out->frames_sampled = retired_frames.load();
  for (const Player* p : players) {
    out->sample_ns += p->sample_ns.load(std::memory_order_relaxed);
    out->transition_ns += p->transition_ns.load(std::memory_order_relaxed);
    out->frames_sampled += p->frames.load(std::memory_order_relaxed);
  }
}

void Db::reset_stats() {
  std::lock_guard<std::mutex> lk(mu);
  for (auto* a : {&loads, &evictions, &failures, &stalls, &fallbacks, &sqlite_ns, &decode_ns,
                  &repack_ns, &retired_sample_ns, &retired_transition_ns, &retired_frames})
    a->store(0);
  for (Player* p : players) {
    p->sample_ns.store(0);
    p->transition_ns.store(0);
    p->frames.store(0);
  }
}

}  // namespace clothrt
