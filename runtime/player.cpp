// A player: follows the game's path through the primary graph and the secondary cloth graph,
// blends at transitions into different states, and samples the cloth at any time.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>

#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include "internal.hpp"

namespace clothrt {

namespace {

using Clock = std::chrono::steady_clock;

// Blend length from a link's blend error (docs/DATABASE.md, "Dead ends and links"): a transition
// through a precomputed link (ClothLink) whose error exceeds blend_frames x kBlendPerFrame fades
// over error / kBlendPerFrame frames, at most kMaxBlendFrames. Edges linked within epsilon keep the
// player's blend_frames.
constexpr double kBlendPerFrame = 1e-3;  // m of state distance per frame
constexpr double kMaxBlendFrames = 60;

uint64_t ns_since(Clock::time_point t) {
  return uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now() - t).count());
}

// Single-writer counters: only the owning thread adds, the stats reader only loads.
void add(std::atomic<uint64_t>& a, uint64_t v) {
  a.store(a.load(std::memory_order_relaxed) + v, std::memory_order_relaxed);
}

uint64_t splitmix64(uint64_t& s) {
  uint64_t z = (s += 0x9e3779b97f4a7c15ull);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

// One coordinate i of frame f of a decoded clip.
inline float value(const ClipView& v, size_t n, size_t f, size_t i) {
  if (v.quantised)
    return v.origin[i % 3] + v.step * float(static_cast<const uint16_t*>(v.data)[f * n + i]);
  return static_cast<const float*>(v.data)[f * n + i];
}

// The per-frame kernels: out = frame(t) [+ r * offset]. Coordinates are interleaved x, y, z, so
// the loops run over blocks of 12 floats (4 vertices) with the per-axis origin as a constant
// pattern, which the compiler turns into straight vector code.
// Built for AVX2 as well as the x86-64 baseline, picked at load time: the loops are bound by
// conversions and loads, which AVX2 does twice as wide.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define CLOTHRT_MULTIVERSION __attribute__((target_clones("avx2", "default")))
#else
#define CLOTHRT_MULTIVERSION
#endif
// The render pass's 3-vectors as one SSE vector each (part of every x86-64), and two per AVX
// vector where the processor has AVX2 (checked at run time).
#if defined(__SSE2__)
#define CLOTHRT_SSE 1
#else
#define CLOTHRT_SSE 0
#endif
#if CLOTHRT_SSE && defined(__x86_64__) && defined(__GNUC__)
#define CLOTHRT_AVX_DISPATCH 1
#else
#define CLOTHRT_AVX_DISPATCH 0
#endif

template <bool kInterp, bool kBlend>
CLOTHRT_MULTIVERSION void sample_quantised(const uint16_t* __restrict q0,
                                           const uint16_t* __restrict q1, float a,
                                           const float origin[3], float step,
                                           const float* __restrict d, float r,
                                           float* __restrict out, size_t n) {
  float base[12];
  for (int j = 0; j < 12; ++j) base[j] = origin[j % 3];
  auto one = [&](size_t i, float b) {
    float q = float(q0[i]);
    if constexpr (kInterp) q += a * (float(q1[i]) - q);
    float x = b + step * q;
    if constexpr (kBlend) x += r * d[i];
    out[i] = x;
  };
  size_t i = 0;
  for (; i + 12 <= n; i += 12)
    for (size_t j = 0; j < 12; ++j) one(i + j, base[j]);
  for (; i < n; ++i) one(i, base[i % 12]);
}

template <bool kInterp, bool kBlend>
CLOTHRT_MULTIVERSION void sample_floats(const float* __restrict f0, const float* __restrict f1,
                                        float a, const float* __restrict d, float r,
                                        float* __restrict out, size_t n) {
  for (size_t i = 0; i < n; ++i) {
    float x = f0[i];
    if constexpr (kInterp) x += a * (f1[i] - x);
    if constexpr (kBlend) x += r * d[i];
    out[i] = x;
  }
}

template <bool kInterp, bool kBlend>
void sample_view(const ClipView& v, size_t n, size_t f0, size_t f1, float a, const float* d,
                 float r, float* out) {
  if (v.quantised) {
    const uint16_t* q = static_cast<const uint16_t*>(v.data);
    sample_quantised<kInterp, kBlend>(q + f0 * n, q + f1 * n, a, v.origin, v.step, d, r, out, n);
  } else {
    const float* x = static_cast<const float*>(v.data);
    sample_floats<kInterp, kBlend>(x + f0 * n, x + f1 * n, a, d, r, out, n);
  }
}

// World space: out = M * [x y z 1] per vertex, written at a stride.
CLOTHRT_MULTIVERSION void transform(const float* __restrict src, size_t vertices,
                                    const float* __restrict m, float* __restrict out, size_t vs) {
  const float m0 = m[0], m1 = m[1], m2 = m[2], m4 = m[4], m5 = m[5], m6 = m[6], m8 = m[8],
              m9 = m[9], m10 = m[10], m12 = m[12], m13 = m[13], m14 = m[14];
  auto one = [&](size_t v, float* o) {
    const float x = src[3 * v], y = src[3 * v + 1], z = src[3 * v + 2];
    o[0] = m0 * x + m4 * y + m8 * z + m12;
    o[1] = m1 * x + m5 * y + m9 * z + m13;
    o[2] = m2 * x + m6 * y + m10 * z + m14;
  };
  if (vs == 3) {  // packed: a constant stride, which vectorises
    for (size_t v = 0; v < vertices; ++v) one(v, out + 3 * v);
  } else {
    for (size_t v = 0; v < vertices; ++v) one(v, out + v * vs);
  }
}

}  // namespace

Player::Player(Db* d) : db(d) {
  const size_t n = size_t(db->vertex_count) * 3;
  offset_.assign(n, 0.0f);
  local_.assign(n + 1, 0.0f);  // + 1: the render pass reads points as 4 floats
  normals_.assign(n, 0.0f);
  face_normals_.assign((db->triangles.size() / 3 + 1) * 4, 0.0f);
  if (db->all_indexed) {
    world_normals_.assign(n, 0.0f);  // 3 planes
    world_.assign(n, 0.0f);
  }
  if (!db->render_uvs.empty()) {
    face_tangents_.assign((db->render_triangles.size() / 3 + 1) * 8, 0.0f);
    tangents_.assign(size_t(db->render_vertex_count) * 9, 0.0f);
  }
  pinned_.assign(db->max_successors, -1);
  pending_.assign(db->max_successors, 0);
  std::lock_guard<std::mutex> lk(db->mu);
  db->players.push_back(this);
}

