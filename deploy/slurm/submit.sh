#!/bin/bash
# Submits a fleet replay: an array of N shard tasks (replay.sbatch) and the
# merge (merge.sbatch), which starts only when every task exited 0
# (afterok). Prints both job ids.
#   DATA=/shared/binpick RUN=run-1 deploy/slurm/submit.sh N
set -euo pipefail
N="${1:?usage: DATA=DIR RUN=NAME submit.sh SHARDS}"
: "${DATA:?set DATA}" "${RUN:?set RUN}"
here="$(cd "$(dirname "$0")" && pwd)"
array=$(sbatch --parsable --export=ALL,DATA="$DATA",RUN="$RUN" --array="0-$((N - 1))" "$here/replay.sbatch")
array="${array%%;*}"  # --parsable prints "id" or "id;cluster"
merge=$(sbatch --parsable --export=ALL,DATA="$DATA",RUN="$RUN" --dependency="afterok:$array" "$here/merge.sbatch")
echo "replay array $array ($N shards), merge ${merge%%;*} after it: $DATA/reports/$RUN/fleet.json"
