#!/usr/bin/env bash
# The main job (README): builds, then renders the default cell and describes
# what was captured. Later stages extend this into server + simulated robot.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/build.sh
out="${DEMO_OUT:-build/demo}"
mkdir -p "$out"
build/bin/binpick render --seed 1 --out "$out"
for f in "$out"/*.pcd "$out"/*.png; do
  build/bin/binpick info "$f"
done
