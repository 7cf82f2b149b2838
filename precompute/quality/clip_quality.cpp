#include "quality/clip_quality.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "cloth/self_intersection.hpp"
#include "solvers/solver.hpp"

namespace clothdb {

namespace {

// Coefficients of the fourth difference; the sum of their squares is 70 (header: jitter).
constexpr double kFourth[5] = {1, -4, 6, -4, 1};
constexpr double kFourthSquares = 70.0;

}  // namespace

ClipQuality measure_clip(const ClothModel& model, const float* frames, int frame_count,
                         const std::vector<std::vector<CapsuleCollider>>& capsules,
                         std::vector<FrameQuality>* per_frame) {
  const int n = model.vertex_count();
  if (frame_count < 1 || static_cast<int>(capsules.size()) != frame_count)
    throw std::invalid_argument("measure_clip: " + std::to_string(frame_count) + " frames but " +
                                std::to_string(capsules.size()) + " capsule sets");
  const size_t stride = static_cast<size_t>(n) * 3;
  auto at = [&](int f, int i, int k) { return double(frames[f * stride + 3 * size_t(i) + k]); };

  std::vector<FrameQuality> q(static_cast<size_t>(frame_count));
  ClipQuality out;
  double pen_sum = 0, jitter_sum = 0;
  long pen_count = 0, jitter_count = 0;
  Eigen::Matrix3Xd x(3, n);
  Environment env;
  for (int f = 0; f < frame_count; ++f) {
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < 3; ++k) x(k, i) = at(f, i, k);
    FrameQuality& fq = q[size_t(f)];
    fq.strain = max_edge_strain(model, x);
    env.capsules = capsules[size_t(f)];
    for (auto& c : env.capsules) c.a_start = c.a, c.b_start = c.b;  // the pose at frame f
    double frame_jitter = 0;
    int frame_free = 0;
    for (int i = 0; i < n; ++i) {
      if (model.inv_mass[i] <= 0.0) continue;
      const double d = penetration_depth(x.col(i), env, 1.0);
      if (d > 0.0) {
        pen_sum += d;
        ++pen_count;
        fq.max_penetration = std::max(fq.max_penetration, d);
      }
      if (f >= 2 && f + 2 < frame_count) {
        double sq = 0;
        for (int k = 0; k < 3; ++k) {
          double h = 0;
          for (int j = 0; j < 5; ++j) h += kFourth[j] * at(f - 2 + j, i, k);
          sq += h * h;
        }
        frame_jitter += sq / kFourthSquares;
        ++frame_free;
      }
    }
    if (frame_free > 0) {
      jitter_sum += frame_jitter;
      jitter_count += frame_free;
      fq.jitter = std::sqrt(frame_jitter / frame_free);
    }
    fq.self_intersections = count_self_intersections(model.mesh, x);
    if (fq.self_intersections > 0) ++out.self_intersection_frames;
    if (fq.self_intersections > out.self_intersections) {
      out.self_intersections = fq.self_intersections;
      out.self_intersection_frame = f;
    }
    fq.score = std::max({fq.strain / kVisibleStrain, fq.max_penetration / kVisiblePenetration,
                         fq.jitter / kVisibleJitter, double(fq.self_intersections)});
    out.max_strain = std::max(out.max_strain, fq.strain);
    out.max_penetration = std::max(out.max_penetration, fq.max_penetration);
    if (fq.score > q[size_t(out.worst_frame)].score) out.worst_frame = f;
  }
  out.mean_penetration = pen_count > 0 ? pen_sum / double(pen_count) : 0.0;
  out.jitter = jitter_count > 0 ? std::sqrt(jitter_sum / double(jitter_count)) : 0.0;
  if (per_frame) *per_frame = std::move(q);
  return out;
}

namespace {

std::vector<std::vector<CapsuleCollider>> capsules_in_character_space(
    const CharacterScene& scene, const Body& body,
    const std::vector<std::vector<JointPose>>& poses) {
  std::vector<std::vector<CapsuleCollider>> out;
  out.reserve(poses.size());
  for (const auto& pose : poses) {
    const Eigen::Isometry3d inv = character_frame(scene, pose).inverse();
    std::vector<CapsuleCollider> caps = body_capsules(body, scene.skeleton, pose, pose);
    for (auto& c : caps) {
      c.a = c.a_start = inv * c.a;
      c.b = c.b_start = inv * c.b;
    }
    out.push_back(std::move(caps));
  }
  return out;
}

}  // namespace

std::vector<std::vector<CapsuleCollider>> character_space_capsules(
    const CharacterScene& scene, const std::vector<std::vector<JointPose>>& poses) {
  return capsules_in_character_space(scene, scene.body, poses);
}

std::vector<std::vector<CapsuleCollider>> character_space_skeleton(
    const CharacterScene& scene, const std::vector<std::vector<JointPose>>& poses) {
  Body whole;
  whole.capsules = all_bone_capsules(scene.skeleton);
  for (BoneCapsule& c : whole.capsules) c.radius *= 0.6;
  return capsules_in_character_space(scene, whole, poses);
}

ClipQuality measure_clip(const CharacterScene& scene,
                         const std::vector<std::vector<JointPose>>& poses,
                         const std::vector<float>& frames, std::vector<FrameQuality>* per_frame) {
  const size_t per = static_cast<size_t>(scene.model.vertex_count()) * 3;
  if (frames.size() != poses.size() * per)
    throw std::invalid_argument("measure_clip: " + std::to_string(frames.size()) + " floats for " +
                                std::to_string(poses.size()) + " poses of " +
                                std::to_string(scene.model.vertex_count()) +
                                " vertices (expected " + std::to_string(poses.size() * per) + ")");
  // Back to world space, where the body is and what the viewer sees (header: jitter).
  std::vector<float> world(frames.size());
  std::vector<std::vector<CapsuleCollider>> body;
  body.reserve(poses.size());
  for (size_t f = 0; f < poses.size(); ++f) {
    const Eigen::Isometry3d frame = character_frame(scene, poses[f]);
    for (size_t i = 0; i < per; i += 3) {
      const Vec3 p =
          frame * Vec3(frames[f * per + i], frames[f * per + i + 1], frames[f * per + i + 2]);
      for (int k = 0; k < 3; ++k) world[f * per + i + size_t(k)] = static_cast<float>(p[k]);
    }
    body.push_back(body_capsules(scene.body, scene.skeleton, poses[f], poses[f]));
  }
  return measure_clip(scene.model, world.data(), static_cast<int>(poses.size()), body, per_frame);
}

double transition_pop(const float* last, const float* target, size_t vertex_count) {
  double worst2 = 0;
  for (size_t i = 0; i < vertex_count; ++i) {
    double d2 = 0;
    for (int k = 0; k < 3; ++k) {
      const double d = double(last[3 * i + k]) - double(target[3 * i + k]);
      d2 += d * d;
    }
    worst2 = std::max(worst2, d2);
  }
  return std::sqrt(worst2);
}

db::ClipMetrics to_clip_metrics(const ClipQuality& q) {
  db::ClipMetrics m;
  m.max_strain = q.max_strain;
  m.max_penetration = q.max_penetration;
  m.mean_penetration = q.mean_penetration;
  m.jitter = q.jitter;
  m.halved_steps = q.halved_steps;
  m.worst_frame = q.worst_frame;
  m.self_intersections = q.self_intersections;
  return m;
}

}  // namespace clothdb
