#!/usr/bin/env bash
# The deployment files that need no build: the Dockerfile's lint
# (tests/deploy/check_dockerfile.py, which must also refuse broken copies),
# the Prometheus config and rules (promtool check, and promtool test rules
# on deploy/prometheus/binpick.rules.test.yml), the shell scripts
# (shellcheck, where installed). Prints "N passed, M failed"; exit 1 on any
# failure. The metric names against a running binpickd: bp_deploy_tests.
set -uo pipefail
cd "$(dirname "$0")/../.." || exit 2
passed=0 failed=0
check() {
  local what="$1"; shift
  if out=$("$@" 2>&1); then echo "ok: $what"; passed=$((passed + 1)); else echo "FAILED: $what"; echo "$out" | tail -30; failed=$((failed + 1)); fi
}
refuses() {  # refuses DESCRIPTION SED-EXPRESSION EXPECTED-RULE
  local what="$1" edit="$2" rule="$3" copy
  copy=$(mktemp /tmp/Dockerfile.XXXXXX)
  sed "$edit" deploy/docker/Dockerfile > "$copy"
  out=$(/usr/bin/python3 tests/deploy/check_dockerfile.py "$copy" 2>&1)
  if [ $? -eq 1 ] && grep -q ": $rule:" <<<"$out"; then echo "ok: lint refuses $what"; passed=$((passed + 1));
  else echo "FAILED: lint does not refuse $what ($rule)"; echo "$out"; failed=$((failed + 1)); fi
  rm -f "$copy"
}

check "Dockerfile lint" /usr/bin/python3 tests/deploy/check_dockerfile.py
refuses "a shell-form ENTRYPOINT" 's|^ENTRYPOINT .*|ENTRYPOINT /usr/bin/binpickd --cell /etc/binpick/cell.yaml|' exec
refuses "running as root" 's|^USER binpick|USER root|' user
refuses "an untagged base" 's|^FROM debian:12.11-slim|FROM debian|' base
refuses "apt lists left in the image" 's|rm -rf /var/lib/apt/lists/\* ||' apt
refuses "recommends installed" 's| --no-install-recommends||' apt
refuses "an entrypoint unlike the unit's ExecStart" 's|"--http-port", "8080"|"--http-port", "9090"|' service
refuses "the state directory not a volume" 's|, "/var/lib/binpick"\]|]|' volumes
refuses "a robot port not exposed" 's|EXPOSE 6969 |EXPOSE |' ports
refuses "another version's package" 's|binpick_0.1.0_amd64.deb|binpick_0.0.9_amd64.deb|' package

check "promtool check config" promtool check config deploy/prometheus/binpick.yml
check "promtool check rules" promtool check rules deploy/prometheus/binpick.rules.yml
check "promtool test rules (every alert fires on its case, not on its neighbour)" \
  sh -c "cd deploy/prometheus && promtool test rules binpick.rules.test.yml"
check "the Grafana dashboard is JSON with panels" /usr/bin/python3 -c "
import json, sys
d = json.load(open('deploy/grafana/binpick.json'))
ids = [p['id'] for p in d['panels']]
assert len(ids) == len(set(ids)) and len(ids) >= 10, ids
assert any(v['name'] == 'cell' for v in d['templating']['list'])"
if command -v shellcheck >/dev/null; then
  check "shellcheck" shellcheck scripts/package.sh deploy/debian/postinst deploy/debian/prerm deploy/debian/postrm \
    deploy/slurm/replay.sbatch deploy/slurm/merge.sbatch deploy/slurm/submit.sh tests/deploy/package_test.sh \
    tests/deploy/static_checks.sh
fi
echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]
