#include "explore/primary_graph.hpp"

#include <cstdio>
#include <fstream>
#include <iterator>
#include <map>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include "database/format/checksum.hpp"

namespace clothdb {

ExploreGraph make_explore_graph(const MotionGraph& graph, const std::vector<MotionClip>& clips,
                                const std::string& where) {
  // The graph's clip indices must mean these clips.
  for (size_t c = 0; c < graph.clips.size(); ++c)
    if (c >= clips.size() || graph.clips[c].name != clips[c].name)
      throw std::runtime_error(where + ": clips[" + std::to_string(c) + "] is '" +
                               graph.clips[c].name + "' but the scene's clip " + std::to_string(c) +
                               " is '" +
                               (c < clips.size() ? clips[c].name : std::string("(none)")) +
                               "': build the graph from the scene's clips, in its order");
  if (graph.edges.empty()) throw std::runtime_error(where + ": the motion graph has no edges");
  const std::vector<double> reach = edge_reach(graph);
  ExploreGraph eg;
  eg.node_count = graph.node_count();
  eg.rate = clips.front().rate;
  eg.start_node = graph.edges.front().from;
  for (size_t e = 0; e < graph.edges.size(); ++e) {
    const GraphEdge& ge = graph.edges[e];
    ExploreEdge x;
    x.from_node = ge.from;
    x.to_node = ge.to;
    x.name = ge.kind == EdgeKind::clip
                 ? clips[ge.clip].name + "[" + std::to_string(ge.first_frame) + "-" +
                       std::to_string(ge.last_frame) + "]"
                 : clips[ge.clip].name + "[" + std::to_string(ge.first_frame) + "]->" +
                       clips[ge.target_clip].name + "[" + std::to_string(ge.target_frame) + "]";
    x.poses = edge_poses(graph, clips, static_cast<int>(e));
    x.reach = reach[e];
    x.weight = ge.weight;
    eg.edges.push_back(std::move(x));
  }
  return eg;
}

std::string content_hash(const std::string& bytes) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "xxh64:%016llx",
                static_cast<unsigned long long>(db::xxh64(bytes.data(), bytes.size())));
  return buf;
}

std::string file_content_hash(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot read to hash it");
  return content_hash(
      std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>()));
}

void write_primary_graph(db::Writer& writer, ExploreGraph& graph, const std::string& graph_json,
                         const std::vector<std::string>& motion_files) {
  db::Writer::Transaction tx(writer);
  std::vector<int64_t> file_ids;
  for (const std::string& f : motion_files)
    file_ids.push_back(writer.add_motion_file(f, file_content_hash(f)));
  for (auto& e : graph.edges) {
    db::PrimaryClip c;
    c.name = e.name;
    c.motion_file = file_ids.empty() ? 0 : file_ids.front();
    c.first_frame = 0;
    c.frame_count = static_cast<int32_t>(e.poses.size());
    c.frame_rate = graph.rate;
    e.db_clip = writer.add_primary_clip(c);
  }
  for (const auto& a : graph.edges)
    for (const auto& b : graph.edges)
      if (a.to_node == b.from_node) {
        db::PrimaryTransition t;
        t.from_clip = a.db_clip;
        t.from_frame = static_cast<int32_t>(a.poses.size()) - 1;
        t.to_clip = b.db_clip;
        t.to_frame = 0;
        writer.add_primary_transition(t);
      }
  if (const int64_t start = db::start_clip(node_edges(graph), graph.start_node))
    db::set_meta_integer(writer, db::meta::kStartClip, start);
  db::set_meta_text(writer, db::meta::kMotionGraph, graph_json);
  tx.commit();
}

std::string stored_motion_graph(db::Reader& reader) {
  std::string text;
  db::Error err;
  if (reader.meta(db::meta::kMotionGraph, &text, &err) != db::Status::Ok) return "";
  return text;
}

bool attach_primary_graph(db::Reader& reader, ExploreGraph& graph, const std::string& graph_json) {
  const std::string stored = stored_motion_graph(reader);
  if (stored.empty()) return false;
  const auto same = [](const std::string& a, const std::string& b) {
    const auto ja = nlohmann::json::parse(a, nullptr, false),
               jb = nlohmann::json::parse(b, nullptr, false);
    return !ja.is_discarded() && !jb.is_discarded() ? ja == jb : a == b;
  };
  if (!same(stored, graph_json))
    throw std::runtime_error(
        reader.path() +
        ": holds a different motion graph (meta motion_graph) than the one given; "
        "precompute without --graph uses the database's own, or use a new --db");
  db::Error err;
  std::vector<db::PrimaryClip> clips;
  if (reader.primary_clips(&clips, &err) != db::Status::Ok)
    throw std::runtime_error(reader.path() + ": " + std::string(err.message));
  std::map<std::string, const db::PrimaryClip*> by_name;
  for (const auto& c : clips) by_name[c.name] = &c;
  for (auto& e : graph.edges) {
    const auto it = by_name.find(e.name);
    if (it == by_name.end() || it->second->frame_count != static_cast<int32_t>(e.poses.size()))
      throw std::runtime_error(
          reader.path() + ": primary clip '" + e.name +
          "' is missing or has another length: the motion graph changed since this "
          "database was made");
    e.db_clip = it->second->id;
  }
  return true;
}

void check_motion_files(db::Reader& reader, const std::vector<std::string>& now_at) {
  db::Error err;
  std::vector<db::MotionFile> files;
  db::throw_if_error(reader.motion_files(&files, &err), err);
  for (size_t i = 0; i < files.size(); ++i) {
    const db::MotionFile& f = files[i];
    const std::string path = i < now_at.size() ? now_at[i] : f.path;
    const std::string now = file_content_hash(path);
    if (now != f.content_hash)
      throw std::runtime_error(reader.path() + ": motion file " + path +
                               " changed since this database was made (" + f.content_hash +
                               ", now " + now + "); refusing to mix results");
  }
}

}  // namespace clothdb
