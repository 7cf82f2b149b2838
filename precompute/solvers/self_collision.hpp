// Cloth self-collision for XPBD (docs/notebook/self_collision.md): vertex-triangle and edge-edge
// contacts that keep the cloth at least `thickness` from itself, as unilateral position constraints
// projected in each sub-step, up to three passes, ten where the body's room cuts a move (xpbd.cpp,
// kBodyGive below) (Bridson, Fedkiw & Anderson 2002 sec. 7 for the pair types and their closest
// points; Mueller et al. 2007 sec. 4.2 / Macklin 2016 for projecting C >= 0 with inverse-mass
// weights).
//
// Cost: candidates are found only when needed. A build lists every pair closer than thickness +
// skin (a Verlet list). It stays complete while the regions the build's search settled keep
// together, each within its own slack (PatchWatch; a pair's distance changes by at most the largest
// motion of its corners relative to each other): two patches near each other by no more than the
// skin, two found apart by no more than their separation less the thickness, or while their boxes
// stay apart by more than the reach. This is checked every sub-step in O(vertices + watches).
// When some watches fail, only their regions are searched again (a partial build), unless they
// hold much of the garment or the regions have split into too many since the last full build
// (kPartialShare, kRegrowth); the other regions keep their pairs and watches, with slacks and gaps
// carried over to the new reference by the triangle inequality and low gaps computed afresh there
// (kExactGapShare; refresh_self_collision; docs/notebook/self_collision.md, "Fourteenth round",
// "Fifteenth round: exact watches" and "Sixteenth round (b)"). Until the thirteenth round the
// test was every vertex within skin / 2 of the garment's common motion,
// which the swinging hem failed although the patches near each other moved together (20 % more
// builds on the 12k skirt; docs/notebook/self_collision.md, "Ninth round" and "Thirteenth round").
// Every sub-step tests only the listed pairs, and of those only the ones whose distance at the
// build (less the thickness) is not more than their parts have moved since (`moved`).
//
// The build searches a hierarchy of patches of the garment (Volino & Magnenat-Thalmann 1994,
// "Efficient self-collision detection on smoothly discretized surface animations using geometrical
// shape regularity"; Provot 1997): a binary tree over the triangles, made once from the rest shape,
// whose boxes and normal cones are refit bottom-up at each build; each split is a median split
// repaired along the mesh, so every patch of a connected garment is edge-connected (and its leaves
// disks). A patch that is a topological disk, whose normals lie within a cone of half-angle below
// pi/5 and whose contour, projected along the cone's axis, does not cross itself is a height field
// over that plane: it cannot pass through itself, and its parts are apart by about their distance
// on the sheet, so its own pairs are not searched ("flat"); only pairs of patches whose boxes come
// within the reach are descended, and not two bordering disks whose union is flat. This leaves out
// most of the flat sheet's near neighbours (lists of 66 k pairs instead of 163 k on the 12k skirt's
// first frames, and the same simulation bit for bit in the frames checked:
// docs/notebook/self_collision.md, "Fifth round" and "Sixth round"). A build's lists are sorted by
// (first, second), so the contacts' Gauss-Seidel order does not depend on how the search found
// them. Pairs nearer than the thickness in the rest shape (neighbours on the mesh) are found once,
// in make_self_collision, and skipped by a scan of a short row (docs/notebook/self_collision.md,
// "Cost, second round", also for why pairs up to thickness + skin apart at rest must stay listed).
//
// Side: each contact is pushed to the side its pair was on at the start of the sub-step, so a
// pair that went through within one sub-step is put back, not pushed further through. A crossing
// the contacts let through anyway is undone by running the step again (untangling, below).
//
// Determinism: the build and the projection are serial, in index order (Gauss-Seidel over the
// contact list), so the result does not depend on the thread count. The rest neighbours left out
// cannot be pushed apart (they are nearer than the thickness by construction) and are held by the
// stretch and bending constraints instead.
#pragma once

#include <Eigen/Core>
#include <array>
#include <utility>
#include <vector>

#include "cloth/model.hpp"
#include "cloth/self_intersection.hpp"

