// `binpick bench-cell`: the end-to-end benchmark of issue 40 item 5. Starts
// binpickd (a child process, loopback ports, status page on) on the default
// cell or --cell, switches it to each --config (69) and plays a robot over the
// DaoAI socket with the robot client of `binpick robot` / bp_load: capture (20),
// first pick pose (21), then 21 until the queue is empty or --poses, for
// --cycles cycles. Each cycle reads binpickd's own timings of that detection
// from its status page (/api/status "detection": capture_ms, plan_ms and
// the plan's stages), so the synthetic capture (the simulator's render) is
// separated from the product path (perception + grasps, then serving: the
// rest of capture -> first pose: protocol, queues, the robot's socket).
//
// Every pose handed out takes its part out of the synthetic bin. When a
// capture finds nothing to pick (the bin emptied, or no collision-free grasp
// on the parts left), binpickd is restarted on the same full bin; that cycle
// is not timed and is done again (the report counts the refills).
//
//   binpick bench-cell --cycles 12                  (configs 1 and 2)
//   binpick bench-cell --config 2 --cycles 12 --json report.json
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/http.hpp>
#include <nlohmann/json.hpp>

#include "apps/binpick/command.h"
#include "comms/robot_client.h"
#include "tests/testing/binpickd.h"

namespace bp::cli {
namespace {

using Clock = std::chrono::steady_clock;
using json = nlohmann::json;

struct BenchOptions {
  std::vector<int> configs = {1, 2};
  int cycles = 12;
  int poses = 0;  // further poses per cycle at most; 0: until the queue is empty
  int task = 0;
  std::string cell;      // "" = binpickd's embedded default cell
  std::string binpickd;  // "" = next to this binary
  std::string json_path;
  int timeout_ms = 60000;
};

// One timed cycle. Times in ms; the binpickd_* figures are its own.
struct Cycle {
  double capture_ack = 0;        // 20 sent -> its answer
  double first_pose = 0;         // 20 sent -> the first 21's answer
  std::vector<double> further;   // each later 21 (its own round trip)
  double synthetic_capture = 0;  // binpickd: the camera (simulator) time
  double plan = 0;               // binpickd: perception + grasps
  std::map<std::string, double> stages;  // binpickd: the plan's stages
  double product() const { return first_pose - synthetic_capture; }
  double serving() const { return first_pose - synthetic_capture - plan; }
};

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  // Nearest rank: the smallest value with at least p of the samples at or below it.
  const size_t rank = static_cast<size_t>(std::ceil(p * static_cast<double>(v.size())));
  return v[std::clamp<size_t>(rank, 1, v.size()) - 1];
}

// GET `target` from the status page on 127.0.0.1:port (Boost.Beast, HTTP/1.1,
// connection closed after the reply): the body of a 200 reply, or the error.
Result<std::string> HttpGet(int port, const std::string& target) {
  namespace http = boost::beast::http;
  try {
    boost::asio::io_context io;
    boost::asio::ip::tcp::socket socket(io);
    socket.connect({boost::asio::ip::make_address("127.0.0.1"), static_cast<uint16_t>(port)});
    http::request<http::empty_body> request(http::verb::get, target, 11);
    request.set(http::field::host, "127.0.0.1");
    request.keep_alive(false);
    http::write(socket, request);
    boost::beast::flat_buffer buffer;
    http::response<http::string_body> reply;
    http::read(socket, buffer, reply);
    if (reply.result() != http::status::ok) {
      return Status::Unavailable("status page " + target + ": HTTP " + std::to_string(reply.result_int()));
    }
    return std::move(reply.body());
  } catch (const std::exception& e) {
    return Status::Unavailable("status page " + target + ": " + e.what());
  }
}

// binpickd on its own loopback ports, switched to one camera config.
class Daemon {
 public:
  static Result<std::unique_ptr<Daemon>> Start(const BenchOptions& o, int config, const std::string& log) {
    auto d = std::unique_ptr<Daemon>(new Daemon);
    const int daoai = bp::testing::FreeLoopbackTcpPort();
    std::vector<std::string> args = {o.binpickd, "--daoai-port", std::to_string(daoai), "--gri-port", "0",
                                     "--gri-official-port", "0", "--http-port", "-1", "--no-record"};
    if (!o.cell.empty()) args.insert(args.end(), {"--cell", o.cell});
    d->process_ = std::make_unique<bp::testing::BinpickdProcess>(args, log);
    const std::string ready = d->process_->ReadyLine(300000);
    const size_t http = ready.find("http 127.0.0.1:");
    if (ready.find("binpickd ready") == std::string::npos || http == std::string::npos) {
      return Status::Unavailable("binpickd did not start (" + o.binpickd + "; its log: " + log + ")");
    }
    d->http_port_ = std::atoi(ready.c_str() + http + 15);
    RobotClientOptions ro;
    ro.port = daoai;
    ro.timeout = std::chrono::milliseconds(o.timeout_ms);
    Result<std::unique_ptr<RobotClient>> robot = RobotClient::Connect(ro);
    if (!robot.ok()) return robot.status();
    d->robot_ = std::move(*robot);
    Result<RobotReply> switched = d->robot_->Call(daoai::kSwitchConfig, config);
    if (!switched.ok()) return switched.status();
    if (switched->status != daoai::kSwitchConfigSuccess) {
      return Status::InvalidArgument("binpickd refused camera config " + std::to_string(config));
    }
    return d;
  }
  ~Daemon() {
    robot_.reset();
    if (process_) process_->Stop();
  }
  RobotClient& robot() { return *robot_; }
  int http_port() const { return http_port_; }

