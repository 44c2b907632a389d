#include "web/server_metrics.h"

namespace bp {

void AddTransportMetrics(MetricsRegistry& metrics, const std::string& server,
                         std::function<TransportStats()> read) {
  const MetricLabels labels{{"server", server}};
  metrics.AddGaugeCallback("binpick_connections", "Robot connections open.", labels,
                           [read] { return static_cast<double>(read().open); });
  metrics.AddCounterCallback("binpick_connections_accepted_total", "Robot connections accepted.",
                             labels, [read] { return static_cast<double>(read().accepted); });
  metrics.AddCounterCallback(
      "binpick_protocol_errors_total",
      "Requests rejected as unframeable, undecodable or over the queue limit.", labels,
      [read] { return static_cast<double>(read().protocol_errors); });
  metrics.AddCounterCallback("binpick_read_timeouts_total", "Robot connections closed for silence.",
                             labels, [read] { return static_cast<double>(read().read_timeouts); });
}

void AddModbusMetrics(MetricsRegistry& metrics, const ModbusMaster& master) {
  const ModbusMaster* m = &master;
  const MetricLabels labels{{"robot", m->address()}};
  metrics.AddGaugeCallback("binpick_modbus_connected",
                           "1 while the robot's Modbus slave is connected.", labels,
                           [m] { return m->stats().connected ? 1.0 : 0.0; });
  metrics.AddCounterCallback("binpick_modbus_connects_total", "Modbus connections made.", labels,
                             [m] { return static_cast<double>(m->stats().connects); });
  metrics.AddCounterCallback("binpick_modbus_requests_total", "Modbus requests taken.", labels,
                             [m] { return static_cast<double>(m->stats().requests); });
  metrics.AddCounterCallback(
      "binpick_modbus_protocol_errors_total",
      "Modbus responses refused (out of range), saturated or lost, and requests over an unread "
      "response.",
      labels, [m] {
        const ModbusMasterStats s = m->stats();
        return static_cast<double>(s.refused + s.saturated + s.lost + s.unread);
      });
}

void AddQueueMetrics(MetricsRegistry& metrics, const RequestHandler& handler) {
  for (const TaskSpec& task : handler.cell().tasks) {
    metrics.AddGaugeCallback("binpick_queue_grasps", "Grasps left in the task's queue.",
                             {{"task", std::to_string(task.id)}},
                             [&handler, id = task.id] { return handler.QueueSize(id); });
  }
}

}  // namespace bp
