#include "comms/modbus_robot_sim.h"

#include <arpa/inet.h>
#include <modbus.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <thread>

#include "comms/modbus_codec.h"

namespace bp {
namespace {

constexpr int kRegisters = 65536;
constexpr int kTcpUnitIdOffset = 6;  // MBAP header: transaction 2, protocol 2, length 2, unit 1

}  // namespace

class ModbusRobotSim::Impl {
 public:
  explicit Impl(ModbusRobotSimOptions o) : o_(std::move(o)) {}
  ~Impl() { Stop(); }

  Status Start() {
    ctx_ = modbus_new_tcp(o_.bind.c_str(), o_.port);
    if (ctx_ == nullptr) return Status::Unavailable(std::string("modbus_new_tcp: ") + modbus_strerror(errno));
    mapping_ = modbus_mapping_new(0, 0, kRegisters, 0);
    if (mapping_ == nullptr) return Status::Internal("modbus_mapping_new failed");
    listen_fd_ = modbus_tcp_listen(ctx_, 1);
    if (listen_fd_ < 0) {
      return Status::Unavailable("cannot listen on " + o_.bind + ":" + std::to_string(o_.port) +
                                 ": " + modbus_strerror(errno));
    }
    sockaddr_in addr{};
    socklen_t len = sizeof(addr);
    if (::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len) == 0) {
      port_ = ntohs(addr.sin_port);
    }
    thread_ = std::thread([this] { Serve(); });
    return Status::Ok();
  }

  void Stop() {
    {
      std::lock_guard lock(mutex_);
      stopping_ = true;
    }
    cv_.notify_all();
    {
      std::lock_guard join(join_mutex_);
      if (thread_.joinable()) thread_.join();
    }
    std::lock_guard lock(mutex_);
    if (ctx_) {
      modbus_close(ctx_);
      modbus_free(ctx_);
      ctx_ = nullptr;
    }
    if (listen_fd_ >= 0) ::close(listen_fd_);
    listen_fd_ = -1;
    if (mapping_) modbus_mapping_free(mapping_);
    mapping_ = nullptr;
  }

  int port() const { return port_; }

  bool WaitForMaster(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    return cv_.wait_for(lock, timeout, [this] { return stopping_ || stats_.masters > 0; }) &&
           !stopping_;
  }

  Status SendRobotData(const daoai::Request& request, bool expects_response,
                       std::chrono::milliseconds timeout) {
    Result<std::array<uint16_t, daoai::kRequestFields>> regs = modbus::EncodeRequest(request);
    if (!regs.ok()) return regs.status();
    std::unique_lock lock(mutex_);
    if (awaiting_take_) {
      // The previous request had no response: wait until the master took it.
      const bool taken = cv_.wait_for(lock, timeout, [this] {
        return stopping_ || Reg(o_.map.request_flag) != 1;
      });
      if (stopping_) return Status::Unavailable("robot stopped");
      if (!taken) return Status::Unavailable("the master did not take the previous request");
    }
    if (stopping_) return Status::Unavailable("robot stopped");
    // Waiting from the first register on: a master polling faster than the
    // robot writes takes the request as soon as its last register is there,
    // and may answer before the flag write below.
    outstanding_ = expects_response;
    awaiting_take_ = !expects_response;
    // Register by register, as write_port_register does; the master may poll
    // in between (it sees the flag last).
    for (size_t i = 0; i < regs->size(); ++i) {
      SetReg(o_.map.request_base + static_cast<int>(i), (*regs)[i]);
      lock.unlock();
      if (o_.write_interval.count() > 0) std::this_thread::sleep_for(o_.write_interval);
      lock.lock();
      if (stopping_) return Status::Unavailable("robot stopped");
    }
    SetReg(o_.map.request_flag, 1);
    ++stats_.requests_sent;
    return Status::Ok();
  }

