// The request handler driving the real BinPickingPlanner on a small synthetic
// pile, with ground-truth detections (TruthPerception: not perception): the
// robot's loop of capture / pick pose clears the bin through simulated picks,
// the remaining count runs down, and the empty-box check then says EMPTY.
#include <gtest/gtest.h>

#include <vector>

#include "comms/request_handler.h"
#include "grasp/bin_picking_planner.h"
#include "pipeline/capture_source.h"
#include "pipeline/truth_perception.h"

namespace bp {
namespace {

daoai::Request Req(int32_t command, int32_t task) {
  daoai::Request r;
  r.position = {5000, 0, 6000};
  r.orientation = {0, 0, 0, 10000};
  r.command = command;
  r.payload_1 = task;
  r.meta_1 = 7;
  r.meta_2 = 2;
  return r;
}

TEST(RequestHandlerWithPlanner, ClearsASmallPileThenReportsTheBoxEmpty) {
  Result<Cell> cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok());
  cell->source.kind = SourceSpec::Kind::kSynthetic;
  cell->source.num_parts = 3;
  cell->source.part_classes = {0};  // bushings: always graspable with suction
  cell->source.seed = 4;
  cell->source.simulate_picks = true;
  auto source = MakeCaptureSource(*cell);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  BinPickingPlannerOptions options;
  options.teach_file = "-";
  auto planner = BinPickingPlanner::Create(*cell, std::make_shared<TruthPerception>(*cell), std::move(*source),
                                           options);
  ASSERT_TRUE(planner.ok()) << planner.status().ToString();
  RequestHandler handler(*cell, std::shared_ptr<GraspPlanner>(std::move(*planner)), nullptr);
  ClientContext client;

  int picks = 0;
  std::vector<int> remaining;
  for (int cycle = 0; cycle < 10; ++cycle) {
    ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
    const auto pick = handler.Handle(Req(daoai::kPickPose, 0), client);
    ASSERT_TRUE(pick);
    if (pick->status != daoai::kObjectsFound) {
      EXPECT_EQ(pick->status, daoai::kNoObjectFound);
      break;
    }
    remaining.push_back(pick->payload[0]);
    ++picks;
  }
  EXPECT_EQ(picks, 3);
  // Each capture re-plans the pile as it is: one part fewer every time
  // (payload_1 is sent in the MULT fixed point, x 10000).
  EXPECT_EQ(remaining, (std::vector<int>{30000, 20000, 10000}));
  EXPECT_EQ(handler.Handle(Req(daoai::kCheckEmptyBox, 0), client)->status, daoai::kBoxEmpty);
}

}  // namespace
}  // namespace bp
