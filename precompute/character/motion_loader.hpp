// Skeletal motion from BVH, FBX, glTF 2 and Collada files through assimp: the node hierarchy
// becomes a Skeleton and the animation channels are sampled at a fixed output rate (positions
// lerped, rotations slerped between keys) into per-frame joint world transforms, in metres, +y up.
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "character/skeleton.hpp"

namespace clothdb {

enum class UpAxis { X, Y, Z };
const char* up_axis_name(UpAxis axis);  // "x", "y", "z"
// Parses "x"/"y"/"z" (either case); throws std::invalid_argument naming the accepted values.
UpAxis parse_up_axis(const std::string& text);
// Rotation taking a frame whose up axis is `axis` to clothdb's +y up (right-handed, a quarter turn
// about x for z-up, about z for x-up).
Eigen::Matrix3d up_axis_rotation(UpAxis axis);

struct MotionLoadOptions {
  std::string name;  // clip name; empty: the file stem
  // File units -> metres. Default: the file's own declaration where assimp reports one (FBX
  // UnitScaleFactor, in centimetres per unit), else 1. BVH has none: CMU data needs 0.0564444.
  std::optional<double> scale;
  // Up axis of the file. Default: FBX's UpAxis metadata, else +y (BVH, glTF; assimp already
  // rotates Collada's Z_UP scenes to +y).
  std::optional<UpAxis> up_axis;
  // Frame rate of the source in Hz; first_frame/last_frame count these frames. Default: the
  // file's: BVH 1 / "Frame Time" (snapped to the nearest integer when within 1e-4, since BVH
  // writers print 1/120 as .0083333), FBX its frame rate; for glTF and Collada, whose times are in
  // milliseconds, the spacing of the keys. Setting it retimes the motion (source frame k plays at
  // k / source_rate seconds): meant for files whose frame time is wrong, and for evenly keyed
  // files only.
  std::optional<double> source_rate;
  double output_rate = 0.0;  // Hz of the sampled clip; 0: the source rate
  int first_frame = 0;       // first source frame of the clip
  int last_frame = -1;       // last source frame, inclusive; -1: the last frame of the file
  std::string animation;     // animation name when the file has several; empty: the first one
};

struct LoadedMotion {
  Skeleton skeleton;
  MotionClip clip;
};

// Loads `file` and samples its animation. Throws MotionError naming the file and the problem when
// the file is missing or unreadable (including truncated), has no animation, has no skeleton
// (no animated node), or the options do not fit it (frame range, unknown animation name).
LoadedMotion load_motion(const std::filesystem::path& file, const MotionLoadOptions& options = {});

}  // namespace clothdb
