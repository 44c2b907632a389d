#include "comms/internal/tcp_server.h"

#include <netinet/in.h>
#include <netinet/tcp.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

namespace bp::internal {

Session::Session(SessionArgs args, const char* log_name, std::chrono::milliseconds read_timeout)
    : socket_(std::move(args.socket)),
      strand_(std::move(args.strand)),
      log_name_(log_name),
      timer_(strand_),
      throttle_timer_(strand_),
      max_message_rate_(args.max_message_rate),
      gate_(std::move(args.gate)),
      on_closed_(std::move(args.on_closed)),
      counters_(args.counters ? std::move(args.counters) : std::make_shared<TransportCounters>()),
      read_timeout_(read_timeout) {
  client_.id = args.id;
  client_.may_change_cell = args.may_change_cell;
  // Answers are written after their Reply runs: a pick's grasp is handed out
  // when the write completes, and put back when it fails.
  client_.settle_after_write = true;
  if (args.limits) SetKeepAlive(*args.limits);
  tokens_ = std::max(1.0, max_message_rate_);
  boost::system::error_code ec;
  const tcp::endpoint peer = socket_.remote_endpoint(ec);
  client_.peer = ec ? "?" : peer.address().to_string() + ":" + std::to_string(peer.port());
}

void Session::SetKeepAlive(const ConnectionLimits& limits) {
  const int fd = socket_.native_handle();
  if (limits.send_buffer_bytes > 0) {
    ::setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &limits.send_buffer_bytes, sizeof(limits.send_buffer_bytes));
  }
  if (limits.keepalive_idle.count() <= 0) return;
  const int on = 1;
  const int idle = static_cast<int>(limits.keepalive_idle.count());
  const int interval = static_cast<int>(std::max<int64_t>(1, limits.keepalive_interval.count()));
  const int probes = std::max(1, limits.keepalive_probes);
  // Unacknowledged data gets the same bound as an idle connection.
  const unsigned user_timeout_ms = static_cast<unsigned>((idle + interval * probes) * 1000);
  if (::setsockopt(fd, SOL_SOCKET, SO_KEEPALIVE, &on, sizeof(on)) != 0 ||
      ::setsockopt(fd, IPPROTO_TCP, TCP_KEEPIDLE, &idle, sizeof(idle)) != 0 ||
      ::setsockopt(fd, IPPROTO_TCP, TCP_KEEPINTVL, &interval, sizeof(interval)) != 0 ||
      ::setsockopt(fd, IPPROTO_TCP, TCP_KEEPCNT, &probes, sizeof(probes)) != 0 ||
      ::setsockopt(fd, IPPROTO_TCP, TCP_USER_TIMEOUT, &user_timeout_ms, sizeof(user_timeout_ms)) != 0) {
    spdlog::warn("{}: {}: cannot set TCP keepalive: {}", log_name_, client_.peer, std::strerror(errno));
  }
}

void Session::Start() {
  boost::system::error_code ec;
  socket_.set_option(tcp::no_delay(true), ec);
  spdlog::info("{}: robot connected from {} (connection {})", log_name_, client_.peer, client_.id);
  asio::dispatch(strand_, [self = shared_from_this()] {
    self->ArmTimer();
    self->BeginReading();
  });
}

void Session::AckNow() {
#ifdef TCP_QUICKACK
  const int one = 1;
  ::setsockopt(socket_.native_handle(), IPPROTO_TCP, TCP_QUICKACK, &one, sizeof(one));
#endif
}

void Session::Close(const char* why) {
  asio::dispatch(strand_, [self = shared_from_this(), why] { self->DoClose(why); });
}

void Session::OnReadError(boost::system::error_code ec) {
  if (ec == asio::error::eof || ec == asio::error::connection_reset) {
    DoClose(busy_ ? "disconnected with a request in progress" : "disconnected");
  } else {
    DoClose(ec.message().c_str());
  }
}

