#include "pipeline/internal/table_memo.h"

#include <atomic>

namespace bp::internal {
namespace {

std::atomic<bool> memo_on{false};
std::atomic<size_t> memo_hits{0};

}  // namespace

void SetModelTableMemo(bool on) { memo_on.store(on, std::memory_order_relaxed); }
bool ModelTableMemoOn() { return memo_on.load(std::memory_order_relaxed); }
size_t ModelTableMemoHits() { return memo_hits.load(std::memory_order_relaxed); }
void CountModelTableMemoHit() { memo_hits.fetch_add(1, std::memory_order_relaxed); }

}  // namespace bp::internal
