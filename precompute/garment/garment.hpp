// Garments on a character: a procedural skirt or cape, or an imported mesh, built in the
// skeleton's bind (rest) pose, with pinned vertices that follow their bones by linear blend
// skinning from that pose (the bone-versus-world coordinate problem of seed 001: pins are stored
// in bind space and mapped through each bone's motion T_j(pose) T_j(bind)^-1).
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "character/skeleton.hpp"
#include "cloth/mesh.hpp"
#include "database/format/rows.hpp"

namespace clothdb {

struct GarmentError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Linear blend skinning weights of one pinned vertex (they sum to 1).
struct PinBinding {
  int vertex = -1;
  std::vector<std::pair<int, double>> weights;  // (joint, weight)
};

struct Garment {
  std::string name;
  ClothMesh mesh;                    // rest positions in bind space, metres
  std::vector<int> pins;             // pinned vertices (the model's kinematic vertices, this order)
  std::vector<PinBinding> bindings;  // one per pin, same order
  int anchor_joint = -1;             // the bone the whole garment is carried by for its first frame
  // The artist's mesh as the file gives it and its map onto `mesh` (docs/guide/mesh_garments.md);
  // empty positions for a procedural garment (its artist mesh is `mesh` itself).
  db::ArtistMesh artist;
};

struct SkirtSpec {
  std::string bone = "Hips";  // the waist follows this bone
  double waist_radius = 0.0;  // metres; 0: from the hip joints' spread plus the thigh radius
  double flare = 1.6;         // hem radius / waist radius (a cone; 1 = cylinder)
  double length = 0.55;       // along the surface, metres
  double raise = 0.06;        // waist height above the bone's joint, metres
  int vertices = 1000;        // approximate
};

struct CapeSpec {
  std::string bone;     // the bone the collar follows; empty: the torso joint nearest the shoulders
  double width = 0.0;   // metres; 0: the shoulder span plus 10 cm
  double length = 0.8;  // metres
  double back_offset = 0.0;  // distance behind the shoulders' line, metres; 0: torso radius + 3 cm
  int vertices = 1000;
};

enum class PinRuleKind { VertexGroup, HeightBand, BoneDistance };
struct PinRule {
  PinRuleKind kind = PinRuleKind::HeightBand;
  std::string group;                // VertexGroup: mesh/group name in the file
  double y_min = 0.0, y_max = 0.0;  // HeightBand, bind space metres
  std::string bone;                 // BoneDistance: vertices within `distance` of this bone
  double distance = 0.05;
};

struct MeshGarmentSpec {
  // OBJ (read as given: its vertex order, faces, UVs, normals and groups), or glTF or FBX
  // (through assimp: its vertices, split where UVs or normals differ, and polygons)
  std::string file;
  double scale = 1.0;            // file units -> metres
  double weld_tolerance = 1e-5;  // metres
  PinRule pins;
  std::string bone;  // bone the pins follow; empty: each pin binds to its nearest bone
};

Garment make_skirt(const Skeleton& skeleton, const SkirtSpec& spec);
Garment make_cape(const Skeleton& skeleton, const CapeSpec& spec);
// The file's faces are fanned into triangles and welded into the simulation mesh; Garment::artist
// keeps the file's mesh and the map. Throws GarmentError naming the file when it cannot be read,
// holds no faces, is not a manifold mesh after welding, or when the pin rule matches no vertex.
Garment import_garment(const Skeleton& skeleton, const MeshGarmentSpec& spec);

// The garment's artist mesh: the file's (Garment::artist), or for a procedural garment its own
// simulation mesh with the identity map (db::identity_artist_mesh).
db::ArtistMesh artist_mesh_of(const Garment& garment);

// Positions of the pins at `pose`, by linear blend skinning from the bind pose (3 x pins).
Eigen::Matrix3Xd skin_pins(const Garment& garment, const std::vector<JointPose>& bind,
                           const std::vector<JointPose>& pose);
// The whole garment carried rigidly by its anchor bone from bind to `pose` (the first frame of a
// simulation, before the cloth settles), with the pins skinned exactly.
Eigen::Matrix3Xd carry_garment(const Garment& garment, const std::vector<JointPose>& bind,
                               const std::vector<JointPose>& pose);

}  // namespace clothdb