void Session::ReadNextRequest() {
  if (max_message_rate_ <= 0) {
    BeginReading();
    return;
  }
  const auto now = std::chrono::steady_clock::now();
  const double burst = std::max(1.0, max_message_rate_);
  tokens_ = std::min(burst, tokens_ + max_message_rate_ *
                                          std::chrono::duration<double>(now - tokens_at_).count());
  tokens_at_ = now;
  if (tokens_ >= 1.0) {
    tokens_ -= 1.0;
    BeginReading();
    return;
  }
  if (!throttle_logged_) {
    spdlog::warn("{}: {} sends more than {} requests/s; reading it no faster (max_message_rate)",
                 log_name_, client_.peer, max_message_rate_);
    throttle_logged_ = true;
  }
  const auto wait = std::chrono::duration<double>((1.0 - tokens_) / max_message_rate_);
  throttle_timer_.expires_after(std::chrono::duration_cast<std::chrono::nanoseconds>(wait));
  throttle_timer_.async_wait([self = shared_from_this()](boost::system::error_code ec) {
    if (ec || self->closed_) return;
    self->ReadNextRequest();
  });
}

void Session::Write(std::vector<uint8_t> bytes, const char* close_reason,
                    std::function<void(bool)> on_written) {
  write_buf_ = std::move(bytes);
  writing_ = true;
  write_start_ = std::chrono::steady_clock::now();
  asio::async_write(socket_, asio::buffer(write_buf_),
                    asio::bind_executor(strand_, [self = shared_from_this(), close_reason,
                                                  on_written = std::move(on_written)](
                                                     boost::system::error_code ec, size_t) {
                      self->writing_ = false;
                      if (on_written) on_written(!ec);
                      if (ec) {
                        self->DoClose("write failed");
                      } else if (close_reason) {
                        self->DoClose(close_reason);
                      } else {
                        self->Done();
                      }
                    }));
}

void Session::EndHandle() {
  in_handle_ = false;
  if (sync_work_) {
    std::function<void()> work = std::move(sync_work_);
    sync_work_ = nullptr;
    work();
  }
}

// The timer is re-armed lazily from the last activity instead of on every
// message.
void Session::ArmTimer() {
  const auto now = std::chrono::steady_clock::now();
  timer_.expires_at(busy_ ? now + read_timeout_ : last_activity_ + read_timeout_);
  timer_.async_wait([self = shared_from_this()](boost::system::error_code ec) {
    if (ec || self->closed_) return;
    if (self->writing_ &&
        std::chrono::steady_clock::now() - self->write_start_ >= self->read_timeout_) {
      spdlog::warn("{}: {} read no answer for {} ms; closing", self->log_name_,
                   self->client_.peer, self->read_timeout_.count());
      self->DoClose("write timeout (robot not reading)");
      return;
    }
    const auto idle = std::chrono::steady_clock::now() - self->last_activity_;
    if (!self->busy_ && idle >= self->read_timeout_) {
      spdlog::warn("{}: {} sent no complete request for {} ms; closing", self->log_name_,
                   self->client_.peer, self->read_timeout_.count());
      self->counters_->read_timeouts.fetch_add(1, std::memory_order_relaxed);
      self->DoClose("read timeout");
      return;
    }
    self->ArmTimer();
  });
}

void Session::DoClose(const char* why) {
  if (closed_) return;
  closed_ = true;
  spdlog::info("{}: connection {} ({}) closed: {}", log_name_, client_.id, client_.peer, why);
  boost::system::error_code ec;
  timer_.cancel();
  throttle_timer_.cancel();
  socket_.shutdown(tcp::socket::shutdown_both, ec);
  socket_.close(ec);
  OnClosed();
  if (on_closed_) on_closed_(client_.id);
}

Listener::Listener(const char* log_name, Factory factory, ConnectionLimits limits)
    : log_name_(log_name), factory_(std::move(factory)), limits_(std::move(limits)) {}

Listener::~Listener() {
  Stop();
  std::lock_guard lock(gate_->mutex);
  gate_->open = false;  // from now on, late completions are dropped
}

