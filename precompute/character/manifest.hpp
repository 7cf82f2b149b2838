// Motion manifests (motions/*.json): which motion files a character uses, which frames of each,
// and how to bring them to metres and +y up. The data stays where it is installed; the manifest
// only names it. Format:
//
//   {
//     "output_rate": 30,
//     "clips": [
//       { "name": "walk", "file": "${ASSIMP_TESTMODELS}/BVH/01_01.bvh",
//         "first_frame": 1, "last_frame": 1200, "source_rate": 120,
//         "scale": 0.0564444, "up_axis": "y", "animation": "", "weight": 1 }
//     ],
//     "transitions": [ { "from": "walk", "frame": 120, "to": "run", "to_frame": 30, "weight": 1 } ]
//   }
//
// Only "clips" and each clip's "file" are required. A file path is absolute, relative to the
// manifest, or starts with "${ASSIMP_TESTMODELS}": the directory of Debian's assimp-testmodels
// (environment variable ASSIMP_TESTMODELS if set, else the installed package's directory).
// "transitions" (optional) declares motion-graph transitions by hand, besides those found
// automatically (graph/motion_graph.hpp): frame `frame` of clip `from` (frames of the clip at the
// output rate) corresponds to frame `to_frame` of clip `to`.
//
// "weight" (optional, > 0, default 1) says how likely the game is to take a way out of a
// motion-graph node: at a node, each edge leaving it is taken with probability weight / (sum of
// the weights of the edges leaving that node). An edge's weight is its declared transition's
// "weight" if it has one, else the "weight" of the clip it plays into (its target clip), so a
// clip's weight makes every way into it more or less likely. The explorer weights a dead end's
// error by how often the game reaches it (graph/motion_graph.hpp: edge_reach).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "character/motion_loader.hpp"

namespace clothdb {

struct MotionClipSpec {
  std::string name;
  std::filesystem::path file;  // resolved
  MotionLoadOptions options;   // name, range, rates, scale, up axis, animation
  double weight = 1.0;         // relative likelihood of the edges into this clip (see above)
};

// A transition declared in the manifest: clip names are checked against the manifest's clips here,
// frames against the clips' lengths when the graph is built.
struct ManifestTransition {
  std::string from;
  int frame = 0;
  std::string to;
  int to_frame = 0;
  std::string where;    // "<manifest>: transitions[k]", for error messages
  double weight = 0.0;  // > 0: this transition's weight (see above); 0: not given
};

struct MotionManifest {
  std::filesystem::path path;  // the manifest file
  double output_rate = 30.0;
  std::vector<MotionClipSpec> clips;
  std::vector<ManifestTransition> transitions;

  // Index of the clip called `name`; throws MotionError naming the manifest if there is none.
  int require(const std::string& name) const;
};

// Directory of the assimp test models: $ASSIMP_TESTMODELS, else the first of the known install
// locations that exists (Debian: /usr/share/assimp/models). Empty if none is found.
std::filesystem::path assimp_testmodels_dir();

// Reads and validates a manifest. Throws MotionError whose message names the manifest file and the
// JSON field, e.g. "motions/cmu_walk.json: clips[1].scale: expected a positive number". Referenced
// files are not opened here (load_clip does), but a "${ASSIMP_TESTMODELS}" path with no test
// models installed is reported.
MotionManifest load_manifest(const std::filesystem::path& file);

// Loads one clip of a manifest (resampled at the manifest's output rate).
LoadedMotion load_clip(const MotionManifest& manifest, int clip);

}  // namespace clothdb
