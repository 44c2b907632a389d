#include "tests/web/web_test_util.h"

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>

#include <cmath>
#include <regex>
#include <set>
#include <sstream>

namespace bp::webtest {

HttpResult HttpRequest(int port, const std::string& target, std::string_view method,
                       const std::string& from) {
  namespace http = boost::beast::http;
  const http::verb verb = http::string_to_verb(boost::beast::string_view(method.data(), method.size()));
  if (verb == http::verb::unknown) return HttpResult{0, "", "", "unknown method " + std::string(method)};
  HttpResult r;
  try {
    boost::asio::io_context io;
    boost::asio::ip::tcp::socket socket(io);
    if (!from.empty()) {
      socket.open(boost::asio::ip::tcp::v4());
      socket.bind({boost::asio::ip::make_address(from), 0});
    }
    socket.connect({boost::asio::ip::make_address("127.0.0.1"), static_cast<uint16_t>(port)});
    http::request<http::empty_body> req(verb, target, 11);
    req.set(http::field::host, "127.0.0.1");
    req.keep_alive(false);
    http::write(socket, req);
    boost::beast::flat_buffer buffer;
    http::response_parser<http::string_body> parser;
    parser.body_limit(64 * 1024 * 1024);
    if (verb == http::verb::head) parser.skip(true);
    http::read(socket, buffer, parser);
    r.status = static_cast<int>(parser.get().result_int());
    r.content_type = std::string(parser.get()[http::field::content_type]);
    r.body = parser.get().body();
  } catch (const std::exception& e) {
    r.error = e.what();
  }
  return r;
}

std::string RawExchange(int port, const std::string& bytes) {
  boost::asio::io_context io;
  boost::asio::ip::tcp::socket socket(io);
  socket.connect({boost::asio::ip::make_address("127.0.0.1"), static_cast<uint16_t>(port)});
  boost::system::error_code ec;
  boost::asio::write(socket, boost::asio::buffer(bytes), ec);
  std::string out;
  char buf[4096];
  for (;;) {
    const size_t n = socket.read_some(boost::asio::buffer(buf), ec);
    if (ec) break;
    out.append(buf, n);
  }
  return out;
}

std::vector<std::string> CheckPrometheusText(const std::string& text,
                                             std::map<std::string, double>* samples) {
  std::vector<std::string> problems;
  if (!text.empty() && text.back() != '\n') problems.push_back("does not end with a newline");
  const std::regex help_re(R"(^# HELP ([a-zA-Z_:][a-zA-Z0-9_:]*) (.*)$)");
  const std::regex type_re(R"(^# TYPE ([a-zA-Z_:][a-zA-Z0-9_:]*) (counter|gauge|histogram|summary|untyped)$)");
  const std::regex sample_re(
      R"re(^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{((?:[a-zA-Z_][a-zA-Z0-9_]*="(?:[^"\\\n]|\\[\\"n])*")(?:,[a-zA-Z_][a-zA-Z0-9_]*="(?:[^"\\\n]|\\[\\"n])*")*)?\})? ([^ ]+)( -?[0-9]+)?$)re");
  const std::regex label_re(R"re(([a-zA-Z_][a-zA-Z0-9_]*)="((?:[^"\\]|\\.)*)")re");
  const std::regex value_re(R"(^([+-]?Inf|NaN|[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?)$)");
  std::map<std::string, std::string> types;
  std::set<std::string> done_families;
  std::string current;
  struct Hist {
    std::vector<std::pair<double, double>> buckets;  // le, value (one label set)
    bool has_sum = false;
    double count = -1;
  };
  std::map<std::string, Hist> hists;  // family + labels without le
  std::istringstream in(text);
  std::string line;
  int n = 0;
  auto family_of = [&](const std::string& name) {
    for (const char* suffix : {"_bucket", "_sum", "_count"}) {
      const std::string s = suffix;
      if (name.size() > s.size() && name.compare(name.size() - s.size(), s.size(), s) == 0) {
        const std::string base = name.substr(0, name.size() - s.size());
        if (types.count(base) && types[base] == "histogram") return base;
      }
    }
    return name;
  };
  while (std::getline(in, line)) {
    ++n;
    const std::string where = "line " + std::to_string(n) + " '" + line + "': ";
    std::smatch m;
    if (line.rfind("# HELP ", 0) == 0) {
      if (!std::regex_match(line, m, help_re)) problems.push_back(where + "bad HELP");
      continue;
    }
    if (line.rfind("# TYPE ", 0) == 0) {
      if (!std::regex_match(line, m, type_re)) {
        problems.push_back(where + "bad TYPE");
        continue;
      }
      const std::string name = m[1];
      if (types.count(name)) problems.push_back(where + "second TYPE for " + name);
      types[name] = m[2];
      if (!current.empty()) done_families.insert(current);
      current = name;
      continue;
    }
    if (line.empty() || line[0] == '#') {
      problems.push_back(where + "empty line or unknown comment");
      continue;
    }
    if (!std::regex_match(line, m, sample_re)) {
      problems.push_back(where + "not a sample");
      continue;
    }
    const std::string name = m[1];
    const std::string labels = m[3];
    const std::string value_text = m[4];
    if (!std::regex_match(value_text, value_re)) problems.push_back(where + "bad value");
    const double value = value_text == "+Inf" || value_text == "Inf" ? INFINITY
                         : value_text == "-Inf"                       ? -INFINITY
                                                                      : std::strtod(value_text.c_str(), nullptr);
    const std::string family = family_of(name);
    if (!types.count(family)) problems.push_back(where + "sample before its TYPE");
    if (done_families.count(family) || (family != current && types.count(family))) {
      problems.push_back(where + "family " + family + " interleaved with another");
    }
    std::set<std::string> names;
    std::string le;
    std::string labels_wo_le;
    for (std::sregex_iterator it(labels.begin(), labels.end(), label_re);
         it != std::sregex_iterator(); ++it) {
      const std::string label = (*it)[1];
      if (!names.insert(label).second) problems.push_back(where + "label " + label + " twice");
      if (label == "le") {
        le = (*it)[2];
      } else {
        labels_wo_le += (*it).str() + ",";
      }
    }
    if (samples) (*samples)[name + (labels.empty() ? "" : "{" + labels + "}")] = value;
    const std::string type = types.count(family) ? types[family] : "";
    if (type == "counter" && !(value >= 0)) problems.push_back(where + "negative counter");
    if (type == "histogram") {
      Hist& h = hists[family + "{" + labels_wo_le + "}"];
      if (name == family + "_bucket") {
        if (le.empty()) {
          problems.push_back(where + "bucket without le");
        } else {
          const double bound = le == "+Inf" ? INFINITY : std::strtod(le.c_str(), nullptr);
          if (!h.buckets.empty() && !(bound > h.buckets.back().first)) {
            problems.push_back(where + "le not increasing");
          }
          if (!h.buckets.empty() && value < h.buckets.back().second) {
            problems.push_back(where + "buckets not cumulative");
          }
          h.buckets.emplace_back(bound, value);
        }
      } else if (name == family + "_sum") {
        h.has_sum = true;
      } else if (name == family + "_count") {
        h.count = value;
      } else {
        problems.push_back(where + "unexpected histogram sample");
      }
    }
  }
  for (const auto& [key, h] : hists) {
    if (h.buckets.empty() || !std::isinf(h.buckets.back().first)) {
      problems.push_back(key + ": no le=\"+Inf\" bucket");
    } else if (h.buckets.back().second != h.count) {
      problems.push_back(key + ": +Inf bucket differs from _count");
    }
    if (!h.has_sum) problems.push_back(key + ": no _sum");
  }
  return problems;
}

Result<CaptureHandle> FramePlanner::Capture(const PlanRequest& request) {
  Result<CaptureHandle> scripted = script_->Capture(request);
  if (!scripted.ok()) return scripted.status();
  Frame frame;
  frame.intrinsics.width = 160;
  frame.intrinsics.height = 120;
  frame.intrinsics.fx = frame.intrinsics.fy = 150.0;
  frame.intrinsics.cx = 80.0;
  frame.intrinsics.cy = 60.0;
  frame.depth = DepthImage(160, 120, 1.0f);
  frame.intensity = IntensityImage(160, 120, 60);
  for (int v = 40; v < 80; ++v) {
    for (int u = 50; u < 110; ++u) {
      frame.depth.at(u, v) = 0.9f;
      frame.intensity.at(u, v) = 200;
    }
  }
  frame.depth.at(0, 0) = NAN;  // an invalid pixel
  // Camera 1.1 m above (0.52, -0.1), z down: rotation pi about x.
  frame.X_BC = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0.52, -0.08, 1.1));
  return CaptureHandle(std::make_shared<CapturedFrame>(std::move(frame)));
}

Result<PlanResult> FramePlanner::Plan(const PlanRequest& request, const CapturedScene& scene) {
  Result<PlanResult> r = script_->Plan(request, scene);
  if (!r.ok()) return r;
  for (const Grasp& g : r->grasps) r->parts.push_back(DetectedPart{g.class_id, g.X_BO, g.score});
  r->stages = {{"roi", 1.5}, {"segment", 2.25}, {"pose", 12.5}, {"grasps", 4.0}};
  return r;
}

void FramePlanner::NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) {
  script_->NotifyHandedOut(task, grasp);
}

}  // namespace bp::webtest
