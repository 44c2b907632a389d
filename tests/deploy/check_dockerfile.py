#!/usr/bin/python3
"""Lints deploy/docker/Dockerfile (Debian 12 packages no hadolint).

Rules, with the hadolint rule each stands for where there is one:
  base     FROM is Debian 12 with an explicit tag, never latest (DL3006, DL3007)
  apt      apt-get, not apt (DL3027); install with -y (DL3014) and
           --no-install-recommends (DL3015); the lists removed in the same
           RUN (DL3009)
  add      COPY, not ADD (DL3020)
  user     the last USER is not root (DL3002)
  exec     ENTRYPOINT / CMD in exec (JSON) form, so the program is PID 1 and
           gets SIGTERM (DL3025)
  signal   STOPSIGNAL, if given, is SIGTERM (binpickd's stop signal)
  service  the ENTRYPOINT is the systemd unit's ExecStart, word for word
  volumes  /etc/binpick and /var/lib/binpick are volumes (the unit's
           ConfigurationDirectory and StateDirectory)
  ports    EXPOSE lists the default cell's robot ports and the unit's
           --http-port
  package  the COPY'd .deb is the one scripts/package.sh builds for this
           version (project() in CMakeLists.txt)

Usage: check_dockerfile.py [DOCKERFILE]   (default: the repository's)
Prints one line per problem; exit 1 if any, else 0.
"""
import json
import re
import shlex
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def instructions(text):
    """(keyword, argument) per instruction; continuation lines joined."""
    out, buf = [], ""
    for line in text.splitlines():
        if not buf and (not line.strip() or line.lstrip().startswith("#")):
            continue
        if line.rstrip().endswith("\\"):
            buf += line.rstrip()[:-1] + " "
            continue
        buf += line
        keyword, _, arg = buf.strip().partition(" ")
        out.append((keyword.upper(), arg.strip()))
        buf = ""
    return out


def unit_exec_start():
    for line in (REPO / "deploy/debian/binpickd.service").read_text().splitlines():
        if line.startswith("ExecStart="):
            return shlex.split(line[len("ExecStart="):])
    return None


def default_ports():
    text = (REPO / "assets/cells/default.yaml").read_text()
    return {m.group(2) for m in re.finditer(r"^\s*(daoai_port|gri_port|gri_official_port):\s*(\d+)", text, re.M)}


def check(path):
    problems = []
    ins = instructions(Path(path).read_text())
    kw = [k for k, _ in ins]
    froms = [a for k, a in ins if k == "FROM"]
    if not froms:
        problems.append("base: no FROM")
    for a in froms:
        image = a.split()[0]
        name, _, tag = image.partition(":")
        if name != "debian" or not tag or tag == "latest" or not (tag.startswith("12") or tag.startswith("bookworm")):
            problems.append(f"base: FROM {image}: expected debian:12... or debian:bookworm... with an explicit tag")
    for k, a in ins:
        if k == "RUN":
            if re.search(r"(^|[;&|]\s*)apt\s", a):
                problems.append("apt: RUN uses apt; use apt-get")
            if "apt-get install" in a:
                if not re.search(r"apt-get install[^&;|]*\s(-y|--yes|-[a-z]*y)", a):
                    problems.append("apt: apt-get install without -y")
                if "--no-install-recommends" not in a:
                    problems.append("apt: apt-get install without --no-install-recommends")
            if "apt-get update" in a and "rm -rf /var/lib/apt/lists" not in a:
                problems.append("apt: apt-get update without rm -rf /var/lib/apt/lists/* in the same RUN")
        if k == "ADD":
            problems.append(f"add: ADD {a}: use COPY")
    users = [a for k, a in ins if k == "USER"]
    if not users or users[-1].split(":")[0] in ("root", "0"):
        problems.append("user: the image runs as root (no USER, or the last USER is root)")
    entry = None
    for k, a in ins:
        if k in ("ENTRYPOINT", "CMD"):
            try:
                words = json.loads(a)
                if not isinstance(words, list) or not all(isinstance(w, str) for w in words):
                    raise ValueError
            except ValueError:
                problems.append(f"exec: {k} {a}: not in exec (JSON array) form; the shell would be PID 1")
                continue
            if k == "ENTRYPOINT":
                entry = words
    for k, a in ins:
        if k == "STOPSIGNAL" and a not in ("SIGTERM", "15"):
            problems.append(f"signal: STOPSIGNAL {a}: binpickd stops on SIGTERM")
    if entry is None:
        problems.append("service: no ENTRYPOINT")
    elif entry != unit_exec_start():
        problems.append(f"service: ENTRYPOINT {entry} is not the unit's ExecStart {unit_exec_start()}")
    volumes = set()
    for k, a in ins:
        if k == "VOLUME":
            try:
                volumes.update(json.loads(a))
            except ValueError:
                volumes.update(a.split())
    for v in ("/etc/binpick", "/var/lib/binpick"):
        if v not in volumes:
            problems.append(f"volumes: {v} is not a VOLUME")
    exposed = set()
    for k, a in ins:
        if k == "EXPOSE":
            exposed.update(p.split("/")[0] for p in a.split())
    exec_start = unit_exec_start() or []
    wanted = default_ports()
    if "--http-port" in exec_start:
        wanted.add(exec_start[exec_start.index("--http-port") + 1])
    for p in sorted(wanted - exposed):
        problems.append(f"ports: port {p} is not EXPOSEd")
    version = re.search(r"project\(binpick VERSION (\S+)", (REPO / "CMakeLists.txt").read_text()).group(1)
    deb = f"build/package/binpick_{version}_amd64.deb"
    args = dict(a.split("=", 1) for k, a in ins if k == "ARG" and "=" in a)
    copies = [a.split() for k, a in ins if k == "COPY"]
    sources = [re.sub(r"\$\{?(\w+)\}?", lambda m: args.get(m.group(1), m.group(0)), c[0]) for c in copies]
    if deb not in sources:
        problems.append(f"package: no COPY of {deb} (scripts/package.sh's package of version {version})")
    return problems


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else REPO / "deploy/docker/Dockerfile"
    problems = check(path)
    for p in problems:
        print(f"{path}: {p}")
    if not problems:
        print(f"{path}: ok")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
