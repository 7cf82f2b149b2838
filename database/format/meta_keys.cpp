#include "database/format/meta_keys.hpp"

namespace clothdb::db {

namespace meta {
const std::vector<std::string>& known_keys() {
  static const std::vector<std::string> keys = {kFormat,
                                                kFormatVersion,
                                                kCreated,
                                                kUnits,
                                                kCodecPositionBound,
                                                kCodecVelocityBound,
                                                kCodecKeyInterval,
                                                kCodecZstdLevel,
                                                kCodecFormatVersion,
                                                kCodecRecodedBound,
                                                kCodecBasis,
                                                kScene,
                                                kScenePath,
                                                kSceneHash,
                                                kMotionGraph,
                                                kStartClip,
                                                kAutoSolver,
                                                kErrorFloor,
                                                kErrorFloorDetail,
                                                kDeadEndsLinked,
                                                kForecast};
  return keys;
}
}  // namespace meta

}  // namespace clothdb::db
