// Writing result files so that a failure never leaves one half-written: write to a temporary file
// beside the target, then rename it into place (atomic on POSIX file systems).
#pragma once

#include <string>

namespace clothdb {

// Writes `content` to `path` atomically; throws std::runtime_error naming the path on failure.
void write_file_atomic(const std::string& path, const std::string& content);

// Creates a directory and its parents; throws std::runtime_error naming it on failure.
void make_directories(const std::string& path);

}  // namespace clothdb
