// Linked into every test binary, and under TSan into binpickd, binpick and
// binpick-robot (apps/CMakeLists.txt). Under ThreadSanitizer (scripts/test.sh's
// tsan stage) oneTBB runs every parallel algorithm on the calling thread:
// Debian's libtbb is not instrumented, so the hand-over between its worker
// threads and the caller is invisible to TSan and every parallel_for would be
// reported as a race. The stage checks the servers, queues, status page,
// recorder and binpickd, which run on Asio and plain threads; the
// parallel loops themselves are not checked by it. No effect in other builds.
#include "core/sanitizers.h"

#if BP_UNDER_TSAN
#include <tbb/global_control.h>

namespace {
const tbb::global_control kSerialTbb(tbb::global_control::max_allowed_parallelism, 1);
}  // namespace
#endif
