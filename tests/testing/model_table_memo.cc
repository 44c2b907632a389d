// Linked into the test binaries that build the same parts' models in many
// tests (bp_pipeline_tests, bp_grasp_tests; tests/CMakeLists.txt): turns on
// the model table memo (pipeline/internal/table_memo.h), so that a
// closest-point field, PPF table, surface sampling or other model geometry
// built from the same inputs as an earlier one is copied, not computed again.
// The tables are a function of their inputs alone, so every test sees the
// tables a fresh build gives; under ASan building them again was about 55%
// of bp_pipeline_tests' CPU and 8% of bp_grasp_tests' (docs/reliability.md,
// "Timings").
#include "pipeline/internal/table_memo.h"

namespace {
const bool kMemoOn = [] {
  bp::internal::SetModelTableMemo(true);
  return true;
}();
}  // namespace
