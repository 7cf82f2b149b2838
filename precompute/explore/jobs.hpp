// Jobs: one simulation of the garment along one primary edge from one cloth state (run_job and
// the runners are declared in explore/explorer.hpp, which the MPI back end and the tests use).
// Kim et al. 2013 simulate each dead end from its state; this project's addition is steering: the
// last frames of a clip may be pulled toward the nearest state at its end node (SceneFile::
// steering), so that more clip ends link within epsilon.
#pragma once

#include <memory>
#include <vector>

#include "explore/dead_ends.hpp"
#include "explore/explorer.hpp"
#include "explore/secondary_graph.hpp"

namespace clothdb {

// The jobs of a batch: each dead end's state as stored, the scene's solver (one thread inside each
// job), the file's codec and the newest basis (codec version 2; null: version 1), and with
// steering the states at the edge's end node as targets.
std::vector<JobInput> job_inputs(const CharacterScene& scene, const ExploreGraph& graph,
                                 const SecondaryGraph& sg, const std::vector<Job>& batch,
                                 const ExploreOptions& options, const db::CodecSettings& codec,
                                 const std::shared_ptr<const codec::Basis>& basis,
                                 const std::shared_ptr<const BodyAnchors>& body);

}  // namespace clothdb
