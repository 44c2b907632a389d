// Crash-safe file replacement: the data goes to a temporary file next to the
// target, is fsync'ed, then renamed over the target, and the directory is
// fsync'ed. A crash at any point leaves either the old file or the new one,
// never a mix. Used for everything binpick must not lose: calibrations,
// taught grasps, recordings.
//
// Safe against other writers and planted links (docs/reliability.md "Threat
// model"): each write creates its own temporary file, `<path>.tmp.<unique>`,
// with O_CREAT | O_EXCL | O_NOFOLLOW, so two writers never share one and a
// symbolic link planted at a temporary name is never written through; a
// target (or backup) that is a symbolic link is refused, not followed.
#pragma once

#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "core/status.h"

namespace bp {

struct AtomicWriteOptions {
  // Permission bits of the new file (calibrations and recordings are not
  // world-readable by default; the umask still applies).
  unsigned mode = 0640;
  // Before replacing an existing target, keep it as `<path>.bak` (itself
  // replaced atomically: hard link, then rename).
  bool keep_backup = false;
  // Tests only: runs after the temporary file is complete and synced, right
  // before the rename (a test forks and exits here to play a crash).
  std::function<void()> before_rename;
};

// Replaces `path` with `data`. Internal on any I/O failure (disk full,
// permission, missing directory) with the path and errno text;
// InvalidArgument when `path` or its backup is a symbolic link. The old file
// is then untouched and the temporary file removed.
Status WriteFileAtomic(const std::string& path, std::string_view data,
                       const AtomicWriteOptions& options = {});

// The prefix of the temporary files WriteFileAtomic creates for `path`
// (`<path>.tmp`; each write appends `.<unique>`). A leftover one after a
// crash is ignored by readers.
std::string AtomicTempPath(const std::string& path);
// The temporary files of `path` present in its directory (leftovers of
// crashed writers, or writes in progress), sorted.
std::vector<std::string> AtomicTempFiles(const std::string& path);

// The backup WriteFileAtomic keeps with keep_backup.
std::string AtomicBackupPath(const std::string& path);

}  // namespace bp
