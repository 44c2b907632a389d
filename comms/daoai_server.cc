#include "comms/daoai_server.h"

#include <spdlog/spdlog.h>

#include <array>
#include <deque>
#include <optional>
#include <vector>

#include "comms/daoai_message.h"
#include "comms/internal/tcp_server.h"

namespace bp {
namespace {

namespace asio = internal::asio;
using internal::Session;
using internal::SessionArgs;

// Reads exactly 48 bytes per request, keeps reading while a request is in
// progress (requests that arrive meanwhile are queued), writes 64 bytes per
// response for commands that have one. Every read that gets no answer is
// acknowledged at once (a segment short of a message, a command without a
// response): Session::AckNow.
class Connection final : public Session {
 public:
  Connection(SessionArgs args, RequestHandler& handler, const DaoaiServerOptions& options)
      : Session(std::move(args), "daoai", options.read_timeout),
        handler_(handler),
        max_queued_(options.max_queued_requests) {}

 private:
  void BeginReading() override { Read(); }

  void Read() {
    ReadExactly(read_buf_.data(), read_buf_.size(), [self = Self()] { self->OnRead(); });
  }

  std::shared_ptr<Connection> Self() {
    return std::static_pointer_cast<Connection>(shared_from_this());
  }

  void OnRead() {
    MarkActivity();
    if (queued_.size() >= max_queued_) {
      spdlog::warn("daoai: {} sent more than {} requests without waiting for answers", client_.peer,
                   max_queued_);
      CountProtocolError();
      DoClose("request queue overflow");
      return;
    }
    queued_.push_back(daoai::DecodeRequest(read_buf_));
    ReadNextRequest();
    if (!busy_) ProcessNext();
  }

  void ProcessNext() {
    if (closed_ || queued_.empty()) return;
    const daoai::Request request = queued_.front();
    queued_.pop_front();
    BeginHandle();
    handler_.HandleAsync(request, client_,
                         Completion<RequestHandler::Reply>(
                             [this](const RequestHandler::Reply& reply) { OnReply(reply); }));
    EndHandle();
  }

  void OnReply(const RequestHandler::Reply& reply) {
    std::optional<daoai::Response> response = reply ? reply() : std::nullopt;
    std::function<void(bool)> settle = TakeSettle();
    if (!response) {
      if (settle) settle(false);  // nothing is written: the grasp goes back
      AckNow();  // no answer to carry the ACK: the robot's next request must not wait for it
      Done();
      return;
    }
    client_.last_answer = *response;
    const auto bytes = daoai::EncodeResponse(*response);
    Write(std::vector<uint8_t>(bytes.begin(), bytes.end()), nullptr, std::move(settle));
  }

  void Done() override {
    Finish();
    ProcessNext();
  }

  void OnClosed() override { queued_.clear(); }

  RequestHandler& handler_;
  const size_t max_queued_;
  // Touched on strand_ only.
  std::array<uint8_t, daoai::kRequestSize> read_buf_{};
  std::deque<daoai::Request> queued_;
};

}  // namespace

class DaoaiServer::Impl {
 public:
  Impl(RequestHandler& handler, DaoaiServerOptions options)
      : options_(std::move(options)),
        listener_("daoai", [&handler, this](SessionArgs args) -> std::shared_ptr<Session> {
          return std::make_shared<Connection>(std::move(args), handler, options_);
        },
        internal::ConnectionLimits{options_.max_connections, options_.max_connections_per_peer,
                                   options_.max_message_rate, options_.allowlist,
                                   options_.config_allowlist, options_.keepalive_idle,
                                   options_.keepalive_interval, options_.keepalive_probes,
                                   options_.send_buffer_bytes}) {}

  Status Listen() { return listener_.Listen(options_.bind, {options_.port}, options_.io_threads); }
  void Stop() { listener_.Stop(); }
  int port() const { return listener_.ports().at(0); }
  std::string address() const { return options_.bind + ":" + std::to_string(port()); }
  size_t connection_count() const { return listener_.connection_count(); }
  TransportStats stats() const { return listener_.stats(); }
  uint64_t refused_count() const { return listener_.refused_count(); }

 private:
  const DaoaiServerOptions options_;
  internal::Listener listener_;
};

Result<std::unique_ptr<DaoaiServer>> DaoaiServer::Start(RequestHandler& handler,
                                                        const DaoaiServerOptions& options) {
  auto impl = std::make_unique<Impl>(handler, options);
  Status s = impl->Listen();
  if (!s.ok()) return s;
  return std::unique_ptr<DaoaiServer>(new DaoaiServer(std::move(impl)));
}

DaoaiServer::DaoaiServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
DaoaiServer::~DaoaiServer() = default;
int DaoaiServer::port() const { return impl_->port(); }
std::string DaoaiServer::address() const { return impl_->address(); }
size_t DaoaiServer::connection_count() const { return impl_->connection_count(); }
TransportStats DaoaiServer::stats() const { return impl_->stats(); }
uint64_t DaoaiServer::refused_count() const { return impl_->refused_count(); }
void DaoaiServer::Stop() { impl_->Stop(); }

}  // namespace bp