Status Listener::Listen(const std::string& bind, const std::vector<int>& ports, int io_threads) {
  boost::system::error_code ec;
  const asio::ip::address address = asio::ip::make_address(bind, ec);
  if (ec)
    return Status::InvalidArgument(std::string(log_name_) + ": bad bind address '" + bind + "'");
  Result<AddressList> allowed = AddressList::Parse(limits_.allowlist);
  if (!allowed.ok()) {
    return Status::InvalidArgument(std::string(log_name_) + ": bad allowlist entry: " +
                                   allowed.status().message());
  }
  allowed_ = *allowed;
  Result<AddressList> config_allowed = AddressList::Parse(limits_.config_allowlist);
  if (!config_allowed.ok()) {
    return Status::InvalidArgument(std::string(log_name_) + ": bad config allowlist entry: " +
                                   config_allowed.status().message());
  }
  config_allowed_ = *config_allowed;
  for (int port : ports) {
    if (port < 0 || port > 65535) {
      return Status::InvalidArgument(std::string(log_name_) + ": bad port " + std::to_string(port));
    }
    const tcp::endpoint endpoint(address, static_cast<uint16_t>(port));
    auto acceptor = std::make_unique<tcp::acceptor>(io_);
    acceptor->open(endpoint.protocol(), ec);
    if (!ec) acceptor->set_option(tcp::acceptor::reuse_address(true), ec);
    if (!ec) acceptor->bind(endpoint, ec);
    if (!ec) acceptor->listen(asio::socket_base::max_listen_connections, ec);
    if (ec) {
      return Status::Unavailable(std::string(log_name_) + ": cannot listen on " + bind + ":" +
                                 std::to_string(port) + ": " + ec.message());
    }
    ports_.push_back(acceptor->local_endpoint(ec).port());
    acceptors_.push_back(std::move(acceptor));
    accept_strands_.push_back(asio::make_strand(io_));
    accept_timers_.push_back(std::make_unique<asio::steady_timer>(accept_strands_.back()));
    accept_backoff_.push_back(std::chrono::milliseconds(0));
  }
  for (size_t i = 0; i < acceptors_.size(); ++i) Accept(i);
  for (int i = 0; i < std::max(1, io_threads); ++i) {
    threads_.emplace_back([this] { io_.run(); });
  }
  return Status::Ok();
}

void Listener::Stop() {
  if (stopped_.exchange(true)) return;
  asio::post(io_, [this] {
    boost::system::error_code ec;
    for (auto& acceptor : acceptors_) acceptor->close(ec);
    for (auto& timer : accept_timers_) timer->cancel();
    std::vector<std::shared_ptr<Session>> open;
    {
      std::lock_guard lock(mutex_);
      for (auto& [id, c] : connections_) {
        if (auto session = c.session.lock()) open.push_back(std::move(session));
      }
    }
    for (auto& c : open) c->Close("server stopping");  // may call back into connections_
  });
  // run() returns once the closes have completed every pending operation;
  // completions posted later stay queued and are destroyed with io_.
  for (auto& t : threads_) t.join();
  threads_.clear();
}

size_t Listener::connection_count() const {
  std::lock_guard lock(mutex_);
  return connections_.size();
}

uint64_t Listener::refused_count() const {
  return counters_->refused_allowlist.load() + counters_->refused_max_connections.load() +
         counters_->refused_per_peer.load();
}

TransportStats Listener::stats() const {
  TransportStats s;
  s.accepted = counters_->accepted.load(std::memory_order_relaxed);
  s.open = connection_count();
  s.read_timeouts = counters_->read_timeouts.load(std::memory_order_relaxed);
  s.protocol_errors = counters_->protocol_errors.load(std::memory_order_relaxed);
  s.refused_allowlist = counters_->refused_allowlist.load(std::memory_order_relaxed);
  s.refused_max_connections = counters_->refused_max_connections.load(std::memory_order_relaxed);
  s.refused_per_peer = counters_->refused_per_peer.load(std::memory_order_relaxed);
  s.accept_errors = counters_->accept_errors.load(std::memory_order_relaxed);
  return s;
}

