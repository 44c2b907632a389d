// The recorder's state in /metrics (docs/status_page.md), read at scrape
// time: binpick_recording_paused (1 while paused after a write failure, e.g.
// a full disk), binpick_recording_captures_total{result=recorded|failed|
// dropped}, binpick_recording_answers_total{result=recorded|dropped},
// binpick_recording_disk_bytes. `recorder` must outlive every Render() (stop
// the HTTP server first).
#pragma once

#include "record/recorder.h"
#include "web/metrics.h"

namespace bp {

void AddRecorderMetrics(MetricsRegistry& metrics, const Recorder& recorder);

}  // namespace bp
