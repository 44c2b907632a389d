#!/usr/bin/env bash
# Builds the Debian package (cmake/Package.cmake, docs/fleet.md) from the
# normal build in build/: builds binpickd, binpick and binpick-robot if they
# are not up to date (nothing else: the tests and benches are not packaged),
# then runs CPack. Prints the .deb's path as the last line.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/build.sh --target binpickd binpick binpick-robot >/dev/null
rm -f build/package/binpick_*.deb
(cd build && cpack -G DEB --config CPackConfig.cmake >/dev/null)
deb=$(ls build/package/binpick_*.deb)
echo "package.sh: $(du -h "$deb" | cut -f1) $deb" >&2
echo "$PWD/$deb"
