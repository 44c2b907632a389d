// GRI request semantics (docs/protocols.md, "GRI semantics"), independent of
// the transport (comms/gri_server.h) and of the wire format: v2 and the
// official format are served by the same code, only the codes and data slots
// differ (gri::WireErrorCode, Build below).
//
// A GRI job id is a binpick task id. Jobs run on the RequestHandler's tasks:
// the same detections and the same grasp queue as the DaoAI protocol, so a
// DaoAI robot and a GRI robot on one task never get the same grasp.
//
// Job status (per task, shared by every GRI connection):
//   RUNNING  a detection is in flight (whoever triggered it);
//   FAILED   the last detection could not capture, not yet reported;
//   DONE     the last detection finished and its results are not exhausted;
//   INACTIVE nothing triggered yet, or the last results were all taken (or
//            reported empty / failed) through the GRI.
//
// Threading: as RequestHandler. HandleAsync never blocks; the Reply is built
// when the transport is about to write it, which is when a pose is popped: a
// robot that disconnects (or whose request timed out) loses nothing.
#pragma once

#include <array>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "comms/gri_message.h"
#include "comms/request_handler.h"

namespace bp {

class GriHandler {
 public:
  // Builds the response right before it is written. Called at most once.
  using Reply = std::function<gri::Response()>;
  // Receives the Reply, inside HandleAsync or later from a detection worker.
  using Completion = std::function<void(Reply)>;

  // `tasks` must outlive the handler.
  explicit GriHandler(RequestHandler& tasks);
  GriHandler(const GriHandler&) = delete;
  GriHandler& operator=(const GriHandler&) = delete;

  // Never throws: an exception in the request's handling is answered
  // INTERNAL_ERROR, logged and counted (RequestHandler::CountAnswerFailure),
  // unless the request was answered before it; the first answer given wins.
  void HandleAsync(const gri::Request& request, ClientContext& client, Completion done) noexcept;
  // An answer the transport had to replace because building or serializing
  // it threw (logged by the transport).
  void CountAnswerFailure() { tasks_.CountAnswerFailure(); }

  // The job status the GRI reports for `job_id`; nullopt for an unknown job.
  std::optional<gri::JobStatus> JobStatusOf(int job_id) const;

  // An answer carrying only `code`, echoing the request's header and job id.
  static gri::Response ErrorResponse(const gri::Request& request, gri::Code code);
  // The response's bytes; a response that does not fit its format (e.g. an
  // official pose beyond +-2147 mm) is logged and sent as INTERNAL_ERROR
  // without a pose (`*replaced` set: a pose it carried was not sent).
  static std::vector<uint8_t> Serialize(const gri::Response& response, bool* replaced = nullptr);

 private:
  struct Job {
    uint64_t consumed = 0;      // detections finished whose results the GRI used up
    std::vector<Pose> related;  // of the last primary handed out, in order
    size_t next_related = 0;
  };
  void Handle(const gri::Request& request, ClientContext& client, Completion done);  // HandleAsync's body
  gri::JobStatus StatusLocked(const RequestHandler::TaskSnapshot& s, const Job& job) const;
  // `client` (the connection's, alive while its Reply can run) holds the
  // popped grasp until the transport settles it (ClientContext::settle).
  Reply NextPoseReply(const gri::Request& request, bool after_trigger, ClientContext* client);
  void HandEye(const gri::Request& request, const std::optional<Pose>& X_BF, Completion done);

  RequestHandler& tasks_;
  mutable std::mutex mutex_;
  std::map<int, Job> jobs_;  // GUARDED_BY(mutex_); one per cell task
  bool hec_started_ = false;  // GUARDED_BY(mutex_); HEC_INIT done, HEC_CALIBRATE not yet
};

}  // namespace bp
