#include "database/format/status.hpp"

#include <cstdarg>
#include <cstdio>

namespace clothdb {

const char* status_name(Status status) {
  switch (status) {
    case Status::Ok:
      return "ok";
    case Status::InvalidArgument:
      return "invalid-argument";
    case Status::OutputTooSmall:
      return "output-too-small";
    case Status::NotClothdb:
      return "not-clothdb";
    case Status::NewerVersion:
      return "newer-version";
    case Status::Truncated:
      return "truncated";
    case Status::Corrupt:
      return "corrupt";
    case Status::ChecksumMismatch:
      return "checksum-mismatch";
    case Status::NotFound:
      return "not-found";
    case Status::IoError:
      return "io-error";
  }
  return "unknown";
}

Recorded Error::set(Status s, const char* format, ...) {
  status = s;
  va_list args;
  va_start(args, format);
  std::vsnprintf(message, sizeof message, format, args);
  va_end(args);
  return {s};
}

Recorded fail(Error* err, Status s, const char* format, ...) {
  if (err) {
    err->status = s;
    va_list args;
    va_start(args, format);
    std::vsnprintf(err->message, sizeof err->message, format, args);
    va_end(args);
  }
  return {s};
}

}  // namespace clothdb
