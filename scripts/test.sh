#!/usr/bin/env bash
# The README's test command (and CI's, through .ci/run). Stages, in order:
#   build  normal build of the programs and the load test (scripts/build.sh,
#          target bp_programs), bounded load test (bp_load: 8 robots, 5 s,
#          fails on any error); with arguments, the whole build and a ctest
#          run with them (e.g. `scripts/test.sh -R Perception`)
#   deploy the Debian package from build/'s programs (scripts/package.sh:
#          no rebuild) installed into a scratch root and checked
#          (tests/deploy/package_test.sh), the Dockerfile's lint and the
#          Prometheus config, rules and their unit tests
#          (tests/deploy/static_checks.sh); the asan and tsan trees of the
#          stages that follow are configured beside these checks
#   asan   every test under AddressSanitizer + UBSan (build-asan/; each test
#          binary once, all its tests in one process). The tests run here
#          only, not also in the normal build: compiling them twice cost
#          about 4 min of CI (docs/reliability.md, "Timings"); the longest
#          binaries first. The benches are compiled and linked here too, at
#          -O0 without sanitizers, as a check only (never run; their -O2
#          build is the normal one's), at nice 19 beside the test runs
#   tsan   the server and queue tests (bp_comms_tests, bp_grasp_tests) under
#          ThreadSanitizer (build-tsan/; oneTBB runs serially there, see
#          tests/testing/tsan_serial_tbb.cc and scripts/tsan.supp); the fuzz
#          stage's tree is built at nice 19 beside the runs when it follows
#   fuzz   every libFuzzer target, gate mode: seed 1, a fixed number of
#          inputs per target, the same on every machine (scripts/fuzz.sh,
#          build-fuzz/)
# and, not in the default run:
#   tests  every test in the normal build, each binary once (the quick
#          check while working: no sanitizer build)
#   tsan-all  every test binary with threads under ThreadSanitizer: the tsan
#          stage's two and the recorder's writer and binpickd replay
#          (record), the status page's HTTP thread and binpickd end to end
#          (web), the calibration sequence (calib); binpickd, binpick and
#          binpick-robot built with TSan too. Not in CI's run: a cold run
#          with it in the tsan stage took over CI's 30 minutes
#          (docs/reliability.md, "Timings")
# BINPICK_TEST_STAGES picks stages (default: all five, "build deploy asan
# tsan fuzz"; timings in docs/reliability.md); extra arguments go to a ctest run
# of the normal build (e.g. `scripts/test.sh -R Perception`). Each stage logs
# its start and its duration; the first failure stops the run.
set -euo pipefail
cd "$(dirname "$0")/.."
STAGES="${BINPICK_TEST_STAGES:-build deploy asan tsan fuzz}"
export CCACHE_DIR="${CCACHE_DIR:-$HOME/.cache/ccache}"
export CCACHE_MAXSIZE="${CCACHE_MAXSIZE:-5G}"
export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=true
# Depend mode: on a miss ccache takes the headers from the compiler's -MD file
# instead of running the preprocessor once more to hash its output (0.2-0.25
# CPU s a file, about 100 of a cold CI's CPU seconds; docs/reliability.md,
# "Timings"). Its entries and the default mode's hit each other.
# CCACHE_NODEPEND=1 turns it off.
if [ -z "${CCACHE_NODEPEND:-}" ]; then export CCACHE_DEPEND=1; fi
JOBS="$(nproc)"
timings=()

run_stage() {
  local name="$1"
  shift
  echo "=== test.sh: stage '$name' started $(date -u +%H:%M:%S)"
  local t0=$SECONDS
  "$@"
  local dt=$((SECONDS - t0))
  timings+=("$(printf '%-6s %4d s' "$name" "$dt")")
  echo "=== test.sh: stage '$name' passed in ${dt} s"
}

