#include "web/status_server.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <mutex>
#include <optional>
#include <string_view>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

// After <utility>: Asio's awaitable.hpp uses std::exchange without including it.
#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>

#include "core/address_list.h"
#include "web/internal/page.h"

namespace bp {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = asio::ip::tcp;

struct Reply {
  http::status status = http::status::ok;
  std::string content_type;
  std::string body;
  bool allow = false;  // add "Allow: GET, HEAD" (405)
};

Reply Text(http::status status, std::string body) {
  return {status, "text/plain; charset=utf-8", std::move(body) + "\n", false};
}

}  // namespace

class StatusServer::Impl {
 public:
  Impl(const StatusState& state, MetricsRegistry& metrics, StatusServerOptions options)
      : state_(state), metrics_(metrics), options_(std::move(options)), acceptor_(io_) {}
  ~Impl() { Stop(); }

  Status Listen() {
    boost::system::error_code ec;
    const asio::ip::address address = asio::ip::make_address(options_.bind, ec);
    if (ec) return Status::InvalidArgument("http: bad bind address '" + options_.bind + "'");
    if (options_.port < 0 || options_.port > 65535) {
      return Status::InvalidArgument("http: bad port " + std::to_string(options_.port));
    }
    Result<AddressList> allowed = AddressList::Parse(options_.allowlist);
    if (!allowed.ok()) {
      return Status::InvalidArgument("http: bad allowlist entry: " + allowed.status().message());
    }
    allowed_ = *allowed;
    // Both reasons appear in /metrics from the start, at 0.
    refused_allowlist_ = &RefusedCounter("allowlist");
    refused_limit_ = &RefusedCounter("max_connections");
    const tcp::endpoint endpoint(address, static_cast<uint16_t>(options_.port));
    acceptor_.open(endpoint.protocol(), ec);
    if (!ec) acceptor_.set_option(tcp::acceptor::reuse_address(true), ec);
    if (!ec) acceptor_.bind(endpoint, ec);
    if (!ec) acceptor_.listen(asio::socket_base::max_listen_connections, ec);
    if (ec) {
      return Status::Unavailable("http: cannot listen on " + options_.bind + ":" +
                                 std::to_string(options_.port) + ": " + ec.message());
    }
    port_ = acceptor_.local_endpoint(ec).port();
    Accept();
    thread_ = std::thread([this] { io_.run(); });
    return Status::Ok();
  }

  void Stop() {
    if (stopped_.exchange(true)) return;
    asio::post(io_, [this] {
      boost::system::error_code ec;
      acceptor_.close(ec);
      for (auto& [id, session] : sessions_) session->Close();
    });
    if (thread_.joinable()) thread_.join();
  }

  int port() const { return port_; }
  const std::string& bind() const { return options_.bind; }

 private:
  // One browser connection. Runs on the io thread only (one thread: no strand).
  class Session : public std::enable_shared_from_this<Session> {
   public:
    Session(Impl& server, uint64_t id, tcp::socket socket)
        : server_(server), id_(id), stream_(std::move(socket)) {}

    void Start() { Read(); }
    void Close() {
      boost::system::error_code ec;
      stream_.socket().shutdown(tcp::socket::shutdown_both, ec);
      stream_.close();
    }
    // Answers 503 and closes (over the connection limit).
    void Refuse() {
      Reply r = Text(http::status::service_unavailable, "too many connections");
      Send(std::move(r), false, 11, false);
    }

   private:
    void Read() {
      parser_.emplace();
      parser_->header_limit(static_cast<uint32_t>(server_.options_.max_request_bytes));
      parser_->body_limit(server_.options_.max_request_bytes);
      stream_.expires_after(server_.options_.idle_timeout);
      http::async_read(stream_, buffer_, *parser_,
                       [self = shared_from_this()](beast::error_code ec, size_t) { self->OnRead(ec); });
    }

    void OnRead(beast::error_code ec) {
      if (ec == http::error::end_of_stream || ec == beast::error::timeout ||
          ec == asio::error::operation_aborted || ec == asio::error::connection_reset ||
          ec == asio::error::eof) {
        Finish();
        return;
      }
      if (ec) {
        const bool too_big = ec == http::error::body_limit || ec == http::error::header_limit ||
                             ec == http::error::buffer_overflow;
        Send(Text(too_big ? http::status::payload_too_large : http::status::bad_request,
                  too_big ? "request too large" : "bad request: " + ec.message()),
             false, 11, false);
        return;
      }
      const auto& req = parser_->get();
      const bool head = req.method() == http::verb::head;
      Reply reply;
      if (req.method() != http::verb::get && !head) {
        reply = Text(http::status::method_not_allowed, "only GET and HEAD");
        reply.allow = true;
      } else {
        reply = server_.Route(std::string_view(req.target().data(), req.target().size()));
      }
      Send(std::move(reply), req.keep_alive(), req.version(), head);
    }

    void Send(Reply reply, bool keep_alive, unsigned version, bool head) {
      server_.metrics_
          .GetCounter("binpick_http_requests_total", "Status page HTTP responses by code.",
                      {{"code", std::to_string(static_cast<int>(reply.status))}})
          .Inc();
      auto res = std::make_shared<http::response<http::string_body>>(reply.status, version);
      res->set(http::field::server, "binpickd");
      res->set(http::field::content_type, reply.content_type);
      res->set(http::field::cache_control, "no-store");
      if (reply.allow) res->set(http::field::allow, "GET, HEAD");
      res->keep_alive(keep_alive);
      const size_t length = reply.body.size();
      if (!head) res->body() = std::move(reply.body);
      res->content_length(length);
      stream_.expires_after(server_.options_.idle_timeout);
      if (head) {
        auto sr = std::make_shared<http::response_serializer<http::string_body>>(*res);
        http::async_write_header(stream_, *sr,
                                 [self = shared_from_this(), res, sr, keep_alive](beast::error_code ec,
                                                                                  size_t) {
                                   self->AfterWrite(ec, keep_alive);
                                 });
        return;
      }
      http::async_write(stream_, *res,
                        [self = shared_from_this(), res, keep_alive](beast::error_code ec, size_t) {
                          self->AfterWrite(ec, keep_alive);
                        });
    }

