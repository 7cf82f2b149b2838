// `clothdb motion info`: what a motion file or motion manifest holds once loaded (joints, frames,
// rate, duration, hip height range, bounding box), to check a manifest's scale, up axis and frame
// range before simulating with it.
#include <cstdio>
#include <memory>
#include <optional>
#include <string>

#include "character/body.hpp"
#include "character/manifest.hpp"
#include "character/motion_loader.hpp"
#include "commands.hpp"

namespace clothdb::cli {

namespace {

void print_motion(const LoadedMotion& m, bool list_joints) {
  const Skeleton& sk = m.skeleton;
  const MotionClip& c = m.clip;
  std::printf("clip '%s' from %s\n", c.name.c_str(), c.source.c_str());
  std::printf("  joints: %d (root %s)\n", sk.joint_count(), sk.names[0].c_str());
  std::printf("  source: %d frames at %g Hz; clip uses frames %d..%g\n", c.source_frame_count,
              c.source_rate, c.first_source_frame,
              c.first_source_frame + (c.frame_count - 1) * c.source_rate / c.rate);
  std::printf("  frames: %d at %g Hz, duration %.3f s\n", c.frame_count, c.rate, c.duration());
  std::printf(
      "  scale: %g m per file unit; skeleton size %.3f m (%g x its span, %.3f m along "
      "the bones: the default capsule radii's reference)\n",
      c.scale, skeleton_size(sk), kStatureOverSpan, skeleton_span(sk));
  // End sites give the last capsule of each chain its far end (head top, toe and finger tips):
  // say which are the file's and which the loader made up (docs/guide/garment_placement.md,
  // "Motion from Blender").
  int from_file = 0, made_up = 0;
  for (int j = 0; j < sk.joint_count(); ++j)
    if (sk.end_site[j]) ++(sk.end_site_from_file[j] ? from_file : made_up);
  std::printf("  end sites: %d from the file, %d made up for leaves the file gives no end\n",
              from_file, made_up);
  Eigen::Vector3d lo = c.positions.front(), hi = c.positions.front();
  double hip_lo = c.position(0, 0).y(), hip_hi = hip_lo;
  for (int f = 0; f < c.frame_count; ++f) {
    hip_lo = std::min(hip_lo, c.position(f, 0).y());
    hip_hi = std::max(hip_hi, c.position(f, 0).y());
    for (int j = 0; j < c.joint_count; ++j) {
      lo = lo.cwiseMin(c.position(f, j));
      hi = hi.cwiseMax(c.position(f, j));
    }
  }
  std::printf("  hip (%s) height: %.3f .. %.3f m\n", sk.names[0].c_str(), hip_lo, hip_hi);
  std::printf("  bounding box (joints, all frames): [%.3f %.3f %.3f] .. [%.3f %.3f %.3f] m\n",
              lo.x(), lo.y(), lo.z(), hi.x(), hi.y(), hi.z());
  if (!list_joints) return;
  const std::vector<JointPose> rest = rest_pose(sk);
  for (int j = 0; j < sk.joint_count(); ++j) {
    int depth = 0;
    for (int p = sk.parents[j]; p >= 0; p = sk.parents[p]) ++depth;
    std::printf("  %3d %*s%s  (%s, rest at %.3f %.3f %.3f)\n", j, 2 * depth, "",
                sk.names[j].c_str(), body_region_name(classify_bone(sk, j)), rest[j].position.x(),
                rest[j].position.y(), rest[j].position.z());
  }
}

}  // namespace

void register_motion_commands(CLI::App& app) {
  CLI::App* motion = app.add_subcommand("motion", "Character motion (BVH, FBX, glTF 2, Collada)");
  motion->require_subcommand(1);

  struct Args {
    std::string input, clip, up_axis;
    std::optional<double> scale, source_rate;
    double rate = 0.0;
    int first = 0, last = -1;
    bool joints = false;
  };
  auto args = std::make_shared<Args>();
  CLI::App* info = motion->add_subcommand(
      "info",
      "Loads a motion manifest (.json, every clip) or a motion file and prints its joints, frames, "
      "rate, duration, hip height range and bounding box in metres.");
  info->add_option("input", args->input, "Motion manifest (.json) or motion file")->required();
  info->add_option("--clip", args->clip, "Manifest: only this clip");
  info->add_option("--scale", args->scale,
                   "File: file units -> metres (default: the file's, or 1)");
  info->add_option("--up-axis", args->up_axis,
                   "File: up axis x | y | z (default: the file's, or y)");
  info->add_option("--source-rate", args->source_rate, "File: source frame rate, Hz");
  info->add_option("--rate", args->rate, "File: output rate, Hz (0: the source rate)")
      ->capture_default_str();
  info->add_option("--first", args->first, "File: first source frame")->capture_default_str();
  info->add_option("--last", args->last, "File: last source frame (-1: the last)")
      ->capture_default_str();
  info->add_flag("--joints", args->joints,
                 "List the joints with their body region and rest position");
  info->callback([args] {
    const std::filesystem::path input = args->input;
    if (input.extension() == ".json") {
      const MotionManifest manifest = load_manifest(input);
      std::printf("manifest %s: %zu clips, output rate %g Hz\n", input.string().c_str(),
                  manifest.clips.size(), manifest.output_rate);
      if (!args->clip.empty()) manifest.require(args->clip);  // fail before loading anything
      for (int c = 0; c < static_cast<int>(manifest.clips.size()); ++c) {
        if (!args->clip.empty() && manifest.clips[c].name != args->clip) continue;
        print_motion(load_clip(manifest, c), args->joints);
      }
      return;
    }
    MotionLoadOptions options;
    options.scale = args->scale;
    if (!args->up_axis.empty()) options.up_axis = parse_up_axis(args->up_axis);
    options.source_rate = args->source_rate;
    options.output_rate = args->rate;
    options.first_frame = args->first;
    options.last_frame = args->last;
    print_motion(load_motion(input, options), args->joints);
  });
}

}  // namespace clothdb::cli