  Result<daoai::Response> RecvDaoaiData(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    const bool ready = cv_.wait_for(lock, timeout, [this] {
      return stopping_ || Reg(o_.map.response_flag) != 0;
    });
    if (stopping_) return Status::Unavailable("robot stopped");
    if (!ready) return Status::Unavailable("no response within the timeout");
    std::array<uint16_t, daoai::kResponseFields> regs{};
    for (size_t i = 0; i < regs.size(); ++i) regs[i] = Reg(o_.map.response_base + static_cast<int>(i));
    SetReg(o_.map.response_flag, 0);
    outstanding_ = false;
    ++stats_.responses_read;
    return modbus::DecodeResponse(regs);
  }

  uint16_t ReadRegister(int address) const {
    std::lock_guard lock(mutex_);
    return mapping_ ? mapping_->tab_registers[address & 0xFFFF] : 0;
  }
  void WriteRegister(int address, uint16_t value) {
    std::lock_guard lock(mutex_);
    if (mapping_) SetReg(address, value);
  }
  ModbusRobotSimStats stats() const {
    std::lock_guard lock(mutex_);
    return stats_;
  }
  void DropNextWriteTo(int address) {
    std::lock_guard lock(mutex_);
    drop_write_to_ = address;
  }
  void LoseReplyToNextWrite(int address) {
    std::lock_guard lock(mutex_);
    lose_reply_to_ = address;
  }

 private:
  // REQUIRES: mutex_ held.
  uint16_t Reg(int address) const { return mapping_ ? mapping_->tab_registers[address & 0xFFFF] : 0; }
  void SetReg(int address, uint16_t v) { mapping_->tab_registers[address & 0xFFFF] = v; }
  // Applies a write request (function 6 or 16, TCP framing: the unit id at
  // byte 6) to the registers as modbus_reply would, without replying.
  // REQUIRES: mutex_ held.
  void ApplyWrite(const uint8_t* q, int length) {
    const int at = kTcpUnitIdOffset;
    const auto u16 = [q](int i) { return static_cast<uint16_t>((q[i] << 8) | q[i + 1]); };
    const int address = u16(at + 2);
    if (q[at + 1] == 0x06) {
      SetReg(address, u16(at + 4));
      return;
    }
    const int count = u16(at + 4);
    for (int i = 0; i < count && at + 8 + 2 * i < length; ++i) SetReg(address + i, u16(at + 7 + 2 * i));
  }

  bool stopping() {
    std::lock_guard lock(mutex_);
    return stopping_;
  }

  // The slave loop: accept masters (a new one replaces the old), answer
  // their requests. ctx_'s socket is the connected master's, or -1.
  void Serve() {
    int client = -1;
    std::array<uint8_t, MODBUS_TCP_MAX_ADU_LENGTH> query{};
    while (!stopping()) {
      pollfd fds[2] = {{listen_fd_, POLLIN, 0}, {client, POLLIN, 0}};
      const int n = ::poll(fds, client >= 0 ? 2 : 1, 20);
      if (n <= 0) continue;
      if (fds[0].revents & POLLIN) {
        std::lock_guard lock(mutex_);
        if (client >= 0) modbus_close(ctx_);
        int s = listen_fd_;
        client = modbus_tcp_accept(ctx_, &s);
        if (client >= 0) ++stats_.masters;
        cv_.notify_all();
        continue;
      }
      if (client < 0 || !(fds[1].revents & (POLLIN | POLLHUP | POLLERR))) continue;
      const int rc = modbus_receive(ctx_, query.data());
      if (rc < 0) {
        std::lock_guard lock(mutex_);
        modbus_close(ctx_);
        client = -1;
        continue;
      }
      if (rc == 0) continue;  // not for this slave
      const int unit = query[kTcpUnitIdOffset];
      if (unit != o_.unit_id && unit != MODBUS_TCP_SLAVE) continue;  // another unit: no answer
      {
        std::lock_guard lock(mutex_);
        const int function = query[kTcpUnitIdOffset + 1];
        const int address = (query[kTcpUnitIdOffset + 2] << 8) | query[kTcpUnitIdOffset + 3];
        if (drop_write_to_ >= 0 && (function == 0x06 || function == 0x10) &&
            address == drop_write_to_) {
          drop_write_to_ = -1;
          ++stats_.dropped_writes;
          modbus_close(ctx_);
          client = -1;
          continue;
        }
        const uint16_t before = Reg(o_.map.response_flag);
        const bool lose_reply = lose_reply_to_ >= 0 && (function == 0x06 || function == 0x10) &&
                                address == lose_reply_to_;
        if (lose_reply) {
          lose_reply_to_ = -1;
          ++stats_.lost_replies;
          ApplyWrite(query.data(), rc);
        } else {
          modbus_reply(ctx_, query.data(), rc, mapping_);
        }
        if (before == 0 && Reg(o_.map.response_flag) != 0 && !outstanding_) {
          ++stats_.unexpected_responses;
        }
        if (lose_reply) {
          modbus_close(ctx_);
          client = -1;
        }
      }
      cv_.notify_all();
    }
    std::lock_guard lock(mutex_);
    if (client >= 0) modbus_close(ctx_);
  }

