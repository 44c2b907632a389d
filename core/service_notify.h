// Readiness and stop notifications to the service manager: systemd's
// sd_notify protocol, without libsystemd. With Type=notify, systemd passes
// the path of a unix datagram socket in $NOTIFY_SOCKET (a leading '@' names
// a socket in the abstract namespace); each notification is one datagram of
// newline-separated KEY=VALUE lines, e.g. "READY=1\nSTATUS=serving".
#pragma once

#include <string_view>

#include "core/status.h"

namespace bp {

// Sends `state` (e.g. "READY=1", "STOPPING=1", "STATUS=...") to the socket
// named by $NOTIFY_SOCKET. Ok and nothing sent when the variable is unset or
// empty (not run by a service manager); Unavailable with the socket's path
// and the reason when it is set but the datagram cannot be sent.
// Thread-safe (no shared state; the environment is only read).
Status NotifyServiceManager(std::string_view state);

}  // namespace bp
