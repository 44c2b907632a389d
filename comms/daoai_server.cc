#include "comms/daoai_server.h"

#include <spdlog/spdlog.h>

#include <array>
#include <atomic>
#include <boost/asio.hpp>
#include <deque>
#include <mutex>
#include <optional>
#include <thread>
#include <unordered_map>
#include <vector>

#include "comms/daoai_message.h"

namespace bp {
namespace {

namespace asio = boost::asio;
using asio::ip::tcp;
using Strand = asio::strand<asio::io_context::executor_type>;

// Lets detection workers post completions into the io_context only while it
// exists: the server closes the gate (under the mutex) before destroying it.
struct PostGate {
  std::mutex mutex;
  bool open = true;  // GUARDED_BY(mutex)
};

class Connection : public std::enable_shared_from_this<Connection> {
 public:
  Connection(tcp::socket socket, Strand strand, RequestHandler& handler,
             std::shared_ptr<PostGate> gate, const DaoaiServerOptions& options, uint64_t id,
             std::function<void(uint64_t)> on_closed)
      : socket_(std::move(socket)),
        strand_(std::move(strand)),
        timer_(strand_),
        handler_(handler),
        gate_(std::move(gate)),
        options_(options),
        on_closed_(std::move(on_closed)) {
    client_.id = id;
    boost::system::error_code ec;
    const tcp::endpoint peer = socket_.remote_endpoint(ec);
    client_.peer = ec ? "?" : peer.address().to_string() + ":" + std::to_string(peer.port());
  }

  void Start() {
    boost::system::error_code ec;
    socket_.set_option(tcp::no_delay(true), ec);
    spdlog::info("daoai: robot connected from {} (connection {})", client_.peer, client_.id);
    asio::dispatch(strand_, [self = shared_from_this()] {
      self->ArmTimer();
      self->Read();
    });
  }

  // Safe from any thread.
  void Close(const char* why) {
    asio::dispatch(strand_, [self = shared_from_this(), why] { self->DoClose(why); });
  }

 private:
  void Read() {
    asio::async_read(socket_, asio::buffer(read_buf_),
                     asio::bind_executor(strand_, [self = shared_from_this()](
                                                      boost::system::error_code ec, size_t) {
                       self->OnRead(ec);
                     }));
  }

  void OnRead(boost::system::error_code ec) {
    if (closed_) return;
    if (ec) {
      if (ec == asio::error::eof || ec == asio::error::connection_reset) {
        DoClose(busy_ ? "disconnected with a request in progress" : "disconnected");
      } else {
        DoClose(ec.message().c_str());
      }
      return;
    }
    last_activity_ = std::chrono::steady_clock::now();
    if (queued_.size() >= options_.max_queued_requests) {
      spdlog::warn("daoai: {} sent more than {} requests without waiting for answers",
                   client_.peer, options_.max_queued_requests);
      DoClose("request queue overflow");
      return;
    }
    queued_.push_back(daoai::DecodeRequest(read_buf_));
    Read();
    if (!busy_) ProcessNext();
  }

  void ProcessNext() {
    if (closed_ || queued_.empty()) return;
    busy_ = true;
    const daoai::Request request = queued_.front();
    queued_.pop_front();
    std::weak_ptr<Connection> weak = weak_from_this();
    // A completion called inside HandleAsync (on this thread, hence on the
    // strand) is kept and run below without a trip through the io queue;
    // completions from detection workers are posted to the strand.
    in_handle_ = true;
    handler_.HandleAsync(
        request, client_,
        [weak, gate = gate_, caller = std::this_thread::get_id()](RequestHandler::Reply reply) {
          if (std::this_thread::get_id() == caller) {
            std::shared_ptr<Connection> self = weak.lock();
            if (self && self->in_handle_) {
              self->sync_reply_ = std::move(reply);
              return;
            }
          }
          std::lock_guard lock(gate->mutex);
          if (!gate->open) return;
          std::shared_ptr<Connection> self = weak.lock();
          if (!self) return;  // closed and gone: nothing popped
          asio::post(self->strand_, [self, reply = std::move(reply)] { self->OnReply(reply); });
        });
    in_handle_ = false;
    if (sync_reply_) {
      RequestHandler::Reply reply = std::move(*sync_reply_);
      sync_reply_.reset();
      OnReply(reply);
    }
  }

  void OnReply(const RequestHandler::Reply& reply) {
    if (closed_) return;  // the robot left: do not pop its grasp
    std::optional<daoai::Response> response = reply ? reply() : std::nullopt;
    if (!response) {
      Done();
      return;
    }
    write_buf_ = daoai::EncodeResponse(*response);
    asio::async_write(socket_, asio::buffer(write_buf_),
                      asio::bind_executor(strand_, [self = shared_from_this()](
                                                       boost::system::error_code ec, size_t) {
                        if (ec) {
                          self->DoClose("write failed");
                          return;
                        }
                        self->Done();
                      }));
  }

  void Done() {
    busy_ = false;
    last_activity_ = std::chrono::steady_clock::now();
    ProcessNext();
  }

  // Closes the connection when no complete request arrived (and nothing was
  // answered) for read_timeout while no request was in progress. The timer is
  // re-armed lazily from the last activity instead of on every message.
  void ArmTimer() {
    const auto now = std::chrono::steady_clock::now();
    timer_.expires_at(busy_ ? now + options_.read_timeout : last_activity_ + options_.read_timeout);
    timer_.async_wait([self = shared_from_this()](boost::system::error_code ec) {
      if (ec || self->closed_) return;
      const auto idle = std::chrono::steady_clock::now() - self->last_activity_;
      if (!self->busy_ && idle >= self->options_.read_timeout) {
        spdlog::warn("daoai: {} sent no complete request for {} ms; closing",
                     self->client_.peer, self->options_.read_timeout.count());
        self->DoClose("read timeout");
        return;
      }
      self->ArmTimer();
    });
  }

