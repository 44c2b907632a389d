#!/usr/bin/env bash
# Installs binpick's build and test dependencies from Debian 12 packages.
# Skips apt entirely when every package is already installed. Run as root.
set -euo pipefail

PACKAGES=(
  build-essential cmake ninja-build ccache pkg-config git
  clang clang-14 libclang-rt-14-dev lld  # lld: the linker (CMakeLists.txt)
  libeigen3-dev libpcl-dev libopencv-dev libopencv-contrib-dev libfcl-dev
  libmodbus-dev libboost-dev libboost-system-dev libtbb-dev libosmesa6-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libyaml-cpp-dev libspdlog-dev libcli11-dev nlohmann-json3-dev
  python3 python3-pymodbus python3-serial python3-serial-asyncio python3-numpy
  python3-prometheus-client  # tests: the reference /metrics parser
  chromium                   # tests: the status page in a headless browser
  python3-yaml               # tests: the monitoring and fleet manifest checks (tests/deploy)
  prometheus                 # tests: promtool checks the rules and the dashboard's queries
  systemd                    # tests: systemd-analyze verify / security on the packaged unit
  dpkg-dev fakeroot          # scripts/package.sh: CPack's dpkg-shlibdeps
  shellcheck                 # tests: the package's maintainer scripts and the Slurm scripts
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install_deps: all ${#PACKAGES[@]} packages present"
  exit 0
fi

echo "install_deps: installing ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