Player::~Player() {
  release_prefetch();
  if (clip_ >= 0) db->unpin(clip_);
  std::lock_guard<std::mutex> lk(db->mu);
  db->retired_sample_ns += sample_ns.load();
  db->retired_transition_ns += transition_ns.load();
  db->retired_frames += frames.load();
  db->players.erase(std::find(db->players.begin(), db->players.end(), this));
}

size_t Player::memory() const {
  return sizeof(Player) +
         (offset_.capacity() + local_.capacity() + normals_.capacity() + face_normals_.capacity() +
          world_normals_.capacity() + world_.capacity() + face_tangents_.capacity() +
          tangents_.capacity()) *
             sizeof(float) +
         pinned_.capacity() * sizeof(int) + pending_.capacity();
}

int Player::start_clip(int clip) {
  ClipView v;
  bool stalled = false;
  Error e;
  if (Status st = db->acquire(clip, &v, &stalled, &e); st != Status::Ok) {
    error = e;
    return to_code(st);
  }
  release_prefetch();
  if (clip_ >= 0 && !unloaded_) db->unpin(clip_);
  unloaded_ = false;
  clip_ = clip;
  view_ = v;
  primary_ = db->clips[size_t(clip)].primary;
  t_ = 0;
  r0_ = 0;
  holding_ = fallback_ = false;
  started_ = true;
  next_named_ = false;
  next_k_ = -1;
  if (random_) next_k_ = choose_next();
  return CLOTHRT_OK;
}

int Player::set_next(int primary) {
  if (!started_) {
    error.set(Status::InvalidArgument, "set_next: the player has not been started");
    return CLOTHRT_ERR_INVALID;
  }
  const PrimaryInfo& p = db->primaries[size_t(primary_)];
  for (uint32_t k = 0; k < p.succ_end - p.succ_begin; ++k) {
    if (db->successors[p.succ_begin + k] != primary) continue;
    const PrimaryInfo& b = db->primaries[size_t(primary)];
    if (b.cand_begin == b.cand_end) {
      error.set(Status::NotFound, "set_next: no cloth was precomputed along primary clip %lld",
                (long long)b.id);
      return CLOTHRT_ERR_NOT_FOUND;
    }
    next_k_ = int(k);
    next_named_ = true;
    // Prefetch only what will be played from now on.
    if (prefetch_issued_) {
      release_prefetch();
      issue_prefetch();
    }
    return CLOTHRT_OK;
  }
  error.set(Status::InvalidArgument,
            "set_next: primary clip %lld does not follow primary clip %lld",
            (long long)db->primaries[size_t(primary)].id, (long long)p.id);
  return CLOTHRT_ERR_INVALID;
}

void Player::set_random(bool enabled, uint64_t seed) {
  random_ = enabled;
  rng_ = seed;
  if (started_ && !next_named_) {
    next_k_ = -1;
    if (random_) next_k_ = choose_next();
    if (prefetch_issued_) {
      release_prefetch();
      issue_prefetch();
    }
  }
}

int Player::choose_next() {
  if (next_k_ >= 0) return next_k_;
  const PrimaryInfo& p = db->primaries[size_t(primary_)];
  uint32_t with_cloth = 0;
  for (uint32_t k = p.succ_begin; k < p.succ_end; ++k) {
    const PrimaryInfo& b = db->primaries[size_t(db->successors[k])];
    with_cloth += b.cand_end > b.cand_begin;
  }
  if (with_cloth == 0) return -1;
  uint32_t pick = random_ ? uint32_t(splitmix64(rng_) % with_cloth) : 0;
  for (uint32_t k = p.succ_begin; k < p.succ_end; ++k) {
    const PrimaryInfo& b = db->primaries[size_t(db->successors[k])];
    if (b.cand_end > b.cand_begin && pick-- == 0) return next_k_ = int(k - p.succ_begin);
  }
  return -1;
}

void Player::request(uint32_t k) {
  if (pinned_[k] >= 0 || pending_[k]) return;
  if (holding_) {
    const PrimaryInfo& b =
        db->primaries[size_t(db->successors[db->primaries[size_t(primary_)].succ_begin + k])];
    if (b.cand_begin == b.cand_end) return;
    pinned_[k] = db->candidates[b.cand_begin];
    db->pin(pinned_[k]);
    return;
  }
  const int32_t v =
      db->slots[db->clips[size_t(clip_)].slot_begin + k].load(std::memory_order_acquire);
  if (v >= 0) {
    pinned_[k] = v >> 1;
    db->pin(pinned_[k]);
  } else if (v != kSlotNone) {
    db->request_resolve(clip_, k);
    pending_[k] = 1;
  }
}

void Player::issue_prefetch() {
  prefetch_issued_ = true;
  const PrimaryInfo& p = db->primaries[size_t(primary_)];
  if (next_k_ >= 0) {
    request(uint32_t(next_k_));
    return;
  }
  // Nothing decided yet: everything the game may pick.
  for (uint32_t k = 0; k < p.succ_end - p.succ_begin; ++k) request(k);
}

void Player::poll_prefetch() {
  for (size_t k = 0; k < pending_.size(); ++k) {
    if (!pending_[k]) continue;
    const int32_t v =
        db->slots[db->clips[size_t(clip_)].slot_begin + k].load(std::memory_order_acquire);
    if (v >= 0) {
      pending_[k] = 0;
      pinned_[k] = v >> 1;
      db->pin(pinned_[k]);
    } else if (v == kSlotNone) {
      pending_[k] = 0;
    }
  }
}

void Player::release_prefetch() {
  for (size_t k = 0; k < pinned_.size(); ++k) {
    if (pinned_[k] >= 0) db->unpin(pinned_[k]);
    pinned_[k] = -1;
    pending_[k] = 0;
  }
  prefetch_issued_ = false;
}

