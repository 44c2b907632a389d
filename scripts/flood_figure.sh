#!/usr/bin/env bash
# Issue 39's flood figure against real perception, as one command: binpickd
# on the default cell (synthetic camera; picks not simulated, so the pile
# stays and every pick is planned on the same scene), one robot flooding
# DaoAI command 19 (async capture) on task 0 for SECONDS, a second robot
# picking on task 5 (pick_mixed_async, the same bin) meanwhile. bp_soak
# prints the second robot's single plan time (its pick p50 alone), its pick
# p50 and p99 under the flood and "p99 / single plan time" (the issue's
# bound: at most 2). binpickd runs with its defaults (the rate cap of
# endpoints.max_message_rate, 1000/s); the GRI ports are off.
#
# Take the figure on an idle machine: with other jobs on the two cores the
# single plan time and the tail move with their load (docs/reliability.md,
# "Capture flood and soak").
#
# usage: scripts/flood_figure.sh [SECONDS] [bp_soak option...]
#   SECONDS      the flood's duration (default 30)
#   BINPICK_BIN  where binpickd and bp_soak are (default build/bin: the
#                normal build, `scripts/build.sh --target binpickd bp_soak`)
# e.g. scripts/flood_figure.sh 30 --flood-command 20   (an RC 20 flood)
# Exit status: bp_soak's (1 on a transport error or an unexpected status;
# the ratio itself is printed, not judged), 2 if binpickd did not start.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-30}"
if [ $# -gt 0 ]; then shift; fi
bin="${BINPICK_BIN:-build/bin}"
for p in binpickd bp_soak; do
  if [ ! -x "$bin/$p" ]; then
    echo "flood_figure: no $bin/$p (scripts/build.sh --target binpickd bp_soak)" >&2
    exit 2
  fi
done

work="$(mktemp -d)"
pid=""
cleanup() {
  if [ -n "$pid" ]; then
    kill "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
  fi
  rm -rf "$work"
}
trap cleanup EXIT

sed -e "s#\.\./#$PWD/assets/#g" -e "s/simulate_picks: true/simulate_picks: false/" \
  assets/cells/default.yaml >"$work/flood.yaml"
# A loopback port free at the time of the call.
port="$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
"$bin/binpickd" --cell "$work/flood.yaml" --daoai-port "$port" --gri-port 0 --gri-official-port 0 \
  --no-record --log-level warn >"$work/ready" 2>"$work/binpickd.log" &
pid=$!
# binpickd prints one line on stdout when it accepts robots (model tables
# built: about a second on an idle machine).
for _ in $(seq 1200); do
  if grep -q '^binpickd ready' "$work/ready"; then break; fi
  if ! kill -0 "$pid" 2>/dev/null; then
    echo "flood_figure: binpickd exited before it was ready:" >&2
    tail -n 20 "$work/binpickd.log" >&2
    exit 2
  fi
  sleep 0.1
done
if ! grep -q '^binpickd ready' "$work/ready"; then
  echo "flood_figure: binpickd not ready after 120 s" >&2
  exit 2
fi
echo "flood_figure: $(cat "$work/ready"), load average $(cut -d' ' -f1-3 /proc/loadavg)"
"$bin/bp_soak" --mode flood --seconds "$seconds" --port "$port" --pick-task 5 "$@"
