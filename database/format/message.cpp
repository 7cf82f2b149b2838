#include "database/format/message.hpp"

#include <cstdarg>
#include <cstdio>

namespace clothdb::db {

std::string format_message(const char* format, ...) {
  char buf[512];
  va_list args;
  va_start(args, format);
  std::vsnprintf(buf, sizeof buf, format, args);
  va_end(args);
  return buf;
}

}  // namespace clothdb::db