int Player::transition() {
  const auto t0 = Clock::now();
  const uint32_t k = uint32_t(next_k_);
  const PrimaryInfo& from = db->primaries[size_t(primary_)];
  const int next_primary = db->successors[from.succ_begin + k];
  const PrimaryInfo& to = db->primaries[size_t(next_primary)];
  const size_t n = size_t(db->vertex_count) * 3;

  int target = -1;
  bool fallback = holding_;
  double blend_error = 0, link_error = 0;
  if (holding_) {
    target = db->candidates[to.cand_begin];
  } else {
    std::atomic<int32_t>& slot = db->slots[db->clips[size_t(clip_)].slot_begin + k];
    int32_t v = slot.load(std::memory_order_acquire);
    if (v < 0 && v != kSlotNone) {
      v = db->resolve_now(clip_, k);
      db->stalls.fetch_add(1, std::memory_order_relaxed);
    }
    if (v >= 0) {
      target = v >> 1;
      fallback = v & 1;
    }
    blend_error = db->clips[size_t(clip_)].blend_error;
    link_error = db->slot_blend[db->clips[size_t(clip_)].slot_begin + k];
    blend_error = std::max(blend_error, link_error);
  }
  ClipView nv;
  bool stalled = false;
  Error e;
  Status st = Status::NotFound;
  if (target >= 0)
    st = db->acquire(target, &nv, &stalled, &e);
  else
    e.set(Status::NotFound, "no cloth along primary clip %lld", (long long)to.id);
  if (stalled) db->stalls.fetch_add(1, std::memory_order_relaxed);

  // The pose at the node, as it would be shown there: the old clip's last frame plus what is left
  // of a blend still in progress (when holding, offset_ is that pose already).
  const double end = double(from.frames - 1);
  const double r_end = r0_ > 0 ? std::max(0.0, r0_ - end / blend_span_) : 0.0;
  const bool blend = st == Status::Ok && (holding_ || fallback || blend_error > 0);
  if (!holding_ && (st != Status::Ok || blend)) {
    const float r = float(r_end);
    const size_t last = size_t(from.frames - 1);
    for (size_t i = 0; i < n; ++i) offset_[i] = value(view_, n, last, i) + r * offset_[i];
  }
  int code = CLOTHRT_OK;
  if (st != Status::Ok) {
    // Keep showing that pose while the primary clip plays on; restart at the next node.
    error = e;
    code = to_code(st);
    if (clip_ >= 0) db->unpin(clip_);
    clip_ = -1;
    holding_ = true;
    fallback_ = false;
    r0_ = 0;
  } else {
    if (blend) {
      // Offset blend: the difference to the new clip's first frame fades out over blend_frames,
      // so the cloth keeps the new clip's motion and never jumps.
      for (size_t i = 0; i < n; ++i) offset_[i] -= value(nv, n, 0, i);
      if (r_end > 0) ++interrupted_;
      r0_ = blend_frames > 0 ? 1.0 : 0.0;
      // A link that closed a dead end (up to the garment's error floor away) fades over more
      // frames, so that no frame moves the cloth by much more than kBlendPerFrame of it.
      blend_span_ =
          std::max({blend_frames, 1e-9, std::min(kMaxBlendFrames, link_error / kBlendPerFrame)});
    } else {
      // Same state: nothing to blend, but a blend still in progress carries on across the node.
      if (r_end > 0) ++interrupted_;
      r0_ = r_end;
    }
    if (clip_ >= 0) db->unpin(clip_);
    clip_ = target;
    view_ = nv;
    holding_ = false;
    fallback_ = fallback;
    fallbacks_ += fallback;
  }
  release_prefetch();
  ++transitions_;
  primary_ = next_primary;
  next_k_ = -1;
  next_named_ = false;
  if (random_) choose_next();
  add(transition_ns, ns_since(t0));
  return code;
}

bool Player::pass_node() {
  const uint32_t k = uint32_t(next_k_);
  const PrimaryInfo& from = db->primaries[size_t(primary_)];
  const int next_primary = db->successors[from.succ_begin + k];
  const PrimaryInfo& to = db->primaries[size_t(next_primary)];
  int target = -1;
  bool fallback = holding_;
  if (holding_) {
    target = db->candidates[to.cand_begin];
  } else {
    int32_t v = db->slots[db->clips[size_t(clip_)].slot_begin + k].load(std::memory_order_acquire);
    if (v < 0 && v != kSlotNone) v = db->resolve_now(clip_, k);
    if (v >= 0) {
      target = v >> 1;
      fallback = v & 1;
    }
  }
  if (target < 0) return false;  // transition() reports it and holds
  release_prefetch();
  if (clip_ >= 0 && !unloaded_) db->unpin(clip_);
  clip_ = target;
  unloaded_ = true;
  holding_ = false;
  fallback_ = fallback;
  fallbacks_ += fallback;
  r0_ = 0;  // the clip is passed whole: a blend into it has ended (or is cut) by its end
  ++transitions_;
  primary_ = next_primary;
  next_k_ = -1;
  next_named_ = false;
  if (random_) choose_next();
  return true;
}

int Player::load_current() {
  if (!unloaded_) return CLOTHRT_OK;
  unloaded_ = false;
  ClipView v;
  bool stalled = false;
  Error e;
  if (Status st = db->acquire(clip_, &v, &stalled, &e); st != Status::Ok) {
    // As transition() does when a clip cannot be read: hold the last pose shown.
    error = e;
    clip_ = -1;
    holding_ = true;
    fallback_ = false;
    r0_ = 0;
    return to_code(st);
  }
  if (stalled) db->stalls.fetch_add(1, std::memory_order_relaxed);
  view_ = v;
  return CLOTHRT_OK;
}

