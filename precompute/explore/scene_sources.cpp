#include "explore/scene_sources.hpp"

#include <stdlib.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <stdexcept>

#include "database/format/meta_keys.hpp"
#include "explore/primary_graph.hpp"

namespace clothdb {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

std::string read_bytes(const fs::path& path, const std::string& what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path.string() + ": cannot read the " + what + " to store it");
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

db::SourceFile source(const std::string& role, const std::string& spelled, const fs::path& at,
                      const std::string& what) {
  const std::string bytes = read_bytes(at, what);
  return {0, role, spelled, content_hash(bytes), std::vector<uint8_t>(bytes.begin(), bytes.end())};
}

std::string text_of(const db::SourceFile& f) {
  return std::string(f.bytes.begin(), f.bytes.end());
}

// A glTF's buffers and images that are separate files (not data: URIs), relative to it.
std::vector<std::string> gltf_parts(const std::string& text) {
  std::vector<std::string> out;
  const json j = json::parse(text, nullptr, false);
  if (j.is_discarded() || !j.is_object()) return out;
  for (const char* key : {"buffers", "images"})
    if (j.contains(key) && j[key].is_array())
      for (const json& b : j[key])
        if (b.is_object() && b.contains("uri") && b["uri"].is_string()) {
          const std::string uri = b["uri"].get<std::string>();
          if (uri.rfind("data:", 0) != 0 && fs::path(uri).is_relative()) out.push_back(uri);
        }
  return out;
}

std::string short_value(const json& v) {
  std::string s = v.dump();
  if (s.size() > 60) s = s.substr(0, 57) + "...";
  return s;
}

std::string first_difference(const json& a, const json& b, const std::string& at) {
  const std::string here = at.empty() ? "(top level)" : at;
  if (a.type() != b.type() && !(a.is_number() && b.is_number()))
    return here + ": stored " + short_value(a) + ", given " + short_value(b);
  if (a.is_object()) {
    std::set<std::string> keys;
    for (auto it = a.begin(); it != a.end(); ++it) keys.insert(it.key());
    for (auto it = b.begin(); it != b.end(); ++it) keys.insert(it.key());
    for (const std::string& k : keys) {
      const std::string path = at.empty() ? k : at + "." + k;
      if (!a.contains(k)) return path + ": not stored, given " + short_value(b[k]);
      if (!b.contains(k)) return path + ": stored " + short_value(a[k]) + ", not given";
      const std::string d = first_difference(a[k], b[k], path);
      if (!d.empty()) return d;
    }
    return "";
  }
  if (a.is_array()) {
    for (size_t i = 0; i < std::min(a.size(), b.size()); ++i) {
      const std::string d = first_difference(a[i], b[i], at + "[" + std::to_string(i) + "]");
      if (!d.empty()) return d;
    }
    if (a.size() != b.size())
      return here + ": stored " + std::to_string(a.size()) + " entries, given " +
             std::to_string(b.size());
    return "";
  }
  if (a.is_number() && b.is_number() ? a.get<double>() != b.get<double>() : a != b)
    return here + ": stored " + short_value(a) + ", given " + short_value(b);
  return "";
}

// The database's motion_file rows and source_file rows.
std::vector<db::MotionFile> motion_rows(db::Reader& reader) {
  std::vector<db::MotionFile> rows;
  db::Error err;
  db::throw_if_error(reader.motion_files(&rows, &err), err);
  return rows;
}

std::vector<db::SourceFile> source_rows(db::Reader& reader) {
  std::vector<db::SourceFile> rows;
  db::Error err;
  db::throw_if_error(reader.source_files(&rows, &err), err);
  return rows;
}

// A temporary folder removed when it goes out of scope.
struct TempFolder {
  fs::path path;
  TempFolder() {
    std::string pattern = (fs::temp_directory_path() / "clothdb_scene_XXXXXX").string();
    if (!mkdtemp(pattern.data()))
      throw std::runtime_error("cannot make a temporary folder in " +
                               fs::temp_directory_path().string() + " for the stored scene");
    path = pattern;
  }
  ~TempFolder() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
  TempFolder(const TempFolder&) = delete;
  TempFolder& operator=(const TempFolder&) = delete;
};

void write_bytes(const fs::path& path, const std::string& bytes) {
  fs::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!out) throw std::runtime_error(path.string() + ": cannot write the stored scene's copy");
}

}  // namespace

std::vector<std::string> scene_motion_files(const SceneFile& file) {
  std::vector<std::string> out;
  for (const auto& name : file.clips)
    out.push_back(file.manifest.clips[file.manifest.require(name)].file.string());
  return out;
}