namespace clothdb {

struct Environment;

// A patch of the hierarchy: its triangles are tri_order[tri_begin, tri_end); each vertex and edge
// is owned by the first triangle in tri_order that holds it, and a patch's own vertices and edges
// are vert_order[vert_begin, vert_end) and edge_order[edge_begin, edge_end) (so every
// vertex-triangle and edge-edge pair is met in exactly one leaf or pair of leaves). Its contour
// (edges in one of its triangles only) is contour[contour_begin, contour_end). Children come after
// their parent.
struct Patch {
  int left = -1, right = -1;  // children; -1 for a leaf
  int tri_begin = 0, tri_end = 0, vert_begin = 0, vert_end = 0, edge_begin = 0, edge_end = 0;
  int contour_begin = 0, contour_end = 0;
  bool disk = false;  // edge-connected with Euler characteristic 1: a topological disk
};

// A patch's box and normal cone at the last build (refit bottom-up).
struct PatchBounds {
  Vec3 lo, hi;      // box of its vertices
  Vec3 normal_sum;  // sum of its triangles' area-weighted normals
  Vec3 axis;        // normal_sum normalised (zero if it vanishes)
  // Cone half-angle (rad) about axis holding every triangle normal; pi if none. Only ever compared
  // with the flat cone (self_collision.cpp, kFlatAngle), so a cone known to be at least that wide
  // is stored as pi without computing it.
  double angle;
};

// An own edge of a patch at the last build, stored in edge_order's order so that a leaf's edges are
// read in a row (self_collision.cpp, PairSearch::edges_edges): its box and its ends.
struct EdgeBox {
  double lo[3], hi[3];
  int edge, v0, v1;
};

// A triangle's box at the last build, stored in tri_order's order (PairSearch::triangles_vertices).
struct TriangleBox {
  double lo[3], hi[3];
};

// What keeps a build's lists complete over one region the search settled: every vertex-triangle
// and edge-edge pair between patches a and b (a == b: within a) is either listed, or was at least
// `slack` (m) farther than the thickness at the build, or lies in a patch or union of two found
// flat. The slack: for a leaf or a pair of leaves searched, and for a flat patch or union, the skin
// (the reach less the thickness); for two patches found apart, their boxes' separation less the
// thickness. The search leaves one watch per region, and they cover every pair once. The lists
// stay complete while no two vertices of a and b have moved by more than the slack relative to
// each other since the last build, full or partial (refresh_self_collision; a partial build lowers
// a kept watch's slack by how far its region has drifted). A watch of two patches found apart also
// holds while their boxes at the positions tested are still apart by more than the reach
// (thickness + skin) along an axis, as a search there would find them (every pair between them is
// at least that far, whatever either patch did inside its box): the box test does not wear out
// with the patches' own motion, so the large regions found apart are not searched again because
// they deformed (docs/notebook/self_collision.md, "Fifteenth round: exact watches").
struct PatchWatch {
  int a, b;
  float slack;
  bool apart = false;  // found apart (between, the boxes' separation): the box test applies too
};

// Holds `vertex` to `side` of `triangle`'s plane (plan_untangle, below).
struct UntangleConstraint {
  int vertex, triangle;
  double side;                   // +1 or -1 along the triangle's normal
  std::array<double, 3> weight;  // barycentric coordinates of where the edge met the triangle
  // m: the crossing edge's rest length. The constraint holds only while the vertex is that near
  // the point it crossed at: the triangle's plane says nothing about a vertex that has gone far
  // from it (held to a plane the whole step, such a vertex was thrown across the twisted skirt).
  double reach;
};

// The hierarchy's crossing search's arrays (hierarchy_crossings, below), kept from call to call so
// that a search allocates nothing: per patch its box and normal cone at the positions searched
// (refit by the search itself, so the build's patch_bounds are not touched; angle compared with
// the search's own flat cone, not the build's), and the crossings found as (triangle, edge).
struct HierarchyCrossingScratch {
  std::vector<PatchBounds> bounds;
  std::vector<std::array<int, 2>> found;
};

// The flat tests' working arrays (self_collision.cpp: contour_is_simple, union_is_flat), one set
// for the build, its partial builds (most sub-steps) and the crossing search (once a step), kept
// from search to search: stamps made afresh per search were a vertex and an edge array allocated
// at every partial build.
struct FlatTestScratch {
  // A contour edge projected onto the plane of a cone's axis.
  struct ProjectedEdge {
    double high;                   // its largest value along the sweep's coordinate (a[0], b[0])
    double cross_low, cross_high;  // its range along the other one
    double a[2], b[2];             // its ends
    int v0, v1;                    // its vertices
  };
  std::vector<ProjectedEdge> edges;
  // Per edge, (lowest sweep value, position), sorted instead of the edges themselves (a sixth of
  // the bytes to move).
  std::vector<std::pair<double, int>> by_low;
  // The union test's stamps per vertex and per edge, and the union's contour.
  std::vector<int> vertex_stamp, edge_stamp, union_contour;
  int stamp = 0;
};

// A partial build (refresh_self_collision) searches again only the regions whose watches failed,
// unless their patches hold more than this share of the garment's triangles (counted once per
// watch and patch, so it may pass 1): then it searches everything. It was 0.5 (the fourteenth
// round: 0.24 self-collision samples per sample of the rest at 0.25-0.5 against 0.28-0.31 at 1-2)
// while the share rule was also what merged the regions back; since kRegrowth does that and
// watches of patches found apart hold by their boxes, most full builds it made were for failures
// of large regions that a partial search settles again cheaply: on the 12k skirt's first 60
// frames of 01_01 (with the box test against the thickness, before it was made the reach), 0.308
// at 0.5, 0.279 at 1.5 and 0.282-0.291 at 3 (never reached); main's rule 0.333-0.367, the rule
// as committed 0.254-0.261 (docs/notebook/self_collision.md, "Fifteenth round: exact watches").
constexpr double kPartialShare = 1.5;
// A partial search only ever splits regions further (a failed flat patch that is no longer flat
// leaves its leaves' watches, which stay leaves after it is flat again), so between full builds the
// watches and lists grow. When a partial build would start from more than kRegrowth times the
// watches the last full build left, everything is searched instead, which merges the regions back.
// Same 60 frames and box test: 0.282-0.291 at 1.05, 0.286 at 1.03, 0.337 at 1.2 (watches 7 % more,
// lists 7 % longer) (docs/notebook/self_collision.md, "Fifteenth round: exact watches").
constexpr double kRegrowth = 1.05;
// A kept pair's gap, lowered at each partial build by its region's drift (a sum of drifts over the
// partial builds since its search), is computed afresh at the new reference once it falls below
// this share of the skin, about 1 mm on the 12k skirt (rebuild_regions): over 200 frames of its
// 01_01, 10.7 M gaps computed, and half as many pairs let through the contacts' gap test
// (docs/notebook/self_collision.md, "Sixteenth round (b)").
constexpr double kExactGapShare = 0.15;

struct SelfCollision {
  double thickness = 0.0;  // m
  double skin = 0.0;       // m: how much farther than thickness a listed pair may be at build
  double mean_edge = 0.0;  // m, mean rest edge length (sets the skin)
  // m: pairs nearer than this in the rest shape (the thickness) are neighbours on the mesh and
  // never listed.
  double rest_gap = 0.0;
  // Those rest neighbours, found once: for triangle t the vertices rest_vt[rest_vt_begin[t] ..
  // rest_vt_begin[t + 1]), for edge e the edges after it likewise in rest_ee.
  std::vector<int> rest_vt_begin, rest_vt, rest_ee_begin, rest_ee;
  // Candidate pairs of the last build: (triangle, vertex) and (edge, edge) with edge indices into
  // mesh.edges, the first less than the second.
  std::vector<std::array<int, 2>> vertex_triangle;
  std::vector<std::array<int, 2>> edge_edge;
  // Per listed pair, a lower bound on its distance at the last build (`built_at`) minus the
  // thickness (m, rounded down to float): how far its parts must still move towards each other
  // before it can be in contact. Exact at the search that found the pair; for a pair kept
  // through a partial build, the earlier bound less how far its parts may have moved relative to
  // each other since (refresh_self_collision).
  std::vector<float> vertex_triangle_gap, edge_edge_gap;
  // Per listed pair, the watch (index into `watches`) of the region whose search found it: a
  // partial build drops the pairs of the regions it searches again.
  std::vector<int> vertex_triangle_region, edge_edge_region;
  // The patch hierarchy (topology from the rest shape; bounds refit at each build).
  std::vector<Patch> patches;
  std::vector<int> tri_order, vert_order, edge_order, contour;
  // Per contour entry, the tri_order position of the triangle across that edge (-1: a border of
  // the mesh; build_topology refuses an edge of more than two triangles): two patches share the
  // edge when it falls in the other's triangle range.
  std::vector<int> contour_across;
  std::vector<PatchBounds> patch_bounds;
  // Per edge_order position (ends set once, boxes refit with patch_bounds), and per tri_order
  // position (boxes refit likewise).
  std::vector<EdgeBox> edge_boxes;
  std::vector<TriangleBox> triangle_boxes;
  // Positions at the last build, full or partial (empty: never built): the one reference of the
  // watches' slacks, the gaps and `moved`.
  Eigen::Matrix3Xd built_at;
  // The watches (one per region the searches settled, together covering every pair once), and
  // per patch the box (low, high corner) of its vertices' displacements since the last build
  // (scratch of their test).
  std::vector<PatchWatch> watches;
  std::vector<std::array<Vec3, 2>> displacement_box;
  // x - built_at at the positions the watches were last tested at (scratch of that test and of
  // the motion bounds after it).
  Eigen::Matrix3Xd displacement;
  // Per patch the box (low, high corner) of its vertices at the positions tested (scratch of the
  // watches' box test for patches found apart), made only for the patches that test asks about
  // (RebuildScratch::position_needed).
  std::vector<std::array<Vec3, 2>> position_box;
  // A partial build searches again only the regions whose watches failed, unless their patches
  // hold more than this share of the garment's triangles (counted once per watch and patch, so
  // the share may pass 1): then it searches everything (refresh_self_collision). 0: every failed
  // watch rebuilds everything (the rule before partial builds).
  double partial_share = kPartialShare;
  // Full builds when the watches pass this many times those of the last full build (kRegrowth);
  // INFINITY: never for that reason.
  double regrowth = kRegrowth;
  std::size_t full_build_watches = 0;  // watches the last full build left
  // Whether watches of patches found apart also hold by their boxes (PatchWatch); false: by their
  // slack only (the rule before the fifteenth round, which the tests compare with).
  bool apart_boxes = true;
  // Per leaf patch id, its vertices (those of its triangles, each once):
  // leaf_vertices[leaf_vertex_begin[id] .. leaf_vertex_begin[id + 1]) (empty for other patches).
  // The vertices of no triangle are loose_vertices: the root's displacement box and theirs
  // together are the box of every vertex's displacement (refresh_self_collision's common motion).
  std::vector<int> leaf_vertex_begin, leaf_vertices, loose_vertices;
  // Per vertex, a bound (m) on how far it has moved since the build relative to the garment's
  // common motion, over every position a pass may see (the sub-step's start and now, and each move
  // of the passes): a pair whose gap exceeds the sum of its parts' bounds cannot be in contact and
  // is skipped (docs/notebook/self_collision.md, "Fourth round").
  std::vector<double> moved;
  // Untangling constraints of the step being run again (plan_untangle); empty otherwise.
  std::vector<UntangleConstraint> untangle;
  // The body under the cloth, set by the solver after its collision pass in each sub-step (null:
  // not used): its colliders and the pose fraction they are at. Per vertex, the outward normal of
  // the nearest collider surface within kBodyReach thicknesses, and how far (m) the contacts may
  // still move the vertex against that normal (+infinity: no surface that near). The room is the
  // vertex's distance from the surface plus kBodyGive thicknesses: the contacts may press the layer
  // next to the body into it by that much, no deeper (docs/notebook/self_collision.md, "Eleventh
  // round"). The solver sets every room to NaN, "not asked yet", in each sub-step, and a contact
  // finds a vertex's surface (nearest_surface) when it first moves the vertex in the sub-step,
  // where the collision pass left it: a few vertices a sub-step, instead of every vertex in the
  // collision pass (docs/notebook/self_collision.md, "Seventeenth round").
  const Environment* body = nullptr;
  double body_pose = 1.0;
  Eigen::Matrix3Xd body_normal;
  std::vector<double> body_room;
  // The crossing search's arrays, kept from step to step (plan_untangle runs it once a step):
  // the grid's (edge_triangle_crossings, used where the hierarchy cannot be) and the hierarchy's.
  CrossingScratch crossing_scratch;
  HierarchyCrossingScratch hierarchy_crossing;
  FlatTestScratch flat_tests;
  long body_cuts = 0;       // contact moves the body's room has cut short so far
  long builds = 0;          // how many full builds so far (reported by describe / benchmarks)
  long partial_builds = 0;  // how many partial builds so far
  // Watches the searches have made so far, full builds and partial: one per region settled, so a
  // measure of the searches' work that does not depend on the machine.
  long regions_settled = 0;
  // m: a partial build computes the gap of a kept pair afresh at the new reference when the
  // carried gap falls below this (kExactGapShare); -INFINITY: never (the rule before).
  double exact_gap_below = 0.0;
  long gaps_computed = 0;  // kept pairs' gaps computed afresh so far (partial builds)
  // Scratch of the partial builds, kept from build to build (lists of tens of thousands).
  struct RebuildScratch {
    std::vector<int> failed, renumber, order, patches;
    // The watches' test's: per patch whether its box at the positions tested is made
    // (find_failed_watches).
    std::vector<char> position_needed;
    std::vector<double> drift;
    std::vector<char> refit;
    std::vector<std::array<int, 2>> roots, vertex_triangle, edge_edge, pairs_out;
    std::vector<float> vertex_triangle_gap, edge_edge_gap, gaps_out;
    std::vector<int> vertex_triangle_region, edge_edge_region, regions_out;
  } rebuild;
};

// The contacts after the body's collision pass (xpbd.cpp) push the layer next to the body into it
// when the layers over it press on it (the wrung twisted skirt: 18.7 mm deep). They may push a
// vertex at most kBodyGive thicknesses below the body's surface, counted from where the collision
// pass left it along the normal of the surface nearest it; the vertices within kBodyReach
// thicknesses of a surface are watched. Give, not a hard wall: with none (0) or one thickness
// the twisted skirt went through itself for one of the three build schedules tried, with two for
// none (docs/notebook/self_collision.md, "Eleventh round").
constexpr double kBodyGive = 2.0;
constexpr double kBodyReach = 3.0;
// Contact passes per sub-step: up to kContactPasses, until one projects no contact; up to
// kContactPassesAtBody while the body's room cuts moves short in the sub-step (the other layer
// then has to move out, which takes the Gauss-Seidel passes more rounds; with three, the twisted
// skirt went through itself).
constexpr int kContactPasses = 3;
constexpr int kContactPassesAtBody = 10;

// An upper bound on acos(c), c in [-1, 1] (clamped), at most 2 kAcosAbove above it: a polynomial
// (Abramowitz & Stegun 4.4.46, error 2e-8) raised by kAcosAbove. The normal cones need only bounds
// (a cone taken wider is at worst not found flat, and searched), and std::acos was 3 % of
// self-collision's time on the 12k skirt, in the refits and the union tests
// (docs/notebook/self_collision.md, "Seventeenth round").
constexpr double kAcosAbove = 1e-7;
double acos_above(double c);

// A SelfCollision for `model` with thickness (m) > 0. The skin is half the mean rest edge length,
// but at least the thickness: enough that a build lasts several sub-steps, small enough that the
// lists hold a few pairs per vertex.
SelfCollision make_self_collision(const ClothModel& model, double thickness);

// Rebuilds the candidate lists if they may be incomplete for positions x (some watch of the last
// build fails, or they were never built), and brings the per-vertex motion bounds up to x and
// x_start (the sub-step's start). A rebuild searches only the failed watches' regions again
// unless their patches hold more than sc.partial_share of the triangles, the watches have passed
// sc.regrowth times those of the last full build, or the lists were never built: then it searches
// everything. Returns whether it rebuilt (fully or partly).
bool refresh_self_collision(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x,
                            const Eigen::Matrix3Xd& x_start);

// One Gauss-Seidel pass over the listed pairs at positions x (moved in place), with x_start the
// positions at the start of the sub-step (which side each pair was on). Returns the number of
// contacts projected.
int project_self_collision(SelfCollision& sc, const ClothModel& model, Eigen::Matrix3Xd& x,
                           const Eigen::Matrix3Xd& x_start);

// Untangling (Baraff, Witkin & Kass 2003, "Untangling cloth", sec. 3-4): the contacts push each
// pair to the side it was on at the sub-step's start, so a crossing that one sub-step lets through
// is kept by every later one (docs/notebook/self_collision.md, "Seventh round"). plan_untangle
// finds the edge-triangle crossings of x (the crossing metric, cloth/self_intersection.hpp) and,
// for each, holds the crossing edge's end that went through to its side of the triangle's plane
// (`untangle`); the solver then runs the step again from its start with those constraints
// projected after the contacts in every sub-step (project_untangle), so stretch, bending and the
// strain limit act on the corrected positions. Which end went through, and to which side it goes
// back: if both ends were on one side of the plane at the step's start (x_start), the crossing
// formed in this step: the end now on the other side goes back (whether it moved or the triangle
// did). Otherwise (a crossing older than the step, or an edge that came in over the triangle's
// border) the crossing edges cut the mesh along the intersection contour, and the end in the
// smaller piece went through (BWK's rule; a piece holding a fixed vertex counts as the largest) and
// goes to the other end's side; both ends in one piece (the contour does not close on that side):
// the end nearer the plane. Serial, in the crossings' order: the same for any thread count.
//
// How many times a step that ends with crossings is run again (each adding the constraints for the
// crossings its end still has).
constexpr int kUntangleRedos = 3;
// Appends constraints for the crossings of x to sc.untangle (one per vertex and triangle; a later
// plan replaces an earlier one's), x_start the positions at the step's start. Returns the number of
// crossings found (0: nothing appended).
int plan_untangle(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x,
                  const Eigen::Matrix3Xd& x_start);
// The crossings of x: exactly edge_triangle_crossings(mesh, x), the same pairs in the same order
// (by triangle, then by edge), found by descending sc's patch hierarchy with reach 0 instead of a
// grid over the whole mesh (docs/notebook/self_collision.md, "Fourteenth round (b)"). A patch, or
// a union of two bordering patches, that is flat (a disk whose normals lie in a cone below
// kCrossingFlatAngle, self_collision.cpp, and whose contour projected along the cone's axis does
// not cross itself) is a height field: it cannot pass through itself (Volino & Magnenat-Thalmann
// 1994). Two patches whose boxes are apart by more than the metric's slack (kCrossingBoxSlack)
// hold no pair the metric would test. What is left (leaves and pairs of leaves) is tested with the
// metric's own box test and segment_crosses_triangle, so each pair gets the metric's answer to the
// bit. The grid answers instead for positions it would reject and for a mesh without the
// hierarchy. Refits only sc.hierarchy_crossing.
std::vector<std::array<int, 2>> hierarchy_crossings(SelfCollision& sc, const ClothMesh& mesh,
                                                    const Eigen::Matrix3Xd& x);

// One Gauss-Seidel pass over sc.untangle: C = side (x_v - q) . n - thickness >= 0, q the point of
// the triangle at `weight`, with inverse-mass weights as the vertex-triangle contacts. Returns the
// constraints projected.
int project_untangle(SelfCollision& sc, const ClothModel& model, Eigen::Matrix3Xd& x);

// Every vertex-triangle (triangle, vertex) and edge-edge (first, second edge, first < second) pair
// nearer than `reach` at positions x, except pairs that share a vertex, pairs of only fixed
// vertices, the rest neighbours (when skip_rest_neighbours) and, when skip_flat, the pairs within a
// flat patch (self_collision.hpp, top). Refits sc's patch bounds to x. Unsorted. For builds and
// tests.
void find_self_collision_pairs(SelfCollision& sc, const ClothModel& model,
                               const Eigen::Matrix3Xd& x, double reach, bool skip_rest_neighbours,
                               bool skip_flat, std::vector<std::array<int, 2>>& vertex_triangle,
                               std::vector<std::array<int, 2>>& edge_edge);

}  // namespace clothdb
