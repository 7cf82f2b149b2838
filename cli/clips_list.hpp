// What `clothdb clips list --json` prints, for other commands to reuse (`clothdb view` shows the
// same table in the page, sorted by any of the same metrics).
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "database/format/reader.hpp"

namespace clothdb::cli {

// {"file", "by", "clips_in_file", "clips": [rows]}, worst `by` first (unknown values last, ties
// by id); worst > 0 keeps only that many. Throws std::runtime_error naming the unknown metric or
// what the reader could not read.
nlohmann::json clips_list_json(db::Reader& reader, const std::string& by, int worst);
// The metrics `--by` accepts, in the order the table shows them: the name given to --by and the
// key of its value in the JSON rows.
struct ClipMetricName {
  std::string name, json_key;
};
std::vector<ClipMetricName> clip_metrics();

}  // namespace clothdb::cli
