#include "database/store/writer_lock.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <map>
#include <mutex>

#include "database/format/status.hpp"

namespace clothdb::db {
namespace {

// Locks this process holds, by lock file: a second Writer in the same process shares the lock
// (flock would refuse it, and closing its descriptor must not drop the first one's).
std::mutex registry_mu;
std::map<std::string, std::weak_ptr<WriterLock>>& registry() {
  static std::map<std::string, std::weak_ptr<WriterLock>> r;
  return r;
}

std::string read_all(int fd) {
  std::string text;
  char buf[512];
  ssize_t n;
  off_t at = 0;
  while ((n = ::pread(fd, buf, sizeof buf, at)) > 0) {
    text.append(buf, size_t(n));
    at += n;
    if (text.size() > 4096) break;
  }
  while (!text.empty() && (text.back() == '\n' || text.back() == '\0')) text.pop_back();
  return text;
}

std::string describe_self() {
  char host[256] = "unknown";
  ::gethostname(host, sizeof host - 1);
  char when[32];
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  ::gmtime_r(&now, &tm);
  std::strftime(when, sizeof when, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return "pid " + std::to_string(::getpid()) + " on host " + host + " since " + when;
}

}  // namespace

std::string WriterLock::lock_path(const std::string& path) {
  return path + ".lock";
}

std::string WriterLock::holder(const std::string& path) {
  const int fd = ::open(lock_path(path).c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return "";
  std::string text = read_all(fd);
  ::close(fd);
  return text;
}

std::shared_ptr<WriterLock> WriterLock::acquire(const std::string& path) {
  const std::string file = lock_path(path);
  std::error_code ec;
  const std::filesystem::path abs = std::filesystem::absolute(file, ec);
  const std::string key = ec ? file : abs.lexically_normal().string();
  std::lock_guard<std::mutex> lk(registry_mu);
  if (auto held = registry()[key].lock()) return held;
  for (int attempt = 0; attempt < 8; ++attempt) {
    const int fd = ::open(file.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd < 0)
      throw ClothdbError(Status::IoError, "cannot lock " + path + " for writing: " + file + ": " +
                                              std::strerror(errno));
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
      const int e = errno;
      std::string who = read_all(fd);
      ::close(fd);
      if (e != EWOULDBLOCK)
        throw ClothdbError(Status::IoError, "cannot lock " + path + " for writing: " + file + ": " +
                                                std::strerror(e));
      throw ClothdbError(Status::IoError,
                         path + " is being written by another clothdb process (" +
                             (who.empty() ? std::string("holder unknown") : who) +
                             "); one writer at a time: wait for it to finish or stop it (its "
                             "lock, " +
                             file + ", is released when it exits)");
    }
    // The file may have been unlinked by its last holder between our open and our lock: then we
    // locked an orphan, and must lock the file that is at the path now.
    struct stat a {
    }, b{};
    if (::fstat(fd, &a) != 0 || ::stat(file.c_str(), &b) != 0 || a.st_ino != b.st_ino ||
        a.st_dev != b.st_dev) {
      ::close(fd);
      continue;
    }
    auto lock = std::shared_ptr<WriterLock>(new WriterLock());
    lock->fd_ = fd;
    lock->lock_path_ = file;
    lock->key_ = key;
    // Text left by a holder that died without removing the file: its lock was free, so stale.
    lock->stale_ = read_all(fd);
    if (!lock->stale_.empty())
      std::fprintf(stderr, "clothdb: %s: took over the write lock left by a run that died (%s)\n",
                   path.c_str(), lock->stale_.c_str());
    const std::string me = describe_self() + "\n";
    if (::ftruncate(fd, 0) != 0 || ::pwrite(fd, me.data(), me.size(), 0) != ssize_t(me.size()))
      throw ClothdbError(Status::IoError,
                         "cannot write the lock file " + file + ": " + std::strerror(errno));
    registry()[key] = lock;
    return lock;
  }
  throw ClothdbError(Status::IoError, "cannot lock " + path + ": its lock file keeps changing");
}

WriterLock::~WriterLock() {
  {
    std::lock_guard<std::mutex> lk(registry_mu);
    auto it = registry().find(key_);
    if (it != registry().end() && it->second.expired()) registry().erase(it);
  }
  // Unlink while still holding the lock: a process that opened the old file sees the inode
  // change after locking it and retries (acquire).
  if (fd_ >= 0) {
    ::unlink(lock_path_.c_str());
    ::close(fd_);
  }
}

}  // namespace clothdb::db