  const ModbusRobotSimOptions o_;
  modbus_t* ctx_ = nullptr;
  modbus_mapping_t* mapping_ = nullptr;  // GUARDED_BY(mutex_) (contents)
  int listen_fd_ = -1;
  int port_ = 0;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  bool stopping_ = false;       // GUARDED_BY(mutex_)
  bool outstanding_ = false;    // GUARDED_BY(mutex_): a request waits for its response
  bool awaiting_take_ = false;  // GUARDED_BY(mutex_): a request without response not taken yet
  int drop_write_to_ = -1;      // GUARDED_BY(mutex_): DropNextWriteTo's address, -1: none
  int lose_reply_to_ = -1;      // GUARDED_BY(mutex_): LoseReplyToNextWrite's address, -1: none
  ModbusRobotSimStats stats_;   // GUARDED_BY(mutex_)
  std::mutex join_mutex_;
  std::thread thread_;
};

namespace {

class SimTransport final : public RobotTransport {
 public:
  explicit SimTransport(ModbusRobotSim& sim) : sim_(sim) {}
  Status Write(const daoai::Request& request, bool expects_response) override {
    return sim_.SendRobotData(request, expects_response, std::chrono::seconds(10));
  }
  Result<daoai::Response> Read(std::chrono::milliseconds timeout) override {
    return sim_.RecvDaoaiData(timeout);
  }

 private:
  ModbusRobotSim& sim_;
};

}  // namespace

Result<std::unique_ptr<ModbusRobotSim>> ModbusRobotSim::Start(const ModbusRobotSimOptions& options) {
  if (Status s = ValidateModbusRegisterMap(options.map); !s.ok()) return s;
  auto impl = std::make_unique<Impl>(options);
  if (Status s = impl->Start(); !s.ok()) return s;
  return std::unique_ptr<ModbusRobotSim>(new ModbusRobotSim(std::move(impl)));
}

ModbusRobotSim::ModbusRobotSim(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ModbusRobotSim::~ModbusRobotSim() { Stop(); }
void ModbusRobotSim::Stop() { impl_->Stop(); }
int ModbusRobotSim::port() const { return impl_->port(); }
bool ModbusRobotSim::WaitForMaster(std::chrono::milliseconds timeout) {
  return impl_->WaitForMaster(timeout);
}
Status ModbusRobotSim::SendRobotData(const daoai::Request& request, bool expects_response,
                                     std::chrono::milliseconds timeout) {
  return impl_->SendRobotData(request, expects_response, timeout);
}
Result<daoai::Response> ModbusRobotSim::RecvDaoaiData(std::chrono::milliseconds timeout) {
  return impl_->RecvDaoaiData(timeout);
}
uint16_t ModbusRobotSim::ReadRegister(int address) const { return impl_->ReadRegister(address); }
void ModbusRobotSim::WriteRegister(int address, uint16_t value) { impl_->WriteRegister(address, value); }
void ModbusRobotSim::DropNextWriteTo(int address) { impl_->DropNextWriteTo(address); }
void ModbusRobotSim::LoseReplyToNextWrite(int address) { impl_->LoseReplyToNextWrite(address); }
ModbusRobotSimStats ModbusRobotSim::stats() const { return impl_->stats(); }
std::unique_ptr<RobotTransport> ModbusRobotSim::Transport() {
  return std::make_unique<SimTransport>(*this);
}

}  // namespace bp