int Player::advance(double dt) {
  if (!started_) {
    error.set(Status::InvalidArgument, "advance: the player has not been started");
    return CLOTHRT_ERR_INVALID;
  }
  if (!(dt >= 0) || !std::isfinite(dt)) {
    error.set(Status::InvalidArgument, "advance: time step %g is not a finite non-negative number",
              dt);
    return CLOTHRT_ERR_INVALID;
  }
  int code = CLOTHRT_OK;
  const PrimaryInfo* p = &db->primaries[size_t(primary_)];
  // Beyond 1e250 s every step lands alike (the wrap below); the cap keeps t_ finite.
  t_ += std::min(dt, 1e250) * p->rate;
  // Work is bounded whatever dt is (clothrt.h): clips the step passes whole are passed without
  // loading them (pass_node), a deterministic walk is cut short by whole cycles, and after
  // kMaxNodePasses nodes the rest of the step is wrapped modulo the next clip's length.
  // Cycle detection (Brent): the walk is a function of (primary clip, cloth clip) at each node
  // once nothing is named and nothing is random; `saved_*` is the walk at the last power-of-two
  // checkpoint, compared with every later node.
  constexpr uint64_t kMaxNodePasses = uint64_t(1) << 12;
  uint64_t passes = 0, power = 1, lam = 0;
  int64_t saved_key = -1;
  // Seconds of clips passed since this call began, summed from their lengths: a cycle's period
  // taken as a difference of `carry` values near 1e9 s would be off by microseconds, which times
  // 1e8 turns would land seconds away.
  double elapsed = 0, saved_elapsed = 0;
  uint64_t saved_transitions = 0, saved_fallbacks = 0;
  for (;;) {
    const double end = double(p->frames - 1);
    if (!unloaded_) {
      if (!prefetch_issued_ && (end - t_) / p->rate <= db->options.prefetch_seconds) {
        // The random pick is made at the start of a clip; a game that has not named the next
        // clip yet gets all candidates prefetched.
        issue_prefetch();
      } else if (prefetch_issued_) {
        poll_prefetch();
      }
    }
    if (t_ < end) break;
    if (choose_next() < 0) {
      // A node without any way on that has cloth: stay on the last frame.
      t_ = end;
      break;
    }
    double carry = (t_ - end) / p->rate;  // seconds of the step left past this node
    const PrimaryInfo& ahead =
        db->primaries[size_t(db->successors[p->succ_begin + uint32_t(next_k_)])];
    const double ahead_seconds = double(ahead.frames - 1) / ahead.rate;
    bool passed = false;
    elapsed += ahead_seconds;
    if (carry >= ahead_seconds) {
      if (passes < kMaxNodePasses)
        passed = pass_node();
      else
        carry = std::fmod(carry, ahead_seconds);  // the documented cap on a random walk
    }
    if (!passed) {
      if (const int c = load_current(); c != CLOTHRT_OK) code = c;  // the last frame shown
      const int c = transition();
      if (c != CLOTHRT_OK) code = c;
    }
    p = &db->primaries[size_t(primary_)];
    if (passed) {
      ++passes;
      const int64_t key = int64_t(primary_) << 32 | uint32_t(clip_);
      if (!random_ && key == saved_key && elapsed > saved_elapsed) {
        // A cycle of the deterministic walk: skip as many whole turns as the step holds.
        const double period = elapsed - saved_elapsed;
        const double turns = std::floor(carry / period);
        carry -= turns * period;
        const uint64_t whole = uint64_t(std::min(turns, 1e15));  // counters saturate, not wrap
        transitions_ += whole * (transitions_ - saved_transitions);
        fallbacks_ += whole * (fallbacks_ - saved_fallbacks);
        saved_key = -2;  // less than one turn is left: no further checkpoints needed
      } else if (saved_key != -2 && ++lam == power) {
        saved_key = key;
        saved_elapsed = elapsed;
        saved_transitions = transitions_;
        saved_fallbacks = fallbacks_;
        power *= 2;
        lam = 0;
      }
    }
    t_ = carry * p->rate;
  }
  if (const int c = load_current(); c != CLOTHRT_OK) code = c;
  if (db->workers.empty()) db->service_one();
  return code;
}

void Player::sample_into(float* dst) {
  const size_t n = size_t(db->vertex_count) * 3;
  if (holding_) {
    std::memcpy(dst, offset_.data(), n * sizeof(float));
    return;
  }
  const size_t last = size_t(view_.frames - 1);
  double whole = std::floor(t_);
  size_t f0 = size_t(std::clamp(whole, 0.0, double(last)));
  float a = float(t_ - whole);
  if (f0 >= last) {
    f0 = last;
    a = 0;
  }
  const size_t f1 = std::min(f0 + 1, last);
  const float r = r0_ > 0 ? float(std::max(0.0, r0_ - t_ / blend_span_)) : 0.0f;
  const float* d = offset_.data();
  if (a > 0) {
    if (r > 0)
      sample_view<true, true>(view_, n, f0, f1, a, d, r, dst);
    else
      sample_view<true, false>(view_, n, f0, f1, a, d, r, dst);
  } else {
    if (r > 0)
      sample_view<false, true>(view_, n, f0, f1, a, d, r, dst);
    else
      sample_view<false, false>(view_, n, f0, f1, a, d, r, dst);
  }
}

int Player::positions(float* out, size_t stride, const float* m) {
  if (!out || stride < 3 * sizeof(float) || stride % sizeof(float) != 0) {
    error.set(Status::InvalidArgument,
              "get_positions: need an output buffer and a stride >= 12 "
              "that is a multiple of 4");
    return CLOTHRT_ERR_INVALID;
  }
  if (!started_) {
    error.set(Status::InvalidArgument, "get_positions: the player has not been started");
    return CLOTHRT_ERR_INVALID;
  }
  const bool timed = db->timing.load(std::memory_order_relaxed);
  Clock::time_point t0;
  if (timed) t0 = Clock::now();
  const bool direct = stride == 3 * sizeof(float) && !m;
  float* dst = direct ? out : local_.data();
  sample_into(dst);
  if (!direct) {
    const size_t vs = stride / sizeof(float);
    const size_t vertices = db->vertex_count;
    const float* __restrict src = local_.data();
    if (m) {
      transform(src, vertices, m, out, vs);
    } else {
      for (size_t v = 0; v < vertices; ++v) std::memcpy(out + v * vs, src + 3 * v, 12);
    }
  }
  if (timed) add(sample_ns, ns_since(t0));
  add(frames, 1);
  return CLOTHRT_OK;
}

