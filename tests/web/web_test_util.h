// Helpers for the status page tests: a loopback HTTP client (Boost.Beast,
// synchronous, one request per connection), a strict Prometheus text format
// checker, and a planner whose captures are real organized frames. Defined
// in web_test_util.cc: Beast and std::regex are compiled once, not in every
// test file that includes this.
#pragma once

#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "grasp/bin_picking_planner.h"
#include "tests/testing/scripted_planner.h"

namespace bp::webtest {

struct HttpResult {
  int status = 0;
  std::string content_type;
  std::string body;
  std::string error;  // non-empty when the exchange failed
};

// One HTTP/1.1 request with an empty body to 127.0.0.1:`port`. `method`:
// "GET", "HEAD", "POST", "DELETE", ... `from`: the client's source address
// (any 127.0.0.0/8 address works on Linux loopback); empty: chosen by the
// kernel.
HttpResult HttpRequest(int port, const std::string& target, std::string_view method = "GET",
                       const std::string& from = "");

// Writes raw bytes and reads until the server closes; returns what it sent.
std::string RawExchange(int port, const std::string& bytes);

// Checks `text` against the Prometheus text exposition format 0.0.4 strictly:
// every line is a HELP, a TYPE or a sample; a family's TYPE comes before its
// samples and families are not interleaved; names and labels are valid;
// label values are correctly escaped; values are floats; counters are >= 0;
// histogram buckets are cumulative, end with le="+Inf" equal to _count, and
// have a _sum. @returns the problems found (empty: valid) and fills `samples`
// ("name{labels}" -> value).
std::vector<std::string> CheckPrometheusText(const std::string& text,
                                             std::map<std::string, double>* samples);

// ScriptedPlanner's grasps and outcomes, with captures that are organized
// frames (a flat bin floor 1 m below a camera looking straight down at the
// grasps), so the status page has images to draw on, and detected parts.
class FramePlanner final : public GraspPlanner {
 public:
  explicit FramePlanner(std::shared_ptr<testing::ScriptedPlanner> script)
      : script_(std::move(script)) {}

  Result<CaptureHandle> Capture(const PlanRequest& request) override;
  Result<PlanResult> Plan(const PlanRequest& request, const CapturedScene& scene) override;
  void NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) override;

 private:
  std::shared_ptr<testing::ScriptedPlanner> script_;
};

}  // namespace bp::webtest
