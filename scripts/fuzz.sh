#!/usr/bin/env bash
# Builds the libFuzzer targets (fuzz/, `fuzz` preset, clang) and runs each
# from its committed seed corpus (fuzz/corpus/<target>/), one per core at a
# time (FUZZ_JOBS). Fails on a crash, leak, timeout or out-of-memory; the reproducer is kept in
# build-fuzz/artifacts/<target>/ (replay: build-fuzz/bin/<target> FILE).
#
# Two modes:
#   FUZZ_GATE=1 scripts/fuzz.sh     # gate (scripts/test.sh): seed 1, a fixed
#                                   # number of inputs per target (GATE_RUNS
#                                   # below, or FUZZ_RUNS for all), from the
#                                   # committed corpus only. The counts are
#                                   # small enough that every machine runs
#                                   # them all (at most about 7 s each on an
#                                   # idle 2-core box), so a faster CI machine
#                                   # does not go further into the sequence
#                                   # than a run here did: a gate must not
#                                   # fail on a bug it found by luck on
#                                   # another day. (libFuzzer is not quite
#                                   # deterministic even so: values such as
#                                   # heap addresses steer a few of its
#                                   # choices.) FUZZ_SECONDS (120) is only a
#                                   # ceiling against a hung machine.
#   scripts/fuzz.sh                 # explore: every target, FUZZ_SECONDS (20)
#   FUZZ_SECONDS=600 scripts/fuzz.sh pcd_fuzz   # each, random seed; new inputs
#                                   # are kept in build-fuzz/corpus/<target>/
#                                   # and used by the next explore run.
# Add what exploring finds to fuzz/corpus/<target>/ with a regression test.
# Prints one line per target: execs, corpus size, coverage.
set -euo pipefail
cd "$(dirname "$0")/.."
GATE="${FUZZ_GATE:-}"
if [ -n "${FUZZ_RUNS:-}" ]; then GATE=1; fi
if [ -n "$GATE" ]; then SECONDS_EACH="${FUZZ_SECONDS:-120}"; else SECONDS_EACH="${FUZZ_SECONDS:-20}"; fi
# Gate inputs per target: at most about 7 s each on an idle 2-core machine
# (docs/reliability.md, Fuzzing). The slow targets parse whole files.
declare -A GATE_RUNS=([daoai_request_fuzz]=300000 [gri_v2_fuzz]=300000 [gri_official_fuzz]=300000
                      [modbus_registers_fuzz]=300000 [cell_yaml_fuzz]=25000 [mesh_fuzz]=300000
                      [pcd_fuzz]=60000 [ply_frame_fuzz]=100000 [depth_png_fuzz]=100000)
# The longest gate runs first (mesh_fuzz about 11 s, the file parsers about
# 7 s, the wire decoders about 1 s), so the parallel runs below end together.
TARGETS=(mesh_fuzz cell_yaml_fuzz pcd_fuzz ply_frame_fuzz depth_png_fuzz daoai_request_fuzz gri_v2_fuzz
         gri_official_fuzz modbus_registers_fuzz)
if [ $# -gt 0 ]; then TARGETS=("$@"); fi

export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=true
if [ -z "${CCACHE_NODEPEND:-}" ]; then export CCACHE_DEPEND=1; fi  # as scripts/build.sh
if [ ! -f build-fuzz/CMakeCache.txt ]; then cmake --preset fuzz >/dev/null; fi
cmake --build build-fuzz --target "${TARGETS[@]}"

export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
export ASAN_OPTIONS="detect_leaks=1"

# One target: its run, its log build-fuzz/<target>.log, its summary line in
# build-fuzz/<target>.summary; returns non-zero (log tail printed) on a
# crash, leak, timeout or out-of-memory.
fuzz_one() {
  local t="$1" work="build-fuzz/corpus/$1" art="build-fuzz/artifacts/$1" log="build-fuzz/$1.log"
  local mode=() runs execs cov n
  if [ -n "$GATE" ]; then
    runs="${FUZZ_RUNS:-${GATE_RUNS[$t]}}"
    work="build-fuzz/gate-corpus/$t"
    rm -rf "$work"
    mode=(-seed=1 -runs="$runs" -reload=0)
    echo "fuzz: $t, seed 1, $runs inputs (at most ${SECONDS_EACH}s)"
  else
    echo "fuzz: $t for ${SECONDS_EACH}s"
  fi
  mkdir -p "$work" "$art"
  if ! build-fuzz/bin/"$t" "${mode[@]}" -max_total_time="$SECONDS_EACH" -timeout=10 -rss_limit_mb=2048 \
        -print_final_stats=1 -artifact_prefix="$art/" "$work" "fuzz/corpus/$t" >"$log" 2>&1; then
    tail -n 60 "$log"
    echo "fuzz: $t FAILED (reproducer in $art/, log $log)"
    return 1
  fi
  execs=$(grep -o 'stat::number_of_executed_units: [0-9]*' "$log" | awk '{print $2}')
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | awk '{print $2}')
  n=$(ls "$work" | wc -l)
  printf '%-24s execs %10s  corpus %5s  cov %6s\n' "$t" "$execs" "$n" "$cov" >"build-fuzz/$t.summary"
}

# FUZZ_JOBS targets at a time (default: one per core). Each run is
# single-threaded and its inputs depend on its seed and count only, not on
# what runs beside it; one after the other the gate's runs left a core idle
# for about 50 s of CI. A failure stops new runs; the running ones finish.
JOBS="${FUZZ_JOBS:-$(nproc)}"
rm -f build-fuzz/*.summary build-fuzz/*.failed
for t in "${TARGETS[@]}"; do
  while [ "$(jobs -rp | wc -l)" -ge "$JOBS" ]; do wait -n || true; done
  if compgen -G 'build-fuzz/*.failed' >/dev/null; then break; fi
  { fuzz_one "$t" || touch "build-fuzz/$t.failed"; } &
done
wait
if compgen -G 'build-fuzz/*.failed' >/dev/null; then exit 1; fi
for t in "${TARGETS[@]}"; do printf 'fuzz: %s' "$(cat "build-fuzz/$t.summary")"; echo; done