    void AfterWrite(beast::error_code ec, bool keep_alive) {
      if (ec || !keep_alive) {
        Finish();
        return;
      }
      Read();
    }

    void Finish() {
      Close();
      server_.sessions_.erase(id_);
    }

    Impl& server_;
    const uint64_t id_;
    beast::tcp_stream stream_;
    beast::flat_buffer buffer_;
    std::optional<http::request_parser<http::string_body>> parser_;
  };

  void Accept() {
    acceptor_.async_accept([this](boost::system::error_code ec, tcp::socket socket) {
      if (ec) {
        if (ec == asio::error::operation_aborted || stopped_) return;
        spdlog::warn("http: accept failed: {}", ec.message());
        Accept();
        return;
      }
      if (!Allowed(socket)) {
        Accept();
        return;
      }
      const uint64_t id = ++next_id_;
      auto session = std::make_shared<Session>(*this, id, std::move(socket));
      sessions_[id] = session;
      if (options_.max_connections > 0 && sessions_.size() > options_.max_connections) {
        refused_limit_->Inc();
        session->Refuse();
      } else {
        session->Start();
      }
      Accept();
    });
  }

  static asio::ip::address Unmapped(const asio::ip::address& a) {
    if (a.is_v6() && a.to_v6().is_v4_mapped()) {
      return asio::ip::make_address_v4(asio::ip::v4_mapped, a.to_v6());
    }
    return a;
  }

  Counter& RefusedCounter(const char* reason) {
    return metrics_.GetCounter("binpick_http_refused_connections_total",
                               "Status page connections refused (allowlist: closed at accept; "
                               "max_connections: answered 503).",
                               {{"reason", reason}});
  }

  // Applies the allowlist; closes a refused socket with a log line.
  bool Allowed(tcp::socket& socket) {
    if (allowed_.empty()) return true;
    boost::system::error_code ec;
    const tcp::endpoint peer = socket.remote_endpoint(ec);
    if (!ec && allowed_.Contains(Unmapped(peer.address()).to_string())) return true;
    refused_allowlist_->Inc();
    spdlog::warn("http: refused a connection from {}: {}",
                 ec ? std::string("?") : peer.address().to_string() + ":" + std::to_string(peer.port()),
                 ec ? "peer address unknown: " + ec.message() : std::string("not in the allowlist"));
    socket.shutdown(tcp::socket::shutdown_both, ec);
    socket.close(ec);
    return false;
  }

  Reply Route(std::string_view target) const {
    const size_t q = target.find('?');
    const std::string_view path = target.substr(0, q);
    try {
      if (path == "/" || path == "/index.html") {
        return {http::status::ok, "text/html; charset=utf-8", std::string(internal::StatusPageHtml()),
                false};
      }
      if (path == "/api/status") {
        return {http::status::ok, "application/json", state_.StatusJson(), false};
      }
      if (path == "/metrics") {
        return {http::status::ok, "text/plain; version=0.0.4; charset=utf-8", metrics_.Render(),
                false};
      }
      if (path == "/api/image/depth.png" || path == "/api/image/intensity.png") {
        std::optional<std::vector<uint8_t>> png = path == "/api/image/depth.png"
                                                      ? state_.RenderDepthPng()
                                                      : state_.RenderIntensityPng();
        if (!png) return Text(http::status::not_found, "no image captured");
        return {http::status::ok, "image/png", std::string(png->begin(), png->end()), false};
      }
    } catch (const std::exception& e) {
      spdlog::error("http: {} failed: {}", path, e.what());
      return Text(http::status::internal_server_error, "internal error");
    }
    return Text(http::status::not_found, "not found");
  }

  const StatusState& state_;
  MetricsRegistry& metrics_;
  const StatusServerOptions options_;
  asio::io_context io_;
  tcp::acceptor acceptor_;
  std::thread thread_;
  std::atomic<bool> stopped_{false};
  int port_ = 0;
  AddressList allowed_;  // parsed options_.allowlist
  Counter* refused_allowlist_ = nullptr;
  Counter* refused_limit_ = nullptr;
  uint64_t next_id_ = 0;                                                // io thread
  std::unordered_map<uint64_t, std::shared_ptr<Session>> sessions_;     // io thread
};

Result<std::unique_ptr<StatusServer>> StatusServer::Start(const StatusState& state,
                                                          MetricsRegistry& metrics,
                                                          const StatusServerOptions& options) {
  auto impl = std::make_unique<Impl>(state, metrics, options);
  if (Status s = impl->Listen(); !s.ok()) return s;
  return std::unique_ptr<StatusServer>(new StatusServer(std::move(impl)));
}

StatusServer::StatusServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
StatusServer::~StatusServer() { Stop(); }
int StatusServer::port() const { return impl_->port(); }
std::string StatusServer::address() const { return impl_->bind() + ":" + std::to_string(impl_->port()); }
void StatusServer::Stop() {
  if (impl_) impl_->Stop();
}

}  // namespace bp
