// binpickd as a service: the sd_notify datagrams (core/service_notify.h) on
// a real unix datagram socket; binpickd started the way systemd and a
// container start it (NOTIFY_SOCKET set; PID 1 of its own PID namespace)
// says READY=1 only once its listeners accept robots, serves a robot, exports
// every metric the Prometheus rules and the Grafana dashboard name
// (tests/deploy/check_monitoring.py on its real /metrics), and on SIGTERM
// from outside its namespace says STOPPING=1 and exits 0.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <cstdlib>
#include <cstring>
#include <sstream>
#include <filesystem>
#include <fstream>
#include <optional>
#include <regex>
#include <string>

#include "core/service_notify.h"
#include "tests/record/record_test_util.h"
#include "tests/testing/files.h"
#include "tests/testing/run_command.h"

namespace bp {
namespace {

namespace fs = std::filesystem;

const std::string kBin = std::string(BINPICK_BINARY_DIR) + "/bin/";

// Sets an environment variable for the lifetime of the object.
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const std::string& value) : name_(name) {
    if (const char* old = std::getenv(name)) old_ = old;
    ::setenv(name, value.c_str(), 1);
  }
  ~ScopedEnv() {
    if (old_) ::setenv(name_, old_->c_str(), 1);
    else ::unsetenv(name_);
  }

 private:
  const char* name_;
  std::optional<std::string> old_;
};

// A bound unix datagram socket, as systemd listens on NOTIFY_SOCKET; it
// asks for the sender's credentials (SO_PASSCRED), as systemd does.
class NotifyListener {
 public:
  // `path`: a filesystem path, or "@name" for the abstract namespace.
  explicit NotifyListener(const std::string& path) : path_(path) {
    fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::memcpy(a.sun_path, path.data(), path.size());
    if (path[0] == '@') a.sun_path[0] = '\0';
    const socklen_t len = offsetof(sockaddr_un, sun_path) + path.size() + (path[0] == '@' ? 0 : 1);
    ok_ = ::bind(fd_, reinterpret_cast<sockaddr*>(&a), len) == 0;
    const int on = 1;
    ::setsockopt(fd_, SOL_SOCKET, SO_PASSCRED, &on, sizeof(on));
  }
  ~NotifyListener() { ::close(fd_); }
  bool ok() const { return ok_; }

  struct Datagram {
    std::string text;
    pid_t sender = 0;  // in this process's PID namespace
  };
  // The next datagram, or nullopt after `timeout_ms`.
  std::optional<Datagram> Receive(int timeout_ms) {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, timeout_ms) != 1) return std::nullopt;
    char buf[4096];
    alignas(cmsghdr) char control[CMSG_SPACE(sizeof(ucred))];
    iovec iov{buf, sizeof(buf)};
    msghdr msg{};
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control;
    msg.msg_controllen = sizeof(control);
    const ssize_t n = ::recvmsg(fd_, &msg, 0);
    if (n < 0) return std::nullopt;
    Datagram d{std::string(buf, static_cast<size_t>(n)), 0};
    for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c != nullptr; c = CMSG_NXTHDR(&msg, c)) {
      if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_CREDENTIALS) {
        ucred cred;
        std::memcpy(&cred, CMSG_DATA(c), sizeof(cred));
        d.sender = cred.pid;
      }
    }
    return d;
  }

 private:
  std::string path_;
  int fd_ = -1;
  bool ok_ = false;
};

TEST(ServiceNotify, SendsTheStateAsOneDatagramToAFilesystemSocket) {
  // sun_path holds 108 bytes: a short directory, not the test's scratch path.
  const std::string path = "/tmp/bp_notify." + std::to_string(::getpid());
  ::unlink(path.c_str());
  NotifyListener listener(path);
  ASSERT_TRUE(listener.ok()) << path;
  {
    ScopedEnv env("NOTIFY_SOCKET", path);
    ASSERT_TRUE(NotifyServiceManager("READY=1\nSTATUS=serving").ok());
  }
  const auto d = listener.Receive(5000);
  ::unlink(path.c_str());
  ASSERT_TRUE(d.has_value());
  EXPECT_EQ(d->text, "READY=1\nSTATUS=serving");
  EXPECT_EQ(d->sender, ::getpid());
}

