#include "character/manifest.hpp"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>

namespace clothdb {

namespace {

constexpr const char* kTestModelsVariable = "${ASSIMP_TESTMODELS}";

using nlohmann::json;

class FieldReader {
 public:
  explicit FieldReader(std::string manifest) : manifest_(std::move(manifest)) {}

  [[noreturn]] void fail(const std::string& field, const std::string& what) const {
    throw MotionError(manifest_ + ": " + field + ": " + what);
  }

  double positive_number(const json& value, const std::string& field) const {
    if (!value.is_number() || !(value.get<double>() > 0) || !std::isfinite(value.get<double>()))
      fail(field, "expected a positive number");
    return value.get<double>();
  }

  int frame(const json& value, const std::string& field) const {
    if (!value.is_number_integer() || value.get<long long>() < -1 ||
        value.get<long long>() > (1LL << 30))
      fail(field, "expected a frame number (an integer >= 0, or -1 for the last frame)");
    return static_cast<int>(value.get<long long>());
  }

  std::string string(const json& value, const std::string& field) const {
    if (!value.is_string()) fail(field, "expected a string");
    return value.get<std::string>();
  }

  void only_known_keys(const json& object, const std::set<std::string>& known,
                       const std::string& prefix) const {
    for (const auto& item : object.items())
      if (!known.count(item.key()))
        fail(prefix + item.key(), "unknown field (typo?); known fields: " + join(known));
  }

