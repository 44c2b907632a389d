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
  const char* refused_help =
      "Robot connections closed at accept: not in the allowlist, over max_connections, or over "
      "max_connections_per_peer.";
  metrics.AddCounterCallback("binpick_refused_connections_total", refused_help,
                             {{"server", server}, {"reason", "allowlist"}},
                             [read] { return static_cast<double>(read().refused_allowlist); });
  metrics.AddCounterCallback("binpick_refused_connections_total", refused_help,
                             {{"server", server}, {"reason", "max_connections"}},
                             [read] { return static_cast<double>(read().refused_max_connections); });
  metrics.AddCounterCallback("binpick_refused_connections_total", refused_help,
                             {{"server", server}, {"reason", "per_peer"}},
                             [read] { return static_cast<double>(read().refused_per_peer); });
  metrics.AddCounterCallback(
      "binpick_accept_errors_total",
      "Failed accepts (out of descriptors or memory: retried after a pause up to 1 s).", labels,
      [read] { return static_cast<double>(read().accept_errors); });
}

void AddHandlerMetrics(MetricsRegistry& metrics, const RequestHandler& handler) {
  const RequestHandler* h = &handler;
  metrics.AddCounterCallback(
      "binpick_captures_coalesced_total",
      "Capture requests that joined the detection pending after the running one (one detection "
      "in flight per task).",
      {}, [h] { return static_cast<double>(h->stats().captures_coalesced); });
  metrics.AddCounterCallback("binpick_planner_failures_total",
                             "Detections that failed with an error: the plan returned one, or "
                             "anything in the detection's path threw (answered as errors, never as "
                             "an empty bin); planner exceptions when told of a grasp handed out.",
                             {}, [h] { return static_cast<double>(h->stats().planner_failures); });
  metrics.AddCounterCallback("binpick_answer_failures_total",
                             "Answers whose building threw: answered UNKNOWN_COMMAND.", {},
                             [h] { return static_cast<double>(h->stats().answer_failures); });
  metrics.AddCounterCallback("binpick_observer_failures_total",
                             "Exceptions an observer (recorder, status page) let escape; contained.",
                             {}, [h] { return static_cast<double>(h->stats().observer_failures); });
  const char* refused_help =
      "Requests refused: calibration or teach jobs over the queue bound (queue_full), or "
      "state-changing requests from peers not in the config allowlist (not_allowed).";
  metrics.AddCounterCallback("binpick_requests_refused_total", refused_help,
                             {{"reason", "queue_full"}},
                             [h] { return static_cast<double>(h->stats().jobs_refused); });
  metrics.AddCounterCallback("binpick_requests_refused_total", refused_help,
                             {{"reason", "not_allowed"}},
                             [h] { return static_cast<double>(h->stats().changes_refused); });
  const char* unsent_help =
      "Grasps popped whose answer was not written (write failed, connection closed first): put "
      "back at the front of the queue (requeued), or dropped because a later detection had "
      "replaced the queue (superseded).";
  metrics.AddCounterCallback("binpick_grasps_unsent_total", unsent_help, {{"result", "requeued"}},
                             [h] { return static_cast<double>(h->stats().grasps_requeued); });
  metrics.AddCounterCallback("binpick_grasps_unsent_total", unsent_help, {{"result", "superseded"}},
                             [h] { return static_cast<double>(h->stats().grasps_superseded); });
  metrics.AddCounterCallback(
      "binpick_grasps_discarded_total",
      "Grasps never handed out because a later detection of their task replaced the queue.", {},
      [h] { return static_cast<double>(h->stats().grasps_discarded); });
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
