#include "graph/motion_graph.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <map>
#include <numbers>
#include <set>
#include <tuple>

namespace clothdb {

// ---------------------------------------------------------------------------------------------
// Floor transforms

namespace {

double wrap_angle(double a) {
  a = std::remainder(a, 2.0 * std::numbers::pi);
  return a <= -std::numbers::pi ? a + 2.0 * std::numbers::pi : a;
}

}  // namespace

Eigen::Quaterniond FloorTransform::rotation() const {
  return Eigen::Quaterniond(Eigen::AngleAxisd(theta, Eigen::Vector3d::UnitY()));
}

Eigen::Vector3d FloorTransform::rotate(const Eigen::Vector3d& v) const {
  const double c = std::cos(theta), s = std::sin(theta);
  return {c * v.x() + s * v.z(), v.y(), -s * v.x() + c * v.z()};
}

Eigen::Vector3d FloorTransform::apply(const Eigen::Vector3d& p) const {
  return rotate(p) + Eigen::Vector3d(x, 0.0, z);
}

JointPose FloorTransform::apply(const JointPose& pose) const {
  JointPose out;
  out.position = apply(pose.position);
  out.rotation = (rotation() * pose.rotation).normalized();
  return out;
}

FloorTransform FloorTransform::inverse() const {
  FloorTransform inv;
  inv.theta = wrap_angle(-theta);
  const Eigen::Vector3d t = inv.rotate(Eigen::Vector3d(x, 0.0, z));
  inv.x = -t.x();
  inv.z = -t.z();
  return inv;
}

FloorTransform FloorTransform::operator*(const FloorTransform& other) const {
  FloorTransform out;
  out.theta = wrap_angle(theta + other.theta);
  const Eigen::Vector3d t = apply(Eigen::Vector3d(other.x, 0.0, other.z));
  out.x = t.x();
  out.z = t.z();
  return out;
}

FloorTransform floor_frame(const JointPose& root) {
  const Eigen::Vector3d forward_z = root.rotation * Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d side_x = root.rotation * Eigen::Vector3d::UnitX();
  // side_x x (+y) = (-side_x.z, 0, side_x.x): forward for a root whose +x points to its left.
  const double fx = forward_z.x() - side_x.z();
  const double fz = forward_z.z() + side_x.x();
  FloorTransform frame;
  frame.theta = (fx == 0.0 && fz == 0.0) ? 0.0 : std::atan2(fx, fz);  // R_y(theta) +z = forward
  frame.x = root.position.x();
  frame.z = root.position.z();
  return frame;
}

// ---------------------------------------------------------------------------------------------
// Kovar 2002 point-cloud distance

namespace {

// Weighted sums over a pair of point clouds that determine the optimal floor alignment and the
// distance it leaves (Kovar 2002, sec. 3.1): with xbar = sum w x etc. over each cloud,
//   a = sum w (x x' + z z'),  b = sum w (x z' - x' z),  c = sum w y y',
//   theta = atan2(b - (xbar zbar' - xbar' zbar) / W, a - (xbar xbar' + zbar zbar') / W),
//   x0 = (xbar - xbar' cos theta - zbar' sin theta) / W,
//   z0 = (zbar + xbar' sin theta - zbar' cos theta) / W.
// Kovar writes theta with arctan, which can pick the maximum of the error instead of the minimum;
// atan2 picks the minimum. The remaining error has the closed form
//   D = sum w |q|^2 + sum w |q'|^2 - (|qbar|^2 + |qbar'|^2) / W - 2 |(a_c, b_c)| + sum w (y - y')^2
// with q the floor (x, z) part and a_c, b_c the centred a, b above.
struct PairSums {
  double w = 0;            // W
  double sx = 0, sz = 0;   // first cloud: xbar, zbar
  double sx2 = 0, sy = 0;  // x, z: sum w (x^2 + z^2); y: sum w y^2
  double tx = 0, tz = 0;   // second cloud
  double tx2 = 0, ty = 0;
  double a = 0, b = 0, c = 0;  // cross terms

  WindowAlignment solve() const {
    WindowAlignment r;
    if (!(w > 0)) return r;
    const double ac = a - (sx * tx + sz * tz) / w;
    const double bc = b - (sx * tz - tx * sz) / w;
    const double theta = (ac == 0.0 && bc == 0.0) ? 0.0 : std::atan2(bc, ac);
    const double ct = std::cos(theta), st = std::sin(theta);
    r.transform.theta = theta;
    r.transform.x = (sx - tx * ct - tz * st) / w;
    r.transform.z = (sz + tx * st - tz * ct) / w;
    const double floor_part =
        sx2 + tx2 - (sx * sx + sz * sz + tx * tx + tz * tz) / w - 2.0 * std::hypot(ac, bc);
    const double up_part = sy + ty - 2.0 * c;
    r.distance = std::max(0.0, floor_part + up_part);  // rounding can leave a tiny negative
    r.rms = std::sqrt(r.distance / w);
    return r;
  }
};

// Mean floor position of a clip's joints: clouds are centred on it before the sums so that the
// differences of large numbers in D stay small for clips far from the origin (D does not change:
// the optimal translation absorbs any floor offset).
Eigen::Vector3d floor_centre(const MotionClip& clip) {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : clip.positions) c += p;
  if (!clip.positions.empty()) c /= static_cast<double>(clip.positions.size());
  c.y() = 0.0;
  return c;
}

// Undo the centring: the transform found between centred clouds, T~ with p - ca = T~ (q - cb),
// is T = translate(ca) * T~ * translate(-cb).
FloorTransform uncentre(const FloorTransform& t, const Eigen::Vector3d& ca,
                        const Eigen::Vector3d& cb) {
  FloorTransform out = t;
  const Eigen::Vector3d shift = ca - t.rotate(cb);
  out.x += shift.x();
  out.z += shift.z();
  return out;
}

void check_weights(const std::vector<double>& weights, int joints) {
  if (!weights.empty() && static_cast<int>(weights.size()) != joints)
    throw GraphError("joint weights: " + std::to_string(weights.size()) + " given for " +
                     std::to_string(joints) + " joints");
  for (double w : weights)
    if (!(w >= 0.0) || !std::isfinite(w))
      throw GraphError("joint weights: expected finite non-negative numbers");
}

}  // namespace

WindowAlignment align_point_clouds(const std::vector<Eigen::Vector3d>& p,
                                   const std::vector<Eigen::Vector3d>& q,
                                   const std::vector<double>& w) {
  if (p.size() != q.size() || (!w.empty() && w.size() != p.size()))
    throw GraphError("align_point_clouds: clouds and weights differ in size");
  PairSums s;
  for (size_t i = 0; i < p.size(); ++i) {
    const double wi = w.empty() ? 1.0 : w[i];
    s.w += wi;
    s.sx += wi * p[i].x();
    s.sz += wi * p[i].z();
    s.sx2 += wi * (p[i].x() * p[i].x() + p[i].z() * p[i].z());
    s.sy += wi * p[i].y() * p[i].y();
    s.tx += wi * q[i].x();
    s.tz += wi * q[i].z();
    s.tx2 += wi * (q[i].x() * q[i].x() + q[i].z() * q[i].z());
    s.ty += wi * q[i].y() * q[i].y();
    s.a += wi * (p[i].x() * q[i].x() + p[i].z() * q[i].z());
    s.b += wi * (p[i].x() * q[i].z() - q[i].x() * p[i].z());
    s.c += wi * p[i].y() * q[i].y();
  }
  return s.solve();
}

WindowAlignment align_windows(const MotionClip& a, int i, const MotionClip& b, int j, int window,
                              const std::vector<double>& joint_weights) {
  if (a.joint_count != b.joint_count)
    throw GraphError("clips '" + a.name + "' and '" + b.name + "' have different joint counts");
  if (window < 1 || i < 0 || j < 0 || i + window > a.frame_count || j + window > b.frame_count)
    throw GraphError("window of " + std::to_string(window) + " frames at '" + a.name + "' " +
                     std::to_string(i) + " / '" + b.name + "' " + std::to_string(j) +
                     " does not fit the clips");
  check_weights(joint_weights, a.joint_count);
  const Eigen::Vector3d ca = floor_centre(a), cb = floor_centre(b);
  std::vector<Eigen::Vector3d> p, q;
  std::vector<double> w;
  for (int t = 0; t < window; ++t)
    for (int k = 0; k < a.joint_count; ++k) {
      p.push_back(a.position(i + t, k) - ca);
      q.push_back(b.position(j + t, k) - cb);
      w.push_back(joint_weights.empty() ? 1.0 : joint_weights[k]);
    }
  WindowAlignment r = align_point_clouds(p, q, w);
  r.transform = uncentre(r.transform, ca, cb);
  return r;
}

