// The explorer of Kim et al. 2013 ("Near-exhaustive Precomputation of Secondary Cloth Effects"):
// grows the secondary cloth graph over a primary motion graph until every way the game can move
// the character has cloth that continues within an error bound, or a budget runs out.
//
// A dead end is a pair (cloth state, primary edge leaving its node) with no cloth clip yet. The
// explorer repeatedly takes the dead ends whose unresolved error is largest, simulates the garment
// along their edges (in parallel, one solver per job), and at each clip's end either links back to
// the closest existing state at that node (distance <= epsilon: a cloth edge with that blend
// error) or makes the end a new state (a new dead end per edge leaving the node). Conventions for
// the database are in docs/SECONDARY_GRAPH.md.
//
// Determinism: dead ends are taken in batches of fixed size in a total order (error, state id,
// edge), simulated independently, and integrated in that order; every simulation starts from the
// state as stored (decoded), so a resumed run continues exactly as an uninterrupted one. Each batch
// is one transaction: a run killed at any moment resumes from the last committed batch.
//
// Who runs a batch's jobs is the only thing a parallel back end changes: explore() chooses the
// batch, hands its jobs (JobInput: plain data) to a BatchRunner, and integrates the results
// (JobResult: plain data, serialisable by explore/job_wire.hpp) in the batch's order. The default
// runner uses OpenMP threads in this process; explore/explore_mpi.hpp sends jobs to MPI ranks.
#pragma once

#include <functional>
#include <istream>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "character_scene/character_scene.hpp"
#include "compress/body_frame.hpp"
#include "database/codec/contract.hpp"
#include "database/format/cloth_graph.hpp"
#include "database/store/run_settings.hpp"
#include "database/store/writer.hpp"
#include "explore/state_store.hpp"
#include "quality/clip_quality.hpp"