std::vector<db::SourceFile> scene_sources(const SceneFile& file) {
  std::vector<db::SourceFile> out;
  const json j = json::parse(file.text, nullptr, false);
  const std::string where = file.path.string();
  if (j.is_object() && j.contains("manifest") && j["manifest"].is_string())
    out.push_back(source("manifest", j["manifest"].get<std::string>(), file.manifest.path,
                         "motion manifest of " + where));
  if (file.garment_kind == GarmentKind::Mesh && j.is_object() && j.contains("garment") &&
      j["garment"].is_object() && j["garment"].contains("file")) {
    const fs::path mesh = file.mesh.file;
    out.push_back(source("garment_mesh", j["garment"]["file"].get<std::string>(), mesh,
                         "garment mesh of " + where));
    const std::string ext = mesh.extension().string();
    if (ext == ".gltf" || ext == ".GLTF")
      for (const std::string& part : gltf_parts(text_of(out.back())))
        out.push_back(source("garment_mesh_part", part, mesh.parent_path() / part,
                             "part of the garment mesh " + mesh.string()));
  }
  return out;
}

std::string json_difference(const std::string& stored, const std::string& given) {
  const json a = json::parse(stored, nullptr, false), b = json::parse(given, nullptr, false);
  if (a.is_discarded() || b.is_discarded()) return stored == given ? "" : "not JSON";
  return first_difference(a, b, "");
}

std::string scene_difference(db::Reader& reader, const SceneFile& file) {
  std::string stored_scene;
  db::Error err;
  if (reader.meta(db::meta::kScene, &stored_scene, &err) != db::Status::Ok) return "";
  const std::string where = reader.path() + ": was made from another scene: ";
  if (const std::string d = json_difference(stored_scene, file.text); !d.empty())
    return where + file.path.string() + ": " + d;
  for (const db::SourceFile& stored : source_rows(reader)) {
    if (stored.role == "garment_mesh_part") continue;
    const std::vector<db::SourceFile> now = scene_sources(file);
    for (const db::SourceFile& f : now)
      if (f.role == stored.role && f.content_hash != stored.content_hash) {
        if (f.role == "manifest") {
          const std::string d = json_difference(text_of(stored), text_of(f));
          return where + "its motion manifest " + file.manifest.path.string() + ": " +
                 (d.empty() ? "the bytes differ" : d);
        }
        return where + "its garment mesh " + file.mesh.file + " differs from the stored one (" +
               stored.content_hash + ", now " + f.content_hash + ")";
      }
  }
  return "";
}

std::string locate_motion_file(const db::MotionFile& file, const std::string& resolved_now,
                               const std::string& motions_dir, const std::string& database) {
  std::vector<std::string> tried;
  std::error_code ec;
  auto matches = [&](const fs::path& p) {
    if (!fs::is_regular_file(p, ec)) return false;
    tried.push_back(p.string());
    if (file_content_hash(p.string()) == file.content_hash) return true;
    tried.back() += " (other content)";
    return false;
  };
  if (!resolved_now.empty() && matches(resolved_now)) return resolved_now;
  if (file.path != resolved_now && matches(file.path)) return file.path;
  if (!motions_dir.empty()) {
    if (!fs::is_directory(motions_dir, ec))
      throw std::runtime_error("--motions " + motions_dir + ": not a folder");
    const fs::path by_name = fs::path(motions_dir) / fs::path(file.path).filename();
    if (matches(by_name)) return by_name.string();
    // Renamed: every file under it is hashed until one matches (xxh64 of a few MB is quick).
    for (auto it = fs::recursive_directory_iterator(motions_dir, ec);
         it != fs::recursive_directory_iterator(); it.increment(ec)) {
      if (ec) break;
      if (it->path() != by_name && matches(it->path())) return it->path().string();
    }
  }
  std::string list;
  for (const std::string& t : tried) list += (list.empty() ? "" : ", ") + t;
  throw std::runtime_error(
      database + ": motion file " + file.path + " (" + file.content_hash + ") not found" +
      (list.empty() ? std::string(" (no such file)") : "; tried " + list) +
      (motions_dir.empty() ? "; give --motions DIR, a folder that holds it (found by content hash)"
                           : "; not under --motions " + motions_dir + " either"));
}

