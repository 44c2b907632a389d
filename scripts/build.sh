#!/usr/bin/env bash
# Installs what is missing, configures (Release with debug info, ccache) and
# builds into build/. Executables land in build/bin/.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install_deps.sh
export CCACHE_DIR="${CCACHE_DIR:-$HOME/.cache/ccache}"
export CCACHE_MAXSIZE="${CCACHE_MAXSIZE:-5G}"
# Share cache hits between checkouts (worktrees, CI clones) of the same tree.
export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=true
# No second preprocessor run on a miss (ccache's depend mode: the compiler's
# -MD file names the headers; scripts/test.sh, docs/reliability.md).
if [ -z "${CCACHE_NODEPEND:-}" ]; then export CCACHE_DEPEND=1; fi
if [ ! -f build/CMakeCache.txt ]; then
  cmake --preset default
fi
cmake --build build --parallel "$(nproc)" "$@"
