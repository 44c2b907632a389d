// Metrics read from the servers at scrape time (docs/status_page.md): robot
// connections and protocol errors per transport, Modbus master counters, and
// the grasps left per task. Each registers callbacks: the objects read must
// outlive every MetricsRegistry::Render() (stop the HTTP server first).
#pragma once

#include <functional>
#include <string>

#include "comms/modbus_master.h"
#include "comms/request_handler.h"
#include "comms/transport_stats.h"
#include "web/metrics.h"

namespace bp {

// binpick_connections, binpick_connections_accepted_total,
// binpick_protocol_errors_total, binpick_read_timeouts_total,
// binpick_accept_errors_total {server=...};
// binpick_refused_connections_total {server, reason}.
void AddTransportMetrics(MetricsRegistry& metrics, const std::string& server,
                         std::function<TransportStats()> read);
// binpick_modbus_* {robot="host:port"}.
void AddModbusMetrics(MetricsRegistry& metrics, const ModbusMaster& master);
// binpick_captures_coalesced_total, binpick_planner_failures_total,
// binpick_observer_failures_total, binpick_answer_failures_total,
// binpick_requests_refused_total {reason}.
void AddHandlerMetrics(MetricsRegistry& metrics, const RequestHandler& handler);
// binpick_queue_grasps {task=...} for each of the cell's tasks.
void AddQueueMetrics(MetricsRegistry& metrics, const RequestHandler& handler);

}  // namespace bp
