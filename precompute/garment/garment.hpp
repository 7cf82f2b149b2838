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
  std::string file;              // OBJ, glTF or FBX (through assimp)
  double scale = 1.0;            // file units -> metres
  double weld_tolerance = 1e-5;  // metres
  PinRule pins;
  std::string bone;  // bone the pins follow; empty: each pin binds to its nearest bone
};

Garment make_skirt(const Skeleton& skeleton, const SkirtSpec& spec);
Garment make_cape(const Skeleton& skeleton, const CapeSpec& spec);
// Throws GarmentError naming the file when it cannot be read, holds no triangles, is not a
// manifold triangle mesh after welding, or when the pin rule matches no vertex.
Garment import_garment(const Skeleton& skeleton, const MeshGarmentSpec& spec);

// Positions of the pins at `pose`, by linear blend skinning from the bind pose (3 x pins).
Eigen::Matrix3Xd skin_pins(const Garment& garment, const std::vector<JointPose>& bind,
                           const std::vector<JointPose>& pose);
// The whole garment carried rigidly by its anchor bone from bind to `pose` (the first frame of a
// simulation, before the cloth settles), with the pins skinned exactly.
Eigen::Matrix3Xd carry_garment(const Garment& garment, const std::vector<JointPose>& bind,
                               const std::vector<JointPose>& pose);

}  // namespace clothdb
