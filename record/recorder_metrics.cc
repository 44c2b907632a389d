#include "record/recorder_metrics.h"

namespace bp {

void AddRecorderMetrics(MetricsRegistry& metrics, const Recorder& recorder) {
  const Recorder* r = &recorder;
  metrics.AddGaugeCallback("binpick_recording_paused",
                           "1 while recording is paused after a write failure (disk full, permission).", {},
                           [r] { return r->stats().paused ? 1.0 : 0.0; });
  const char* captures = "Captures seen by the recorder: recorded, failed (write error or paused), dropped "
                         "(queue full).";
  metrics.AddCounterCallback("binpick_recording_captures_total", captures, {{"result", "recorded"}},
                             [r] { return static_cast<double>(r->stats().captures_recorded); });
  metrics.AddCounterCallback("binpick_recording_captures_total", captures, {{"result", "failed"}},
                             [r] { return static_cast<double>(r->stats().captures_failed); });
  metrics.AddCounterCallback("binpick_recording_captures_total", captures, {{"result", "dropped"}},
                             [r] { return static_cast<double>(r->stats().captures_dropped); });
  const char* answers = "Answers to robots seen by the recorder: recorded, dropped (queue full or paused).";
  metrics.AddCounterCallback("binpick_recording_answers_total", answers, {{"result", "recorded"}},
                             [r] { return static_cast<double>(r->stats().answers_recorded); });
  metrics.AddCounterCallback("binpick_recording_answers_total", answers, {{"result", "dropped"}},
                             [r] { return static_cast<double>(r->stats().answers_dropped); });
  metrics.AddGaugeCallback("binpick_recording_disk_bytes", "Bytes under the recording directory, as accounted.",
                           {}, [r] { return static_cast<double>(r->stats().disk_bytes); });
}

}  // namespace bp