DistanceMatrix window_distances(const MotionClip& a, const MotionClip& b, int window, int span,
                                const std::vector<double>& joint_weights) {
  if (a.joint_count != b.joint_count)
    throw GraphError("clips '" + a.name + "' and '" + b.name + "' have different joint counts");
  if (window < 1 || span < window) throw GraphError("window_distances: bad window or span");
  check_weights(joint_weights, a.joint_count);
  const int joints = a.joint_count;
  DistanceMatrix m;
  m.rows = std::max(0, a.frame_count - span + 1);
  m.cols = std::max(0, b.frame_count - span + 1);
  m.rms.assign(static_cast<size_t>(m.rows) * m.cols, 0.0);
  if (m.rows == 0 || m.cols == 0) return m;

  // Per-frame sums of each clip, centred as in align_windows.
  struct FrameSums {
    double sx = 0, sz = 0, sx2 = 0, sy = 0;
  };
  const Eigen::Vector3d ca = floor_centre(a), cb = floor_centre(b);
  auto frame_sums = [&](const MotionClip& clip, const Eigen::Vector3d& centre,
                        std::vector<Eigen::Vector3d>& centred) {
    std::vector<FrameSums> out(clip.frame_count);
    centred.resize(clip.positions.size());
    for (size_t n = 0; n < clip.positions.size(); ++n) centred[n] = clip.positions[n] - centre;
    for (int f = 0; f < clip.frame_count; ++f)
      for (int k = 0; k < joints; ++k) {
        const double w = joint_weights.empty() ? 1.0 : joint_weights[k];
        const Eigen::Vector3d& p = centred[static_cast<size_t>(f) * joints + k];
        out[f].sx += w * p.x();
        out[f].sz += w * p.z();
        out[f].sx2 += w * (p.x() * p.x() + p.z() * p.z());
        out[f].sy += w * p.y() * p.y();
      }
    return out;
  };
  std::vector<Eigen::Vector3d> pa, pb;
  const std::vector<FrameSums> fa = frame_sums(a, ca, pa);
  const std::vector<FrameSums> fb = frame_sums(b, cb, pb);
  double joint_weight_sum = 0.0;
  for (int k = 0; k < joints; ++k)
    joint_weight_sum += joint_weights.empty() ? 1.0 : joint_weights[k];

  // Cross terms for every pair of frames (f, g) that some window uses; a window's cross terms are
  // then the sum of `window` of them along a diagonal.
  const int fa_used = m.rows + window - 1, fb_used = m.cols + window - 1;
  std::vector<Eigen::Vector3d> cross(static_cast<size_t>(fa_used) * fb_used);
#pragma omp parallel for schedule(static)
  for (int f = 0; f < fa_used; ++f)
    for (int g = 0; g < fb_used; ++g) {
      double sa = 0, sb = 0, sc = 0;
      for (int k = 0; k < joints; ++k) {
        const double w = joint_weights.empty() ? 1.0 : joint_weights[k];
        const Eigen::Vector3d& p = pa[static_cast<size_t>(f) * joints + k];
        const Eigen::Vector3d& q = pb[static_cast<size_t>(g) * joints + k];
        sa += w * (p.x() * q.x() + p.z() * q.z());
        sb += w * (p.x() * q.z() - q.x() * p.z());
        sc += w * p.y() * q.y();
      }
      cross[static_cast<size_t>(f) * fb_used + g] = {sa, sb, sc};
    }

#pragma omp parallel for schedule(static)
  for (int i = 0; i < m.rows; ++i)
    for (int j = 0; j < m.cols; ++j) {
      PairSums s;
      s.w = window * joint_weight_sum;
      for (int t = 0; t < window; ++t) {
        const FrameSums& x = fa[i + t];
        const FrameSums& y = fb[j + t];
        s.sx += x.sx;
        s.sz += x.sz;
        s.sx2 += x.sx2;
        s.sy += x.sy;
        s.tx += y.sx;
        s.tz += y.sz;
        s.tx2 += y.sx2;
        s.ty += y.sy;
        const Eigen::Vector3d& c = cross[static_cast<size_t>(i + t) * fb_used + (j + t)];
        s.a += c.x();
        s.b += c.y();
        s.c += c.z();
      }
      m.rms[static_cast<size_t>(i) * m.cols + j] = s.solve().rms;
    }
  return m;
}

// ---------------------------------------------------------------------------------------------
// Transitions

namespace {

void check_settings(const GraphSettings& s) {
  if (s.window < 1) throw GraphError("window: expected at least 1 frame");
  if (s.blend < 1) throw GraphError("blend: expected at least 1 frame");
  if (s.spacing < 0) throw GraphError("spacing: expected a number of frames >= 0");
  if (s.min_self_offset < 1) throw GraphError("min_self_offset: expected at least 1 frame");
  if (!std::isfinite(s.threshold) || s.threshold < 0)
    throw GraphError("threshold: expected a finite number >= 0");
  if (s.threshold_mode == ThresholdMode::percentile && s.threshold > 100)
    throw GraphError("threshold: a percentile is between 0 and 100");
  if (!(s.max_distance >= 0) || !std::isfinite(s.max_distance))
    throw GraphError("max_distance: expected a finite number >= 0");
  if (!(s.min_segment_s >= 0) || !std::isfinite(s.min_segment_s))
    throw GraphError("min_segment_s: expected a finite number of seconds >= 0");
}

int span_of(const GraphSettings& s) {
  return std::max(s.window, s.blend + 1);
}

bool excluded(int clip_a, int clip_b, int i, int j, const GraphSettings& s) {
  return clip_a == clip_b && std::abs(i - j) < s.min_self_offset;
}

}  // namespace

namespace {

// What the transition search computed: D and the threshold of every unordered pair of clips, and
// the transitions found. Snapping looks D up again at the frames it moves a transition to.
struct TransitionSearch {
  std::vector<std::pair<int, int>> pairs;  // (a, b), a <= b
  std::vector<DistanceMatrix> matrices;    // D_ab, per pair
  std::vector<double> limit;               // threshold, per pair
  std::vector<TransitionCandidate> found;

  int pair_index(int a, int b) const {
    const auto key = std::minmax(a, b);
    return static_cast<int>(
        std::find(pairs.begin(), pairs.end(), std::pair(key.first, key.second)) - pairs.begin());
  }
  // D(A_i, B_j) in metres RMS, or infinity when the windows do not fit (or are excluded).
  double distance(int a, int i, int b, int j, const GraphSettings& s) const {
    if (excluded(a, b, i, j, s)) return std::numeric_limits<double>::infinity();
    const DistanceMatrix& m = matrices[pair_index(a, b)];
    if (a > b) std::swap(i, j);  // D_ab(i, j) = D_ba(j, i)
    if (i < 0 || j < 0 || i >= m.rows || j >= m.cols)
      return std::numeric_limits<double>::infinity();
    return m.at(i, j);
  }
};

TransitionSearch search_transitions(const std::vector<MotionClip>& clips,
                                    const GraphSettings& settings) {
  check_settings(settings);
  TransitionSearch search;
  const int n = static_cast<int>(clips.size());
  const int span = span_of(settings);
  // Unordered pairs (a <= b): D is symmetric, D_ab(i, j) = D_ba(j, i).
  std::vector<std::pair<int, int>>& pairs = search.pairs;
  for (int a = 0; a < n; ++a)
    for (int b = a; b < n; ++b) pairs.emplace_back(a, b);
  std::vector<DistanceMatrix>& matrices = search.matrices;
  std::vector<double>& limit = search.limit;
  for (const auto& [a, b] : pairs) {
    matrices.push_back(
        window_distances(clips[a], clips[b], settings.window, span, settings.joint_weights));
    const DistanceMatrix& m = matrices.back();
    if (settings.threshold_mode == ThresholdMode::absolute) {
      limit.push_back(settings.threshold);
      continue;
    }
    std::vector<double> all;
    for (int i = 0; i < m.rows; ++i)
      for (int j = (a == b ? i + 1 : 0); j < m.cols; ++j)
        if (!excluded(a, b, i, j, settings)) all.push_back(m.at(i, j));
    if (all.empty()) {
      limit.push_back(0.0);
      continue;
    }
    const size_t rank =
        std::min(all.size() - 1, static_cast<size_t>(std::floor(settings.threshold / 100.0 *
                                                                static_cast<double>(all.size()))));
    std::nth_element(all.begin(), all.begin() + static_cast<std::ptrdiff_t>(rank), all.end());
    limit.push_back(std::min(all[rank], settings.max_distance));
  }
  std::vector<TransitionCandidate>& out = search.found;
  for (size_t p = 0; p < pairs.size(); ++p) {
    const auto [ca, cb] = pairs[p];
    const DistanceMatrix& m = matrices[p];
    const bool self = ca == cb;
    for (int i = 0; i < m.rows; ++i)
      for (int j = self ? i + 1 : 0; j < m.cols; ++j) {
        if (excluded(ca, cb, i, j, settings)) continue;
        const double d = m.at(i, j);
        if (d > limit[p]) continue;
        // A local minimum over the neighbourhood, ties broken by (i, j) so that a flat valley
        // (identical frames) gives one transition. Within a clip, the neighbourhood is
        // restricted to the same (upper) half, whose entries are the ones considered.
        bool minimum = true;
        for (int u = std::max(0, i - settings.spacing);
             minimum && u <= std::min(m.rows - 1, i + settings.spacing); ++u)
          for (int v = std::max(0, j - settings.spacing);
               v <= std::min(m.cols - 1, j + settings.spacing); ++v) {
            if ((u == i && v == j) || (self && v <= u) || excluded(ca, cb, u, v, settings))
              continue;
            const double e = m.at(u, v);
            if (e < d || (e == d && std::tie(u, v) < std::tie(i, j))) {
              minimum = false;
              break;
            }
          }
        if (!minimum) continue;
        const WindowAlignment al =
            align_windows(clips[ca], i, clips[cb], j, settings.window, settings.joint_weights);
        TransitionCandidate forward{ca, i, cb, j, d, al.transform, false};
        TransitionCandidate backward{cb, j, ca, i, d, al.transform.inverse(), false};
        out.push_back(forward);
        out.push_back(backward);
      }
  }
  std::sort(out.begin(), out.end(), [](const TransitionCandidate& x, const TransitionCandidate& y) {
    return std::tie(x.from_clip, x.from_frame, x.to_clip, x.to_frame) <
           std::tie(y.from_clip, y.from_frame, y.to_clip, y.to_frame);
  });
  return search;
}

std::vector<PairThreshold> pair_thresholds(const TransitionSearch& search) {
  std::vector<PairThreshold> out;
  for (size_t p = 0; p < search.pairs.size(); ++p)
    out.push_back({search.pairs[p].first, search.pairs[p].second, search.limit[p]});
  return out;
}

}  // namespace