namespace {

// Area-weighted vertex normals of the simulation mesh (the cross product of a triangle's edges is
// its normal times twice its area), normalised; a vertex of no triangle gets +y. First each
// triangle's normal once, into 4-float rows; then each vertex gathers its triangles' rows through
// the adjacency (Db::vertex_faces, ascending), which adds the same floats in the same order as
// scattering them triangle by triangle, without the scatter's store-to-load chains; the square
// roots run last over contiguous planes, where they vectorise. With SSE a row is one vector: a
// point is read as 4 floats (the 4th is the next point's x, or the padding float after the last
// point; its lane is never used), and each lane does the scalar code's operations, so the results
// are the same bits.
#if CLOTHRT_SSE
// One triangle's normal row (the scalar code's operations, lane by lane).
inline __m128 face_normal(const float* pa, const float* pb, const float* pc) {
  const __m128 a = _mm_loadu_ps(pa);
  const __m128 e = _mm_sub_ps(_mm_loadu_ps(pb), a), f = _mm_sub_ps(_mm_loadu_ps(pc), a);
  // (e1 f2 - e2 f1, e2 f0 - e0 f2, e0 f1 - e1 f0): e.yzx * f.zxy - e.zxy * f.yzx
  const __m128 eyzx = _mm_shuffle_ps(e, e, _MM_SHUFFLE(3, 0, 2, 1));
  const __m128 ezxy = _mm_shuffle_ps(e, e, _MM_SHUFFLE(3, 1, 0, 2));
  const __m128 fyzx = _mm_shuffle_ps(f, f, _MM_SHUFFLE(3, 0, 2, 1));
  const __m128 fzxy = _mm_shuffle_ps(f, f, _MM_SHUFFLE(3, 1, 0, 2));
  return _mm_sub_ps(_mm_mul_ps(eyzx, fzxy), _mm_mul_ps(ezxy, fyzx));
}
#endif

#if CLOTHRT_AVX_DISPATCH
// Two triangles per 256-bit vector (one per 128-bit half, where the shuffles stay): half the
// arithmetic of face_normal per triangle, the same operations in every lane.
__attribute__((target("avx2"))) void face_normals_avx2(const float* __restrict x,
                                                       const uint32_t* __restrict tri,
                                                       size_t triangles, float* __restrict fn) {
  // Corner k of triangles t (low half) and t + 1 (high half).
#define CLOTHRT_PAIR(i, k)                                                           \
  _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(x + 3 * size_t((i)[k]))), \
                       _mm_loadu_ps(x + 3 * size_t((i)[3 + (k)])), 1)
  size_t t = 0;
  for (; t + 2 <= triangles; t += 2) {
    const uint32_t* i = tri + 3 * t;
    const __m256 a = CLOTHRT_PAIR(i, 0);
    const __m256 e = _mm256_sub_ps(CLOTHRT_PAIR(i, 1), a), f = _mm256_sub_ps(CLOTHRT_PAIR(i, 2), a);
    const __m256 eyzx = _mm256_shuffle_ps(e, e, _MM_SHUFFLE(3, 0, 2, 1));
    const __m256 ezxy = _mm256_shuffle_ps(e, e, _MM_SHUFFLE(3, 1, 0, 2));
    const __m256 fyzx = _mm256_shuffle_ps(f, f, _MM_SHUFFLE(3, 0, 2, 1));
    const __m256 fzxy = _mm256_shuffle_ps(f, f, _MM_SHUFFLE(3, 1, 0, 2));
    _mm256_storeu_ps(fn + 4 * t,
                     _mm256_sub_ps(_mm256_mul_ps(eyzx, fzxy), _mm256_mul_ps(ezxy, fyzx)));
  }
#undef CLOTHRT_PAIR
  for (; t < triangles; ++t)
    _mm_storeu_ps(fn + 4 * t,
                  face_normal(x + 3 * size_t(tri[3 * t]), x + 3 * size_t(tri[3 * t + 1]),
                              x + 3 * size_t(tri[3 * t + 2])));
}
#endif

void face_normals(const float* __restrict x, const uint32_t* __restrict tri, size_t triangles,
                  float* __restrict fn) {
#if CLOTHRT_AVX_DISPATCH
  if (__builtin_cpu_supports("avx2")) return face_normals_avx2(x, tri, triangles, fn);
#endif
  for (size_t t = 0; t < triangles; ++t) {
    const float* pa = x + 3 * size_t(tri[3 * t]);
    const float* pb = x + 3 * size_t(tri[3 * t + 1]);
    const float* pc = x + 3 * size_t(tri[3 * t + 2]);
#if CLOTHRT_SSE
    _mm_storeu_ps(fn + 4 * t, face_normal(pa, pb, pc));
#else
    const float e0 = pb[0] - pa[0], e1 = pb[1] - pa[1], e2 = pb[2] - pa[2];
    const float f0 = pc[0] - pa[0], f1 = pc[1] - pa[1], f2 = pc[2] - pa[2];
    float* o = fn + 4 * t;
    o[0] = e1 * f2 - e2 * f1;
    o[1] = e2 * f0 - e0 * f2;
    o[2] = e0 * f1 - e1 * f0;
#endif
  }
}

// Per vertex, sums the listed rows of `rows` (rows of kVectors 3-vectors, each padded to 4 floats;
// the lists hold row offsets, two at a time: Db::vertex_faces) into planes: lane k of vector q into
// out[(3 q + k) * vertices + v]: the tangent pass's sums (kVectors 2: the u and v directions; the
// vertex normals' sums, kVectors 1, made unit by unit_normals). The sums start at +0 and add in
// the listed order, as the scatter did.
template <int kVectors>
CLOTHRT_MULTIVERSION void gather_rows(const float* __restrict rows,
                                      const uint32_t* __restrict begin,
                                      const uint32_t* __restrict faces, size_t vertices,
                                      float* __restrict out) {
  constexpr size_t kStride = 4 * kVectors;
  size_t v = 0;
#if CLOTHRT_SSE
  // One vertex's sums, vector q.
  auto sums = [&](size_t u, __m128* sum) {
    for (int q = 0; q < kVectors; ++q) sum[q] = _mm_setzero_ps();
    for (uint32_t j = begin[u]; j < begin[u + 1]; j += 2) {
      const float* r0 = rows + faces[j];
      const float* r1 = rows + faces[j + 1];
      for (int q = 0; q < kVectors; ++q)
        sum[q] = _mm_add_ps(_mm_add_ps(sum[q], _mm_loadu_ps(r0 + 4 * q)), _mm_loadu_ps(r1 + 4 * q));
    }
  };
  // Four vertices at a time, turned into planes by a 4x4 transpose.
  for (; v + 4 <= vertices; v += 4) {
    __m128 s[4][kVectors];
    for (int i = 0; i < 4; ++i) sums(v + size_t(i), s[i]);
    for (int q = 0; q < kVectors; ++q) {
      __m128 a = s[0][q], b = s[1][q], c = s[2][q], d = s[3][q];
      _MM_TRANSPOSE4_PS(a, b, c, d);
      _mm_storeu_ps(out + (3 * size_t(q)) * vertices + v, a);
      _mm_storeu_ps(out + (3 * size_t(q) + 1) * vertices + v, b);
      _mm_storeu_ps(out + (3 * size_t(q) + 2) * vertices + v, c);
    }
  }
#endif
  for (; v < vertices; ++v) {
    float acc[kStride];
    for (size_t k = 0; k < kStride; ++k) acc[k] = 0.0f;
    for (uint32_t j = begin[v]; j < begin[v + 1]; ++j) {
      const float* r = rows + faces[j];
      for (size_t k = 0; k < kStride; ++k) acc[k] += r[k];
    }
    for (size_t q = 0; q < size_t(kVectors); ++q)
      for (size_t k = 0; k < 3; ++k) out[(3 * q + k) * vertices + v] = acc[4 * q + k];
  }
}

