#include "web/metrics.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

namespace bp {
namespace {

// Misuse of the registry is a programming error: abort, also in release builds.
void Check(bool ok, const char* what, std::string_view name) {
  if (ok) return;
  std::fprintf(stderr, "MetricsRegistry: %s: '%.*s'\n", what, static_cast<int>(name.size()),
               name.data());
  std::abort();
}

bool ValidName(std::string_view name, bool label) {
  if (name.empty()) return false;
  if (label && name.size() >= 2 && name.substr(0, 2) == "__") return false;
  for (size_t i = 0; i < name.size(); ++i) {
    const char c = name[i];
    const bool alpha = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_' ||
                       (!label && c == ':');
    const bool digit = c >= '0' && c <= '9';
    if (!(alpha || (i > 0 && digit))) return false;
  }
  return true;
}

// Prometheus float: Go's strconv-compatible enough for the parser ("+Inf",
// "NaN", integers without exponent, else shortest round-trip).
std::string FormatValue(double v) {
  if (std::isnan(v)) return "NaN";
  if (std::isinf(v)) return v > 0 ? "+Inf" : "-Inf";
  char buf[64];
  if (v == std::floor(v) && std::fabs(v) < 1e15) {
    std::snprintf(buf, sizeof(buf), "%.0f", v);
  } else {
    std::snprintf(buf, sizeof(buf), "%.17g", v);
    // Shorter when it still round-trips.
    for (int precision = 6; precision < 17; ++precision) {
      char shorter[64];
      std::snprintf(shorter, sizeof(shorter), "%.*g", precision, v);
      if (std::strtod(shorter, nullptr) == v) return shorter;
    }
  }
  return buf;
}

std::string EscapeHelp(std::string_view s) {
  std::string out;
  for (char c : s) {
    if (c == '\\') out += "\\\\";
    else if (c == '\n') out += "\\n";
    else out += c;
  }
  return out;
}

std::string EscapeLabelValue(std::string_view s) {
  std::string out;
  for (char c : s) {
    if (c == '\\') out += "\\\\";
    else if (c == '\n') out += "\\n";
    else if (c == '"') out += "\\\"";
    else out += c;
  }
  return out;
}

std::string LabelText(const MetricLabels& labels, const std::pair<std::string, std::string>* extra) {
  if (labels.empty() && !extra) return "";
  std::string out = "{";
  bool first = true;
  auto add = [&](const std::pair<std::string, std::string>& l) {
    if (!first) out += ",";
    first = false;
    out += l.first + "=\"" + EscapeLabelValue(l.second) + "\"";
  };
  for (const auto& l : labels) add(l);
  if (extra) add(*extra);
  return out + "}";
}

}  // namespace

Histogram::Histogram(std::vector<double> bounds)
    : bounds_(std::move(bounds)),
      buckets_(std::make_unique<std::atomic<uint64_t>[]>(bounds_.size() + 1)) {
  for (size_t i = 0; i < bounds_.size(); ++i) {
    Check(std::isfinite(bounds_[i]) && (i == 0 || bounds_[i] > bounds_[i - 1]),
          "histogram bounds must be finite and increasing", "");
  }
  for (size_t i = 0; i <= bounds_.size(); ++i) buckets_[i].store(0, std::memory_order_relaxed);
}

void Histogram::Observe(double v) {
  size_t i = 0;
  while (i < bounds_.size() && v > bounds_[i]) ++i;  // le: v <= bound
  buckets_[i].fetch_add(1, std::memory_order_relaxed);
  sum_.fetch_add(v, std::memory_order_relaxed);
  count_.fetch_add(1, std::memory_order_relaxed);
}

Histogram::Snapshot Histogram::Read() const {
  Snapshot s;
  s.bounds = bounds_;
  uint64_t running = 0;
  for (size_t i = 0; i <= bounds_.size(); ++i) {
    running += buckets_[i].load(std::memory_order_relaxed);
    s.cumulative.push_back(running);
  }
  // Concurrent observations may land between the loads: the +Inf bucket is
  // the count by definition, so report the bucket total as the count.
  s.count = running;
  s.sum = sum_.load(std::memory_order_relaxed);
  return s;
}

std::vector<double> LatencyBucketsSeconds() {
  return {0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0};
}

MetricsRegistry::Series& MetricsRegistry::Find(std::string_view name, std::string_view help,
                                               Type type, const MetricLabels& labels,
                                               bool* created) {
  Check(ValidName(name, false), "bad metric name", name);
  for (const auto& l : labels) Check(ValidName(l.first, true) && l.first != "le", "bad label name", l.first);
  auto it = families_.find(name);
  if (it == families_.end()) {
    it = families_.emplace(std::string(name), Family{type, std::string(help), {}}).first;
  }
  Family& family = it->second;
  Check(family.type == type, "one metric name, two types", name);
  for (Series& s : family.series) {
    if (s.labels == labels) {
      *created = false;
      return s;
    }
  }
  family.series.push_back(Series{labels, nullptr, nullptr, nullptr, nullptr});
  *created = true;
  return family.series.back();
}

Counter& MetricsRegistry::GetCounter(std::string_view name, std::string_view help,
                                     const MetricLabels& labels) {
  std::lock_guard lock(mutex_);
  bool created = false;
  Series& s = Find(name, help, Type::kCounter, labels, &created);
  if (created) s.counter = std::make_unique<Counter>();
  Check(s.counter != nullptr, "a callback series asked for as a counter", name);
  return *s.counter;
}

Gauge& MetricsRegistry::GetGauge(std::string_view name, std::string_view help,
                                 const MetricLabels& labels) {
  std::lock_guard lock(mutex_);
  bool created = false;
  Series& s = Find(name, help, Type::kGauge, labels, &created);
  if (created) s.gauge = std::make_unique<Gauge>();
  Check(s.gauge != nullptr, "a callback series asked for as a gauge", name);
  return *s.gauge;
}

Histogram& MetricsRegistry::GetHistogram(std::string_view name, std::string_view help,
                                         std::vector<double> bounds, const MetricLabels& labels) {
  std::lock_guard lock(mutex_);
  bool created = false;
  Series& s = Find(name, help, Type::kHistogram, labels, &created);
  if (created) {
    s.histogram = std::make_unique<Histogram>(bounds);
  } else {
    Check(s.histogram && s.histogram->bounds() == bounds, "one histogram, two bucket layouts", name);
  }
  Check(s.histogram != nullptr, "a callback series asked for as a histogram", name);
  return *s.histogram;
}

void MetricsRegistry::AddCounterCallback(std::string_view name, std::string_view help,
                                         const MetricLabels& labels, std::function<double()> read) {
  std::lock_guard lock(mutex_);
  bool created = false;
  Series& s = Find(name, help, Type::kCounter, labels, &created);
  Check(created, "series registered twice", name);
  s.read = std::move(read);
}

void MetricsRegistry::AddGaugeCallback(std::string_view name, std::string_view help,
                                       const MetricLabels& labels, std::function<double()> read) {
  std::lock_guard lock(mutex_);
  bool created = false;
  Series& s = Find(name, help, Type::kGauge, labels, &created);
  Check(created, "series registered twice", name);
  s.read = std::move(read);
}

std::string MetricsRegistry::Render() const {
  std::lock_guard lock(mutex_);
  std::string out;
  for (const auto& [name, family] : families_) {
    out += "# HELP " + name + " " + EscapeHelp(family.help) + "\n";
    out += "# TYPE " + name + " ";
    out += family.type == Type::kCounter ? "counter" : family.type == Type::kGauge ? "gauge" : "histogram";
    out += "\n";
    for (const Series& s : family.series) {
      if (s.histogram) {
        const Histogram::Snapshot h = s.histogram->Read();
        for (size_t i = 0; i <= h.bounds.size(); ++i) {
          const std::pair<std::string, std::string> le{
              "le", i < h.bounds.size() ? FormatValue(h.bounds[i]) : "+Inf"};
          out += name + "_bucket" + LabelText(s.labels, &le) + " " +
                 FormatValue(static_cast<double>(h.cumulative[i])) + "\n";
        }
        out += name + "_sum" + LabelText(s.labels, nullptr) + " " + FormatValue(h.sum) + "\n";
        out += name + "_count" + LabelText(s.labels, nullptr) + " " +
               FormatValue(static_cast<double>(h.count)) + "\n";
        continue;
      }
      double v = 0.0;
      if (s.read) v = s.read();
      else if (s.counter) v = s.counter->value();
      else if (s.gauge) v = s.gauge->value();
      out += name + LabelText(s.labels, nullptr) + " " + FormatValue(v) + "\n";
    }
  }
  return out;
}

}  // namespace bp
