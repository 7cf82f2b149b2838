#include "database/format/rows.hpp"

namespace clothdb::db {

const char* clip_status_name(ClipStatus status) {
  switch (status) {
    case ClipStatus::Ok:
      return "ok";
    case ClipStatus::Flagged:
      return "flagged";
    case ClipStatus::Edited:
      return "edited";
  }
  return "ok";
}

bool parse_clip_status(const std::string& name, ClipStatus* status) {
  for (ClipStatus s : {ClipStatus::Ok, ClipStatus::Flagged, ClipStatus::Edited}) {
    if (name == clip_status_name(s)) {
      *status = s;
      return true;
    }
  }
  return false;
}

}  // namespace clothdb::db