TEST(ServiceNotify, SendsToAnAbstractSocketNamedWithAnAt) {
  const std::string name = "@binpick_notify_test." + std::to_string(::getpid());
  NotifyListener listener(name);
  ASSERT_TRUE(listener.ok());
  ScopedEnv env("NOTIFY_SOCKET", name);
  ASSERT_TRUE(NotifyServiceManager("STOPPING=1").ok());
  const auto d = listener.Receive(5000);
  ASSERT_TRUE(d.has_value());
  EXPECT_EQ(d->text, "STOPPING=1");
}

TEST(ServiceNotify, IsANoOpWithoutASocketAndAnErrorNamingABadOne) {
  {
    ScopedEnv env("NOTIFY_SOCKET", "");
    EXPECT_TRUE(NotifyServiceManager("READY=1").ok());
  }
  {
    ScopedEnv env("NOTIFY_SOCKET", "relative/socket");
    const Status s = NotifyServiceManager("READY=1");
    EXPECT_EQ(s.code(), Status::Code::kUnavailable);
    EXPECT_NE(s.message().find("'relative/socket'"), std::string::npos) << s.ToString();
  }
  {
    const std::string nobody = "/tmp/bp_notify_nobody." + std::to_string(::getpid());
    ScopedEnv env("NOTIFY_SOCKET", nobody);
    const Status s = NotifyServiceManager("READY=1");
    EXPECT_EQ(s.code(), Status::Code::kUnavailable);
    EXPECT_NE(s.message().find(nobody), std::string::npos) << s.ToString();
  }
  {
    ScopedEnv env("NOTIFY_SOCKET", "/" + std::string(200, 'x'));
    EXPECT_EQ(NotifyServiceManager("READY=1").code(), Status::Code::kUnavailable);
  }
}

int FreeLoopbackPort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof(a);
  if (::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0 ||
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) != 0) {
    ::close(fd);
    return -1;
  }
  ::close(fd);
  return ntohs(a.sin_port);
}

bool Connects(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = htons(static_cast<uint16_t>(port));
  const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0;
  ::close(fd);
  return ok;
}

// GET `target` from 127.0.0.1:`port` (HTTP/1.0: the server closes after the
// response); the body, or "" on failure.
std::string HttpGet(int port, const std::string& target) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = htons(static_cast<uint16_t>(port));
  std::string response;
  if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0) {
    const std::string request = "GET " + target + " HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n";
    if (::send(fd, request.data(), request.size(), MSG_NOSIGNAL) == static_cast<ssize_t>(request.size())) {
      char buf[65536];
      for (ssize_t n; (n = ::recv(fd, buf, sizeof(buf), 0)) > 0;) response.append(buf, static_cast<size_t>(n));
    }
  }
  ::close(fd);
  const size_t body = response.find("\r\n\r\n");
  return body == std::string::npos ? "" : response.substr(body + 4);
}