 private:
  Daemon() = default;
  std::unique_ptr<bp::testing::BinpickdProcess> process_;
  std::unique_ptr<RobotClient> robot_;
  int http_port_ = 0;
};

double Ms(Clock::time_point from) { return std::chrono::duration<double, std::milli>(Clock::now() - from).count(); }

// One cycle: capture, first pose, the rest. nullopt (no error) when the first
// pose found nothing to pick (NO_OBJECT_FOUND, or NO_COLLISION_FREE_POSE for
// the parts left): the bin is done for this task.
Result<std::optional<Cycle>> RunCycle(Daemon& d, const BenchOptions& o, uint64_t* seq) {
  Cycle c;
  const auto t0 = Clock::now();
  Result<RobotReply> cap = d.robot().Call(daoai::kCaptureAndProcess, o.task);
  c.capture_ack = Ms(t0);
  if (!cap.ok()) return cap.status();
  if (cap->status != daoai::kDetection) return Status::Internal("capture answered status " + std::to_string(cap->status));
  Result<RobotReply> first = d.robot().Call(daoai::kPickPose, o.task);
  c.first_pose = Ms(t0);
  if (!first.ok()) return first.status();
  // Nothing left, or parts left but no collision-free grasp (the bin's last parts).
  if (first->status == daoai::kNoObjectFound || first->status == daoai::kNoCollisionFreePose) {
    return std::optional<Cycle>();
  }
  if (first->status != daoai::kObjectsFound) return Status::Internal("pick pose answered status " + std::to_string(first->status));
  while (o.poses == 0 || static_cast<int>(c.further.size()) < o.poses) {
    const auto t1 = Clock::now();
    Result<RobotReply> next = d.robot().Call(daoai::kPickPose, o.task);
    if (!next.ok()) return next.status();
    if (next->status == daoai::kNoObjectFound || next->status == daoai::kNoCollisionFreePose) break;
    if (next->status != daoai::kObjectsFound) return Status::Internal("pick pose answered status " + std::to_string(next->status));
    c.further.push_back(Ms(t1));
  }
  // binpickd's own timings of this detection (read after the cycle, untimed).
  Result<std::string> body = HttpGet(d.http_port(), "/api/status");
  if (!body.ok()) return body.status();
  const json status = json::parse(*body, nullptr, false);
  if (status.is_discarded() || !status.contains("detection") || !status["detection"].is_object()) {
    return Status::Internal("binpickd's /api/status has no detection");
  }
  const json& det = status["detection"];
  const uint64_t now_seq = det.value("seq", uint64_t{0});
  if (now_seq != *seq + 1) {
    return Status::Internal("expected binpickd's detection " + std::to_string(*seq + 1) + ", its last is " +
                            std::to_string(now_seq));
  }
  *seq = now_seq;
  c.synthetic_capture = det.value("capture_ms", 0.0);
  c.plan = det.value("plan_ms", 0.0);
  for (const json& s : det.value("stages", json::array())) c.stages[s.value("stage", "")] += s.value("ms", 0.0);
  return std::optional<Cycle>(std::move(c));
}

// Runs --cycles timed cycles at one config, restarting binpickd on a full bin when it empties.
// `refills`: how often binpickd was restarted on a full bin.
Result<std::vector<Cycle>> RunConfig(const BenchOptions& o, int config, const std::string& log, int* refills) {
  std::vector<Cycle> cycles;
  int restarts = 0;
  *refills = -1;
  while (static_cast<int>(cycles.size()) < o.cycles) {
    Result<std::unique_ptr<Daemon>> d = Daemon::Start(o, config, log);
    if (!d.ok()) return d.status();
    ++*refills;
    uint64_t seq = 0;
    bool timed_one = false;
    while (static_cast<int>(cycles.size()) < o.cycles) {
      Result<std::optional<Cycle>> c = RunCycle(**d, o, &seq);
      if (!c.ok()) return c.status();
      if (!*c) break;  // bin empty: restart on a full one
      cycles.push_back(std::move(**c));
      timed_one = true;
    }
    if (!timed_one && ++restarts > 1) {
      return Status::Internal("task " + std::to_string(o.task) + " finds nothing to pick on a full bin");
    }
  }
  return cycles;
}

json StepJson(const std::vector<double>& v) {
  return {{"n", v.size()}, {"p50", Percentile(v, 0.5)}, {"p90", Percentile(v, 0.9)}, {"p99", Percentile(v, 0.99)}};
}

// The per-step figures of one config, in table order.
std::vector<std::pair<std::string, std::vector<double>>> Steps(const std::vector<Cycle>& cycles) {
  std::vector<std::pair<std::string, std::vector<double>>> steps = {
      {"capture_ack", {}}, {"first_pose", {}}, {"further_pose", {}}, {"synthetic_capture", {}},
      {"product", {}},     {"plan", {}},       {"serving", {}}};
  std::map<std::string, std::vector<double>> stages;
  for (const Cycle& c : cycles) {
    steps[0].second.push_back(c.capture_ack);
    steps[1].second.push_back(c.first_pose);
    steps[2].second.insert(steps[2].second.end(), c.further.begin(), c.further.end());
    steps[3].second.push_back(c.synthetic_capture);
    steps[4].second.push_back(c.product());
    steps[5].second.push_back(c.plan);
    steps[6].second.push_back(c.serving());
    for (const auto& [name, ms] : c.stages) stages[name].push_back(ms);
  }
  for (auto& [name, v] : stages) steps.emplace_back("stage:" + name, std::move(v));
  return steps;
}

void PrintTable(int config, const std::vector<Cycle>& cycles, int refills) {
  std::printf("config %d: %zu cycles, bin refilled %d times (ms)\n", config, cycles.size(), refills);
  std::printf("  %-40s %5s %9s %9s %9s\n", "step", "n", "p50", "p90", "p99");
  const std::map<std::string, std::string> label = {
      {"capture_ack", "capture (20) ack"},
      {"first_pose", "capture -> first pose (21)"},
      {"further_pose", "each further pose (21)"},
      {"synthetic_capture", "  synthetic capture (render)"},
      {"product", "  product path (first pose - capture)"},
      {"plan", "    perception + grasps"},
      {"serving", "    serving (the rest)"}};
  for (const auto& [name, v] : Steps(cycles)) {
    const auto it = label.find(name);
    const std::string shown = it != label.end() ? it->second : "      " + name;
    std::printf("  %-40s %5zu %9.1f %9.1f %9.1f\n", shown.c_str(), v.size(), Percentile(v, 0.5),
                Percentile(v, 0.9), Percentile(v, 0.99));
  }
}

json ConfigJson(int config, const std::vector<Cycle>& cycles, int refills) {
  json j = {{"config", config}, {"cycles", cycles.size()}, {"refills", refills}};
  json steps = json::object();
  for (const auto& [name, v] : Steps(cycles)) steps[name] = StepJson(v);
  j["steps"] = steps;
  json per_cycle = json::array();
  for (const Cycle& c : cycles) {
    per_cycle.push_back({{"capture_ack", c.capture_ack}, {"first_pose", c.first_pose},
                         {"further_poses", c.further}, {"synthetic_capture", c.synthetic_capture},
                         {"plan", c.plan}, {"product", c.product()}, {"serving", c.serving()},
                         {"stages", c.stages}});
  }
  j["per_cycle"] = per_cycle;
  return j;
}

double LoadAverage() {
  double load = -1;
  if (FILE* f = std::fopen("/proc/loadavg", "r")) {
    if (std::fscanf(f, "%lf", &load) != 1) load = -1;
    std::fclose(f);
  }
  return load;
}

int Run(BenchOptions o) {
  if (o.binpickd.empty()) {
    std::error_code ec;
    o.binpickd = (std::filesystem::read_symlink("/proc/self/exe", ec).parent_path() / "binpickd").string();
  }
  json report = {{"load_average_1min_before", LoadAverage()}, {"cell", o.cell.empty() ? "default" : o.cell},
                 {"task", o.task}, {"poses", o.poses}};
  json configs = json::array();
  for (int config : o.configs) {
    const std::string log = (std::filesystem::temp_directory_path() /
                             ("binpick_bench_cell_" + std::to_string(::getpid()) + "_config" +
                              std::to_string(config) + ".log")).string();
    int refills = 0;
    Result<std::vector<Cycle>> cycles = RunConfig(o, config, log, &refills);
    if (!cycles.ok()) return Fail("bench-cell", cycles.status());
    PrintTable(config, *cycles, refills);
    configs.push_back(ConfigJson(config, *cycles, refills));
  }
  report["configs"] = configs;
  report["load_average_1min_after"] = LoadAverage();
  std::printf("load average (1 min): %.2f before, %.2f after\n", report["load_average_1min_before"].get<double>(),
              report["load_average_1min_after"].get<double>());
  if (!o.json_path.empty()) {
    std::ofstream out(o.json_path);
    out << report.dump(2) << "\n";
    if (!out) return Fail("bench-cell", Status::Internal("cannot write " + o.json_path));
  }
  return kExitOk;
}

}  // namespace

Command BenchCellCommand() {
  return {"bench-cell",
          "end-to-end benchmark: binpickd on the cell, a robot doing capture -> first pose -> the rest, "
          "p50/p90/p99 per step, synthetic capture apart from the product path",
          [](CLI::App& sub) -> std::function<int()> {
            auto o = std::make_shared<BenchOptions>();
            sub.add_option("--config", o->configs, "camera config ids (repeatable; default 1 2)")
                ->capture_default_str();
            sub.add_option("--cycles", o->cycles, "timed cycles per config")->check(CLI::Range(1, 100000));
            sub.add_option("--poses", o->poses, "further poses per cycle at most (0: until the queue is empty)")
                ->check(CLI::NonNegativeNumber);
            sub.add_option("--task", o->task, "pick task id (payload_1)");
            sub.add_option("--cell", o->cell, "cell file for binpickd (default: its embedded default cell)");
            sub.add_option("--binpickd", o->binpickd, "binpickd executable (default: next to binpick)");
            sub.add_option("--json", o->json_path, "also write the report as JSON to this file");
            sub.add_option("--timeout-ms", o->timeout_ms, "per-answer timeout of the robot");
            return [o] { return Run(*o); };
          }};
}

}  // namespace bp::cli