# Runs every test binary of build dir $1 once, all its tests in one process
# ($JOBS binaries at a time; ctest's process per test rebuilds the
# perception model tables for every test: 181 s against 85 s for the normal
# build, and ~50 s per test under ASan). Each binary gets TEST_TIMEOUT
# seconds (a hang fails the stage, it does not stall CI). Logs go to
# $1/test-logs/; a failing binary's log tail is printed. Further arguments
# name the binaries to run (default: every bin/*_tests).
run_test_binaries() {
  local dir="$1" logs="$1/test-logs" failed=0 t
  shift
  rm -rf "$logs" && mkdir -p "$logs"
  export BINPICK_ASSETS="$PWD/assets" TEST_TIMEOUT="${TEST_TIMEOUT:-900}"
  { if [ $# -gt 0 ]; then printf '%s\n' "$@"; else ls "$dir/bin/" | grep '_tests$'; fi; } |
    xargs -P "$JOBS" -I{} sh -c \
    'cd "$0" && timeout "$TEST_TIMEOUT" bin/{} --gtest_brief=1 >test-logs/{}.log 2>&1 && echo "--- $0: {} passed" \
     || { echo "--- $0: {} FAILED (exit $?)"; exit 1; }' "$dir" || failed=1
  if [ "$failed" != 0 ]; then
    for t in "$logs"/*.log; do
      if ! grep -q '^\[  PASSED  \]' "$t" || grep -q 'FAILED\|ERROR: \(Address\|Leak\|Thread\)Sanitizer\|runtime error:' "$t"; then
        echo "=== $t"; tail -n 80 "$t"
      fi
    done
    return 1
  fi
}

stage_build() {
  if [ $# -gt 0 ]; then
    scripts/build.sh
    (cd build && ctest --output-on-failure --parallel "$JOBS" --timeout 300 "$@")
  else
    scripts/build.sh --target bp_programs
  fi
  build/bin/bp_load --robots 8 --seconds 5
}

# Configures build dir $1 from preset $2 unless it is configured already; a
# sanitizer tree configured with GCC before (clang-14 since 2026-12-03 for
# asan, 2026-12-05 for tsan) is configured again.
configure_tree() {
  if [ -f "$1/CMakeCache.txt" ] && ! grep -q '^CMAKE_CXX_COMPILER:.*clang++-14' "$1/CMakeCache.txt"; then
    rm -rf "$1"
  fi
  if [ ! -f "$1/CMakeCache.txt" ]; then cmake --preset "$2" >/dev/null; fi
}

stage_deploy() {
  # The sanitizer trees of the stages that follow are configured beside the
  # checks (about 5 s each, one core; the checks leave the other idle).
  local trees=""
  if [[ " $STAGES " == *" asan "* ]]; then trees+="build-asan:asan "; fi
  if [[ " $STAGES " == *" tsan "* || " $STAGES " == *" tsan-all "* ]]; then trees+="build-tsan:tsan "; fi
  if [ -n "$trees" ]; then
    bg_build build/configure-trees.log bash -c "$(declare -f configure_tree)"'
      for t in "$@"; do configure_tree "${t%%:*}" "${t##*:}"; done' _ $trees
  fi
  local deb
  deb=$(scripts/package.sh)
  tests/deploy/package_test.sh "$deb"
  tests/deploy/static_checks.sh
  bg_wait
}

stage_tests() {
  scripts/build.sh
  run_test_binaries build
}

# The test binaries of build dir $1 (bin/*_tests): the ones named after it
# first, in that order, then the others in name order.
longest_first() {
  local dir="$1" t f
  shift
  for t in "$@"; do
    if [ -x "$dir/bin/$t" ]; then echo "$t"; fi
  done
  for f in "$dir"/bin/*_tests; do
    t="${f##*/}"
    case " $* " in *" $t "*) ;; *) echo "$t" ;; esac
  done
}

# A build beside a stage's test runs (bg_build LOG COMMAND...: the command
# at nice 19, its output to LOG; bg_wait: waits for it, printing its log's
# tail if it failed). The tests keep their CPU; the build takes what they
# leave (the comms tests wait on sockets and timers, the last binary runs
# alone). Started in this script's session, so in its scheduling group,
# where nice ranks it below the tests (setsid would make it a group of its
# own, with its own share of the CPU).
bg_pid=""
bg_log=""
bg_build() {
  bg_log="$1"
  shift
  nice -n 19 "$@" >"$bg_log" 2>&1 &
  bg_pid=$!
}
bg_wait() {
  local pid="$bg_pid"
  bg_pid=""
  if [ -n "$pid" ] && ! wait "$pid"; then
    echo "=== $bg_log"
    tail -n 60 "$bg_log"
    return 1
  fi
}
# A failed stage stops the run: its background build stops with it.
trap 'if [ -n "$bg_pid" ]; then kill "$bg_pid" 2>/dev/null || true; fi' EXIT