void relocate_motion_files(SceneFile& file, const std::vector<db::MotionFile>& rows,
                           const std::string& motions_dir, const std::string& database) {
  if (rows.size() != file.clips.size()) return;  // not written by write_primary_graph: as given
  std::map<std::string, std::string> moved;      // resolved path -> found path
  for (size_t i = 0; i < rows.size(); ++i) {
    MotionClipSpec& clip = file.manifest.clips[file.manifest.require(file.clips[i])];
    const std::string now = clip.file.string();
    auto it = moved.find(now);
    const std::string found =
        it != moved.end() ? it->second : locate_motion_file(rows[i], now, motions_dir, database);
    moved[now] = found;
    clip.file = found;
  }
  for (MotionClipSpec& clip : file.manifest.clips)
    if (auto it = moved.find(clip.file.string()); it != moved.end()) clip.file = it->second;
}

bool has_stored_scene(db::Reader& reader) {
  std::string scene;
  db::Error err;
  if (reader.meta(db::meta::kScene, &scene, &err) != db::Status::Ok) return false;
  for (const db::SourceFile& f : source_rows(reader))
    if (f.role == "manifest") return true;
  return false;
}

CharacterScene build_stored_scene(db::Reader& reader, const std::string& motions_dir) {
  const std::string& database = reader.path();
  std::string scene_text, scene_path;
  db::Error err;
  db::throw_if_error(reader.meta(db::meta::kScene, &scene_text, &err), err);
  if (reader.meta(db::meta::kScenePath, &scene_path, &err) != db::Status::Ok)
    scene_path = "scene.json";
  const std::vector<db::SourceFile> sources = source_rows(reader);
  const db::SourceFile* manifest = nullptr;
  const db::SourceFile* mesh = nullptr;
  for (const db::SourceFile& f : sources) {
    if (f.role == "manifest") manifest = &f;
    if (f.role == "garment_mesh") mesh = &f;
  }
  if (!manifest)
    throw std::runtime_error(database + ": stores no motion manifest (table source_file)");
  json scene = json::parse(scene_text, nullptr, false);
  json man = json::parse(text_of(*manifest), nullptr, false);
  if (!scene.is_object() || !man.is_object() || !man.contains("clips") || !man["clips"].is_array())
    throw std::runtime_error(database + ": its stored scene or manifest is not valid JSON");

  // The scene's clips, in order: what the motion_file rows follow (write_primary_graph).
  std::vector<std::string> clips;
  if (scene.contains("clips") && scene["clips"].is_array())
    for (const json& c : scene["clips"]) clips.push_back(c.get<std::string>());
  else
    for (const json& c : man["clips"]) clips.push_back(c.value("name", ""));
  const std::vector<db::MotionFile> rows = motion_rows(reader);
  if (rows.size() == clips.size()) {
    std::map<std::string, std::string> moved;  // the file as spelled -> found path
    for (size_t i = 0; i < clips.size(); ++i)
      for (json& c : man["clips"])
        if (c.value("name", "") == clips[i]) {
          const std::string spelled = c.value("file", "");
          if (!moved.count(spelled))
            moved[spelled] = locate_motion_file(rows[i], "", motions_dir, database);
        }
    for (json& c : man["clips"])
      if (auto it = moved.find(c.value("file", "")); it != moved.end())
        c["file"] = fs::absolute(it->second).string();
  }

  // The stored files where the scene loader reads them: the scene's references rewritten to them.
  TempFolder tmp;
  const std::string manifest_name = "manifest.json";
  write_bytes(tmp.path / manifest_name, man.dump(2));
  scene["manifest"] = manifest_name;
  if (mesh) {
    const fs::path mesh_name = fs::path("mesh") / fs::path(mesh->path).filename();
    write_bytes(tmp.path / mesh_name, text_of(*mesh));
    for (const db::SourceFile& f : sources)
      if (f.role == "garment_mesh_part") {
        const fs::path part = fs::path(f.path).lexically_normal();
        if (part.is_absolute() || (!part.empty() && *part.begin() == ".."))
          throw std::runtime_error(database + ": stored mesh part " + f.path +
                                   " is outside the mesh's folder");
        write_bytes(tmp.path / "mesh" / part, text_of(f));
      }
    if (scene.contains("garment") && scene["garment"].is_object())
      scene["garment"]["file"] = mesh_name.string();
  }
  write_bytes(tmp.path / "scene.json", scene.dump(2));
  SceneFile file = load_scene_file(tmp.path / "scene.json");
  file.text = scene_text;
  file.path = scene_path;
  file.manifest.path = fs::path(scene_path).parent_path() / manifest->path;
  CharacterScene built = build_character_scene(file);
  if (mesh) built.file.mesh.file = (fs::path(scene_path).parent_path() / mesh->path).string();
  return built;
}

}  // namespace clothdb
