#include "core/atomic_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

namespace bp {
namespace {

std::string Errno() { return std::strerror(errno); }

std::string DirOf(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  if (slash == std::string::npos) return ".";
  if (slash == 0) return "/";
  return path.substr(0, slash);
}

// Makes a rename in `dir` durable. Best effort: some file systems refuse
// fsync on a directory, and the data itself is already synced.
void SyncDir(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  (void)::fsync(fd);
  ::close(fd);
}

}  // namespace

std::string AtomicTempPath(const std::string& path) { return path + ".tmp"; }
std::string AtomicBackupPath(const std::string& path) { return path + ".bak"; }

Status WriteFileAtomic(const std::string& path, std::string_view data,
                       const AtomicWriteOptions& options) {
  if (path.empty()) return Status::InvalidArgument("cannot write a file with an empty path");
  const std::string tmp = AtomicTempPath(path);
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC,
                        static_cast<mode_t>(options.mode));
  if (fd < 0) return Status::Internal("cannot create '" + tmp + "': " + Errno());
  // O_CREAT applies the mode only to a new file: a leftover temp file keeps
  // its own bits otherwise.
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
    // temporary name, then rename that over the old backup.
    const std::string bak = AtomicBackupPath(path);
    const std::string bak_tmp = bak + ".tmp";
    ::unlink(bak_tmp.c_str());
    if (::link(path.c_str(), bak_tmp.c_str()) != 0 || ::rename(bak_tmp.c_str(), bak.c_str()) != 0) {
      const std::string reason = Errno();
      ::unlink(bak_tmp.c_str());
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
