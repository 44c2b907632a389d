// A small metrics registry rendered in the Prometheus text exposition format
// (version 0.0.4): counters, gauges, histograms with fixed buckets, and
// values read at scrape time from a callback (a server's own counters).
// Debian 12 has no prometheus-cpp; this is the subset binpickd needs.
//
// Thread-safety: every member is safe to call concurrently. Get*() takes the
// registry's mutex (look a metric up once and keep the reference: it lives as
// long as the registry); Inc / Set / Observe on the returned metric are
// lock-free atomics. Render() takes the mutex and calls the callbacks, which
// must be quick and must not touch the registry.
//
// Names follow Prometheus rules ([a-zA-Z_:][a-zA-Z0-9_:]*, labels without
// ':' and not starting with "__"); a bad name, or one name registered with
// two types or two bucket layouts, is a programming error (assert).
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace bp {

// Label pairs, in the order they are rendered.
using MetricLabels = std::vector<std::pair<std::string, std::string>>;

class Counter {
 public:
  void Inc(double v = 1.0) { value_.fetch_add(v, std::memory_order_relaxed); }  // v >= 0
  double value() const { return value_.load(std::memory_order_relaxed); }

 private:
  std::atomic<double> value_{0.0};
};

class Gauge {
 public:
  void Set(double v) { value_.store(v, std::memory_order_relaxed); }
  void Add(double v) { value_.fetch_add(v, std::memory_order_relaxed); }
  double value() const { return value_.load(std::memory_order_relaxed); }

 private:
  std::atomic<double> value_{0.0};
};

class Histogram {
 public:
  // `bounds`: upper bounds, strictly increasing, finite; +Inf is implicit.
  explicit Histogram(std::vector<double> bounds);
  void Observe(double v);

  struct Snapshot {
    std::vector<double> bounds;
    std::vector<uint64_t> cumulative;  // per bound, then +Inf (== count)
    double sum = 0.0;
    uint64_t count = 0;
  };
  Snapshot Read() const;
  const std::vector<double>& bounds() const { return bounds_; }

 private:
  const std::vector<double> bounds_;
  std::unique_ptr<std::atomic<uint64_t>[]> buckets_;  // bounds_.size() + 1, not cumulative
  std::atomic<double> sum_{0.0};
  std::atomic<uint64_t> count_{0};
};

// Bucket bounds in seconds for latencies from 1 ms to 10 s.
std::vector<double> LatencyBucketsSeconds();

class MetricsRegistry {
 public:
  MetricsRegistry() = default;
  MetricsRegistry(const MetricsRegistry&) = delete;
  MetricsRegistry& operator=(const MetricsRegistry&) = delete;

  // The metric `name` with `labels`, created on first use. `help` is taken
  // from the first registration of the name.
  Counter& GetCounter(std::string_view name, std::string_view help, const MetricLabels& labels = {});
  Gauge& GetGauge(std::string_view name, std::string_view help, const MetricLabels& labels = {});
  Histogram& GetHistogram(std::string_view name, std::string_view help, std::vector<double> bounds,
                          const MetricLabels& labels = {});
  // A counter or gauge whose value `read` returns at each Render().
  void AddCounterCallback(std::string_view name, std::string_view help, const MetricLabels& labels,
                          std::function<double()> read);
  void AddGaugeCallback(std::string_view name, std::string_view help, const MetricLabels& labels,
                        std::function<double()> read);

  // Every metric, families sorted by name, series in creation order.
  std::string Render() const;

 private:
  enum class Type { kCounter, kGauge, kHistogram };
  struct Series {
    MetricLabels labels;
    std::unique_ptr<Counter> counter;
    std::unique_ptr<Gauge> gauge;
    std::unique_ptr<Histogram> histogram;
    std::function<double()> read;
  };
  struct Family {
    Type type;
    std::string help;
    std::vector<Series> series;
  };
  // REQUIRES: mutex_ is held.
  Series& Find(std::string_view name, std::string_view help, Type type, const MetricLabels& labels,
               bool* created);

  mutable std::mutex mutex_;
  std::map<std::string, Family, std::less<>> families_;  // GUARDED_BY(mutex_)
};

}  // namespace bp