stage_asan() {
  configure_tree build-asan asan
  # The test binaries and the programs they run (binpickd, binpick,
  # binpick-robot), then the rest of the tree beside their runs: the
  # benches, a compile-and-link check (the preset's BINPICK_BENCH_CHECK_ONLY).
  cmake --build build-asan --parallel "$JOBS" --target bp_tests
  bg_build build-asan/bench-check.log ninja -C build-asan -j "$JOBS"
  export LSAN_OPTIONS="suppressions=$PWD/scripts/lsan.supp"
  export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
  export ASAN_OPTIONS="detect_leaks=1:abort_on_error=0"
  # The longest first, so the two slots end together (in name order the
  # pipeline tests, over a third of the runs, started eighth and ran alone
  # at the end). Under ASan, gtest's totals in the cold run of c2d2d34:
  # pipeline 172 s, integration 61, record 60, web 39, grasp 37, calib 38,
  # comms 36, 2D 12, deploy 5, core 1, collision 0.
  local order
  mapfile -t order < <(longest_first build-asan bp_pipeline_tests bp_integration_tests bp_record_tests \
    bp_web_tests bp_calib_tests bp_grasp_tests bp_comms_tests bp_twod_tests bp_deploy_tests)
  run_test_binaries build-asan "${order[@]}"
  bg_wait
}

# Builds the named test binaries in build-tsan/ and runs them under
# ThreadSanitizer, in the order given (the longest first: two at a time).
run_tsan() {
  configure_tree build-tsan tsan
  cmake --build build-tsan --parallel "$JOBS" --target "$@"
  # The fuzz stage's tree beside the runs, when that stage comes next (its
  # gate's inputs depend on the seed and counts only, not on how it was
  # built; scripts/fuzz.sh then finds it built).
  if [[ " $STAGES " == *" fuzz "* ]]; then
    bg_build build-tsan/fuzz-build.log sh -c \
      '{ [ -f build-fuzz/CMakeCache.txt ] || cmake --preset fuzz; } && exec ninja -C build-fuzz -j "$0"' "$JOBS"
  fi
  export TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:suppressions=$PWD/scripts/tsan.supp"
  run_test_binaries build-tsan "$@"
}

# Every test binary whose code has threads: besides the servers, queues and
# handler (comms, grasp), the recorder's writer thread and binpickd replay
# (record), the status page and its HTTP thread and the binpickd end-to-end
# tests (web), the calibration sequence behind the servers (calib). The
# tests run binpickd, binpick and binpick-robot, built here with TSan too.
# ReplayShards (recorded in-process like RecordReplay, then six
# single-threaded `binpick replay` processes and their merges) runs under
# ASan only: under TSan it is two thirds of the record tests' CPU and checks
# no thread the other record tests do not (docs/reliability.md, "Timings").
stage_tsan_all() {
  # The longest first, so the two cores finish together.
  GTEST_FILTER='-ReplayShards.*' \
    run_tsan bp_grasp_tests bp_web_tests bp_calib_tests bp_comms_tests bp_record_tests
}

# The servers, queues and handler: the threads every robot request crosses.
# OwnPoints, MixedPixels and HiddenSpace (grasp planning on rendered piles
# against the truth; one thread, oneTBB runs serially under TSan) run under
# ASan only:
# under TSan they were about 27 and 18 s of bp_grasp_tests, the stage's
# longest run, and check no thread (docs/reliability.md, "Timings").
stage_tsan() {
  GTEST_FILTER='-OwnPoints.*:MixedPixels.*:HiddenSpace.*' run_tsan bp_grasp_tests bp_comms_tests
}

stage_fuzz() {
  bg_wait
  FUZZ_GATE=1 scripts/fuzz.sh
}

for s in $STAGES; do
  case "$s" in
    build) run_stage build stage_build "$@" ;;
    deploy) run_stage deploy stage_deploy ;;
    tests) run_stage tests stage_tests ;;
    asan) run_stage asan stage_asan ;;
    tsan) run_stage tsan stage_tsan ;;
    tsan-all) run_stage tsan-all stage_tsan_all ;;
    fuzz) run_stage fuzz stage_fuzz ;;
    *) echo "test.sh: unknown stage '$s' (build deploy tests asan tsan tsan-all fuzz)"; exit 2 ;;
  esac
done
echo "=== test.sh: all stages passed"
printf '    %s\n' "${timings[@]}"