  void DoClose(const char* why) {
    if (closed_) return;
    closed_ = true;
    spdlog::info("daoai: connection {} ({}) closed: {}", client_.id, client_.peer, why);
    boost::system::error_code ec;
    timer_.cancel();
    socket_.shutdown(tcp::socket::shutdown_both, ec);
    socket_.close(ec);
    queued_.clear();
    if (on_closed_) on_closed_(client_.id);
  }

  tcp::socket socket_;
  Strand strand_;
  asio::steady_timer timer_;
  RequestHandler& handler_;
  std::shared_ptr<PostGate> gate_;
  const DaoaiServerOptions options_;
  std::function<void(uint64_t)> on_closed_;

  // Touched on strand_ only.
  ClientContext client_;
  std::array<uint8_t, daoai::kRequestSize> read_buf_{};
  std::array<uint8_t, daoai::kResponseSize> write_buf_{};
  std::deque<daoai::Request> queued_;
  bool busy_ = false;
  bool closed_ = false;
  bool in_handle_ = false;                            // inside HandleAsync
  std::optional<RequestHandler::Reply> sync_reply_;   // completed inside HandleAsync
  std::chrono::steady_clock::time_point last_activity_ = std::chrono::steady_clock::now();
};

}  // namespace

class DaoaiServer::Impl {
 public:
  Impl(RequestHandler& handler, DaoaiServerOptions options)
      : handler_(handler), options_(std::move(options)), acceptor_(io_) {}

  ~Impl() {
    Stop();
    std::lock_guard lock(gate_->mutex);
    gate_->open = false;  // from now on, late completions are dropped
  }

  Status Listen() {
    boost::system::error_code ec;
    const asio::ip::address address = asio::ip::make_address(options_.bind, ec);
    if (ec) return Status::InvalidArgument("daoai: bad bind address '" + options_.bind + "'");
    if (options_.port < 0 || options_.port > 65535) {
      return Status::InvalidArgument("daoai: bad port " + std::to_string(options_.port));
    }
    const tcp::endpoint endpoint(address, static_cast<uint16_t>(options_.port));
    acceptor_.open(endpoint.protocol(), ec);
    if (!ec) acceptor_.set_option(tcp::acceptor::reuse_address(true), ec);
    if (!ec) acceptor_.bind(endpoint, ec);
    if (!ec) acceptor_.listen(asio::socket_base::max_listen_connections, ec);
    if (ec) {
      return Status::Unavailable("daoai: cannot listen on " + options_.bind + ":" +
                                 std::to_string(options_.port) + ": " + ec.message());
    }
    port_ = acceptor_.local_endpoint(ec).port();
    Accept();
    for (int i = 0; i < std::max(1, options_.io_threads); ++i) {
      threads_.emplace_back([this] { io_.run(); });
    }
    return Status::Ok();
  }

  void Stop() {
    if (stopped_.exchange(true)) return;
    asio::post(io_, [this] {
      boost::system::error_code ec;
      acceptor_.close(ec);
      std::vector<std::shared_ptr<Connection>> open;
      {
        std::lock_guard lock(mutex_);
        for (auto& [id, weak] : connections_) {
          if (auto c = weak.lock()) open.push_back(std::move(c));
        }
      }
      for (auto& c : open) c->Close("server stopping");  // may call back into connections_
    });
    // run() returns once the closes have completed every pending operation;
    // completions posted later stay queued and are destroyed with io_.
    for (auto& t : threads_) t.join();
    threads_.clear();
  }

  int port() const { return port_; }
  std::string address() const { return options_.bind + ":" + std::to_string(port_); }
  size_t connection_count() const {
    std::lock_guard lock(mutex_);
    return connections_.size();
  }

 private:
  void Accept() {
    Strand strand = asio::make_strand(io_);
    acceptor_.async_accept(strand, [this, strand](boost::system::error_code ec,
                                                  tcp::socket socket) {
      if (ec) {
        if (ec != asio::error::operation_aborted) {
          spdlog::warn("daoai: accept failed: {}", ec.message());
          Accept();
        }
        return;
      }
      const uint64_t id = ++next_id_;
      auto connection = std::make_shared<Connection>(
          std::move(socket), strand, handler_, gate_, options_, id,
          [this](uint64_t closed_id) {
            std::lock_guard lock(mutex_);
            connections_.erase(closed_id);
          });
      {
        std::lock_guard lock(mutex_);
        connections_[id] = connection;
      }
      connection->Start();
      Accept();
    });
  }

  RequestHandler& handler_;
  const DaoaiServerOptions options_;
  std::shared_ptr<PostGate> gate_ = std::make_shared<PostGate>();
  asio::io_context io_;
  tcp::acceptor acceptor_;
  std::vector<std::thread> threads_;
  std::atomic<bool> stopped_{false};
  int port_ = 0;
  uint64_t next_id_ = 0;  // io thread only
  mutable std::mutex mutex_;
  std::unordered_map<uint64_t, std::weak_ptr<Connection>> connections_;  // GUARDED_BY(mutex_)
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
void DaoaiServer::Stop() { impl_->Stop(); }

}  // namespace bp
