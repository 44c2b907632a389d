// Linked into the test binary that builds the same parts' models in many
// tests (tests/CMakeLists.txt): turns on the model table memo
// (pipeline/internal/table_memo.h), so that a closest-point field or PPF
// table built from the same inputs as an earlier one is copied, not computed
// again. The tables are a function of their inputs alone, so every test sees
// the tables a fresh build gives; under ASan building them again was about
// 40% of bp_pipeline_tests' CPU (docs/reliability.md, "Timings").
#include "pipeline/internal/table_memo.h"

namespace {
const bool kMemoOn = [] {
  bp::internal::SetModelTableMemo(true);
  return true;
}();
}  // namespace
