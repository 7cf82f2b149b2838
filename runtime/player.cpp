// A player: follows the game's path through the primary graph and the secondary cloth graph,
// blends at transitions into different states, and samples the cloth at any time.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>

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
  for (size_t v = 0; v < vertices; ++v) {
    const float x = src[3 * v], y = src[3 * v + 1], z = src[3 * v + 2];
    float* o = out + v * vs;
    o[0] = m0 * x + m4 * y + m8 * z + m12;
    o[1] = m1 * x + m5 * y + m9 * z + m13;
    o[2] = m2 * x + m6 * y + m10 * z + m14;
  }
}

}  // namespace

Player::Player(Db* d) : db(d) {
  const size_t n = size_t(db->vertex_count) * 3;
  offset_.assign(n, 0.0f);
  local_.assign(n, 0.0f);
  normals_.assign(n, 0.0f);
  if (!db->render_uvs.empty()) tangent_sums_.assign(size_t(db->render_vertex_count) * 6, 0.0f);
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
         (offset_.capacity() + local_.capacity() + normals_.capacity() + tangent_sums_.capacity()) *
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
// its normal times twice its area), normalised; a vertex of no triangle gets +y.
CLOTHRT_MULTIVERSION void vertex_normals(const float* __restrict x, const uint32_t* __restrict tri,
                                         size_t triangles, size_t vertices, float* __restrict out) {
  std::memset(out, 0, vertices * 3 * sizeof(float));
  for (size_t t = 0; t < triangles; ++t) {
    const uint32_t a = tri[3 * t], b = tri[3 * t + 1], c = tri[3 * t + 2];
    const float* pa = x + 3 * size_t(a);
    const float* pb = x + 3 * size_t(b);
    const float* pc = x + 3 * size_t(c);
    const float e0 = pb[0] - pa[0], e1 = pb[1] - pa[1], e2 = pb[2] - pa[2];
    const float f0 = pc[0] - pa[0], f1 = pc[1] - pa[1], f2 = pc[2] - pa[2];
    const float n0 = e1 * f2 - e2 * f1, n1 = e2 * f0 - e0 * f2, n2 = e0 * f1 - e1 * f0;
    for (const uint32_t v : {a, b, c}) {
      float* o = out + 3 * size_t(v);
      o[0] += n0;
      o[1] += n1;
      o[2] += n2;
    }
  }
  for (size_t v = 0; v < vertices; ++v) {
    float* o = out + 3 * v;
    const float l2 = o[0] * o[0] + o[1] * o[1] + o[2] * o[2];
    if (l2 > 0) {
      const float s = 1.0f / std::sqrt(l2);
      o[0] *= s;
      o[1] *= s;
      o[2] *= s;
    } else {
      o[0] = 0, o[1] = 1, o[2] = 0;
    }
  }
}

// A vector of a render vertex from per-simulation-vertex values: a copy, or the map's weighted sum.
inline void gather(const float* src, const uint32_t* sim, const float* w, bool indexed, float* o) {
  if (indexed) {
    const float* p = src + 3 * size_t(sim[0]);
    o[0] = p[0], o[1] = p[1], o[2] = p[2];
    return;
  }
  const float* p = src + 3 * size_t(sim[0]);
  const float* q = src + 3 * size_t(sim[1]);
  const float* r = src + 3 * size_t(sim[2]);
  for (int k = 0; k < 3; ++k) o[k] = w[0] * p[k] + w[1] * q[k] + w[2] * r[k];
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
  const bool want_normals = out.normals || out.tangents;
  if (want_normals)
    vertex_normals(x, db->triangles.data(), db->triangles.size() / 3, db->vertex_count,
                   normals_.data());
  const size_t rn = db->render_vertex_count;
  const uint32_t* sim = db->render_sim.data();
  const float* w = db->render_weights.data();
  const bool indexed = db->all_indexed;
  // The root transform's linear part turns normals and tangents (renormalised after).
  auto turn = [m](const float* v, float* o) {
    const float a = v[0], b = v[1], c = v[2];
    o[0] = m[0] * a + m[4] * b + m[8] * c;
    o[1] = m[1] * a + m[5] * b + m[9] * c;
    o[2] = m[2] * a + m[6] * b + m[10] * c;
  };
  if (out.positions) {
    const size_t s = out.position_stride / sizeof(float);
    for (size_t r = 0; r < rn; ++r) {
      float p[3];
      gather(x, sim + 3 * r, w + 3 * r, indexed, p);
      float* o = out.positions + r * s;
      if (m) {
        turn(p, o);
        o[0] += m[12], o[1] += m[13], o[2] += m[14];
      } else {
        o[0] = p[0], o[1] = p[1], o[2] = p[2];
      }
    }
  }
  if (out.normals) {
    const size_t s = out.normal_stride / sizeof(float);
    for (size_t r = 0; r < rn; ++r) {
      float nv[3];
      gather(normals_.data(), sim + 3 * r, w + 3 * r, indexed, nv);
      float* o = out.normals + r * s;
      if (m) {
        turn(nv, o);
        normalise(o);
      } else {
        if (!indexed) normalise(nv);
        o[0] = nv[0], o[1] = nv[1], o[2] = nv[2];
      }
    }
  }
  if (out.tangents) {
    // Per triangle in UV space, the directions of increasing u and v (Lengyel 2001, "Computing
    // tangent space basis vectors"), summed per render vertex; then Gram-Schmidt against the
    // normal, and w from the bitangent's side.
    float* sums = tangent_sums_.data();
    std::memset(sums, 0, rn * 6 * sizeof(float));
    const uint32_t* tri = db->render_triangles.data();
    const float* uv = db->render_uvs.data();
    for (size_t t = 0; t < db->render_triangles.size() / 3; ++t) {
      const uint32_t i[3] = {tri[3 * t], tri[3 * t + 1], tri[3 * t + 2]};
      float p[3][3];
      for (int k = 0; k < 3; ++k)
        gather(x, sim + 3 * size_t(i[k]), w + 3 * size_t(i[k]), indexed, p[k]);
      const float e1[3] = {p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]};
      const float e2[3] = {p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]};
      const float du1 = uv[2 * i[1]] - uv[2 * i[0]], dv1 = uv[2 * i[1] + 1] - uv[2 * i[0] + 1];
      const float du2 = uv[2 * i[2]] - uv[2 * i[0]], dv2 = uv[2 * i[2] + 1] - uv[2 * i[0] + 1];
      const float det = du1 * dv2 - du2 * dv1;
      if (det == 0) continue;  // degenerate in UV space: contributes nothing
      const float f = 1.0f / det;
      float tu[3], tv[3];
      for (int k = 0; k < 3; ++k) {
        tu[k] = f * (dv2 * e1[k] - dv1 * e2[k]);
        tv[k] = f * (du1 * e2[k] - du2 * e1[k]);
      }
      for (const uint32_t v : i)
        for (int k = 0; k < 3; ++k) {
          sums[6 * size_t(v) + size_t(k)] += tu[k];
          sums[6 * size_t(v) + 3 + size_t(k)] += tv[k];
        }
    }
    const size_t s = out.tangent_stride / sizeof(float);
    for (size_t r = 0; r < rn; ++r) {
      float nv[3];
      gather(normals_.data(), sim + 3 * r, w + 3 * r, indexed, nv);
      normalise(nv);
      const float* tu = sums + 6 * r;
      const float* tv = tu + 3;
      const float d = nv[0] * tu[0] + nv[1] * tu[1] + nv[2] * tu[2];
      float tg[3] = {tu[0] - d * nv[0], tu[1] - d * nv[1], tu[2] - d * nv[2]};
      if (tg[0] * tg[0] + tg[1] * tg[1] + tg[2] * tg[2] <= 0) {
        // No UV gradient here: any unit vector orthogonal to the normal.
        tg[0] = std::fabs(nv[0]) < 0.9f ? 1.0f : 0.0f;
        tg[1] = tg[0] == 0 ? 1.0f : 0.0f;
        tg[2] = 0;
        const float e = nv[0] * tg[0] + nv[1] * tg[1];
        tg[0] -= e * nv[0], tg[1] -= e * nv[1], tg[2] -= e * nv[2];
      }
      normalise(tg);
      const float c[3] = {nv[1] * tg[2] - nv[2] * tg[1], nv[2] * tg[0] - nv[0] * tg[2],
                          nv[0] * tg[1] - nv[1] * tg[0]};
      const float hand = c[0] * tv[0] + c[1] * tv[1] + c[2] * tv[2] < 0 ? -1.0f : 1.0f;
      float* o = out.tangents + r * s;
      if (m) {
        turn(tg, o);
        normalise(o);
      } else {
        o[0] = tg[0], o[1] = tg[1], o[2] = tg[2];
      }
      o[3] = hand;
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