namespace clothdb {

struct MotionGraph;

// One edge of the primary motion graph, as the explorer needs it.
struct ExploreEdge {
  int from_node = 0, to_node = 0;
  std::string name;
  std::vector<std::vector<JointPose>> poses;  // frame 0 at from_node, last at to_node
  int64_t db_clip = 0;                        // its primary_clips id
  // How often the game takes this edge relative to the most taken one, in (0, 1] (edge_reach in
  // graph/motion_graph.hpp): a dead end's priority is its error times this.
  double reach = 1.0;
  // Relative likelihood that the game takes this edge at its source node (the manifest's weight,
  // graph/motion_graph.hpp GraphEdge::weight): what a random walk of the game's view uses.
  double weight = 1.0;
};

struct ExploreGraph {
  int node_count = 0;
  int start_node = 0;
  double rate = 30.0;
  std::vector<ExploreEdge> edges;
};

// One job: simulate the garment along one primary edge from one cloth state. Everything a worker
// needs beyond the scene and graph it loaded itself.
// A state at a job's end node that steering may pull the clip's end toward
// (docs/GUIDE.md#the-precompute-kim-et-al-2013).
struct SteerTarget {
  int64_t state = 0;        // its id
  std::vector<float> x, v;  // character space, as stored (decoded)
};

// The same targets read on demand (in-process runners): the states' ids and reduced forms, and the
// explorer's cache of exact states (thread-safe), so that a batch does not copy every state at
// its end nodes. A job reads exactly only the targets the reduced forms leave near its end.
struct SteerTargetSource {
  std::vector<int64_t> ids;                  // in the order `targets` would list them
  std::vector<std::vector<double>> reduced;  // reduce() of each
  StateReducer reducer;
  std::shared_ptr<StateCache> exact;
};

struct JobInput {
  int edge = 0;             // index into ExploreGraph::edges
  std::vector<float> x, v;  // start state in character space, as stored (decoded)
  // The start state's id in the file. The MPI job message names states by id and sends a worker
  // only the states it does not hold yet (explore/job_wire.hpp): it must be set there.
  int64_t state = 0;
  // The explorer's state store (the start state's and the targets' stored blobs for job_wire,
  // which sends those rather than floats); null: job_wire sends floats.
  std::shared_ptr<StateCache> store;
  // Steering (SceneFile::steering, on when frames > 0): the states at the edge's end node when the
  // batch was chosen, and the explorer's epsilon (an end already within it is not steered).
  std::vector<SteerTarget> targets;
  // The explorer and an MPI worker: the targets read on demand instead (then `targets` is empty);
  // job_wire sends their ids, and the states a worker lacks.
  std::shared_ptr<const SteerTargetSource> target_source;
  double epsilon = 0;
  SolverKind solver = SolverKind::Xpbd;
  SolverSettings settings;  // settings.threads: OpenMP threads inside this one simulation
  db::CodecSettings codec;  // the database's: the worker encodes exactly what the writer would
  // Codec version 2 (ExploreOptions::subspace_modes): the newest basis stored when the batch was
  // chosen. The clip is encoded with both versions and the smaller blob kept (version 2 always,
  // with subspace_always). Null: version 1. In-process runners only (job_wire refuses it).
  std::shared_ptr<const codec::Basis> basis;
  std::shared_ptr<const BodyAnchors> body;  // with a basis: cloth relative to the body frame
  bool subspace_always = false;
  // Codec version 3 instead of version 2 when its jitter cap is positive (the clip is encoded
  // within this contract against the simulated frames; ExploreOptions::subspace_contract).
  codec::Contract contract;
};

// What a job sends back: the clip already encoded (so the owner of the database only inserts it)
// and the end state encoded as the writer stores a state (so the owner decodes exactly what a
// resumed run reads back). Every field is in job_wire's serializer.
struct JobResult {
  bool stable = true;
  std::string message;  // why not, when unstable (or when the clip could not be measured/encoded)
  uint32_t frame_count = 0, vertex_count = 0;
  std::vector<uint8_t> clip_blob;  // frame_count frames, codec.position_bound
  double clip_max_error = 0;       // m, the codec's largest error on the clip
  // A version 3 clip: its contract figures, measured against the simulated frames (in-process
  // only: job_wire refuses subspace codecs).
  bool has_contract = false;
  codec::ContractFigures contract;
  std::vector<float> last;  // the clip's last frame as the runtime decodes it (the pop)
  std::vector<uint8_t> end_x_blob, end_v_blob;  // one frame each, position / velocity bound
  ClipQuality quality;     // strain, penetration, jitter, halved steps, worst frame
  double cpu_seconds = 0;  // thread CPU time of the simulation (not measuring or encoding)
  // Steering (0 / 0 when the clip was not steered): the state its end was pulled to, the state
  // distance before steering (m), the largest displacement one frame's pull applied to a vertex
  // (m) and that displacement over dt^2 (m/s^2).
  int64_t steer_target = 0;
  double steer_distance = 0, steer_displacement = 0, steer_acceleration = 0;
};

// Runs one job (thread-safe: its own solver; input.settings.threads threads inside).
JobResult run_job(const CharacterScene& scene, const ExploreGraph& graph, const JobInput& input);

// Fills results[i] for jobs[i] (results has jobs.size() entries). The order in which jobs run or
// finish must not matter: explore() integrates in index order.
using BatchRunner =
    std::function<void(const std::vector<JobInput>& jobs, std::vector<JobResult>& results)>;

// Runs a batch on `threads` OpenMP threads in this process, one job per thread.
BatchRunner openmp_runner(const CharacterScene& scene, const ExploreGraph& graph, int threads);

// The order to start a batch's jobs in: longest edge first (LPT scheduling), ties in batch order.
std::vector<size_t> longest_first(const ExploreGraph& graph, const std::vector<JobInput>& jobs);

struct ExploreOptions {
  double epsilon = 0.005;  // m: link back when the state distance is at most this
  // Budget (0: none): CPU time of everything the run does (process CPU since process_cpu_start,
  // and at least cpu_seconds_spent + the simulations' CPU, which is what MPI workers report),
  // checked before each batch: a run overshoots it by at most one batch.
  double cpu_hours = 0.0;
  double process_cpu_start = -1;  // process_cpu_seconds() when the run began (< 0: explore's start)
  double cpu_seconds_spent = 0;   // CPU spent before exploring (the error floor's simulations)
  long max_frames = 0;            // budget (0: none): frames simulated in this run
  int threads = 1;                // OpenMP threads across jobs (each job's solver runs on one)
  int batch = 8;             // dead ends per batch (fixed: the result does not depend on threads)
  bool progress = true;      // a progress bar on stderr
  bool auto_solver = false;  // recorded in the run: the scene's solver was chosen by --auto
  // Only dead ends of states with at least this id (0: every dead end). `clothdb clip resim`
  // explores from the states its edit made and leaves the rest of the database as it is.
  int64_t min_state_id = 0;
  long resim_clip = 0;  // recorded in the run: a `clip resim` of this clip carried forward
  // Codec version 2 (docs/DATABASE.md, "clothdb precompute ... --codec v2"): the explorer builds a
  // garment subspace of this many modes from the clips stored so far, once the file holds
  // subspace_first_frames clip frames, and a new one each time the frames have grown by
  // subspace_growth since the file's newest basis (with B bases stored, the next is due at
  // first_frames x growth^B frames, so a resumed run decides as an uninterrupted one did). Later
  // clips are encoded with version 1 and with version 2 on the newest basis, and the smaller blob
  // is kept; each version 2 blob names its basis. When the exploration converges, the bases
  // explorer runs built that no blob names are removed (with edits in the file, only this run's).
  // 0: version 1 only. States stay version 1.
  uint32_t subspace_modes = 0;
  long subspace_first_frames = 300;
  double subspace_growth = 2.0;
  uint32_t subspace_sample_frames = 3000;  // frames sampled evenly from the clips for the PCA
  bool subspace_always = false;            // keep version 2 even where it is larger (measuring)
  // Codec version 3 on the same bases instead of version 2 (precompute --codec v3) when its
  // jitter cap is positive: each clip is encoded within this contract against the simulated
  // frames, the smaller of it and version 1 is kept (version 3 always, with subspace_always), and
  // its figures are recorded in codec_contract in the batch's transaction.
  codec::Contract subspace_contract;
  // Cloth relative to the body (compress/body_frame.hpp) for the bases and the version 2 blobs.
  bool subspace_body_frame = false;
  // The state store (explore/state_store.hpp): capacity of the LRU cache of exact states read back
  // from the file. Changes the speed only, never the result.
  size_t state_cache_bytes = size_t(256) << 20;
};

// The run's typed record (database/run_settings.hpp): the scene's solver and settings, the
// options, and the database's codec. Throws db::SettingsError naming the first invalid field
// (NaN or negative epsilon or budget, ...) before anything is simulated or written.
db::RunSettings make_run_settings(const CharacterScene& scene, const ExploreOptions& options,
                                  const db::CodecSettings& codec);

struct CurvePoint {
  double cpu_seconds = 0;  // this run's
  long frames = 0;
  int states = 0;
  // Clips made so far (each closed one way out); the forecast's axis (explore/forecast.hpp).
  // Curves written before the column existed: (states - 1) / (1 - linked share), every clip that
  // did not link having made a state.
  long clips = 0;
  int dead_ends = 0;
  // Dead ends whose state is still alone at its node: no other state to measure their unresolved
  // error against, so it is unknown (Kim et al.'s error is a distance to another state). They are
  // counted here and left out of the errors below, never counted as 0 mm.
  int unexplored = 0;
  // m, over the other dead ends (the measured ones): NaN when every dead end is unexplored (the
  // error is unknown, not 0), 0 when no dead end is left.
  double worst_error = 0;           // largest unresolved error
  double weighted_worst_error = 0;  // largest unresolved error x the edge's reach
  double mean_error = 0;
  double linked_fraction = 0;  // clip ends so far that linked back within epsilon
  // The forecast made at this point from the curve so far (explore/forecast.hpp): CPU seconds of
  // the whole exploration (earlier runs included) at convergence; NaN when there is none.
  double forecast_cpu_seconds = std::numeric_limits<double>::quiet_NaN();
  // Its band (explore/forecast.hpp): NaN when there is no forecast; the upper end is infinite
  // when the band is open above.
  double forecast_low_cpu_seconds = std::numeric_limits<double>::quiet_NaN();
  double forecast_high_cpu_seconds = std::numeric_limits<double>::quiet_NaN();
};

// The forecast of the CPU time to converge (explore/forecast.hpp).
struct Forecast {
  bool converging = false;  // false: none (the trend does not fall, or too little to fit)
  bool converged = false;   // no dead end left: cpu_seconds is what it took
  bool too_few = false;     // none because too few curve points to fit
  double cpu_seconds = 0;   // the whole exploration's CPU seconds at convergence, when converging
  // The band around it, when converging: the earliest and latest convergence the fit's
  // prediction band allows; high is infinite when the band never falls to 0.
  double low_cpu_seconds = 0, high_cpu_seconds = 0;
  double made_at = 0;  // the whole exploration's CPU seconds when it was made
  std::string model;   // the model, stated for people
  std::string why;     // why none
};

struct ExploreReport {
  int states = 0;
  int clips = 0;
  int edges = 0;
  int dead_ends = 0;  // left when it stopped
  long frames = 0;    // stored cloth frames in the database
  long frames_this_run = 0;
  double cpu_seconds = 0;           // this run
  double worst_error = 0;           // m
  double weighted_worst_error = 0;  // m, x the edge's reach
  double linked_fraction = 0;       // of all clip ends in the database
  double worst_blend_error = 0;     // m, largest recorded blend error on a cloth edge
  int steered = 0;                  // clips of this run whose end was steered onto a state
  double worst_steering = 0;        // m, largest steering displacement of a vertex in one frame
  // Dead ends closed when the run ended (db::ClothLink: continue with the nearest state's clip)
  // and their blend errors (m).
  int links = 0;
  double worst_link_error = 0, mean_link_error = 0;
  bool converged = false;  // no dead end left above epsilon
  bool resumed = false;
  long jobs_this_run = 0;  // simulations integrated (stable or not)
  // Codec version 2 (ExploreOptions::subspace_modes): bases built in this run and kept (used by
  // some blob) or removed at its end, and this run's clips stored as version 2.
  int bases_built = 0, bases_removed = 0;
  int clips_v2 = 0;
  int clips_v3 = 0;
  double integrate_seconds = 0;   // wall time spent integrating them into the database
  double cpu_seconds_before = 0;  // simulation CPU of the file's earlier runs (the run table)
  // What the --cpu-hours budget counted when the run stopped (all the run's CPU, the error floor
  // included), and the most one batch added to it: the budget's overshoot is at most that.
  double budget_cpu_seconds = 0, largest_batch_cpu_seconds = 0;
  Forecast forecast;  // made at the end of this run (meta forecast)
  // The state store (explore/state_store.hpp): bytes held per state besides the cache, the
  // cache's counts, and state distances measured (the pruning's effect).
  size_t bytes_per_state = 0;
  StateCache::Stats state_cache;
  long exact_evaluations = 0;
  std::vector<CurvePoint> curve;  // one point per batch (this run)
};

// CPU time of this process, all threads, s (CLOCK_PROCESS_CPUTIME_ID).
double process_cpu_seconds();

// The graph's edges as the cloth-graph contract sees them (database/cloth_graph.hpp), where the
// node-anchor, start-clip and start-state rules are defined.
std::vector<db::NodeEdge> node_edges(const ExploreGraph& graph);
// db::node_anchor_clip on this graph; throws std::runtime_error if no edge leaves the node.
int64_t node_anchor_clip(const ExploreGraph& graph, int node);
// db::node_of_primary_clip on this graph (-1 if no edge of the graph is that clip).
int node_of_primary_clip(const ExploreGraph& graph, int64_t primary_clip);

// The explorer's view of a motion graph built from the scene's clips: one edge per graph edge,
// named as its primary clip in the database ("clip[first-last]" or "clip[frame]->clip[frame]"),
// with its poses and reach (make_explore_graph in explore/primary_graph.hpp). Throws
// std::runtime_error naming `where` if the graph's clips are not the scene's.
ExploreGraph explore_graph(const CharacterScene& scene, const MotionGraph& graph,
                           const std::string& where);

// The scene and primary graph a database was made from, rebuilt from what it stores: the scene
// (below) and the motion graph in meta `motion_graph`; each edge's db_clip is set from the
// primary clips.
// What tools that re-simulate or draw a stored clip with its body need. Throws
// std::runtime_error naming the database and what is missing or different.
struct DatabaseScene {
  CharacterScene scene;
  ExploreGraph graph;
};
// Without scene_file, the scene the database stores (meta `scene` and table source_file,
// explore/scene_sources.hpp), so it works from any directory; a file made before those were
// stored reads the scene file at meta `scene_path` (as given to `precompute`, so relative to where
// it ran) and asks for scene_file when it is not there. scene_file: read the scene from this path;
// refused, naming the first differing field, unless it is the one stored. Motion files are found
// by content hash at their recorded path or under motions_dir (optional).
DatabaseScene load_database_scene(db::Reader& reader, const std::string& scene_file = "",
                                  const std::string& motions_dir = "");

// Writes the garment, scene and graph metadata into a new database (no-op for what is there). A
// primary graph already in the database (`clothdb graph build --db`) must be `graph_json`
// (explore/primary_graph.hpp); the motion files it records must not have changed.
void prepare_database(db::Writer& writer, const CharacterScene& scene, ExploreGraph& graph,
                      const std::string& graph_json);

// Runs (or resumes) the exploration. The database must have been prepared for this scene and graph.
// runner: who simulates each batch (empty: openmp_runner with options.threads).
ExploreReport explore(const CharacterScene& scene, const ExploreGraph& graph, db::Writer& writer,
                      const ExploreOptions& options, const BatchRunner& runner = {});

std::string curve_csv(const std::vector<CurvePoint>& curve);
// A curve as curve_csv writes it, read back (explore/progress.cpp): the counts the forecast is
// made from (cpu_seconds, frames, states, dead_ends, unexplored, linked_percent), not the errors
// nor the forecast columns. Throws std::runtime_error naming `path`, the line and the column when
// a cell is not a number at least 0, or cpu_seconds goes back.
std::vector<CurvePoint> read_curve_csv(std::istream& in, const std::string& path);
// Three panels against this run's CPU time: the unresolved error (worst, worst x reach, mean, and
// epsilon), the dead ends and the unexplored ways out, and the share of clip ends linked.
std::string curve_svg(const std::vector<CurvePoint>& curve, double epsilon);

}  // namespace clothdb
