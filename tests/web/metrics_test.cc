#include "web/metrics.h"

#include <gtest/gtest.h>

#include <thread>
#include <vector>

#include "tests/web/web_test_util.h"

namespace bp {
namespace {

TEST(MetricsRegistry, RendersGoldenTextFormat) {
  MetricsRegistry m;
  m.GetCounter("binpick_b_total", "B things.", {{"status", "2"}}).Inc(3);
  m.GetCounter("binpick_b_total", "ignored help", {{"status", "3"}}).Inc();
  m.GetGauge("binpick_a", "A gauge\nwith \\ newline.").Set(-1.5);
  Histogram& h = m.GetHistogram("binpick_c_seconds", "C.", {0.01, 0.1}, {{"stage", "po\"se"}});
  h.Observe(0.005);
  h.Observe(0.01);  // le is inclusive
  h.Observe(0.05);
  h.Observe(7.0);
  m.AddGaugeCallback("binpick_d", "D.", {}, [] { return 42.0; });
  EXPECT_EQ(m.Render(),
            "# HELP binpick_a A gauge\\nwith \\\\ newline.\n"
            "# TYPE binpick_a gauge\n"
            "binpick_a -1.5\n"
            "# HELP binpick_b_total B things.\n"
            "# TYPE binpick_b_total counter\n"
            "binpick_b_total{status=\"2\"} 3\n"
            "binpick_b_total{status=\"3\"} 1\n"
            "# HELP binpick_c_seconds C.\n"
            "# TYPE binpick_c_seconds histogram\n"
            "binpick_c_seconds_bucket{stage=\"po\\\"se\",le=\"0.01\"} 2\n"
            "binpick_c_seconds_bucket{stage=\"po\\\"se\",le=\"0.1\"} 3\n"
            "binpick_c_seconds_bucket{stage=\"po\\\"se\",le=\"+Inf\"} 4\n"
            "binpick_c_seconds_sum{stage=\"po\\\"se\"} 7.065\n"
            "binpick_c_seconds_count{stage=\"po\\\"se\"} 4\n"
            "# HELP binpick_d D.\n"
            "# TYPE binpick_d gauge\n"
            "binpick_d 42\n");
  std::map<std::string, double> samples;
  EXPECT_TRUE(webtest::CheckPrometheusText(m.Render(), &samples).empty());
  EXPECT_EQ(samples.at("binpick_b_total{status=\"2\"}"), 3.0);
}

TEST(MetricsRegistry, SameNameAndLabelsIsTheSameMetric) {
  MetricsRegistry m;
  Counter& a = m.GetCounter("x_total", "X.", {{"k", "v"}});
  Counter& b = m.GetCounter("x_total", "X.", {{"k", "v"}});
  Counter& c = m.GetCounter("x_total", "X.", {{"k", "w"}});
  EXPECT_EQ(&a, &b);
  EXPECT_NE(&a, &c);
}

TEST(MetricsRegistry, CountsExactlyUnderConcurrentIncrements) {
  MetricsRegistry m;
  Counter& c = m.GetCounter("n_total", "N.");
  Histogram& h = m.GetHistogram("h_seconds", "H.", {0.5});
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int i = 0; i < 20000; ++i) {
        c.Inc();
        h.Observe(t % 2 ? 1.0 : 0.25);
        // Lookups race with increments and rendering too.
        if (i % 1000 == 0) m.GetCounter("n_total", "N.").Inc(0);
      }
    });
  }
  std::thread scraper([&] {
    for (int i = 0; i < 50; ++i) EXPECT_TRUE(webtest::CheckPrometheusText(m.Render(), nullptr).empty());
  });
  for (auto& t : threads) t.join();
  scraper.join();
  EXPECT_EQ(c.value(), 80000.0);
  const Histogram::Snapshot s = h.Read();
  EXPECT_EQ(s.count, 80000u);
  EXPECT_EQ(s.cumulative[0], 40000u);
  EXPECT_EQ(s.sum, 40000 * 0.25 + 40000 * 1.0);
}

TEST(PrometheusTextCheck, RejectsMalformedExpositions) {
  // The checker itself must fail on what the format forbids.
  const std::vector<std::string> bad = {
      "x 1\n",                                                     // sample before TYPE
      "# TYPE x counter\nx -1\n",                                  // negative counter
      "# TYPE x gauge\nx{a=\"1\",a=\"2\"} 1\n",                   // duplicate label
      "# TYPE x gauge\nx{a=\"unterminated} 1\n",                   // bad quoting
      "# TYPE x gauge\nx one\n",                                   // bad value
      "# TYPE x gauge\n# TYPE y gauge\ny 1\nx 1\n",                // interleaved
      "# TYPE h histogram\nh_bucket{le=\"1\"} 2\nh_bucket{le=\"+Inf\"} 1\nh_sum 1\nh_count 1\n",
      "# TYPE h histogram\nh_bucket{le=\"1\"} 2\nh_sum 1\nh_count 2\n",  // no +Inf
      "# TYPE x gauge\nx 1",                                       // no final newline
      "# TYPE 1x gauge\n",                                         // bad name
  };
  for (const std::string& text : bad) {
    EXPECT_FALSE(webtest::CheckPrometheusText(text, nullptr).empty()) << text;
  }
}

}  // namespace
}  // namespace bp