// (a, b, c) made unit into (x, y, z), or (fa, fb, fc) when its length is zero (or NaN). Everything
// is computed on both sides of the choice, so the choice is a blend and the loops that call it
// vectorise. The one rule for every unit vector of the render pass.
inline __attribute__((always_inline)) void unit_or(float a, float b, float c, float fa, float fb,
                                                   float fc, float& x, float& y, float& z) {
  const float l2 = a * a + b * b + c * c;
  const bool ok = l2 > 0;
  const float s = 1.0f / std::sqrt(ok ? l2 : 1.0f);
  const float as = a * s, bs = b * s, cs = c * s;
  x = ok ? as : fa;
  y = ok ? bs : fb;
  z = ok ? cs : fc;
}

// (a, b, c) turned by the upper 3x3 of the column-major m (a root transform's linear part).
struct Turn {
  float m0, m1, m2, m4, m5, m6, m8, m9, m10;
  explicit Turn(const float* m)
      : m0(m[0]),
        m1(m[1]),
        m2(m[2]),
        m4(m[4]),
        m5(m[5]),
        m6(m[6]),
        m8(m[8]),
        m9(m[9]),
        m10(m[10]) {}
  inline __attribute__((always_inline)) void operator()(float a, float b, float c, float& p,
                                                        float& q, float& r) const {
    p = m0 * a + m4 * b + m8 * c;
    q = m1 * a + m5 * b + m9 * c;
    r = m2 * a + m6 * b + m10 * c;
  }
};

// Unit vectors in place over planes x, y, z; a zero (or NaN) vector is kept (the tangent pass's
// normals, already unit, renormalised as the scalar code did).
CLOTHRT_MULTIVERSION void normalise_planes(float* __restrict x, float* __restrict y,
                                           float* __restrict z, size_t n) {
  for (size_t v = 0; v < n; ++v) {
    const float a = x[v], b = y[v], c = z[v];
    unit_or(a, b, c, a, b, c, x[v], y[v], z[v]);
  }
}

// Planes turned by m (Turn) into planes ox, oy, oz; normalise_planes makes them unit again.
CLOTHRT_MULTIVERSION void turn_planes(const float* __restrict x, const float* __restrict y,
                                      const float* __restrict z, size_t n,
                                      const float* __restrict m, float* __restrict ox,
                                      float* __restrict oy, float* __restrict oz) {
  const Turn turn(m);
  for (size_t v = 0; v < n; ++v) turn(x[v], y[v], z[v], ox[v], oy[v], oz[v]);
}

// The vertex normals from their sums (gather_rows<1> of the face rows, in planes x, y, z of n
// floats), in place: made unit, a zero or NaN sum becoming +y; with m (not null) also turned by
// it and made unit again into planes wx, wy, wz (a zero vector stays zero: turn_planes then
// normalise_planes, fused into one loop). A pass of its own after the gather: the gather's loops
// have per-vertex trip counts, and with the square roots and divisions in the same loop (as it
// was) the processor waited on their latency chain every four vertices; here the iterations are
// independent and branch-free, the loop vectorises (eight lanes with AVX2) and the divider stays
// busy. Each lane does the scalar operations, bit for bit.
CLOTHRT_MULTIVERSION void unit_normals(float* __restrict x, float* __restrict y,
                                       float* __restrict z, size_t n, const float* __restrict m,
                                       float* __restrict wx, float* __restrict wy,
                                       float* __restrict wz) {
  if (!m) {
    for (size_t v = 0; v < n; ++v) unit_or(x[v], y[v], z[v], 0.0f, 1.0f, 0.0f, x[v], y[v], z[v]);
    return;
  }
  const Turn turn(m);
  for (size_t v = 0; v < n; ++v) {
    float a, b, c, p, q, r;
    unit_or(x[v], y[v], z[v], 0.0f, 1.0f, 0.0f, a, b, c);
    x[v] = a, y[v] = b, z[v] = c;
    turn(a, b, c, p, q, r);
    unit_or(p, q, r, p, q, r, wx[v], wy[v], wz[v]);
  }
}

// Per render triangle the directions of increasing u and v in space (Lengyel 2001, "Computing
// tangent space basis vectors"), from its UV edges and 1 / det (Db::render_uv_edges), into 8-float
// rows (u direction in 0-2, v direction in 4-6). x is per render vertex when `sim` is null, else
// per simulation vertex through the indexed map; points are read as 4 floats, as in face_normals.
CLOTHRT_MULTIVERSION void face_tangents(const float* __restrict x, const uint32_t* __restrict sim,
                                        const uint32_t* __restrict tri,
                                        const float* __restrict uv_edges, size_t triangles,
                                        float* __restrict out) {
  for (size_t t = 0; t < triangles; ++t) {
    const float* p[3];
    for (int k = 0; k < 3; ++k) {
      const uint32_t i = tri[3 * t + size_t(k)];
      p[k] = x + 3 * size_t(sim ? sim[3 * size_t(i)] : i);
    }
    const float* e = uv_edges + 5 * t;
    float* o = out + 8 * t;
#if CLOTHRT_SSE
    const __m128 a = _mm_loadu_ps(p[0]);
    const __m128 e1 = _mm_sub_ps(_mm_loadu_ps(p[1]), a), e2 = _mm_sub_ps(_mm_loadu_ps(p[2]), a);
    const __m128 du1 = _mm_set1_ps(e[0]), dv1 = _mm_set1_ps(e[1]), du2 = _mm_set1_ps(e[2]),
                 dv2 = _mm_set1_ps(e[3]), f = _mm_set1_ps(e[4]);
    _mm_storeu_ps(o, _mm_mul_ps(f, _mm_sub_ps(_mm_mul_ps(dv2, e1), _mm_mul_ps(dv1, e2))));
    _mm_storeu_ps(o + 4, _mm_mul_ps(f, _mm_sub_ps(_mm_mul_ps(du1, e2), _mm_mul_ps(du2, e1))));
#else
    const float du1 = e[0], dv1 = e[1], du2 = e[2], dv2 = e[3], f = e[4];
    for (int k = 0; k < 3; ++k) {
      const float e1 = p[1][k] - p[0][k], e2 = p[2][k] - p[0][k];
      o[k] = f * (dv2 * e1 - dv1 * e2);
      o[4 + k] = f * (du1 * e2 - du2 * e1);
    }
#endif
  }
}