void Listener::Accept(size_t index) {
  tcp::acceptor& acceptor = *acceptors_[index];
  Strand strand = asio::make_strand(io_);
  acceptor.async_accept(
      strand, asio::bind_executor(accept_strands_[index], [this, index, strand](
                                                              boost::system::error_code ec,
                                                              tcp::socket socket) mutable {
        if (ec) {
          if (ec != asio::error::operation_aborted && !stopped_) OnAcceptError(index, ec);
          return;
        }
        accept_backoff_[index] = std::chrono::milliseconds(0);
        std::optional<std::string> peer = Admit(socket);
        if (!peer) {
          Accept(index);
          return;
        }
        uint64_t id = 0;
        {
          std::lock_guard lock(mutex_);
          id = ++next_id_;
        }
        SessionArgs args{std::move(socket), strand, gate_, id, ports_[index],
                         limits_.max_message_rate,
                         [this](uint64_t closed_id) {
                           std::lock_guard lock(mutex_);
                           auto it = connections_.find(closed_id);
                           if (it == connections_.end()) return;
                           auto peer_it = per_peer_.find(it->second.peer);
                           if (peer_it != per_peer_.end() && --peer_it->second == 0) {
                             per_peer_.erase(peer_it);
                           }
                           connections_.erase(it);
                         },
                         counters_, config_allowed_.Contains(*peer), &limits_};
        std::shared_ptr<Session> session = factory_(std::move(args));
        counters_->accepted.fetch_add(1, std::memory_order_relaxed);
        {
          std::lock_guard lock(mutex_);
          connections_[id] = Connection{session, *peer};
          ++per_peer_[*peer];
        }
        session->Start();
        Accept(index);
      }));
}

void Listener::OnAcceptError(size_t index, boost::system::error_code ec) {
  const uint64_t n = counters_->accept_errors.fetch_add(1, std::memory_order_relaxed) + 1;
  const bool resources = ec == asio::error::no_descriptors ||
                         ec.value() == ENFILE || ec == asio::error::no_buffer_space ||
                         ec == asio::error::no_memory;
  std::chrono::milliseconds& backoff = accept_backoff_[index];
  if (!resources) {
    // Not a shortage (e.g. the peer reset before the accept): go on at once.
    spdlog::warn("{}: accept failed: {}", log_name_, ec.message());
    Accept(index);
    return;
  }
  if (backoff.count() == 0) {
    spdlog::error("{}: accept failed: {} ({} accept errors since start); retrying with a pause "
                  "doubling up to 1 s until it succeeds",
                  log_name_, ec.message(), n);
  }
  backoff = std::min(std::chrono::milliseconds(1000),
                     std::max(std::chrono::milliseconds(10), backoff * 2));
  asio::steady_timer& timer = *accept_timers_[index];
  timer.expires_after(backoff);
  timer.async_wait([this, index](boost::system::error_code wait_ec) {
    if (wait_ec || stopped_) return;
    Accept(index);
  });
}

std::optional<std::string> Listener::Admit(tcp::socket& socket) {
  boost::system::error_code ec;
  const tcp::endpoint peer = socket.remote_endpoint(ec);
  std::string why;
  std::atomic<uint64_t>* counter = &counters_->refused_allowlist;
  asio::ip::address a;
  if (!ec) {
    a = peer.address();
    if (a.is_v6() && a.to_v6().is_v4_mapped()) a = asio::ip::make_address_v4(asio::ip::v4_mapped, a.to_v6());
  }
  const std::string address = ec ? std::string() : a.to_string();
  if (ec) {
    why = "peer address unknown: " + ec.message();
  } else if (!allowed_.Contains(address)) {
    why = "not in the allowlist";
  }
  if (why.empty()) {
    std::lock_guard lock(mutex_);
    if (limits_.max_connections > 0 && connections_.size() >= limits_.max_connections) {
      why = std::to_string(connections_.size()) + " connections open (max_connections " +
            std::to_string(limits_.max_connections) + ")";
      counter = &counters_->refused_max_connections;
    } else if (limits_.max_connections_per_peer > 0) {
      auto it = per_peer_.find(address);
      if (it != per_peer_.end() && it->second >= limits_.max_connections_per_peer) {
        why = std::to_string(it->second) + " connections open from " + address +
              " (max_connections_per_peer " + std::to_string(limits_.max_connections_per_peer) + ")";
        counter = &counters_->refused_per_peer;
      }
    }
  }
  if (why.empty()) return address;
  counter->fetch_add(1, std::memory_order_relaxed);
  spdlog::warn("{}: refused a connection from {}: {}", log_name_,
               ec ? std::string("?") : address + ":" + std::to_string(peer.port()), why);
  socket.shutdown(tcp::socket::shutdown_both, ec);
  socket.close(ec);
  return std::nullopt;
}

}  // namespace bp::internal