 private:
  static std::string join(const std::set<std::string>& names) {
    std::string s;
    for (const std::string& n : names) s += (s.empty() ? "" : ", ") + n;
    return s;
  }
  std::string manifest_;
};

}  // namespace

std::filesystem::path assimp_testmodels_dir() {
  if (const char* env = std::getenv("ASSIMP_TESTMODELS"); env && *env) return env;
  // Debian/Ubuntu's assimp-testmodels installs here; /usr/local for a source install.
  for (const char* dir : {"/usr/share/assimp/models", "/usr/local/share/assimp/models"}) {
    std::error_code ec;
    if (std::filesystem::is_directory(dir, ec)) return dir;
  }
  return {};
}

int MotionManifest::require(const std::string& name) const {
  std::string names;
  for (size_t c = 0; c < clips.size(); ++c) {
    if (clips[c].name == name) return static_cast<int>(c);
    names += (names.empty() ? "" : ", ") + clips[c].name;
  }
  throw MotionError(path.string() + ": no clip named '" + name + "' (it has " + names + ")");
}

MotionManifest load_manifest(const std::filesystem::path& file) {
  const std::string where = file.string();
  std::error_code ec;
  if (std::filesystem::is_directory(file, ec))
    throw MotionError(where + ": is a directory, not a manifest file (JSON)");
  if (!std::filesystem::is_regular_file(file, ec)) throw MotionError(where + ": file not found");
  std::ifstream in(file);
  if (!in) throw MotionError(where + ": cannot open it");
  json root;
  try {
    root = json::parse(in);
  } catch (const json::parse_error& e) {
    throw MotionError(where + ": not valid JSON: " + e.what());
  }
  const FieldReader reader(where);
  if (!root.is_object()) reader.fail("(top level)", "expected an object with a \"clips\" array");
  // A scene given where a manifest is asked for (`graph build motions/skirt_walk.json`): name the
  // mix-up and the scene's manifest, not the scene's first field as a typo.
  if (root.contains("garment") && root.contains("manifest") && root["manifest"].is_string())
    reader.fail("(top level)", "a scene file, not a motion manifest; its manifest is \"" +
                                   root["manifest"].get<std::string>() +
                                   "\" (relative to the scene's folder)");
  reader.only_known_keys(root, {"output_rate", "clips", "transitions"}, "");

  MotionManifest manifest;
  manifest.path = file;
  if (root.contains("output_rate"))
    manifest.output_rate = reader.positive_number(root["output_rate"], "output_rate");
  if (!root.contains("clips")) reader.fail("clips", "missing (expected an array of clips)");
  const json& clips = root["clips"];
  if (!clips.is_array() || clips.empty()) reader.fail("clips", "expected a non-empty array");

  const std::filesystem::path base = file.parent_path();
  std::set<std::string> seen;
  for (size_t c = 0; c < clips.size(); ++c) {
    const std::string prefix = "clips[" + std::to_string(c) + "]";
    const json& clip = clips[c];
    if (!clip.is_object()) reader.fail(prefix, "expected an object");
    reader.only_known_keys(clip,
                           {"name", "file", "first_frame", "last_frame", "source_rate", "scale",
                            "up_axis", "animation", "weight"},
                           prefix + ".");
    MotionClipSpec spec;
    if (!clip.contains("file")) reader.fail(prefix + ".file", "missing (expected a path)");
    std::string path = reader.string(clip["file"], prefix + ".file");
    if (path.empty()) reader.fail(prefix + ".file", "expected a non-empty path");
    if (path.rfind(kTestModelsVariable, 0) == 0) {
      const std::filesystem::path models = assimp_testmodels_dir();
      if (models.empty())
        reader.fail(prefix + ".file",
                    "uses ${ASSIMP_TESTMODELS} but the assimp test models are not installed "
                    "(install Debian's assimp-testmodels or set ASSIMP_TESTMODELS)");
      std::string rest = path.substr(std::string(kTestModelsVariable).size());
      while (!rest.empty() && rest.front() == '/') rest.erase(rest.begin());
      spec.file = models / rest;
    } else {
      spec.file =
          std::filesystem::path(path).is_absolute() ? std::filesystem::path(path) : base / path;
    }
    spec.name = clip.contains("name") ? reader.string(clip["name"], prefix + ".name")
                                      : spec.file.stem().string();
    if (spec.name.empty()) reader.fail(prefix + ".name", "expected a non-empty name");
    if (!seen.insert(spec.name).second)
      reader.fail(prefix + ".name", "duplicate clip name '" + spec.name + "'");

    MotionLoadOptions& o = spec.options;
    o.name = spec.name;
    o.output_rate = manifest.output_rate;
    if (clip.contains("first_frame")) {
      o.first_frame = reader.frame(clip["first_frame"], prefix + ".first_frame");
      if (o.first_frame < 0) reader.fail(prefix + ".first_frame", "expected an integer >= 0");
    }
    if (clip.contains("last_frame"))
      o.last_frame = reader.frame(clip["last_frame"], prefix + ".last_frame");
    if (o.last_frame >= 0 && o.last_frame < o.first_frame)
      reader.fail(prefix + ".last_frame", "is before first_frame " + std::to_string(o.first_frame));
    if (clip.contains("source_rate"))
      o.source_rate = reader.positive_number(clip["source_rate"], prefix + ".source_rate");
    if (clip.contains("scale")) o.scale = reader.positive_number(clip["scale"], prefix + ".scale");
    if (clip.contains("up_axis")) {
      const std::string axis = reader.string(clip["up_axis"], prefix + ".up_axis");
      try {
        o.up_axis = parse_up_axis(axis);
      } catch (const std::invalid_argument& e) {
        reader.fail(prefix + ".up_axis", e.what());
      }
    }
    if (clip.contains("animation"))
      o.animation = reader.string(clip["animation"], prefix + ".animation");
    if (clip.contains("weight"))
      spec.weight = reader.positive_number(clip["weight"], prefix + ".weight");
    manifest.clips.push_back(std::move(spec));
  }

  if (root.contains("transitions")) {
    const json& transitions = root["transitions"];
    if (!transitions.is_array()) reader.fail("transitions", "expected an array");
    for (size_t t = 0; t < transitions.size(); ++t) {
      const std::string prefix = "transitions[" + std::to_string(t) + "]";
      const json& item = transitions[t];
      if (!item.is_object()) reader.fail(prefix, "expected an object");
      reader.only_known_keys(item, {"from", "frame", "to", "to_frame", "weight"}, prefix + ".");
      ManifestTransition transition;
      transition.where = where + ": " + prefix;
      for (const char* key : {"from", "frame", "to", "to_frame"})
        if (!item.contains(key)) reader.fail(prefix + "." + key, "missing");
      transition.from = reader.string(item["from"], prefix + ".from");
      transition.to = reader.string(item["to"], prefix + ".to");
      for (const std::string* name : {&transition.from, &transition.to})
        if (!seen.count(*name))
          reader.fail(prefix + (name == &transition.from ? ".from" : ".to"),
                      "no clip named '" + *name + "'");
      transition.frame = reader.frame(item["frame"], prefix + ".frame");
      transition.to_frame = reader.frame(item["to_frame"], prefix + ".to_frame");
      if (transition.frame < 0) reader.fail(prefix + ".frame", "expected an integer >= 0");
      if (transition.to_frame < 0) reader.fail(prefix + ".to_frame", "expected an integer >= 0");
      if (item.contains("weight"))
        transition.weight = reader.positive_number(item["weight"], prefix + ".weight");
      manifest.transitions.push_back(std::move(transition));
    }
  }
  return manifest;
}

namespace {

// A human skeleton, after the manifest's scale and up axis, stands 0.5 to 3 m tall along +y at its
// first frame. Outside that the clip still loads (it may be a creature), but the usual cause is a
// missing scale (a skeleton in centimetres is 100x too tall) or up axis (lying on its back), so
// say which field to set.
void warn_implausible_skeleton(const LoadedMotion& m, const std::string& field) {
  if (m.clip.frame_count < 1 || m.clip.joint_count < 2) return;
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e300), hi = -lo;
  for (int j = 0; j < m.clip.joint_count; ++j) {
    const Eigen::Vector3d p = m.clip.positions[size_t(j)];
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const Eigen::Vector3d size = hi - lo;
  const double height = size.y(), across = std::max(size.x(), size.z());
  if (!std::isfinite(height)) return;
  if (height > 3.0 || std::max(height, across) < 0.5)
    std::fprintf(stderr,
                 "%s: warning: the skeleton is %.3g m tall (a person is 0.5 to 3 m): set %s.scale "
                 "to the file's units in metres (now %g)\n",
                 m.clip.source.c_str(), height, field.c_str(), m.clip.scale);
  else if (across > 1.5 * height && across > 0.5)
    std::fprintf(stderr,
                 "%s: warning: the skeleton is %.3g m across but only %.3g m tall at its first "
                 "frame, as if lying down: set %s.up_axis (\"x\", \"y\" or \"z\") to the "
                 "file's up axis\n",
                 m.clip.source.c_str(), across, height, field.c_str());
}

}  // namespace

LoadedMotion load_clip(const MotionManifest& manifest, int clip) {
  if (clip < 0 || clip >= static_cast<int>(manifest.clips.size()))
    throw MotionError(manifest.path.string() + ": no clip " + std::to_string(clip));
  const MotionClipSpec& spec = manifest.clips[clip];
  try {
    LoadedMotion m = load_motion(spec.file, spec.options);
    warn_implausible_skeleton(m, manifest.path.string() + ": clips[" + std::to_string(clip) + "]");
    return m;
  } catch (const MotionError& e) {
    // Say which manifest entry led to the file as well: the file message alone may not tell the
    // user which manifest to fix (a frame range, a scale).
    throw MotionError(std::string(e.what()) + " (clip '" + spec.name + "' of " +
                      manifest.path.string() + ")");
  }
}

}  // namespace clothdb
