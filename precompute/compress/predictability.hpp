// How predictable a garment's frames are under a per-coordinate error bound
// (docs/notebook/BENCHMARKS.md, "Codec v2 in the precompute"): what a subspace of k modes leaves,
// in character space and relative to a rigid body frame fitted to the garment's least-moving
// vertices, and how often that residual is already within the bound as is, after subtracting the
// previous frame's residual, or after linear extrapolation in time. A coordinate within the bound
// of its prediction costs a codec (v2: subspace + residual layer) almost nothing; every other one
// costs bits, so these fractions bound the ratio any predictor of that family can reach under a
// hard L-infinity bound. `clothdb bench codec --predictability`.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace clothdb {

struct PredictabilityRow {
  std::string space;  // "character" or "body" (rigid frame of the anchors removed)
  uint32_t modes = 0;
  double rms_left = 0;  // RMS per coordinate of what the modes leave, m
  // Per bound (PredictabilityReport::bounds): fraction of coordinates whose residual r_f is
  // within the bound as is, as r_f - r_{f-1}, and as r_f - 2 r_{f-1} + r_{f-2} (measured in
  // character space, where the codec's bound applies; frames whose predictors would reach back
  // across a clip start are left out of the temporal columns).
  std::vector<double> within_as_is, within_delta, within_linear;
};

struct PredictabilityReport {
  std::vector<double> bounds;   // m
  uint32_t anchors = 0;         // vertices the body frame is fitted to
  double max_rotation_deg = 0;  // largest rotation of the body frame from the anchors' mean pose
  std::vector<PredictabilityRow> rows;
};

// frames: frame_count x 3 x vertices floats (character space); clip_starts: frame indices where a
// new clip begins (0 may be omitted). Modes are built from every frame (build_subspace), the
// largest count once, and truncated for the smaller ones. anchor_fraction of the vertices, those
// whose positions vary least over the frames, carry the body frame (Kabsch fit per frame to
// their mean pose). Throws std::invalid_argument on bad sizes or non-finite frames.
PredictabilityReport analyse_predictability(const std::vector<float>& frames, uint32_t vertices,
                                            uint32_t frame_count,
                                            const std::vector<uint32_t>& clip_starts,
                                            const std::vector<uint32_t>& modes,
                                            const std::vector<double>& bounds,
                                            double anchor_fraction = 0.05);

}  // namespace clothdb
