#!/usr/bin/env bash
# Builds the libFuzzer targets (fuzz/, `fuzz` preset, clang) and runs each for
# a bounded time from its committed seed corpus (fuzz/corpus/<target>/).
# Fails on the first crash, leak, timeout or out-of-memory; the reproducer is
# kept in build-fuzz/artifacts/<target>/ (replay: build-fuzz/bin/<target> FILE).
#
#   scripts/fuzz.sh                 # every target, FUZZ_SECONDS (20) each
#   FUZZ_SECONDS=60 scripts/fuzz.sh gri_v2_fuzz pcd_fuzz
#
# New inputs found go to build-fuzz/corpus/<target>/ (the committed corpus is
# only read). Prints one line per target: execs, corpus size, coverage.
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_EACH="${FUZZ_SECONDS:-20}"
TARGETS=(daoai_request_fuzz gri_v2_fuzz gri_official_fuzz modbus_registers_fuzz cell_yaml_fuzz
         mesh_fuzz pcd_fuzz ply_frame_fuzz depth_png_fuzz)
if [ $# -gt 0 ]; then TARGETS=("$@"); fi

export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=true
if [ ! -f build-fuzz/CMakeCache.txt ]; then cmake --preset fuzz >/dev/null; fi
cmake --build build-fuzz --target "${TARGETS[@]}"

export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
export ASAN_OPTIONS="detect_leaks=1"
summary=()
for t in "${TARGETS[@]}"; do
  work="build-fuzz/corpus/$t" art="build-fuzz/artifacts/$t"
  mkdir -p "$work" "$art"
  log="build-fuzz/$t.log"
  echo "fuzz: $t for ${SECONDS_EACH}s"
  if ! build-fuzz/bin/"$t" -max_total_time="$SECONDS_EACH" -timeout=10 -rss_limit_mb=2048 \
        -print_final_stats=1 -artifact_prefix="$art/" "$work" "fuzz/corpus/$t" >"$log" 2>&1; then
    tail -n 60 "$log"
    echo "fuzz: $t FAILED (reproducer in $art/, log $log)"
    exit 1
  fi
  execs=$(grep -o 'stat::number_of_executed_units: [0-9]*' "$log" | awk '{print $2}')
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | awk '{print $2}')
  n=$(ls "$work" | wc -l)
  summary+=("$(printf '%-24s execs %10s  corpus %5s  cov %6s' "$t" "$execs" "$n" "$cov")")
done
printf 'fuzz: %s\n' "${summary[@]}"
