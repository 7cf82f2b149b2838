#include "database/format/cloth_graph.hpp"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>

namespace clothdb::db {

double state_distance(const float* xa, const float* va, const float* xb, const float* vb,
                      size_t vertices, double tau) {
  double sum = 0;
  for (size_t i = 0; i < 3 * vertices; ++i) {
    const double dx = double(xa[i]) - double(xb[i]), dv = double(va[i]) - double(vb[i]);
    sum += dx * dx + tau * tau * dv * dv;
  }
  return vertices ? std::sqrt(sum / double(vertices)) : 0.0;
}

double state_distance(const std::vector<float>& xa, const std::vector<float>& va,
                      const std::vector<float>& xb, const std::vector<float>& vb, double tau) {
  if (xa.size() != va.size() || xa.size() != xb.size() || xa.size() != vb.size() ||
      xa.size() % 3 != 0)
    throw std::invalid_argument("state_distance: states of " + std::to_string(xa.size()) + ", " +
                                std::to_string(va.size()) + ", " + std::to_string(xb.size()) +
                                " and " + std::to_string(vb.size()) +
                                " floats: not two states of one garment");
  return state_distance(xa.data(), va.data(), xb.data(), vb.data(), xa.size() / 3, tau);
}

int64_t node_anchor_clip(const std::vector<NodeEdge>& edges, int node) {
  for (const NodeEdge& e : edges)
    if (e.from_node == node) return e.primary_clip;
  return 0;
}

int node_of_primary_clip(const std::vector<NodeEdge>& edges, int64_t primary_clip) {
  for (const NodeEdge& e : edges)
    if (e.primary_clip == primary_clip) return e.from_node;
  return -1;
}

int64_t start_state(const std::vector<StoredState>& states, const std::vector<NodeEdge>& edges,
                    int start_node) {
  int64_t start = 0;
  for (const auto& s : states)
    if (node_of_primary_clip(edges, s.primary_clip) == start_node && (start == 0 || s.id < start))
      start = s.id;
  return start;
}

std::optional<std::string> meta_text(Reader& reader, const char* key) {
  std::string value;
  Error err;
  const Status st = reader.meta(key, &value, &err);
  if (st == Status::NotFound) return std::nullopt;
  if (st != Status::Ok) throw ClothdbError(st, err.message);
  return value;
}

std::optional<int64_t> meta_integer(Reader& reader, const char* key) {
  const std::optional<std::string> text = meta_text(reader, key);
  if (!text) return std::nullopt;
  char* end = nullptr;
  errno = 0;
  const long long v = std::strtoll(text->c_str(), &end, 10);
  if (text->empty() || *end != '\0' || errno == ERANGE)
    throw ClothdbError(Status::Corrupt,
                       reader.path() + ": meta " + key + ": '" + *text + "' is not an integer");
  return v;
}

std::optional<double> meta_number(Reader& reader, const char* key) {
  const std::optional<std::string> text = meta_text(reader, key);
  if (!text) return std::nullopt;
  char* end = nullptr;
  const double v = std::strtod(text->c_str(), &end);
  if (text->empty() || *end != '\0' || !std::isfinite(v))
    throw ClothdbError(Status::Corrupt, reader.path() + ": meta " + key + ": '" + *text +
                                            "' is not a finite number");
  return v;
}

int parse_start_clip(const std::string& value, const std::vector<PrimaryClip>& clips) {
  char* end = nullptr;
  const long long id = std::strtoll(value.c_str(), &end, 10);
  if (!value.empty() && end && *end == '\0') {
    for (size_t i = 0; i < clips.size(); ++i)
      if (clips[i].id == id) return static_cast<int>(i);
  }
  for (size_t i = 0; i < clips.size(); ++i)
    if (clips[i].name == value) return static_cast<int>(i);
  return -1;
}

}  // namespace clothdb::db
