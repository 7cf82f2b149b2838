#include "database/format/graph_index.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <set>

#include "database/format/message.hpp"

namespace clothdb::db {
namespace {

int find_root(std::vector<int>& parent, int i) {
  while (parent[size_t(i)] != i) i = parent[size_t(i)] = parent[size_t(parent[size_t(i)])];
  return i;
}

}  // namespace

Status GraphRows::read(Reader& reader, Error* err) {
  if (Status st = reader.primary_clips(&primary_clips, err); st != Status::Ok) return st;
  if (Status st = reader.primary_transitions(&transitions, err); st != Status::Ok) return st;
  if (Status st = reader.cloth_states(&states, err); st != Status::Ok) return st;
  if (Status st = reader.cloth_clips(&clips, err); st != Status::Ok) return st;
  if (Status st = reader.cloth_edges(&edges, err); st != Status::Ok) return st;
  return reader.cloth_links(&links, err);
}

bool GraphIndex::build(const GraphRows& rows, const GraphFindingSink& sink) {
  *this = GraphIndex{};
  auto report = [&](const char* kind, std::string message) {
    return sink(GraphFinding{kind, std::move(message), false});
  };
  auto dangling = [&](const char* kind, std::string message) {
    return sink(GraphFinding{kind, std::move(message), true});
  };
  const std::vector<PrimaryClip>& pcs = rows.primary_clips;
  const int np = int(pcs.size());
  primaries.resize(size_t(np));
  for (int i = 0; i < np; ++i) {
    const PrimaryClip& p = pcs[size_t(i)];
    // A graph edge spans at least two poses; a shorter one would make a zero-length clip.
    if (p.frame_count < 2 || !(p.frame_rate > 0) || !std::isfinite(p.frame_rate))
      if (!report("primary clip", format_message("%lld: %d frames at %g Hz (needs >= 2 frames at a "
                                                 "positive rate)",
                                                 (long long)p.id, p.frame_count, p.frame_rate)))
        return false;
    primaries[size_t(i)].id = p.id;
    primaries[size_t(i)].frames = p.frame_count;
    primaries[size_t(i)].rate = p.frame_rate;
    primary_by_id[p.id] = i;
  }

  // Nodes: edge A's target and edge B's source are one node for every transition A -> B.
  std::vector<int> parent(size_t(2 * np));
  std::iota(parent.begin(), parent.end(), 0);
  std::set<std::pair<int, int>> joined;
  for (const PrimaryTransition& t : rows.transitions) {
    auto a = primary_by_id.find(t.from_clip), b = primary_by_id.find(t.to_clip);
    if (a == primary_by_id.end() || b == primary_by_id.end()) {
      if (!dangling("primary transition",
                    format_message("%lld: clip %lld or %lld does not exist", (long long)t.id,
                                   (long long)t.from_clip, (long long)t.to_clip)))
        return false;
      continue;
    }
    const PrimaryClip& from = pcs[size_t(a->second)];
    if (t.from_frame != from.frame_count - 1 || t.to_frame != 0)
      if (!report("primary transition",
                  format_message(
                      "%lld: joins frame %d of clip %lld (last %d) to frame %d of clip %lld; "
                      "transitions join a clip's last frame to the next clip's first",
                      (long long)t.id, t.from_frame, (long long)t.from_clip, from.frame_count - 1,
                      t.to_frame, (long long)t.to_clip)))
        return false;
    parent[size_t(find_root(parent, 2 * a->second + 1))] = find_root(parent, 2 * b->second);
    joined.insert({a->second, b->second});
  }
  std::vector<int> node_of_root(size_t(2 * np), -1);
  for (int i = 0; i < 2 * np; ++i) {
    const int r = find_root(parent, i);
    if (node_of_root[size_t(r)] < 0) node_of_root[size_t(r)] = nodes++;
  }
  leaving.resize(size_t(nodes));
  entering.resize(size_t(nodes));
  for (int i = 0; i < np; ++i) {
    Primary& p = primaries[size_t(i)];
    p.src_node = node_of_root[size_t(find_root(parent, 2 * i))];
    p.tgt_node = node_of_root[size_t(find_root(parent, 2 * i + 1))];
    leaving[size_t(p.src_node)].push_back(i);
    entering[size_t(p.tgt_node)].push_back(i);
  }
  for (const auto& [a, b] : joined) primaries[size_t(a)].successors.push_back(b);  // sorted
  // Completeness: at a node every clip in continues with every clip out; a missing pair means a
  // transition row was lost (the game could not take that way).
  for (int node = 0; node < nodes; ++node)
    for (int a : entering[size_t(node)])
      for (int b : leaving[size_t(node)])
        if (!joined.count({a, b}))
          if (!report("primary transition",
                      format_message("missing from clip %lld to clip %lld (both meet at one node)",
                                     (long long)pcs[size_t(a)].id, (long long)pcs[size_t(b)].id)))
            return false;

  for (const StoredState& s : rows.states) {
    auto p = primary_by_id.find(s.primary_clip);
    if (p == primary_by_id.end()) {
      if (!dangling("cloth state", format_message("%lld: primary clip %lld does not exist",
                                                  (long long)s.id, (long long)s.primary_clip)))
        return false;
      continue;
    }
    state_by_id[s.id] = int(states.size());
    states.push_back({s.id, p->second, primaries[size_t(p->second)].src_node});
  }

  for (const ClothClip& c : rows.clips) {
    auto s = state_by_id.find(c.start_state);
    auto p = primary_by_id.find(c.primary_clip);
    if (s == state_by_id.end() || p == primary_by_id.end()) {
      if (!dangling(
              "cloth clip",
              format_message("%lld: start state %lld or primary clip %lld does not "
                             "exist",
                             (long long)c.id, (long long)c.start_state, (long long)c.primary_clip)))
        return false;
      continue;
    }
    const Primary& pi = primaries[size_t(p->second)];
    bool ok = true;
    if (c.first_frame != 0 || c.frame_count != pi.frames) {
      ok = false;
      if (!report("cloth clip",
                  format_message("%lld: covers frames %d..+%d of primary clip %lld (%d "
                                 "frames); clips span whole primary clips",
                                 (long long)c.id, c.first_frame, c.frame_count, (long long)pi.id,
                                 pi.frames)))
        return false;
    }
    if (states[size_t(s->second)].node != pi.src_node) {
      ok = false;
      if (!report("cloth clip",
                  format_message("%lld: starts from state %lld, which is not at primary "
                                 "clip %lld's source node",
                                 (long long)c.id, (long long)c.start_state, (long long)pi.id)))
        return false;
    }
    if (!ok) continue;
    clip_by_id[c.id] = int(clips.size());
    clips.push_back({c.id, s->second, p->second, c.frame_count, -1, 0});
  }

  for (const ClothEdge& e : rows.edges) {
    auto c = clip_by_id.find(e.from_clip);
    auto s = state_by_id.find(e.to_state);
    if (c == clip_by_id.end() || s == state_by_id.end()) {
      if (!dangling("cloth edge",
                    format_message("%lld: clip %lld or state %lld does not exist (or was "
                                   "refused above)",
                                   (long long)e.id, (long long)e.from_clip, (long long)e.to_state)))
        return false;
      continue;
    }
    Clip& ci = clips[size_t(c->second)];
    const Primary& pi = primaries[size_t(ci.primary)];
    if (states[size_t(s->second)].node != pi.tgt_node) {
      if (!report("cloth edge",
                  format_message("%lld: leads to state %lld, which is not at the end node "
                                 "of clip %lld (primary clip %lld)",
                                 (long long)e.id, (long long)e.to_state, (long long)e.from_clip,
                                 (long long)pi.id)))
        return false;
      continue;
    }
    // One edge per clip by convention; if there are several, the closest continuation wins.
    const double blend = std::isfinite(e.blend_error) ? e.blend_error : 1.0;
    if (ci.to_state < 0 || blend < ci.blend_error) {
      ci.to_state = s->second;
      ci.blend_error = blend;
    }
  }

  std::set<std::pair<int, int>> explored;  // (state, primary) with a clip
  for (const Clip& c : clips) explored.insert({c.state, c.primary});
  for (const ClothLink& l : rows.links) {
    auto s = state_by_id.find(l.from_state);
    auto p = primary_by_id.find(l.primary_clip);
    auto c = clip_by_id.find(l.to_clip);
    if (s == state_by_id.end() || p == primary_by_id.end() || c == clip_by_id.end()) {
      if (!dangling("cloth link",
                    format_message("%lld: names a missing state %lld, primary clip %lld or "
                                   "cloth clip %lld",
                                   (long long)l.id, (long long)l.from_state,
                                   (long long)l.primary_clip, (long long)l.to_clip)))
        return false;
      continue;
    }
    bool ok = true;
    auto refuse = [&](std::string message) {
      ok = false;
      return report("cloth link", std::move(message));
    };
    if (clips[size_t(c->second)].primary != p->second &&
        !refuse(
            format_message("%lld: continues with cloth clip %lld, which is not along primary clip "
                           "%lld",
                           (long long)l.id, (long long)l.to_clip, (long long)l.primary_clip)))
      return false;
    if (states[size_t(s->second)].node != primaries[size_t(p->second)].src_node &&
        !refuse(
            format_message("%lld: from state %lld, which is not at primary clip %lld's source node",
                           (long long)l.id, (long long)l.from_state, (long long)l.primary_clip)))
      return false;
    if ((!(l.blend_error >= 0) || !std::isfinite(l.blend_error)) &&
        !refuse(format_message("%lld: blend error %g is not a finite length", (long long)l.id,
                               l.blend_error)))
      return false;
    if (explored.count({s->second, p->second}) &&
        !refuse(format_message("%lld: state %lld already has a clip along primary clip %lld",
                               (long long)l.id, (long long)l.from_state,
                               (long long)l.primary_clip)))
      return false;
    if (ok) links.push_back({l.id, s->second, p->second, c->second, l.blend_error});
  }
  return true;
}

}  // namespace clothdb::db
