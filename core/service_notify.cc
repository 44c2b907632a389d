#include "core/service_notify.h"

#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <string>

namespace bp {

Status NotifyServiceManager(std::string_view state) {
  const char* env = std::getenv("NOTIFY_SOCKET");
  if (env == nullptr || env[0] == '\0') return Status::Ok();
  const std::string path(env);
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  // '/' : a filesystem socket; '@': abstract (the '@' becomes a NUL byte and
  // the address length, not a terminator, ends the name).
  if ((path[0] != '/' && path[0] != '@') || path.size() >= sizeof(addr.sun_path)) {
    return Status::Unavailable("NOTIFY_SOCKET '" + path + "': not an absolute or abstract socket path");
  }
  std::memcpy(addr.sun_path, path.data(), path.size());
  if (path[0] == '@') addr.sun_path[0] = '\0';
  const socklen_t len = static_cast<socklen_t>(offsetof(sockaddr_un, sun_path) + path.size() +
                                               (path[0] == '@' ? 0 : 1));
  const int fd = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return Status::Unavailable("NOTIFY_SOCKET: socket(): " + std::string(std::strerror(errno)));
  const ssize_t sent = ::sendto(fd, state.data(), state.size(), MSG_NOSIGNAL, reinterpret_cast<sockaddr*>(&addr), len);
  const int err = errno;
  ::close(fd);
  if (sent != static_cast<ssize_t>(state.size())) {
    return Status::Unavailable("NOTIFY_SOCKET '" + path + "': " +
                               (sent < 0 ? std::string(std::strerror(err)) : std::string("short send")));
  }
  return Status::Ok();
}

}  // namespace bp