// Tangent frames in place over planes (normal n, tangent sum u, bitangent sum w, n unit): the
// tangent is u made orthogonal to n (Gram-Schmidt) and unit, or any unit vector orthogonal to n
// where u has no component off n; its sign is -1 where cross(n, tangent) points away from w.
// Writes the tangent over u and the sign over w's x plane. With m, the tangent is turned and
// renormalised.
CLOTHRT_MULTIVERSION void tangent_frames(const float* __restrict nx, const float* __restrict ny,
                                         const float* __restrict nz, float* __restrict ux,
                                         float* __restrict uy, float* __restrict uz,
                                         float* __restrict wx, const float* __restrict wy,
                                         const float* __restrict wz, size_t n) {
  for (size_t r = 0; r < n; ++r) {
    const float a = nx[r], b = ny[r], c = nz[r];
    const float d = a * ux[r] + b * uy[r] + c * uz[r];
    const float u0 = ux[r] - d * a, u1 = uy[r] - d * b, u2 = uz[r] - d * c;
    const bool none = u0 * u0 + u1 * u1 + u2 * u2 <= 0;
    // No UV gradient here: x (or y when the normal is near x) made orthogonal to the normal.
    // (Both sides of each choice computed, so the loop vectorises.)
    const float g0 = std::fabs(a) < 0.9f ? 1.0f : 0.0f;
    const float g1 = g0 == 0 ? 1.0f : 0.0f;
    const float ge = a * g0 + b * g1;
    const float h0 = g0 - ge * a, h1 = g1 - ge * b, h2 = 0.0f - ge * c;
    float t0 = none ? h0 : u0, t1 = none ? h1 : u1, t2 = none ? h2 : u2;
    unit_or(t0, t1, t2, t0, t1, t2, t0, t1, t2);
    const float c0 = b * t2 - c * t1, c1 = c * t0 - a * t2, c2 = a * t1 - b * t0;
    const float hand = c0 * wx[r] + c1 * wy[r] + c2 * wz[r] < 0 ? -1.0f : 1.0f;
    ux[r] = t0, uy[r] = t1, uz[r] = t2;
    wx[r] = hand;
  }
}

// Per render vertex r of an indexed map (its simulation vertex sim[3 r]), the 3 floats of that
// vertex from the rows p (3 floats per vertex) into po, and from the planes q (plane stride n)
// into qo: the caller's strided buffers (a null buffer is skipped).
void copy_rows(const float* __restrict p, float* __restrict po, size_t ps,
               const float* __restrict q, size_t n, float* __restrict qo, size_t qs,
               const uint32_t* __restrict sim, size_t rn) {
  auto normal = [&](size_t r, size_t v) {
    float* o = qo + r * qs;
    o[0] = q[v], o[1] = q[n + v], o[2] = q[2 * n + v];
  };
  if (po && qo) {  // one pass over the caller's buffer (interleaved: each line touched once)
    for (size_t r = 0; r < rn; ++r) {
      const size_t v = sim[3 * r];
      std::memcpy(po + r * ps, p + 3 * v, 12);
      normal(r, v);
    }
  } else if (po) {
    for (size_t r = 0; r < rn; ++r) std::memcpy(po + r * ps, p + 3 * size_t(sim[3 * r]), 12);
  } else if (qo) {
    for (size_t r = 0; r < rn; ++r) normal(r, sim[3 * r]);
  }
}

// A vector of a render vertex from per-simulation-vertex values in planes (plane stride n): the
// map's weighted sum.
inline void gather_weighted(const float* src, size_t n, const uint32_t* sim, const float* w,
                            float* o) {
  for (size_t k = 0; k < 3; ++k)
    o[k] = w[0] * src[k * n + sim[0]] + w[1] * src[k * n + sim[1]] + w[2] * src[k * n + sim[2]];
}

inline void normalise(float* v) {
  const float l2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
  if (l2 > 0) {
    const float s = 1.0f / std::sqrt(l2);
    v[0] *= s, v[1] *= s, v[2] *= s;
  }
}

bool bad_stride(const float* buffer, size_t stride, size_t least) {
  return buffer && (stride < least || stride % sizeof(float) != 0);
}

}  // namespace

