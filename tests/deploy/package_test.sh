#!/usr/bin/env bash
# The Debian package, installed into a scratch root with dpkg (--root, the
# maintainer scripts run chrootless with $DPKG_ROOT): what it holds, what its
# postinst does (system user, cell copied once and kept on upgrade, state
# directory, unit enabled), the unit through systemd-analyze verify and
# security, the packaged cell loaded by the installed binpick, and purge.
#   tests/deploy/package_test.sh DEB
# Prints "N passed, M failed"; exit 1 on any failure.
set -uo pipefail
deb="$(realpath "$1")"
root="$(mktemp -d /tmp/binpick_pkgroot.XXXXXX)"
trap 'rm -rf "$root"' EXIT
passed=0 failed=0
ok() { echo "ok: $1"; passed=$((passed + 1)); }
bad() { echo "FAILED: $1"; failed=$((failed + 1)); }
check() {  # check DESCRIPTION COMMAND...
  local what="$1"; shift
  if out=$("$@" 2>&1); then ok "$what"; else bad "$what"; echo "$out" | tail -20; fi
}

dpkg_root() { dpkg --root="$root" --force-script-chrootless --force-depends --log=/dev/null "$@"; }

contents=$(dpkg-deb --contents "$deb")
for f in ./usr/bin/binpickd ./usr/bin/binpick ./usr/bin/binpick-robot ./usr/lib/systemd/system/binpickd.service \
         ./usr/lib/sysusers.d/binpick.conf ./usr/share/binpick/cell.yaml ./usr/share/binpick/assets/parts/pipe_tee.ply \
         ./usr/share/man/man8/binpickd.8.gz ./usr/share/doc/binpick/fleet.md; do
  if grep -q " $f\$" <<<"$contents"; then ok "holds $f"; else bad "holds $f"; fi
done
depends=$(dpkg-deb --field "$deb" Depends)
for d in adduser init-system-helpers libpcl-io libopencv-core libfcl libmodbus libtbb libyaml-cpp libspdlog libosmesa6; do
  if grep -q "$d" <<<"$depends"; then ok "depends on $d"; else bad "depends on $d (Depends: $depends)"; fi
done
check "binaries are stripped" sh -c "dpkg-deb --fsys-tarfile '$deb' | tar -xO ./usr/bin/binpickd > '$root.bin' && \
  ! readelf -S '$root.bin' | grep -q debug_line; rc=\$?; rm -f '$root.bin'; exit \$rc"

# A fresh root: an empty dpkg database and Debian's base accounts (what
# base-passwd installs first into every Debian root).
mkdir -p "$root/var/lib/dpkg/info" "$root/var/lib/dpkg/updates" "$root/etc"
touch "$root/var/lib/dpkg/status"
cp /usr/share/base-passwd/passwd.master "$root/etc/passwd"
cp /usr/share/base-passwd/group.master "$root/etc/group"
check "installs into a fresh root" dpkg_root -i "$deb"
check "the cell is copied to /etc/binpick" cmp "$root/usr/share/binpick/cell.yaml" "$root/etc/binpick/cell.yaml"
check "system user binpick, home the state directory, no login" \
  grep -q '^binpick:x:[0-9]*:[0-9]*:binpick vision server:/var/lib/binpick:/usr/sbin/nologin$' "$root/etc/passwd"
check "system user's uid is a system uid" sh -c "[ \$(awk -F: '\$1==\"binpick\"{print \$3}' '$root/etc/passwd') -lt 1000 ]"
check "state directory /var/lib/binpick" test -d "$root/var/lib/binpick"
check "unit enabled for multi-user.target" \
  test "$(readlink "$root/etc/systemd/system/multi-user.target.wants/binpickd.service")" = /usr/lib/systemd/system/binpickd.service
check "the packaged cell keeps its state in /var/lib/binpick" sh -c "
  grep -q '^  hand_eye_file: /var/lib/binpick/hand_eye.yaml' '$root/etc/binpick/cell.yaml' &&
  grep -q '^  directory: /var/lib/binpick/recordings' '$root/etc/binpick/cell.yaml' &&
  ! grep -q '\.\./' '$root/etc/binpick/cell.yaml'"
check "the man page names the cell and state paths" sh -c "
  zcat '$root/usr/share/man/man8/binpickd.8.gz' | grep -q 'I /etc/binpick/cell.yaml' &&
  zcat '$root/usr/share/man/man8/binpickd.8.gz' | grep -q 'I /var/lib/binpick/'"

# The unit and the packaged cell, as on a box with the package installed:
# in a private mount namespace the root's /usr overlays this machine's (its
# systemd units, its man, its libraries), so the unit's ExecStart, its man
# page and the cell's absolute mesh paths resolve to the package's files.
in_root() { unshare -m sh -c "mount -t overlay overlay -o lowerdir='$root/usr:/usr' /usr && $*"; }
if unshare -m true 2>/dev/null; then
  check "systemd-analyze verify (unit, ExecStart, man page)" \
    in_root "SYSTEMD_LOG_LEVEL=notice systemd-analyze verify binpickd.service"
  security=$(in_root "systemd-analyze security --offline=yes --threshold=30 binpickd.service" 2>&1)
  rc=$?
  echo "$security" | tail -1
  if [ $rc -eq 0 ]; then ok "systemd-analyze security: exposure at most 3.0"
  else bad "systemd-analyze security (exposure over 3.0)"; echo "$security" | grep -v '^✓' | head -40; fi
  check "the installed binpick loads the packaged cell" \
    in_root "env -u BINPICK_ASSETS /usr/bin/binpick info '$root/etc/binpick/cell.yaml' | grep -q pipe_tee"
  # The stripped, installed server on the packaged cell: ready, then exit 0
  # on SIGTERM (no recording: the host's /var/lib is not the root's).
  check "the installed binpickd starts on the packaged cell and stops on SIGTERM" in_root "
    env -u BINPICK_ASSETS -u NOTIFY_SOCKET /usr/bin/binpickd --cell '$root/etc/binpick/cell.yaml' --no-record \
      --daoai-port 0 --gri-port 0 --gri-official-port 0 --http-port -1 > '$root/ready' 2> '$root/binpickd.log' &
    pid=\$!; for i in \$(seq 1800); do grep -q 'binpickd ready' '$root/ready' && break; sleep 0.1; done
    grep -q 'binpickd ready' '$root/ready' || { cat '$root/binpickd.log'; kill \$pid; exit 1; }
    kill -TERM \$pid; wait \$pid"
else
  echo "skipped: systemd-analyze and the packaged cell (no private mount namespace: needs root)"
fi

# An upgrade (the same package again) keeps the integrator's cell.
echo "# edited by the integrator" >> "$root/etc/binpick/cell.yaml"
check "reinstalls over itself" dpkg_root -i "$deb"
check "the edited cell survives the upgrade" grep -q "edited by the integrator" "$root/etc/binpick/cell.yaml"

# Purge: the programs and the cell go, the cell's data stays.
touch "$root/var/lib/binpick/hand_eye.yaml"
check "purges" dpkg_root --purge binpick
check "purge removes the programs" test ! -e "$root/usr/bin/binpickd"
check "purge removes the cell file" test ! -e "$root/etc/binpick/cell.yaml"
check "purge keeps the calibration in /var/lib/binpick" test -e "$root/var/lib/binpick/hand_eye.yaml"

echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]
