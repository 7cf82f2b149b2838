// Error reporting shared by the codec and the database reader. The reading side never throws: the
// C runtime API and a game loop need an error code plus a message, without exceptions or heap
// allocation, so failures fill an Error (fixed-size message buffer) and return a Status.
#pragma once

#include <cstddef>
#include <stdexcept>
#include <string>

namespace clothdb {

// [[nodiscard]]: a function returning a Status cannot have its result dropped silently (a dropped
// read error once made the explorer delete bases that blobs still named).
enum class [[nodiscard]] Status{
    Ok = 0,
    InvalidArgument,   // the caller passed something impossible (null buffer, frame out of range)
    OutputTooSmall,    // the caller's output buffer cannot hold the result
    NotClothdb,        // not a clothdb database / not a clothdb frame blob (wrong magic or app id)
    NewerVersion,      // written by a newer clothdb format than this build reads
    Truncated,         // shorter than its header says
    Corrupt,           // inconsistent header, bad compressed data, values out of range
    ChecksumMismatch,  // the stored checksum does not match the bytes
    NotFound,          // no row with that id
    IoError,           // SQLite or the file system failed (cannot open, busy, disk error)
};

// "ok", "invalid-argument", ... (static strings).
const char* status_name(Status status);

// What Error::set and fail return: the status they recorded, which converts to Status so callers
// can `return err.set(...)`, and which may also be dropped (recording an error is the call's whole
// purpose), unlike a Status returned by an operation.
struct Recorded {
  Status status;
  constexpr operator Status() const { return status; }
};

struct Error {
  Status status = Status::Ok;
  char message[320] = {0};

  // Records the status and a printf-style message; returns the status so callers can write
  // `return err.set(Status::Corrupt, "...")`. Never allocates.
  Recorded set(Status s, const char* format, ...) __attribute__((format(printf, 3, 4)));
  void clear() {
    status = Status::Ok;
    message[0] = '\0';
  }
};

// Sets `err` (when not null) and returns `s`: the non-throwing functions accept a null Error*.
Recorded fail(Error* err, Status s, const char* format, ...) __attribute__((format(printf, 3, 4)));

// The writing side (encoder, database writer, check) throws this; what() names the file or blob
// and what is wrong.
class ClothdbError : public std::runtime_error {
 public:
  ClothdbError(Status status, const std::string& message)
      : std::runtime_error(message), status_(status) {}
  Status status() const { return status_; }

 private:
  Status status_;
};

// The one conversion of a reading call's result to the tools' exceptions: throws ClothdbError with
// the Error's status and message when `status` is not Ok.
inline void throw_if_error(Status status, const Error& err) {
  if (status != Status::Ok) throw ClothdbError(status, err.message);
}

// The database API (database/format/, database/store/) lives in clothdb::db; its callers may name
// these there too.
namespace db {
using ::clothdb::ClothdbError;
using ::clothdb::Error;
using ::clothdb::Status;
using ::clothdb::throw_if_error;
}  // namespace db

}  // namespace clothdb