int Player::render(const clothrt_render_output& out, const float* m) {
  if (bad_stride(out.positions, out.position_stride, 12) ||
      bad_stride(out.normals, out.normal_stride, 12) ||
      bad_stride(out.tangents, out.tangent_stride, 16)) {
    error.set(Status::InvalidArgument,
              "get_render_mesh: strides must be multiples of 4, >= 12 (>= 16 for tangents)");
    return CLOTHRT_ERR_INVALID;
  }
  if (out.tangents && db->render_uvs.empty()) {
    error.set(Status::InvalidArgument, "get_render_mesh: tangents need UVs; the mesh has none");
    return CLOTHRT_ERR_INVALID;
  }
  if (!started_) {
    error.set(Status::InvalidArgument, "get_render_mesh: the player has not been started");
    return CLOTHRT_ERR_INVALID;
  }
  const bool timed = db->timing.load(std::memory_order_relaxed);
  Clock::time_point t0;
  if (timed) t0 = Clock::now();
  float* x = local_.data();
  sample_into(x);
  const size_t n = db->vertex_count;
  const size_t rn = db->render_vertex_count;
  const uint32_t* sim = db->render_sim.data();
  const float* w = db->render_weights.data();
  const bool indexed = db->all_indexed;
  // Simulation-vertex normals in planes; with a root transform, their turn too.
  // (Planes where the loops vectorise; interleaved where render vertices copy them.)
  float* nv = normals_.data();
  // Indexed with a root transform: the turned normals (planes), else nv's.
  const bool turned = indexed && m && out.normals;
  const float* wn = turned ? world_normals_.data() : nv;
  if (out.normals || out.tangents) {
    face_normals(x, db->triangles.data(), db->triangles.size() / 3, face_normals_.data());
    gather_rows<1>(face_normals_.data(), db->vertex_faces_begin.data(), db->vertex_faces.data(), n,
                   nv);
    float* w = turned ? world_normals_.data() : nv;  // (not written without m)
    unit_normals(nv, nv + n, nv + 2 * n, n, turned ? m : nullptr, w, w + n, w + 2 * n);
  }
  // The root transform's linear part turns normals and tangents (renormalised after).
  auto turn = [m](const float* v, float* o) {
    const float a = v[0], b = v[1], c = v[2];
    o[0] = m[0] * a + m[4] * b + m[8] * c;
    o[1] = m[1] * a + m[5] * b + m[9] * c;
    o[2] = m[2] * a + m[6] * b + m[10] * c;
  };
  if (indexed) {
    // Each simulation vertex moved and turned once, then copied to its render vertices (seam
    // copies), positions and normals in one pass over the caller's buffer.
    const float* src = x;
    if (out.positions && m) {
      transform(x, n, m, world_.data(), 3);
      src = world_.data();
    }
    copy_rows(src, out.positions, out.position_stride / sizeof(float), wn, n, out.normals,
              out.normal_stride / sizeof(float), sim, rn);
  } else {
    if (out.positions) {
      const size_t s = out.position_stride / sizeof(float);
      for (size_t r = 0; r < rn; ++r) {
        const float* p = x + 3 * size_t(sim[3 * r]);
        const float* q = x + 3 * size_t(sim[3 * r + 1]);
        const float* u = x + 3 * size_t(sim[3 * r + 2]);
        const float* wr = w + 3 * r;
        float v[3];
        for (int k = 0; k < 3; ++k) v[k] = wr[0] * p[k] + wr[1] * q[k] + wr[2] * u[k];
        float* o = out.positions + r * s;
        if (m) {
          turn(v, o);
          o[0] += m[12], o[1] += m[13], o[2] += m[14];
        } else {
          o[0] = v[0], o[1] = v[1], o[2] = v[2];
        }
      }
    }
    if (out.normals) {
      const size_t s = out.normal_stride / sizeof(float);
      for (size_t r = 0; r < rn; ++r) {
        float* o = out.normals + r * s;
        float v[3];
        gather_weighted(nv, n, sim + 3 * r, w + 3 * r, v);
        if (m) {
          turn(v, o);
          normalise(o);
        } else {
          normalise(v);
          o[0] = v[0], o[1] = v[1], o[2] = v[2];
        }
      }
    }
  }
  if (out.tangents) {
    // Per render triangle its tangent directions (Lengyel 2001), summed per render vertex through
    // the adjacency rows; then per vertex the frame against its (renormalised) normal.
    const size_t rt = db->render_triangles.size() / 3;
    float* pl = tangents_.data();  // 9 planes: normal, tangent sum, bitangent sum
    if (indexed) {
      face_tangents(x, sim, db->render_triangles.data(), db->render_uv_edges.data(), rt,
                    face_tangents_.data());
    } else {
      // The render vertices' positions first, in the first 3 planes (overwritten by the normals
      // once the triangles' rows are made).
      float* rp = pl;
      for (size_t r = 0; r < rn; ++r) {
        const float* wr = w + 3 * r;
        for (int k = 0; k < 3; ++k)
          rp[3 * r + size_t(k)] = wr[0] * x[3 * size_t(sim[3 * r]) + size_t(k)] +
                                  wr[1] * x[3 * size_t(sim[3 * r + 1]) + size_t(k)] +
                                  wr[2] * x[3 * size_t(sim[3 * r + 2]) + size_t(k)];
      }
      face_tangents(rp, nullptr, db->render_triangles.data(), db->render_uv_edges.data(), rt,
                    face_tangents_.data());
    }
    gather_rows<2>(face_tangents_.data(), db->render_faces_begin.data(), db->render_faces.data(),
                   rn, pl + 3 * rn);
    for (size_t r = 0; r < rn; ++r) {
      float v[3];
      if (indexed) {
        const size_t i = sim[3 * r];
        v[0] = nv[i], v[1] = nv[n + i], v[2] = nv[2 * n + i];
      } else {
        gather_weighted(nv, n, sim + 3 * r, w + 3 * r, v);
      }
      pl[r] = v[0], pl[rn + r] = v[1], pl[2 * rn + r] = v[2];
    }
    normalise_planes(pl, pl + rn, pl + 2 * rn, rn);
    float* u = pl + 3 * rn;
    float* hand = pl + 6 * rn;
    tangent_frames(pl, pl + rn, pl + 2 * rn, u, u + rn, u + 2 * rn, hand, hand + rn, hand + 2 * rn,
                   rn);
    if (m) {  // into the normal's planes, done with
      turn_planes(u, u + rn, u + 2 * rn, rn, m, pl, pl + rn, pl + 2 * rn);
      normalise_planes(pl, pl + rn, pl + 2 * rn, rn);
      u = pl;
    }
    const size_t s = out.tangent_stride / sizeof(float);
    for (size_t r = 0; r < rn; ++r) {
      float* o = out.tangents + r * s;
      o[0] = u[r], o[1] = u[rn + r], o[2] = u[2 * rn + r], o[3] = hand[r];
    }
  }
  if (timed) add(sample_ns, ns_since(t0));
  add(frames, 1);
  return CLOTHRT_OK;
}

void Player::info(clothrt_frame_info* out) const {
  std::memset(out, 0, sizeof *out);
  if (!started_) return;
  const PrimaryInfo& p = db->primaries[size_t(primary_)];
  out->primary_clip = p.id;
  out->primary_frame = t_;
  if (clip_ >= 0) {
    out->cloth_clip = db->clips[size_t(clip_)].id;
    out->cloth_state = db->states[size_t(db->clips[size_t(clip_)].state)].id;
  }
  if (next_k_ >= 0)
    out->next_clip = db->primaries[size_t(db->successors[p.succ_begin + uint32_t(next_k_)])].id;
  const double r = !holding_ && r0_ > 0 ? std::max(0.0, r0_ - t_ / blend_span_) : 0.0;
  out->blending = r > 0;
  out->blend_weight = 1.0 - r;
  out->fallback = fallback_;
  out->holding = holding_;
  out->transitions = transitions_;
  out->fallbacks = fallbacks_;
  out->interrupted_blends = interrupted_;
}

}  // namespace clothrt
