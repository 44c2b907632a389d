#include "comms/gri_server.h"

#include <spdlog/spdlog.h>

#include <array>
#include <cstring>
#include <deque>
#include <optional>
#include <utility>
#include <vector>

#include "comms/gri_message.h"
#include "comms/internal/exception_text.h"
#include "comms/internal/tcp_server.h"

namespace bp {
namespace {

namespace asio = internal::asio;
using internal::ExceptionText;
using internal::Session;
using internal::SessionArgs;

class Connection final : public Session {
 public:
  Connection(SessionArgs args, GriHandler& handler, const GriServerOptions& options,
             gri::Format port_format)
      : Session(std::move(args), "gri", options.read_timeout),
        handler_(handler),
        options_(options),
        port_format_(port_format),
        format_(port_format),
        processing_timer_(strand_) {}

 private:
  // A request to answer: decoded, or with the error its bytes deserve.
  struct Item {
    gri::Request request;
    std::optional<gri::Code> error;
    const char* close_reason = nullptr;  // close after answering (stream lost)
  };

  std::shared_ptr<Connection> Self() {
    return std::static_pointer_cast<Connection>(shared_from_this());
  }

  void BeginReading() override { ReadFirst(); }

  // Reads in_[at, at + n), then runs `next`.
  // Every GRI request is answered, but a robot may write a message in
  // pieces (header, then body): a segment short of what is read, or a
  // header with nothing after it yet, is acknowledged at once
  // (Session::ReadExactly, AckNow).
  void ReadInto(size_t at, size_t n, void (Connection::*next)()) {
    ReadExactly(in_.data() + at, n, [self = Self(), at, n, next] {
      self->have_ = at + n;
      if (next != &Connection::OnBody) {
        boost::system::error_code ec;
        if (self->socket_.available(ec) == 0 && !ec) self->AckNow();
      }
      ((*self).*next)();
    });
  }

  void ReadFirst() {
    have_ = 0;
    ReadInto(0, 1, &Connection::OnFirst);
  }

  void OnFirst() {
    const std::optional<gri::Format> f = gri::DetectFormat(in_[0]);
    if (!f) {
      format_ = port_format_;
      Reject(gri::Code::kInvalidRequest, "wrong magic: first byte " + std::to_string(in_[0]) +
                                             " is neither 2 (v2) nor 'G' (official)");
      return;
    }
    format_ = *f;
    ReadInto(1, gri::HeaderSize(format_) - 1, &Connection::OnHeader);
  }

  void OnHeader() {
    const bool v2 = format_ == gri::Format::kV2;
    if (!v2 && std::memcmp(in_.data(), gri::kOfficialMagic.data(), 4) != 0) {
      Reject(gri::Code::kInvalidRequest, "wrong magic: official messages start with \"GRI\\0\"");
      return;
    }
    const uint8_t length = in_[v2 ? 2 : 5];
    if (length != gri::RequestSize(format_)) {
      Reject(gri::Code::kInvalidRequestLength,
             "length field says " + std::to_string(length) + " bytes, " +
                 std::string(gri::ToString(format_)) + " requests are " +
                 std::to_string(gri::RequestSize(format_)));
      return;
    }
    ReadInto(have_, gri::RequestSize(format_) - have_, &Connection::OnBody);
  }

  void OnBody() {
    MarkActivity();
    gri::Fault fault = gri::Fault::kShort;
    Result<gri::Request> decoded =
        gri::DecodeRequest(std::span<const uint8_t>(in_.data(), have_), &fault);
    Item item;
    if (decoded.ok()) {
      item.request = *decoded;
    } else {
      spdlog::warn("gri: {}: {}", client_.peer, decoded.status().message());
      CountProtocolError();
      item.request = Echo();
      item.error = gri::CodeFor(fault);
    }
    if (Enqueue(std::move(item))) ReadNextRequest();
  }

  // The stream cannot be re-synchronised: answer, stop reading, close.
  void Reject(gri::Code code, const std::string& why) {
    spdlog::warn("gri: {} sent garbage ({}); answering and closing", client_.peer, why);
    CountProtocolError();
    Item item;
    item.request = Echo();
    item.error = code;
    item.close_reason = "unframeable request";
    Enqueue(std::move(item));
  }

