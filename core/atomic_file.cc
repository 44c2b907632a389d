#include "core/atomic_file.h"

#include <dirent.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <random>

namespace bp {
namespace {

std::string Errno() { return std::strerror(errno); }

std::string DirOf(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  if (slash == std::string::npos) return ".";
  if (slash == 0) return "/";
  return path.substr(0, slash);
}

std::string BaseOf(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  return slash == std::string::npos ? path : path.substr(slash + 1);
}

// Makes a rename in `dir` durable. Best effort: some file systems refuse
// fsync on a directory, and the data itself is already synced.
void SyncDir(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  (void)::fsync(fd);
  ::close(fd);
}

bool IsSymlink(const std::string& path) {
  struct stat st{};
  return ::lstat(path.c_str(), &st) == 0 && S_ISLNK(st.st_mode);
}

// A name no other writer (thread or process) picks: pid, a process-wide
// counter and 32 random bits, as 8 + 8 + 8 hex digits.
std::string UniqueSuffix() {
  static std::atomic<uint64_t> counter{0};
  thread_local std::mt19937 rng{static_cast<uint32_t>(
      std::chrono::steady_clock::now().time_since_epoch().count() ^ ::getpid())};
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%08x%08x%08x", static_cast<unsigned>(::getpid()),
                static_cast<unsigned>(counter.fetch_add(1)), static_cast<unsigned>(rng()));
  return buf;
}

// Creates a new temporary file `<prefix>.<unique>`: O_EXCL (never an
// existing file, never another writer's) and O_NOFOLLOW (never through a
// link). @returns the descriptor, or -1 with errno set and `name` the last
// name tried.
int CreateUnique(const std::string& prefix, unsigned mode, std::string& name) {
  for (int attempt = 0; attempt < 16; ++attempt) {
    name = prefix + "." + UniqueSuffix();
    const int fd = ::open(name.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC,
                          static_cast<mode_t>(mode));
    if (fd >= 0 || errno != EEXIST) return fd;
  }
  return -1;
}

}  // namespace

std::string AtomicTempPath(const std::string& path) { return path + ".tmp"; }
std::string AtomicBackupPath(const std::string& path) { return path + ".bak"; }

std::vector<std::string> AtomicTempFiles(const std::string& path) {
  std::vector<std::string> out;
  const std::string dir = DirOf(path);
  const std::string prefix = BaseOf(AtomicTempPath(path)) + ".";
  DIR* d = ::opendir(dir.c_str());
  if (d == nullptr) return out;
  while (const dirent* e = ::readdir(d)) {
    const std::string name = e->d_name;
    if (name.size() > prefix.size() && name.compare(0, prefix.size(), prefix) == 0) {
      out.push_back((dir == "." && path.find('/') == std::string::npos ? "" : dir + "/") + name);
    }
  }
  ::closedir(d);
  std::sort(out.begin(), out.end());
  return out;
}

Status WriteFileAtomic(const std::string& path, std::string_view data,
                       const AtomicWriteOptions& options) {
  if (path.empty()) return Status::InvalidArgument("cannot write a file with an empty path");
  if (IsSymlink(path)) {
    return Status::InvalidArgument("'" + path + "' is a symbolic link; refusing to follow it (replace "
                                   "it by the file itself)");
  }
  const std::string bak = AtomicBackupPath(path);
  if (options.keep_backup && IsSymlink(bak)) {
    return Status::InvalidArgument("backup '" + bak + "' is a symbolic link; refusing to follow it");
  }
  std::string tmp;
  const int fd = CreateUnique(AtomicTempPath(path), options.mode, tmp);
  if (fd < 0) return Status::Internal("cannot create '" + tmp + "': " + Errno());
  // The mode without the umask's say: calibrations are 0640 even under umask 0.
  (void)::fchmod(fd, static_cast<mode_t>(options.mode));
  auto fail = [&](const std::string& what) {
    const std::string reason = Errno();
    ::close(fd);
    ::unlink(tmp.c_str());
    return Status::Internal(what + " '" + tmp + "': " + reason);
  };
  size_t done = 0;
  while (done < data.size()) {
    const ssize_t n = ::write(fd, data.data() + done, data.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return fail("cannot write");
    done += static_cast<size_t>(n);
  }
  if (::fsync(fd) != 0) return fail("cannot sync");
  if (::close(fd) != 0) {
    const std::string reason = Errno();
    ::unlink(tmp.c_str());
    return Status::Internal("cannot close '" + tmp + "': " + reason);
  }
  if (options.before_rename) options.before_rename();
  if (options.keep_backup && ::access(path.c_str(), F_OK) == 0) {
    // The backup is replaced atomically too: link the current file under a
    // unique temporary name (link() does not follow a link), then rename
    // that over the old backup.
    // link() fails on an existing name (EEXIST) instead of replacing it.
    const std::string bak_tmp = AtomicTempPath(bak) + "." + UniqueSuffix();
    const bool linked = ::link(path.c_str(), bak_tmp.c_str()) == 0;
    if (!linked || ::rename(bak_tmp.c_str(), bak.c_str()) != 0) {
      const std::string reason = Errno();
      if (linked) ::unlink(bak_tmp.c_str());
      ::unlink(tmp.c_str());
      return Status::Internal("cannot keep a backup of '" + path + "' as '" + bak + "': " + reason);
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string reason = Errno();
    ::unlink(tmp.c_str());
    return Status::Internal("cannot replace '" + path + "' with '" + tmp + "': " + reason);
  }
  SyncDir(DirOf(path));
  return Status::Ok();
}

}  // namespace bp