std::vector<TransitionCandidate> find_transitions(const std::vector<MotionClip>& clips,
                                                  const GraphSettings& settings,
                                                  std::vector<PairThreshold>* thresholds) {
  TransitionSearch search = search_transitions(clips, settings);
  if (thresholds) *thresholds = pair_thresholds(search);
  return std::move(search.found);
}

int GraphSettings::min_segment_frames(double rate) const {
  if (!(min_segment_s > 0)) return 0;
  // The small tolerance keeps 0.3 s at 30 Hz at 9 frames despite 0.3 * 30 = 9.000000000000002.
  return static_cast<int>(std::ceil(min_segment_s * rate - 1e-9));
}

namespace {

// Snapping (GraphSettings::min_segment_s). Per clip, the nodes are chosen among the transitions'
// departure and arrival frames: the frames where most transition points lie first (ties: the
// earlier frame), each taken when it is at least m = min_segment_frames apart from every node
// taken before; declared transitions' points are taken first and never move. Every point then
// lies less than m frames from a node. Each found transition (A, i) -> (B, j), which leaves A at
// i and arrives in B at j + blend, is moved to the pair of nodes (i', a') within m - 1 frames of
// (i, j + blend) whose Kovar distance D(A_i', B_(a' - blend)) is smallest (ties: the smaller
// total move, then the earlier frames), and its alignment recomputed there (Kovar 2002 sec.
// 3.1); if no such pair has D within the pair's threshold, the transition is dropped. Moving
// both ends by the same number of frames follows the valley of D along its diagonal (both clips
// advance together), which is why most transitions survive a move of a few frames. Two
// transitions that become the same keep the one of smaller distance.
std::vector<TransitionCandidate> snap_transitions(const std::vector<MotionClip>& clips,
                                                  const GraphSettings& s,
                                                  const TransitionSearch& search,
                                                  const std::vector<TransitionCandidate>& input,
                                                  int* moved, int* dropped) {
  *moved = *dropped = 0;
  const int m = s.min_segment_frames(clips.front().rate);
  if (m <= 1) return input;
  const int n = static_cast<int>(clips.size());
  std::vector<std::map<int, int>> count(n);  // per clip: frame -> transition points there
  std::vector<std::set<int>> nodes(n);
  for (const TransitionCandidate& t : input) {
    const int arrival = t.to_frame + s.blend;
    if (t.manual) {
      nodes[t.from_clip].insert(t.from_frame);
      nodes[t.to_clip].insert(arrival);
    } else {
      ++count[t.from_clip][t.from_frame];
      ++count[t.to_clip][arrival];
    }
  }
  for (int c = 0; c < n; ++c) {
    std::vector<std::pair<int, int>> order;  // (-points, frame)
    for (const auto& [frame, points] : count[c]) order.emplace_back(-points, frame);
    std::sort(order.begin(), order.end());
    for (const auto& [neg, frame] : order) {
      (void)neg;
      const auto next = nodes[c].lower_bound(frame);
      const bool far_after = next == nodes[c].end() || *next - frame >= m;
      const bool far_before = next == nodes[c].begin() || frame - *std::prev(next) >= m;
      if (far_after && far_before) nodes[c].insert(frame);
    }
  }
  const auto near = [&](int clip, int frame) {
    std::vector<int> out;
    for (auto it = nodes[clip].lower_bound(frame - (m - 1));
         it != nodes[clip].end() && *it <= frame + (m - 1); ++it)
      out.push_back(*it);
    return out;
  };
  std::map<std::tuple<int, int, int, int>, TransitionCandidate> kept;
  for (const TransitionCandidate& t : input) {
    TransitionCandidate best = t;
    if (!t.manual) {
      const double limit = search.limit[search.pair_index(t.from_clip, t.to_clip)];
      double best_d = std::numeric_limits<double>::infinity();
      int best_move = 0;
      for (int i : near(t.from_clip, t.from_frame))
        for (int a : near(t.to_clip, t.to_frame + s.blend)) {
          const int j = a - s.blend;
          const double d = search.distance(t.from_clip, i, t.to_clip, j, s);
          const int move = std::abs(i - t.from_frame) + std::abs(j - t.to_frame);
          if (d < best_d || (d == best_d && move < best_move)) {
            best_d = d;
            best_move = move;
            best.from_frame = i;
            best.to_frame = j;
          }
        }
      if (!(best_d <= limit)) {
        ++*dropped;
        continue;
      }
      if (best.from_frame != t.from_frame || best.to_frame != t.to_frame) {
        ++*moved;
        const WindowAlignment al =
            align_windows(clips[t.from_clip], best.from_frame, clips[t.to_clip], best.to_frame,
                          s.window, s.joint_weights);
        best.distance = best_d;
        best.align = al.transform;
      }
    }
    const auto key = std::make_tuple(best.from_clip, best.from_frame, best.to_clip, best.to_frame);
    const auto it = kept.find(key);
    if (it == kept.end()) {
      kept.emplace(key, best);
    } else {
      ++*dropped;
      if (best.manual || (!it->second.manual && best.distance < it->second.distance))
        it->second = best;
    }
  }
  std::vector<TransitionCandidate> out;
  for (const auto& [key, t] : kept) out.push_back(t);  // sorted by (from, to) as found ones are
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Graph

const char* edge_kind_name(EdgeKind kind) {
  return kind == EdgeKind::clip ? "clip" : "transition";
}

int MotionGraph::transition_count() const {
  return static_cast<int>(std::count_if(edges.begin(), edges.end(), [](const GraphEdge& e) {
    return e.kind == EdgeKind::transition;
  }));
}

std::vector<int> MotionGraph::outgoing(int node) const {
  std::vector<int> out;
  for (int e = 0; e < edge_count(); ++e)
    if (edges[e].from == node) out.push_back(e);
  return out;
}

std::vector<int> MotionGraph::incoming(int node) const {
  std::vector<int> out;
  for (int e = 0; e < edge_count(); ++e)
    if (edges[e].to == node) out.push_back(e);
  return out;
}

std::vector<std::vector<int>> strongly_connected_components(
    int node_count, const std::vector<std::pair<int, int>>& edges) {
  // Adjacency in CSR form, successors in edge order.
  std::vector<int> start(node_count + 1, 0), succ(edges.size());
  for (const auto& [u, v] : edges) {
    if (u < 0 || u >= node_count || v < 0 || v >= node_count)
      throw GraphError("strongly_connected_components: edge out of range");
    ++start[u + 1];
  }
  for (int u = 0; u < node_count; ++u) start[u + 1] += start[u];
  {
    std::vector<int> fill(start.begin(), start.end() - 1);
    for (const auto& [u, v] : edges) succ[fill[u]++] = v;
  }
  // Tarjan with an explicit call stack of (node, next successor position).
  constexpr int kUnvisited = -1;
  std::vector<int> index(node_count, kUnvisited), low(node_count, 0);
  std::vector<char> on_stack(node_count, 0);
  std::vector<int> stack;
  std::vector<std::pair<int, int>> calls;
  std::vector<std::vector<int>> components;
  int counter = 0;
  for (int root = 0; root < node_count; ++root) {
    if (index[root] != kUnvisited) continue;
    calls.emplace_back(root, start[root]);
    index[root] = low[root] = counter++;
    stack.push_back(root);
    on_stack[root] = 1;
    while (!calls.empty()) {
      auto& [u, next] = calls.back();
      if (next < start[u + 1]) {
        const int v = succ[next++];
        if (index[v] == kUnvisited) {
          index[v] = low[v] = counter++;
          stack.push_back(v);
          on_stack[v] = 1;
          calls.emplace_back(v, start[v]);  // invalidates u/next: not used again this turn
        } else if (on_stack[v]) {
          low[u] = std::min(low[u], index[v]);
        }
        continue;
      }
      const int done = u;
      calls.pop_back();
      if (!calls.empty()) low[calls.back().first] = std::min(low[calls.back().first], low[done]);
      if (low[done] == index[done]) {
        std::vector<int> component;
        int w;
        do {
          w = stack.back();
          stack.pop_back();
          on_stack[w] = 0;
          component.push_back(w);
        } while (w != done);
        std::sort(component.begin(), component.end());
        components.push_back(std::move(component));
      }
    }
  }
  return components;
}

namespace {

bool edge_less(const GraphEdge& x, const GraphEdge& y) {
  return std::make_tuple(x.from, x.kind, x.to, x.clip, x.first_frame, x.target_clip,
                         x.target_first_frame) < std::make_tuple(y.from, y.kind, y.to, y.clip,
                                                                 y.first_frame, y.target_clip,
                                                                 y.target_first_frame);
}

// Renumbers the nodes in (clip, frame) order, dropping those no edge touches, and sorts the edges.
void renumber(MotionGraph& g, const std::vector<char>& keep) {
  std::vector<int> order;
  for (int v = 0; v < g.node_count(); ++v)
    if (keep[v]) order.push_back(v);
  std::sort(order.begin(), order.end(), [&](int u, int v) {
    return std::tie(g.nodes[u].clip, g.nodes[u].frame) <
           std::tie(g.nodes[v].clip, g.nodes[v].frame);
  });
  std::vector<int> new_index(g.node_count(), -1);
  std::vector<GraphNode> nodes;
  for (int v : order) {
    new_index[v] = static_cast<int>(nodes.size());
    nodes.push_back(g.nodes[v]);
  }
  std::vector<GraphEdge> edges;
  for (GraphEdge e : g.edges) {
    if (new_index[e.from] < 0 || new_index[e.to] < 0) continue;
    e.from = new_index[e.from];
    e.to = new_index[e.to];
    edges.push_back(e);
  }
  std::sort(edges.begin(), edges.end(), edge_less);
  g.nodes = std::move(nodes);
  g.edges = std::move(edges);
}

}  // namespace

void prune_to_largest_component(MotionGraph& g) {
  std::vector<std::pair<int, int>> arcs;
  for (const GraphEdge& e : g.edges) arcs.emplace_back(e.from, e.to);
  const std::vector<std::vector<int>> components =
      strongly_connected_components(g.node_count(), arcs);
  std::vector<int> component_of(g.node_count(), -1);
  for (size_t c = 0; c < components.size(); ++c)
    for (int v : components[c]) component_of[v] = static_cast<int>(c);
  std::vector<int> inner_edges(components.size(), 0);
  for (const auto& [u, v] : arcs)
    if (component_of[u] == component_of[v]) ++inner_edges[component_of[u]];
  int best = -1;
  for (int c = 0; c < static_cast<int>(components.size()); ++c) {
    if (best < 0) {
      best = c;
      continue;
    }
    const auto key = [&](int k) {
      return std::make_tuple(components[k].size(), inner_edges[k], -components[k].front());
    };
    if (key(c) > key(best)) best = c;
  }
  std::vector<char> keep(g.node_count(), 0);
  if (best >= 0)
    for (int v : components[best]) keep[v] = 1;
  std::vector<GraphEdge> edges;
  for (const GraphEdge& e : g.edges)
    if (keep[e.from] && keep[e.to]) edges.push_back(e);
  g.edges = std::move(edges);

  // A node whose only edges are one clip edge in and one clip edge out is where a pruned
  // transition used to leave or arrive: join the two segments (the joined graph has the same
  // paths and stays strongly connected).
  for (int v = 0; v < g.node_count(); ++v) {
    if (!keep[v]) continue;
    int in = -1, out = -1, in_count = 0, out_count = 0;
    for (int e = 0; e < g.edge_count(); ++e) {
      if (g.edges[e].to == v) in = e, ++in_count;
      if (g.edges[e].from == v) out = e, ++out_count;
    }
    if (in_count != 1 || out_count != 1 || in == out) continue;
    GraphEdge& a = g.edges[in];
    const GraphEdge& b = g.edges[out];
    if (a.kind != EdgeKind::clip || b.kind != EdgeKind::clip) continue;
    a.to = b.to;
    a.last_frame = b.last_frame;
    a.target_first_frame = a.target_frame = b.last_frame;
    g.edges.erase(g.edges.begin() + out);
    keep[v] = 0;
  }
  renumber(g, keep);
}

bool is_strongly_connected(const MotionGraph& g) {
  std::vector<std::pair<int, int>> arcs;
  for (const GraphEdge& e : g.edges) arcs.emplace_back(e.from, e.to);
  return g.node_count() > 0 && strongly_connected_components(g.node_count(), arcs).size() == 1;
}

namespace {

void check_clips(const std::vector<MotionClip>& clips, const Skeleton& skeleton) {
  if (clips.empty()) throw GraphError("motion graph: no clips");
  std::set<std::string> names;
  for (const MotionClip& c : clips) {
    if (!names.insert(c.name).second)
      throw GraphError("motion graph: two clips are called '" + c.name + "'");
    if (c.joint_count != skeleton.joint_count())
      throw GraphError("clip '" + c.name + "' (" + c.source + ") has " +
                       std::to_string(c.joint_count) + " joints, the skeleton " +
                       std::to_string(skeleton.joint_count()));
    if (c.rate != clips.front().rate)
      throw GraphError("clip '" + c.name + "' is sampled at " + std::to_string(c.rate) +
                       " Hz, clip '" + clips.front().name + "' at " +
                       std::to_string(clips.front().rate) + " Hz: one rate is needed");
    if (c.frame_count < 2) throw GraphError("clip '" + c.name + "' has fewer than 2 frames");
  }
  if (static_cast<int>(skeleton.parents.size()) != skeleton.joint_count())
    throw GraphError("skeleton " + skeleton.source + ": parents and names differ in size");
  for (int j = 0; j < skeleton.joint_count(); ++j)
    if (skeleton.parents[j] >= j)
      throw GraphError("skeleton " + skeleton.source + ": joints are not in parent-first order");
}

}  // namespace

MotionGraph build_motion_graph(const std::vector<MotionClip>& clips, const Skeleton& skeleton,
                               const GraphSettings& settings,
                               const std::vector<ManifestTransition>& declared) {
  check_settings(settings);
  check_clips(clips, skeleton);
  MotionGraph g;
  g.settings = settings;
  g.joint_names = skeleton.names;
  g.parents = skeleton.parents;
  for (const MotionClip& c : clips) g.clips.push_back({c.name, c.source, c.frame_count, c.rate});

  const TransitionSearch search = search_transitions(clips, settings);
  g.thresholds = pair_thresholds(search);
  std::vector<TransitionCandidate> transitions = search.found;
  for (const ManifestTransition& d : declared) {
    auto clip_index = [&](const std::string& name, const char* field) {
      for (size_t c = 0; c < clips.size(); ++c)
        if (clips[c].name == name) return static_cast<int>(c);
      throw GraphError(d.where + "." + field + ": no clip named '" + name + "' in the graph");
    };
    const int a = clip_index(d.from, "from"), b = clip_index(d.to, "to");
    if (d.frame < 0 || d.frame + settings.blend >= clips[a].frame_count)
      throw GraphError(d.where + ".frame: frame " + std::to_string(d.frame) +
                       " plus the blend of " + std::to_string(settings.blend) +
                       " frames is beyond clip '" + d.from + "' (" +
                       std::to_string(clips[a].frame_count) + " frames)");
    if (d.to_frame < 0 || d.to_frame + settings.blend >= clips[b].frame_count)
      throw GraphError(d.where + ".to_frame: frame " + std::to_string(d.to_frame) +
                       " plus the blend of " + std::to_string(settings.blend) +
                       " frames is beyond clip '" + d.to + "' (" +
                       std::to_string(clips[b].frame_count) + " frames)");
    // The alignment uses the distance window, shortened to the blend if it is longer.
    const int window = std::min(settings.window, settings.blend + 1);
    const WindowAlignment al =
        align_windows(clips[a], d.frame, clips[b], d.to_frame, window, settings.joint_weights);
    TransitionCandidate t{a, d.frame, b, d.to_frame, al.rms, al.transform, true};
    // A declared transition replaces a found one between the same frames.
    std::erase_if(transitions, [&](const TransitionCandidate& x) {
      return x.from_clip == a && x.from_frame == d.frame && x.to_clip == b &&
             x.to_frame == d.to_frame;
    });
    transitions.push_back(t);
  }
  transitions = snap_transitions(clips, settings, search, transitions, &g.snapped_transitions,
                                 &g.snap_dropped);
  g.candidate_transitions = static_cast<int>(transitions.size());

  // Nodes: clip starts and ends, transition departures and arrivals.
  std::set<std::pair<int, int>> points;
  for (int c = 0; c < static_cast<int>(clips.size()); ++c) {
    points.emplace(c, 0);
    points.emplace(c, clips[c].frame_count - 1);
  }
  for (const TransitionCandidate& t : transitions) {
    points.emplace(t.from_clip, t.from_frame);
    points.emplace(t.to_clip, t.to_frame + settings.blend);
  }
  std::map<std::pair<int, int>, int> node_of;
  for (const auto& [clip, frame] : points) {
    node_of[{clip, frame}] = g.node_count();
    g.nodes.push_back({clip, frame});
  }
  g.candidate_nodes = g.node_count();
  for (int v = 0; v + 1 < g.node_count(); ++v) {
    const GraphNode& a = g.nodes[v];
    const GraphNode& b = g.nodes[v + 1];
    if (a.clip != b.clip) continue;
    GraphEdge e;
    e.from = v;
    e.to = v + 1;
    e.kind = EdgeKind::clip;
    e.clip = e.target_clip = a.clip;
    e.first_frame = a.frame;
    e.last_frame = e.target_first_frame = e.target_frame = b.frame;
    g.edges.push_back(e);
  }
  for (const TransitionCandidate& t : transitions) {
    GraphEdge e;
    e.kind = EdgeKind::transition;
    e.from = node_of.at({t.from_clip, t.from_frame});
    e.to = node_of.at({t.to_clip, t.to_frame + settings.blend});
    e.clip = t.from_clip;
    e.first_frame = t.from_frame;
    e.last_frame = t.from_frame + settings.blend;
    e.target_clip = t.to_clip;
    e.target_first_frame = t.to_frame;
    e.target_frame = t.to_frame + settings.blend;
    e.blend = settings.blend;
    e.distance = t.distance;
    e.align = t.align;
    e.manual = t.manual;
    g.edges.push_back(e);
  }
  std::sort(g.edges.begin(), g.edges.end(), edge_less);

  if (settings.prune) {
    prune_to_largest_component(g);
    if (g.edges.empty()) {
      double largest = 0.0;
      for (const PairThreshold& t : g.thresholds) largest = std::max(largest, t.rms);
      char threshold[64];
      std::snprintf(threshold, sizeof threshold, "%.4g m", largest);
      throw GraphError("motion graph: the " + std::to_string(g.candidate_transitions) +
                       " transitions at or below the threshold (at most " + threshold +
                       " RMS) leave no cycle, so pruning to the largest strongly connected "
                       "component leaves no edge; raise the threshold");
    }
  }
  return g;
}

GraphInput load_graph_input(const std::filesystem::path& manifest_file,
                            const std::vector<std::string>& clip_names) {
  const MotionManifest manifest = load_manifest(manifest_file);
  std::vector<int> selected;
  if (clip_names.empty()) {
    for (int c = 0; c < static_cast<int>(manifest.clips.size()); ++c) selected.push_back(c);
  } else {
    for (const std::string& name : clip_names) {
      const int c = manifest.require(name);
      if (std::find(selected.begin(), selected.end(), c) != selected.end())
        throw GraphError(manifest_file.string() + ": clip '" + name + "' selected twice");
      selected.push_back(c);
    }
  }
  GraphInput input;
  std::set<std::string> loaded;
  for (int c : selected) {
    LoadedMotion m = load_clip(manifest, c);
    if (input.clips.empty()) {
      input.skeleton = m.skeleton;
    } else if (m.skeleton.names != input.skeleton.names ||
               m.skeleton.parents != input.skeleton.parents) {
      throw GraphError(manifest_file.string() + ": clip '" + manifest.clips[c].name + "' (" +
                       m.skeleton.source + ") does not have the skeleton of clip '" +
                       input.clips.front().name + "' (" + input.skeleton.source +
                       "): a motion graph needs one skeleton");
    }
    loaded.insert(manifest.clips[c].name);
    input.clips.push_back(std::move(m.clip));
    input.clip_weights.push_back(manifest.clips[c].weight);
    input.files.push_back(manifest.clips[c].file.string());
  }
  for (const ManifestTransition& t : manifest.transitions)
    if (loaded.count(t.from) && loaded.count(t.to)) input.transitions.push_back(t);
  return input;
}

void set_edge_weights(MotionGraph& graph, const std::vector<double>& clip_weights,
                      const std::vector<ManifestTransition>& declared) {
  if (!clip_weights.empty() && clip_weights.size() != graph.clips.size())
    throw GraphError("set_edge_weights: " + std::to_string(clip_weights.size()) +
                     " clip weights for a graph of " + std::to_string(graph.clips.size()) +
                     " clips");
  for (GraphEdge& e : graph.edges) {
    e.weight = clip_weights.empty() ? 1.0 : clip_weights[e.target_clip];
    if (e.kind != EdgeKind::transition || !e.manual) continue;
    for (const ManifestTransition& d : declared)
      if (d.weight > 0 && graph.clips[e.clip].name == d.from && d.frame == e.first_frame &&
          graph.clips[e.target_clip].name == d.to && d.to_frame == e.target_first_frame)
        e.weight = d.weight;
  }
}

std::vector<double> edge_reach(int node_count, const std::vector<std::pair<int, int>>& edges,
                               const std::vector<double>& weights) {
  std::vector<double> out_weight(node_count, 0.0);
  for (size_t e = 0; e < edges.size(); ++e) out_weight[edges[e].first] += weights[e];
  // An unpruned graph (--no-prune) may have nodes with no way out: the game's chain then has no
  // stationary distribution over the whole graph, so every edge counts as equally likely.
  for (int v = 0; v < node_count; ++v)
    if (!(out_weight[v] > 0)) return std::vector<double>(edges.size(), 1.0);
  // Power iteration on the lazy chain pi <- (pi + pi P) / 2 from the uniform distribution.
  std::vector<double> pi(node_count, 1.0 / node_count), next(node_count);
  for (int it = 0; it < 100000; ++it) {
    for (int v = 0; v < node_count; ++v) next[v] = 0.5 * pi[v];
    for (size_t e = 0; e < edges.size(); ++e)
      next[edges[e].second] += 0.5 * pi[edges[e].first] * weights[e] / out_weight[edges[e].first];
    double change = 0;
    for (int v = 0; v < node_count; ++v) change += std::abs(next[v] - pi[v]);
    pi.swap(next);
    if (change < 1e-14) break;
  }
  std::vector<double> reach(edges.size());
  double largest = 0;
  for (size_t e = 0; e < edges.size(); ++e) {
    reach[e] = pi[edges[e].first] * weights[e] / out_weight[edges[e].first];
    largest = std::max(largest, reach[e]);
  }
  for (double& r : reach) r = largest > 0 ? r / largest : 1.0;
  return reach;
}

std::vector<double> edge_reach(const MotionGraph& graph) {
  std::vector<std::pair<int, int>> edges;
  std::vector<double> weights;
  for (const GraphEdge& e : graph.edges) {
    edges.emplace_back(e.from, e.to);
    weights.push_back(e.weight);
  }
  return edge_reach(graph.node_count(), edges, weights);
}

// ---------------------------------------------------------------------------------------------
// Poses along edges

namespace {

void check_graph_clips(const MotionGraph& g, const std::vector<MotionClip>& clips, int edge) {
  if (edge < 0 || edge >= g.edge_count())
    throw GraphError("edge " + std::to_string(edge) + " out of range (the graph has " +
                     std::to_string(g.edge_count()) + " edges)");
  if (clips.size() != g.clips.size())
    throw GraphError("the graph has " + std::to_string(g.clips.size()) + " clips, " +
                     std::to_string(clips.size()) + " given");
  for (size_t c = 0; c < clips.size(); ++c)
    if (clips[c].name != g.clips[c].name || clips[c].frame_count != g.clips[c].frame_count ||
        clips[c].joint_count != static_cast<int>(g.parents.size()))
      throw GraphError("clip " + std::to_string(c) + " '" + clips[c].name +
                       "' is not the graph's clip '" + g.clips[c].name + "' (" +
                       std::to_string(g.clips[c].frame_count) + " frames)");
}

// One frame's pose split into what a blend interpolates: per joint the rotation relative to the
// parent (a root's is its world rotation) and the offset from the parent in the parent's frame
// (a root's is its world position), so that composing them back gives the frame exactly.
struct LocalPose {
  std::vector<Eigen::Quaterniond> rotation;
  std::vector<Eigen::Vector3d> offset;
};

LocalPose local_pose(const MotionClip& clip, int frame, const std::vector<int>& parents,
                     const FloorTransform& place) {
  const int n = clip.joint_count;
  std::vector<JointPose> world(n);
  for (int j = 0; j < n; ++j)
    world[j] = place.apply(JointPose{clip.position(frame, j), clip.rotation(frame, j)});
  LocalPose local;
  local.rotation.resize(n);
  local.offset.resize(n);
  for (int j = 0; j < n; ++j) {
    const int p = parents[j];
    if (p < 0) {
      local.rotation[j] = world[j].rotation;
      local.offset[j] = world[j].position;
    } else {
      const Eigen::Quaterniond inv = world[p].rotation.conjugate();
      local.rotation[j] = inv * world[j].rotation;
      local.offset[j] = inv * (world[j].position - world[p].position);
    }
  }
  return local;
}

}  // namespace

std::vector<std::vector<JointPose>> edge_poses(const MotionGraph& g,
                                               const std::vector<MotionClip>& clips, int edge) {
  check_graph_clips(g, clips, edge);
  const GraphEdge& e = g.edges[edge];
  const MotionClip& clip = clips[e.clip];
  const int n = clip.joint_count;
  std::vector<std::vector<JointPose>> poses;
  if (e.kind == EdgeKind::clip) {
    for (int f = e.first_frame; f <= e.last_frame; ++f) {
      std::vector<JointPose> pose(n);
      for (int j = 0; j < n; ++j) pose[j] = {clip.position(f, j), clip.rotation(f, j)};
      poses.push_back(std::move(pose));
    }
    return poses;
  }
  const MotionClip& target = clips[e.target_clip];
  for (int p = 0; p <= e.blend; ++p) {
    // Kovar's blend weight alpha(p) = 2 s^3 - 3 s^2 + 1 (sec. 3.3) with s = p / blend, so that
    // alpha is 1 on the first pose and 0 on the last, with zero slope at both ends.
    const double s = static_cast<double>(p) / e.blend;
    const double alpha = 2.0 * s * s * s - 3.0 * s * s + 1.0;
    const LocalPose a = local_pose(clip, e.first_frame + p, g.parents, FloorTransform{});
    const LocalPose b = local_pose(target, e.target_first_frame + p, g.parents, e.align);
    std::vector<JointPose> pose(n);
    for (int j = 0; j < n; ++j) {
      // Eigen's slerp takes the shorter arc.
      const Eigen::Quaterniond q = a.rotation[j].slerp(1.0 - alpha, b.rotation[j]).normalized();
      const Eigen::Vector3d o = alpha * a.offset[j] + (1.0 - alpha) * b.offset[j];
      const int parent = g.parents[j];
      if (parent < 0) {
        pose[j] = {o, q};
      } else {
        pose[j].position = pose[parent].position + pose[parent].rotation * o;
        pose[j].rotation = (pose[parent].rotation * q).normalized();
      }
    }
    poses.push_back(std::move(pose));
  }
  return poses;
}

std::vector<std::vector<JointPose>> edge_poses_canonical(const MotionGraph& g,
                                                         const std::vector<MotionClip>& clips,
                                                         int edge) {
  std::vector<std::vector<JointPose>> poses = edge_poses(g, clips, edge);
  const FloorTransform to_canonical = floor_frame(poses.front().front()).inverse();
  for (std::vector<JointPose>& pose : poses)
    for (JointPose& joint : pose) joint = to_canonical.apply(joint);
  return poses;
}

FloorTransform edge_handoff(const MotionGraph& g, const std::vector<MotionClip>& clips, int edge) {
  const std::vector<std::vector<JointPose>> poses = edge_poses(g, clips, edge);
  const FloorTransform start = floor_frame(poses.front().front());
  const FloorTransform end = floor_frame(poses.back().front());
  // canonical(e) = start^-1 world(e); canonical(next) = end^-1 world(e) (the next edge's first
  // pose is the end pose, up to the alignment that the floor frame absorbs).
  return end.inverse() * start;
}

void carry_to_next_edge(const FloorTransform& handoff, std::vector<Eigen::Vector3d>* positions,
                        std::vector<Eigen::Vector3d>* velocities) {
  if (positions)
    for (Eigen::Vector3d& p : *positions) p = handoff.apply(p);
  if (velocities)
    for (Eigen::Vector3d& v : *velocities) v = handoff.rotate(v);
}

// ---------------------------------------------------------------------------------------------
// JSON

namespace {

constexpr const char* kFormat = "clothdb.motion_graph";
constexpr int kVersion = 1;

const char* threshold_mode_name(ThresholdMode m) {
  return m == ThresholdMode::absolute ? "absolute" : "percentile";
}

class Reader {
 public:
  explicit Reader(std::string where) : where_(std::move(where)) {}
  [[noreturn]] void fail(const std::string& field, const std::string& what) const {
    throw GraphError(where_ + ": " + field + ": " + what);
  }
  const nlohmann::json& member(const nlohmann::json& object, const std::string& key,
                               const std::string& field) const {
    if (!object.is_object() || !object.contains(key)) fail(field, "missing");
    return object.at(key);
  }
  int integer(const nlohmann::json& o, const std::string& key, const std::string& prefix, int lo,
              int hi) const {
    const nlohmann::json& v = member(o, key, prefix + key);
    if (!v.is_number_integer() || v.get<long long>() < lo || v.get<long long>() > hi)
      fail(prefix + key,
           "expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    return static_cast<int>(v.get<long long>());
  }
  double number(const nlohmann::json& o, const std::string& key, const std::string& prefix) const {
    const nlohmann::json& v = member(o, key, prefix + key);
    if (!v.is_number() || !std::isfinite(v.get<double>())) fail(prefix + key, "expected a number");
    return v.get<double>();
  }
  std::string string(const nlohmann::json& o, const std::string& key,
                     const std::string& prefix) const {
    const nlohmann::json& v = member(o, key, prefix + key);
    if (!v.is_string()) fail(prefix + key, "expected a string");
    return v.get<std::string>();
  }
  bool boolean(const nlohmann::json& o, const std::string& key, const std::string& prefix) const {
    const nlohmann::json& v = member(o, key, prefix + key);
    if (!v.is_boolean()) fail(prefix + key, "expected true or false");
    return v.get<bool>();
  }
  const nlohmann::json& array(const nlohmann::json& o, const std::string& key,
                              const std::string& prefix) const {
    const nlohmann::json& v = member(o, key, prefix + key);
    if (!v.is_array()) fail(prefix + key, "expected an array");
    return v;
  }

 private:
  std::string where_;
};

constexpr int kMaxInt = std::numeric_limits<int>::max();

}  // namespace

nlohmann::json motion_graph_to_json(const MotionGraph& g) {
  using nlohmann::json;
  json j;
  j["format"] = kFormat;
  j["version"] = kVersion;
  const GraphSettings& s = g.settings;
  j["settings"] = {{"window", s.window},
                   {"blend", s.blend},
                   {"threshold_mode", threshold_mode_name(s.threshold_mode)},
                   {"threshold", s.threshold},
                   {"max_distance", s.max_distance},
                   {"spacing", s.spacing},
                   {"min_self_offset", s.min_self_offset},
                   {"joint_weights", s.joint_weights},
                   {"prune", s.prune}};
  // Only when snapping is on, so that graphs made before it existed keep their exact JSON (a
  // database compares the graph it holds with the one given).
  if (s.min_segment_s > 0) j["settings"]["min_segment_s"] = s.min_segment_s;
  j["thresholds"] = nlohmann::json::array();
  for (const PairThreshold& t : g.thresholds)
    j["thresholds"].push_back({{"clip_a", t.clip_a}, {"clip_b", t.clip_b}, {"rms", t.rms}});
  j["joints"] = {{"names", g.joint_names}, {"parents", g.parents}};
  j["clips"] = json::array();
  for (const GraphClip& c : g.clips)
    j["clips"].push_back(
        {{"name", c.name}, {"source", c.source}, {"frame_count", c.frame_count}, {"rate", c.rate}});
  j["nodes"] = json::array();
  for (const GraphNode& n : g.nodes) j["nodes"].push_back({{"clip", n.clip}, {"frame", n.frame}});
  j["edges"] = json::array();
  for (const GraphEdge& e : g.edges)
    j["edges"].push_back({{"from", e.from},
                          {"to", e.to},
                          {"kind", edge_kind_name(e.kind)},
                          {"clip", e.clip},
                          {"first_frame", e.first_frame},
                          {"last_frame", e.last_frame},
                          {"target_clip", e.target_clip},
                          {"target_first_frame", e.target_first_frame},
                          {"target_frame", e.target_frame},
                          {"blend", e.blend},
                          {"distance", e.distance},
                          {"align", {e.align.theta, e.align.x, e.align.z}},
                          {"manual", e.manual},
                          {"weight", e.weight}});
  j["counts"] = {{"nodes", g.node_count()},
                 {"edges", g.edge_count()},
                 {"transitions", g.transition_count()},
                 {"clip_edges", g.clip_edge_count()},
                 {"candidate_transitions", g.candidate_transitions},
                 {"candidate_nodes", g.candidate_nodes}};
  if (s.min_segment_s > 0) {
    j["counts"]["snapped_transitions"] = g.snapped_transitions;
    j["counts"]["snap_dropped"] = g.snap_dropped;
  }
  return j;
}

MotionGraph motion_graph_from_json(const nlohmann::json& j, const std::string& where) {
  const Reader r(where);
  if (!j.is_object()) r.fail("(top level)", "expected an object");
  if (r.string(j, "format", "") != kFormat)
    r.fail("format", std::string("expected \"") + kFormat + "\"");
  if (r.integer(j, "version", "", 0, kMaxInt) != kVersion)
    r.fail("version", "expected " + std::to_string(kVersion));
  MotionGraph g;
  const nlohmann::json& s = r.member(j, "settings", "settings");
  g.settings.window = r.integer(s, "window", "settings.", 1, kMaxInt);
  g.settings.blend = r.integer(s, "blend", "settings.", 1, kMaxInt);
  const std::string mode = r.string(s, "threshold_mode", "settings.");
  if (mode != "absolute" && mode != "percentile")
    r.fail("settings.threshold_mode", "expected \"absolute\" or \"percentile\"");
  g.settings.threshold_mode =
      mode == "absolute" ? ThresholdMode::absolute : ThresholdMode::percentile;
  g.settings.threshold = r.number(s, "threshold", "settings.");
  g.settings.max_distance = r.number(s, "max_distance", "settings.");
  g.settings.spacing = r.integer(s, "spacing", "settings.", 0, kMaxInt);
  g.settings.min_self_offset = r.integer(s, "min_self_offset", "settings.", 1, kMaxInt);
  const nlohmann::json& weights = r.array(s, "joint_weights", "settings.");
  for (size_t k = 0; k < weights.size(); ++k) {
    if (!weights[k].is_number() || !(weights[k].get<double>() >= 0))
      r.fail("settings.joint_weights[" + std::to_string(k) + "]", "expected a number >= 0");
    g.settings.joint_weights.push_back(weights[k].get<double>());
  }
  g.settings.prune = r.boolean(s, "prune", "settings.");
  if (s.contains("min_segment_s")) {
    g.settings.min_segment_s = r.number(s, "min_segment_s", "settings.");
    if (!(g.settings.min_segment_s >= 0))
      r.fail("settings.min_segment_s", "expected a number of seconds >= 0");
  }

  const nlohmann::json& joints = r.member(j, "joints", "joints");
  const nlohmann::json& names = r.array(joints, "names", "joints.");
  const nlohmann::json& parents = r.array(joints, "parents", "joints.");
  if (names.empty() || names.size() != parents.size())
    r.fail("joints", "expected as many parents as names, at least one");
  for (size_t k = 0; k < names.size(); ++k) {
    if (!names[k].is_string())
      r.fail("joints.names[" + std::to_string(k) + "]", "expected a string");
    g.joint_names.push_back(names[k].get<std::string>());
    const std::string field = "joints.parents[" + std::to_string(k) + "]";
    if (!parents[k].is_number_integer() || parents[k].get<long long>() < -1 ||
        parents[k].get<long long>() >= static_cast<long long>(k))
      r.fail(field, "expected -1 or the index of an earlier joint");
    g.parents.push_back(static_cast<int>(parents[k].get<long long>()));
  }

  const nlohmann::json& clips = r.array(j, "clips", "");
  for (size_t c = 0; c < clips.size(); ++c) {
    const std::string p = "clips[" + std::to_string(c) + "].";
    GraphClip clip;
    clip.name = r.string(clips[c], "name", p);
    clip.source = r.string(clips[c], "source", p);
    clip.frame_count = r.integer(clips[c], "frame_count", p, 2, kMaxInt);
    clip.rate = r.number(clips[c], "rate", p);
    if (!(clip.rate > 0)) r.fail(p + "rate", "expected a positive number");
    g.clips.push_back(clip);
  }
  const int clip_count = static_cast<int>(g.clips.size());
  if (clip_count == 0) r.fail("clips", "expected at least one clip");
  const nlohmann::json& thresholds = r.array(j, "thresholds", "");
  for (size_t k = 0; k < thresholds.size(); ++k) {
    const std::string p = "thresholds[" + std::to_string(k) + "].";
    PairThreshold t;
    t.clip_a = r.integer(thresholds[k], "clip_a", p, 0, clip_count - 1);
    t.clip_b = r.integer(thresholds[k], "clip_b", p, t.clip_a, clip_count - 1);
    t.rms = r.number(thresholds[k], "rms", p);
    g.thresholds.push_back(t);
  }

  const nlohmann::json& nodes = r.array(j, "nodes", "");
  for (size_t v = 0; v < nodes.size(); ++v) {
    const std::string p = "nodes[" + std::to_string(v) + "].";
    GraphNode n;
    n.clip = r.integer(nodes[v], "clip", p, 0, clip_count - 1);
    n.frame = r.integer(nodes[v], "frame", p, 0, g.clips[n.clip].frame_count - 1);
    g.nodes.push_back(n);
  }
  const int node_count = g.node_count();
  const nlohmann::json& edges = r.array(j, "edges", "");
  for (size_t k = 0; k < edges.size(); ++k) {
    const std::string p = "edges[" + std::to_string(k) + "].";
    const nlohmann::json& o = edges[k];
    GraphEdge e;
    e.from = r.integer(o, "from", p, 0, node_count - 1);
    e.to = r.integer(o, "to", p, 0, node_count - 1);
    const std::string kind = r.string(o, "kind", p);
    if (kind != "clip" && kind != "transition")
      r.fail(p + "kind", "expected \"clip\" or \"transition\"");
    e.kind = kind == "clip" ? EdgeKind::clip : EdgeKind::transition;
    e.clip = r.integer(o, "clip", p, 0, clip_count - 1);
    e.first_frame = r.integer(o, "first_frame", p, 0, g.clips[e.clip].frame_count - 1);
    e.last_frame = r.integer(o, "last_frame", p, e.first_frame, g.clips[e.clip].frame_count - 1);
    e.target_clip = r.integer(o, "target_clip", p, 0, clip_count - 1);
    const int target_frames = g.clips[e.target_clip].frame_count;
    e.target_first_frame = r.integer(o, "target_first_frame", p, 0, target_frames - 1);
    e.target_frame = r.integer(o, "target_frame", p, e.target_first_frame, target_frames - 1);
    e.blend = r.integer(o, "blend", p, 0, kMaxInt);
    e.distance = r.number(o, "distance", p);
    const nlohmann::json& align = r.array(o, "align", p);
    if (align.size() != 3 || !align[0].is_number() || !align[1].is_number() ||
        !align[2].is_number())
      r.fail(p + "align", "expected [theta, x, z]");
    e.align = {align[0].get<double>(), align[1].get<double>(), align[2].get<double>()};
    e.manual = r.boolean(o, "manual", p);
    if (o.contains("weight")) {  // graphs written before weights existed have none: all 1
      e.weight = r.number(o, "weight", p);
      if (!(e.weight > 0) || !std::isfinite(e.weight))
        r.fail(p + "weight", "expected a positive number");
    }
    // The edge must fit its nodes: it leaves its source node's frame and arrives at its target's.
    const GraphNode& from = g.nodes[e.from];
    const GraphNode& to = g.nodes[e.to];
    if (from.clip != e.clip || from.frame != e.first_frame)
      r.fail(p + "from", "node " + std::to_string(e.from) + " is not the edge's first frame");
    if (to.clip != e.target_clip || to.frame != e.target_frame)
      r.fail(p + "to", "node " + std::to_string(e.to) + " is not the frame the edge arrives at");
    if (e.kind == EdgeKind::clip
            ? (e.target_clip != e.clip || e.target_frame != e.last_frame || e.blend != 0)
            : (e.last_frame - e.first_frame != e.blend ||
               e.target_frame - e.target_first_frame != e.blend || e.blend < 1))
      r.fail(p + "blend", "frames and blend do not agree with the edge's kind");
    g.edges.push_back(e);
  }
  if (const nlohmann::json* counts = j.contains("counts") ? &j.at("counts") : nullptr) {
    g.candidate_transitions = r.integer(*counts, "candidate_transitions", "counts.", 0, kMaxInt);
    g.candidate_nodes = r.integer(*counts, "candidate_nodes", "counts.", 0, kMaxInt);
    if (counts->contains("snapped_transitions"))
      g.snapped_transitions = r.integer(*counts, "snapped_transitions", "counts.", 0, kMaxInt);
    if (counts->contains("snap_dropped"))
      g.snap_dropped = r.integer(*counts, "snap_dropped", "counts.", 0, kMaxInt);
  }
  return g;
}

GraphSettings graph_settings_from_scene(const nlohmann::json& block, const std::string& where) {
  const Reader r(where);
  GraphSettings s;
  if (block.is_null()) return s;
  if (!block.is_object()) r.fail("graph", "expected an object");
  const std::vector<std::string> known = {"window",       "blend",         "spacing",
                                          "self_offset",  "percentile",    "threshold",
                                          "max_distance", "min_segment_s", "prune"};
  for (auto it = block.begin(); it != block.end(); ++it)
    if (std::find(known.begin(), known.end(), it.key()) == known.end()) {
      std::string list;
      for (const std::string& k : known) list += (list.empty() ? "" : ", ") + k;
      r.fail("graph." + it.key(), "unknown field (known: " + list + ")");
    }
  const auto non_negative = [&](const char* key, double fallback) {
    if (!block.contains(key)) return fallback;
    const double v = r.number(block, key, "graph.");
    if (!(v >= 0)) r.fail(std::string("graph.") + key, "expected a number >= 0");
    return v;
  };
  if (block.contains("window")) s.window = r.integer(block, "window", "graph.", 1, 1000);
  if (block.contains("blend")) s.blend = r.integer(block, "blend", "graph.", 1, 1000);
  if (block.contains("spacing")) s.spacing = r.integer(block, "spacing", "graph.", 0, 100000);
  if (block.contains("self_offset"))
    s.min_self_offset = r.integer(block, "self_offset", "graph.", 1, 100000);
  if (block.contains("percentile") && block.contains("threshold"))
    r.fail("graph.threshold",
           "give either percentile (relative) or threshold (absolute), not both");
  if (block.contains("percentile")) {
    s.threshold_mode = ThresholdMode::percentile;
    s.threshold = non_negative("percentile", s.threshold);
    if (s.threshold > 100) r.fail("graph.percentile", "expected a percentile between 0 and 100");
  }
  if (block.contains("threshold")) {
    s.threshold_mode = ThresholdMode::absolute;
    s.threshold = non_negative("threshold", s.threshold);
  }
  s.max_distance = non_negative("max_distance", s.max_distance);
  s.min_segment_s = non_negative("min_segment_s", s.min_segment_s);
  if (block.contains("prune")) s.prune = r.boolean(block, "prune", "graph.");
  return s;
}

GraphCoverage graph_coverage(const MotionGraph& g) {
  GraphCoverage out;
  std::vector<std::vector<char>> played;
  for (const GraphClip& c : g.clips) {
    out.clips.push_back({c.name, c.frame_count, 0});
    played.emplace_back(static_cast<size_t>(std::max(0, c.frame_count)), 0);
  }
  std::vector<int> lengths;
  for (const GraphEdge& e : g.edges) {
    if (e.kind == EdgeKind::transition) {
      out.largest_transition = std::max(out.largest_transition, e.distance);
      continue;
    }
    if (e.clip < 0 || e.clip >= static_cast<int>(g.clips.size())) continue;
    std::vector<char>& p = played[e.clip];
    for (int f = std::max(0, e.first_frame); f <= e.last_frame && f < static_cast<int>(p.size());
         ++f)
      p[f] = 1;
    const int length = e.last_frame - e.first_frame;
    lengths.push_back(length);
    const int minimum = g.settings.min_segment_frames(g.clips[e.clip].rate);
    const bool at_clip_end = e.first_frame == 0 || e.last_frame == g.clips[e.clip].frame_count - 1;
    if (length < minimum && !at_clip_end) ++out.short_inner_segments;
  }
  for (size_t c = 0; c < g.clips.size(); ++c) {
    out.clips[c].kept = static_cast<int>(std::count(played[c].begin(), played[c].end(), 1));
    out.frames += out.clips[c].frames;
    out.kept += out.clips[c].kept;
  }
  out.segments = static_cast<int>(lengths.size());
  if (!lengths.empty()) {
    std::sort(lengths.begin(), lengths.end());
    out.median_segment = lengths[(lengths.size() - 1) / 2];
    out.shortest_segment = lengths.front();
  }
  return out;
}

std::string coverage_text(const MotionGraph& g) {
  const GraphCoverage c = graph_coverage(g);
  std::string text;
  char line[512];
  const double rate = g.clips.empty() ? 30.0 : g.clips.front().rate;
  std::snprintf(line, sizeof line,
                "coverage: %d of %d frames kept (%.1f %%); %d clip segments, median %d frames "
                "(%.2f s), shortest %d; largest transition distance %.2f cm RMS\n",
                c.kept, c.frames, 100.0 * c.kept_fraction(), c.segments, c.median_segment,
                c.median_segment / rate, c.shortest_segment, 100.0 * c.largest_transition);
  text += line;
  for (const ClipCoverage& clip : c.clips) {
    std::snprintf(line, sizeof line, "  clip %-20s %5d of %5d frames kept (%.1f %%)\n",
                  clip.name.c_str(), clip.kept, clip.frames,
                  clip.frames > 0 ? 100.0 * clip.kept / clip.frames : 0.0);
    text += line;
  }
  const GraphSettings& s = g.settings;
  if (s.min_segment_s > 0) {
    std::snprintf(line, sizeof line,
                  "  snapping: min_segment_s %g (%d frames): %d transitions moved onto shared "
                  "nodes, %d dropped; %d segments shorter away from clip ends\n",
                  s.min_segment_s, s.min_segment_frames(rate), g.snapped_transitions,
                  g.snap_dropped, c.short_inner_segments);
    text += line;
  }
  if (c.kept_fraction() < 0.5) {
    char threshold[128];
    if (s.threshold_mode == ThresholdMode::percentile)
      std::snprintf(threshold, sizeof threshold, "percentile %g (at most max_distance %g m)",
                    s.threshold, s.max_distance);
    else
      std::snprintf(threshold, sizeof threshold, "threshold %g m", s.threshold);
    std::snprintf(line, sizeof line,
                  "warning: the graph keeps only %.1f %% of the frames (under 50 %%) with %s, "
                  "spacing %d, min_segment_s %g: raise the %s to keep more of the motion\n",
                  100.0 * c.kept_fraction(), threshold, s.spacing, s.min_segment_s,
                  s.threshold_mode == ThresholdMode::percentile ? "percentile" : "threshold");
    text += line;
  }
  return text;
}

MotionGraph load_motion_graph(const std::filesystem::path& file) {
  const std::string where = file.string();
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec)) throw GraphError(where + ": file not found");
  std::ifstream in(file);
  if (!in) throw GraphError(where + ": cannot open it");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(in);
  } catch (const nlohmann::json::parse_error& e) {
    throw GraphError(where + ": not valid JSON: " + e.what());
  }
  return motion_graph_from_json(j, where);
}

}  // namespace clothdb
