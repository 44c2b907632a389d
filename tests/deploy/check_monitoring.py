#!/usr/bin/python3
"""Checks the monitoring files against what binpickd exports.

Every metric the alert rules (deploy/prometheus/binpick.rules.yml) and the
Grafana dashboard (deploy/grafana/binpick.json) name must be a family in a
binpickd /metrics scrape (METRICS_FILE), with the label names they match on
or group by; `up` is Prometheus's own and must be the scrape config's job.
The dashboard's queries must parse as PromQL (promtool check rules, with
$cell replaced). So the files cannot drift apart from the code.

Usage: check_monitoring.py METRICS_FILE
Prints one line per problem; exit 1 if any, else 0.
"""
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
PROM = REPO / "deploy/prometheus"
DASHBOARD = REPO / "deploy/grafana/binpick.json"
# Labels Prometheus puts on every scraped series (job, instance) and the
# scrape config's target label (cell).
TARGET_LABELS = {"job", "instance", "cell"}
HISTOGRAM_SUFFIXES = ("_bucket", "_sum", "_count")
PROMQL_WORDS = {"by", "without", "on", "ignoring", "group_left", "group_right", "and", "or", "unless", "bool",
                "offset"}


def scraped_families(text):
    """name -> (type, set of label names) from Prometheus text format."""
    types, labels = {}, {}
    for line in text.splitlines():
        m = re.match(r"# TYPE (\S+) (\S+)", line)
        if m:
            types[m.group(1)] = m.group(2)
            labels.setdefault(m.group(1), set())
            continue
        if not line or line.startswith("#"):
            continue
        m = re.match(r"([a-zA-Z_:][a-zA-Z0-9_:]*)(\{(.*)\})?\s", line)
        if not m:
            continue
        name = m.group(1)
        family = name
        for suffix in HISTOGRAM_SUFFIXES:
            if name.endswith(suffix) and types.get(name[: -len(suffix)]) == "histogram":
                family = name[: -len(suffix)]
        names = set(re.findall(r'([a-zA-Z_][a-zA-Z0-9_]*)="', m.group(3) or ""))
        labels.setdefault(family, set()).update(names)
    return types, labels


def expressions():
    """(where, expr) for every rule and dashboard query."""
    out = []
    rules = yaml.safe_load((PROM / "binpick.rules.yml").read_text())
    for group in rules["groups"]:
        for rule in group["rules"]:
            out.append((f"rule {rule.get('alert') or rule.get('record')}", rule["expr"]))

    def walk(node, title):
        if isinstance(node, dict):
            title = node.get("title", title)
            if isinstance(node.get("expr"), str):
                out.append((f"panel '{title}'", node["expr"]))
            for v in node.values():
                walk(v, title)
        elif isinstance(node, list):
            for v in node:
                walk(v, title)

    dash = json.loads(DASHBOARD.read_text())
    walk(dash["panels"], "")
    for var in dash["templating"]["list"]:
        if var.get("type") == "query":
            q = var["query"]["query"] if isinstance(var["query"], dict) else var["query"]
            m = re.fullmatch(r"label_values\((.*),\s*(\w+)\)", q)
            if not m:
                out.append((f"variable {var['name']}", q))
            else:  # the selector must exist and carry the label
                out.append((f"variable {var['name']}", m.group(1)))
                out.append((f"variable {var['name']} label", f'{m.group(1)} * on ({m.group(2)}) group_left vector(1)'))
    return out


def selectors(expr):
    """(metric, [label names matched]) for each metric selector in expr."""
    found = []
    for m in re.finditer(r"\b([a-zA-Z_:][a-zA-Z0-9_:]*)\s*(\{([^}]*)\})?", expr):
        name = m.group(1)
        before = expr[: m.start()].rstrip()
        after = expr[m.end():].lstrip()
        if name in PROMQL_WORDS or after.startswith("(") or before.endswith(("by (", "without (", "on (")):
            continue
        if re.search(r"(by|without|on|ignoring|group_left|group_right)\s*\([^)]*$", expr[: m.start()]):
            continue  # a label inside a grouping clause
        if before.endswith(("=", "~")) or re.match(r'\s*[=!]~?\s*"', expr[m.end():]):
            continue  # a label name in a matcher, or a value
        if not (name.startswith("binpick_") or name == "up"):
            continue
        found.append((name, re.findall(r"([a-zA-Z_][a-zA-Z0-9_]*)\s*[=!]~?", m.group(3) or "")))
    return found


def grouping_labels(expr):
    labels = set()
    for m in re.finditer(r"\b(by|without|on|ignoring)\s*\(([^)]*)\)", expr):
        labels.update(l.strip() for l in m.group(2).split(",") if l.strip())
    return labels


def check(metrics_text):
    problems = []
    types, labels = scraped_families(metrics_text)
    config = yaml.safe_load((PROM / "binpick.yml").read_text())
    jobs = {s["job_name"] for s in config["scrape_configs"]}
    named = set()
    for where, expr in expressions():
        expr_labels = set(TARGET_LABELS)
        for name, matched in selectors(expr):
            if name == "up":
                if not re.search(r'up\{[^}]*job="([^"]+)"', expr) or re.search(r'up\{[^}]*job="([^"]+)"', expr).group(1) not in jobs:
                    problems.append(f"{where}: up must select a job of deploy/prometheus/binpick.yml ({sorted(jobs)})")
                continue
            family = name
            for suffix in HISTOGRAM_SUFFIXES:
                if name.endswith(suffix) and types.get(name[: -len(suffix)]) == "histogram":
                    family = name[: -len(suffix)]
            named.add(family)
            if family not in types:
                problems.append(f"{where}: {name} is not exported by binpickd")
                continue
            have = labels[family] | TARGET_LABELS
            expr_labels |= have
            for label in matched:
                if label not in have:
                    problems.append(f"{where}: {name} has no label '{label}' (it has {sorted(labels[family])})")
        for label in sorted(grouping_labels(expr) - expr_labels):
            problems.append(f"{where}: groups by '{label}', which none of its metrics has")
    return problems, named


def promql_problems():
    """Dashboard queries through promtool's parser, as recording rules."""
    try:
        subprocess.run(["promtool", "--version"], capture_output=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return ["promtool not found (Debian package prometheus; scripts/install_deps.sh)"]
    rules = []
    for i, (where, expr) in enumerate(expressions()):
        rules.append({"record": f"binpick:check_{i}", "expr": expr.replace("$cell", "cell-01")})
    with tempfile.NamedTemporaryFile("w", suffix=".yml") as f:
        yaml.safe_dump({"groups": [{"name": "dashboard", "rules": rules}]}, f)
        f.flush()
        r = subprocess.run(["promtool", "check", "rules", f.name], capture_output=True, text=True)
        if r.returncode != 0:
            return [f"dashboard queries do not parse: {r.stdout}{r.stderr}"]
    return []


def main():
    if len(sys.argv) != 2:
        print(__doc__)
        return 2
    problems, named = check(Path(sys.argv[1]).read_text())
    problems += promql_problems()
    for p in problems:
        print(p)
    if not problems:
        print(f"check_monitoring: {len(named)} binpickd metrics named by the rules and the dashboard, all exported: "
              + " ".join(sorted(named)))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