TEST(BinpickdService, ReadyOnlyWithListenersUpExportsWhatMonitoringNamesAndStopsAsPid1OnSigterm) {
  if (test::RunCommand("unshare --pid --mount-proc --fork --kill-child true").exit_code != 0) {
    GTEST_SKIP() << "needs a PID namespace (unshare --pid, root)";
  }
  const std::string dir = testing::FreshDir("svc");
  const std::string cell = testing::WriteSmallCell(dir, 3, 5);
  const std::string socket = "/tmp/bp_svc." + std::to_string(::getpid());
  ::unlink(socket.c_str());
  NotifyListener listener(socket);
  struct Unlink {
    std::string path;
    ~Unlink() { ::unlink(path.c_str()); }
  } unlink_socket{socket};
  ASSERT_TRUE(listener.ok());
  const int port = FreeLoopbackPort();
  // binpickd as PID 1 of a new PID namespace with its own /proc, as in a
  // container (with the host's /proc, LeakSanitizer cannot stop the
  // threads it lists and reports their thread_locals as leaks).
  const std::string run = "NOTIFY_SOCKET=" + socket + " unshare --pid --mount-proc --fork --kill-child " + kBin +
                          "binpickd --cell " + cell + " --daoai-port " + std::to_string(port) +
                          " --gri-port 0 --gri-official-port 0 --http-port -1 --record-dir " + dir +
                          "/rec > " + dir + "/ready 2> " + dir + "/binpickd.log; echo $? > " + dir + "/exit";
  ASSERT_EQ(std::system(("sh -c '" + run + "' &").c_str()), 0);

  // Up to 180 s: binpickd builds its perception models first (~45 s under ASan).
  const auto ready = listener.Receive(180000);
  ASSERT_TRUE(ready.has_value()) << testing::ReadBytes(dir + "/binpickd.log");
  EXPECT_EQ(ready->text.rfind("READY=1\nSTATUS=binpickd ready: daoai 127.0.0.1:", 0), 0u) << ready->text;
  ASSERT_GT(ready->sender, 1) << "the sender's PID as this namespace sees it";
  EXPECT_TRUE(Connects(port)) << "READY=1 before the DaoAI listener accepts";
  std::smatch http;
  ASSERT_TRUE(std::regex_search(ready->text, http, std::regex("http 127\\.0\\.0\\.1:(\\d+)"))) << ready->text;
  const int http_port = std::stoi(http[1]);

  // A robot picks (with the final empty-box check) and checks precision.
  const std::string robot = kBin + "binpick-robot --port " + std::to_string(port) + " --cell " + cell;
  // Exit 1 would only say the bin was not empty at the end: the answers count.
  const test::CommandRun pick = test::RunCommand(robot + " --flow pick --max-cycles 4");
  EXPECT_TRUE(pick.exit_code == 0 || pick.exit_code == 1) << pick.out;
  const test::CommandRun precision = test::RunCommand(robot + " --flow precision");
  EXPECT_EQ(precision.exit_code, 0) << precision.out;

  const std::string metrics = HttpGet(http_port, "/metrics");
  ASSERT_NE(metrics.find("# TYPE binpick_"), std::string::npos) << metrics;
  testing::WriteText(dir + "/metrics.txt", metrics);
  const std::string check = "/usr/bin/python3 " + std::string(BINPICK_SOURCE_DIR) + "/tests/deploy/check_monitoring.py ";
  const test::CommandRun checked = test::RunCommand(check + dir + "/metrics.txt");
  EXPECT_EQ(checked.exit_code, 0) << checked.out;
  EXPECT_NE(checked.out.find("binpick_precision_error_mm"), std::string::npos) << checked.out;
  EXPECT_NE(checked.out.find("binpick_empty_box_flips_total"), std::string::npos) << checked.out;
  // The check fails when binpickd stops exporting a metric the rules name.
  std::string without;
  std::istringstream lines(metrics);
  for (std::string line; std::getline(lines, line);) {
    if (line.find("binpick_empty_box_flips_total") == std::string::npos) without += line + "\n";
  }
  testing::WriteText(dir + "/without.txt", without);
  const test::CommandRun missing = test::RunCommand(check + dir + "/without.txt");
  EXPECT_EQ(missing.exit_code, 1) << missing.out;
  EXPECT_NE(missing.out.find("rule BinpickEmptyBoxFlapping: binpick_empty_box_flips_total is not exported"),
            std::string::npos)
      << missing.out;

  // `docker stop`: SIGTERM from outside the namespace to its PID 1.
  ASSERT_EQ(::kill(ready->sender, SIGTERM), 0);
  const auto stopping = listener.Receive(60000);
  ASSERT_TRUE(stopping.has_value());
  EXPECT_EQ(stopping->text, "STOPPING=1");
  std::string exit_code;
  for (int i = 0; i < 1200 && exit_code.empty(); ++i) {  // up to 60 s
    ::usleep(50000);
    exit_code = testing::ReadBytes(dir + "/exit");
  }
  EXPECT_EQ(exit_code, "0\n") << testing::ReadBytes(dir + "/binpickd.log");
  EXPECT_NE(testing::ReadBytes(dir + "/binpickd.log").find("SIGTERM received, stopping"), std::string::npos);
}

}  // namespace
}  // namespace bp
