// printf into a std::string: the messages of `db check` and of the graph index's findings (the
// runtime's messages go into an Error's fixed buffer instead, never the heap).
#pragma once

#include <string>

namespace clothdb::db {

// At most 511 characters of the formatted text.
std::string format_message(const char* format, ...) __attribute__((format(printf, 1, 2)));

}  // namespace clothdb::db