  // Header fields and job id of the bytes read so far, for an error answer.
  gri::Request Echo() const {
    gri::Request r;
    r.format = format_;
    const bool v2 = format_ == gri::Format::kV2;
    const size_t header = gri::HeaderSize(format_);
    if (have_ >= header) {
      r.pose_format = in_[v2 ? 3 : 6];
      r.action = in_[v2 ? 4 : 7];
    }
    if (v2 && have_ > header) r.job_id = static_cast<int8_t>(in_[5]);
    if (!v2 && have_ >= header + 2) r.job_id = in_[8] | (in_[9] << 8);
    return r;
  }

  bool Enqueue(Item item) {
    if (queued_.size() >= options_.max_queued_requests) {
      spdlog::warn("gri: {} sent more than {} requests without waiting for answers", client_.peer,
                   options_.max_queued_requests);
      CountProtocolError();
      DoClose("request queue overflow");
      return false;
    }
    queued_.push_back(std::move(item));
    if (!busy_) ProcessNext();
    return !closed_;
  }

  void ProcessNext() {
    if (closed_ || queued_.empty()) return;
    Item item = std::move(queued_.front());
    queued_.pop_front();
    const uint64_t seq = ++seq_;
    answered_ = false;
    if (item.error) {
      busy_ = true;
      answered_ = true;
      const gri::Code code = *item.error;
      WriteAnswer(item.request, [&] { return GriHandler::ErrorResponse(item.request, code); },
                  item.close_reason);
      return;
    }
    current_ = item.request;
    BeginHandle();
    ArmProcessingTimer(seq);
    handler_.HandleAsync(item.request, client_,
                         Completion<GriHandler::Reply>(
                             [this, seq](const GriHandler::Reply& reply) { OnReply(seq, reply); }));
    EndHandle();
  }

  void OnReply(uint64_t seq, const GriHandler::Reply& reply) {
    if (seq != seq_ || answered_) return;  // timed out: its result is dropped, nothing popped
    answered_ = true;
    processing_timer_.cancel();
    WriteAnswer(current_, reply, nullptr);
  }

  // Builds the answer to `request` (a handler's Reply, an error response),
  // serializes it and writes it. Nothing thrown here reaches Asio (issue
  // 39: it would end the process): building or serializing that throws is
  // answered INTERNAL_ERROR echoing the request, logged and counted
  // (GriHandler::CountAnswerFailure), and a grasp the answer carried goes
  // back to its queue; when not even that can be written the connection is
  // closed.
  void WriteAnswer(const gri::Request& request, const std::function<gri::Response()>& build,
                   const char* close_reason) {
    bool replaced = false;
    std::vector<uint8_t> bytes;
    try {
      bytes = GriHandler::Serialize(build(), &replaced);
    } catch (...) {
      replaced = true;
      handler_.CountAnswerFailure();
      spdlog::error("gri: {}: building the answer to action {} job {} threw ({}); answering INTERNAL_ERROR",
                    client_.peer, request.action, request.job_id, ExceptionText());
      try {
        bytes = GriHandler::Serialize(GriHandler::ErrorResponse(request, gri::Code::kInternalError));
      } catch (...) {
        bytes.clear();
      }
    }
    // Set by the Reply when it popped a grasp (GriHandler::NextPoseReply).
    std::function<void(bool)> settle = TakeSettle();
    // A response that did not fit was replaced by INTERNAL_ERROR: a grasp it
    // carried was not sent and goes back to its queue. Not reached for pose
    // answers that do not fit: their grasp is popped only when the answer
    // encodes (GriHandler::NextPoseReply); reached when the pose answer's
    // serialization throws.
    if (replaced && settle) std::exchange(settle, nullptr)(false);
    if (bytes.empty()) {
      spdlog::error("gri: {}: not even INTERNAL_ERROR could be written; closing", client_.peer);
      if (settle) std::exchange(settle, nullptr)(false);
      DoClose("answer failed");
      return;
    }
    Write(std::move(bytes), close_reason, std::move(settle));
  }

  void ArmProcessingTimer(uint64_t seq) {
    processing_timer_.expires_after(options_.processing_timeout);
    processing_timer_.async_wait([self = Self(), seq](boost::system::error_code ec) {
      if (ec || self->closed_ || seq != self->seq_ || self->answered_) return;
      self->answered_ = true;
      spdlog::warn(
          "gri: {}: job {} action {} has no result after {} ms; answering "
          "PROCESSING_TIMEOUT",
          self->client_.peer, self->current_.job_id, self->current_.action,
          self->options_.processing_timeout.count());
      const gri::Request& current = self->current_;
      self->WriteAnswer(current, [&] { return GriHandler::ErrorResponse(current, gri::Code::kProcessingTimeout); },
                        nullptr);
    });
  }

