// One writer per database (docs/DATABASE.md#durability-and-concurrency): two `precompute` runs on
// one file both finished and left duplicate clips. Every Writer holds an exclusive lock on a
// sidecar file, PATH.lock, for its life; a second process is refused at once with a message naming
// the holder.
//
// The lock is flock(2) on PATH.lock: the kernel drops it when its holder dies, however it dies,
// so a killed run never leaves a lock that blocks the next one. The file's text (pid, host, start
// time) only names the holder; a file left behind by a killed run is recognised as stale (its
// lock is free) and taken over. Writers in one process share the lock (e.g. the graph build and
// the exploration of one `precompute`).
#pragma once

#include <memory>
#include <string>

namespace clothdb::db {

class WriterLock {
 public:
  // Takes the lock for database `path`; throws ClothdbError(Status::IoError) naming the holder
  // (pid, host, start time) when another process holds it. Takes over a stale lock file.
  static std::shared_ptr<WriterLock> acquire(const std::string& path);
  // What a lock file left by a dead holder said, if this lock took one over ("" otherwise).
  const std::string& took_over() const { return stale_; }
  ~WriterLock();
  WriterLock(const WriterLock&) = delete;
  WriterLock& operator=(const WriterLock&) = delete;

  // The sidecar file of database `path`.
  static std::string lock_path(const std::string& path);
  // The holder's description in the lock file (e.g. "pid 123 on host h since ..."), "" if none.
  static std::string holder(const std::string& path);

 private:
  WriterLock() = default;
  int fd_ = -1;
  std::string lock_path_, key_, stale_;
};

}  // namespace clothdb::db