  void Done() override {
    Finish();
    ProcessNext();
  }

  void OnClosed() override {
    queued_.clear();
    processing_timer_.cancel();
  }

  GriHandler& handler_;
  const GriServerOptions& options_;  // owned by the server, which outlives its connections
  const gri::Format port_format_;

  // Touched on strand_ only.
  gri::Format format_;  // of the message being read
  std::array<uint8_t, std::max(gri::kV2RequestSize, gri::kOfficialRequestSize)> in_{};
  size_t have_ = 0;  // bytes of in_ read
  std::deque<Item> queued_;
  uint64_t seq_ = 0;       // request in progress
  bool answered_ = false;  // its answer is written or being written
  gri::Request current_;   // the request in progress
  asio::steady_timer processing_timer_;
};

}  // namespace

class GriServer::Impl {
 public:
  Impl(GriHandler& handler, GriServerOptions options)
      : options_(std::move(options)),
        listener_("gri", [&handler, this](SessionArgs args) -> std::shared_ptr<Session> {
          const gri::Format f = FormatOfPort(args.local_port);
          return std::make_shared<Connection>(std::move(args), handler, options_, f);
        },
        internal::ConnectionLimits{options_.max_connections, options_.max_connections_per_peer,
                                   options_.max_message_rate, options_.allowlist,
                                   options_.config_allowlist, options_.keepalive_idle,
                                   options_.keepalive_interval, options_.keepalive_probes}) {}

  Status Listen() {
    std::vector<int> ports;
    for (auto [port, format] : {std::pair{options_.v2_port, gri::Format::kV2},
                                std::pair{options_.official_port, gri::Format::kOfficial}}) {
      if (port == 0) continue;
      ports.push_back(port < 0 ? 0 : port);
      formats_.push_back(format);
    }
    if (ports.empty()) return Status::InvalidArgument("gri: both ports are disabled");
    return listener_.Listen(options_.bind, ports, options_.io_threads);
  }

  int PortOf(gri::Format f) const {
    for (size_t i = 0; i < formats_.size(); ++i) {
      if (formats_[i] == f) return listener_.ports().at(i);
    }
    return 0;
  }

  std::string Describe() const {
    auto one = [this](gri::Format f) {
      const int port = PortOf(f);
      return std::string(gri::ToString(f)) + " " +
             (port ? options_.bind + ":" + std::to_string(port) : "disabled");
    };
    return one(gri::Format::kV2) + ", " + one(gri::Format::kOfficial);
  }

  void Stop() { listener_.Stop(); }
  size_t connection_count() const { return listener_.connection_count(); }
  TransportStats stats() const { return listener_.stats(); }
  uint64_t refused_count() const { return listener_.refused_count(); }

 private:
  gri::Format FormatOfPort(int port) const {
    const std::vector<int>& ports = listener_.ports();
    for (size_t i = 0; i < ports.size(); ++i) {
      if (ports[i] == port) return formats_[i];
    }
    return gri::Format::kV2;
  }

  const GriServerOptions options_;
  std::vector<gri::Format> formats_;  // of listener_.ports(), fixed before accepting
  internal::Listener listener_;
};

Result<std::unique_ptr<GriServer>> GriServer::Start(GriHandler& handler,
                                                    const GriServerOptions& options) {
  auto impl = std::make_unique<Impl>(handler, options);
  Status s = impl->Listen();
  if (!s.ok()) return s;
  return std::unique_ptr<GriServer>(new GriServer(std::move(impl)));
}

GriServer::GriServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
GriServer::~GriServer() { Stop(); }
int GriServer::v2_port() const { return impl_->PortOf(gri::Format::kV2); }
int GriServer::official_port() const { return impl_->PortOf(gri::Format::kOfficial); }
std::string GriServer::Describe() const { return impl_->Describe(); }
size_t GriServer::connection_count() const { return impl_->connection_count(); }
TransportStats GriServer::stats() const { return impl_->stats(); }
uint64_t GriServer::refused_count() const { return impl_->refused_count(); }
void GriServer::Stop() { impl_->Stop(); }

}  // namespace bp
