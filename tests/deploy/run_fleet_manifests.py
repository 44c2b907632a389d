#!/usr/bin/python3
"""Runs the fleet replay manifests locally, as their schedulers would.

  run_fleet_manifests.py k8s   --data DIR --binpick BIN --shards N --run NAME
  run_fleet_manifests.py slurm --data DIR --binpick BIN --shards N --run NAME

k8s: checks deploy/k8s/replay-job.yaml (an Indexed Job whose SHARDS equals
its completions, restartPolicy Never, the volume at /data, the same RUN and
claim as replay-merge-job.yaml), sets completions and SHARDS to N, then runs
each pod's command with JOB_COMPLETION_INDEX = 0..N-1 (Kubernetes' $(VAR)
expansion, /data mapped to DIR, /usr/bin/binpick to BIN) side by side, and
the merge Job's command after them.
slurm: runs deploy/slurm/submit.sh N with an `sbatch` that records its
arguments (checks: an array 0..N-1 of replay.sbatch, then merge.sbatch with
afterok on the array's id), then each array task (SLURM_ARRAY_TASK_ID,
SLURM_ARRAY_TASK_COUNT) side by side, and the merge.

Prints each command's output; exit status: the merge's (0 no regression,
1 regression, 2 bad reports), 3 when a manifest check or a shard failed.
"""
import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]


def fail(message):
    print(f"run_fleet_manifests: {message}")
    sys.exit(3)


def expand_k8s(text, env):
    """Kubernetes' $(VAR) expansion in command and args."""
    return re.sub(r"\$\((\w+)\)", lambda m: str(env.get(m.group(1), m.group(0))), text)


def local(word, args):
    return word.replace("/usr/bin/binpick", args.binpick).replace("/data/", args.data.rstrip("/") + "/")


def run_all(commands, envs):
    procs = [subprocess.Popen(c, env=e, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for c, e in zip(commands, envs)]
    codes = []
    for c, p in zip(commands, procs):
        out, _ = p.communicate()
        print(f"$ {' '.join(c)}\n{out}", end="")
        codes.append(p.returncode)
    return codes


def container(job):
    spec = job["spec"]["template"]["spec"]
    if spec.get("restartPolicy") != "Never":
        fail("restartPolicy must be Never (a Job's pods)")
    (c,) = spec["containers"]
    env = {e["name"]: e["value"] for e in c.get("env", [])}
    mounts = {m["mountPath"]: m["name"] for m in c.get("volumeMounts", [])}
    if "/data" not in mounts:
        fail(f"{job['metadata']['name']}: no volume at /data")
    claim = next(v["persistentVolumeClaim"]["claimName"] for v in spec["volumes"] if v["name"] == mounts["/data"])
    return c, env, claim


def k8s(args):
    job = yaml.safe_load((REPO / "deploy/k8s/replay-job.yaml").read_text())
    merge_job = yaml.safe_load((REPO / "deploy/k8s/replay-merge-job.yaml").read_text())
    if job.get("kind") != "Job" or job["apiVersion"] != "batch/v1":
        fail("replay-job.yaml is not a batch/v1 Job")
    spec = job["spec"]
    if spec.get("completionMode") != "Indexed":
        fail("replay-job.yaml: completionMode is not Indexed")
    c, env, claim = container(job)
    if int(env.get("SHARDS", -1)) != spec["completions"]:
        fail(f"replay-job.yaml: SHARDS {env.get('SHARDS')} is not completions {spec['completions']}")
    if not any("$(JOB_COMPLETION_INDEX)" in a for a in c["args"]):
        fail("replay-job.yaml: the shard index is not $(JOB_COMPLETION_INDEX)")
    mc, menv, mclaim = container(merge_job)
    if (mclaim, menv.get("RUN")) != (claim, env.get("RUN")):
        fail("replay-merge-job.yaml reads another volume or RUN than replay-job.yaml")
    commands, envs = [], []
    for i in range(args.shards):  # `kubectl patch`: completions and SHARDS = N
        e = dict(env, SHARDS=args.shards, RUN=args.run, JOB_COMPLETION_INDEX=i)
        commands.append([local(expand_k8s(w, e), args) for w in c["command"] + c["args"]])
        envs.append(dict(os.environ, **{k: str(v) for k, v in e.items()}))
    if any(run_all(commands, envs)):
        fail("a shard failed")
    e = dict(os.environ)
    e.update(menv)
    e["RUN"] = args.run
    return run_all([[local(expand_k8s(w, e), args) for w in mc["command"] + mc["args"]]], [e])[0]


def slurm(args):
    here = REPO / "deploy/slurm"
    with tempfile.TemporaryDirectory() as bindir:
        log = Path(bindir) / "sbatch.log"
        sbatch = Path(bindir) / "sbatch"
        sbatch.write_text(f"#!/bin/sh\necho \"$*\" >> {log}\nwc -l < {log} | tr -d ' ' | sed 's/^/100/'\n")
        sbatch.chmod(0o755)
        env = dict(os.environ, PATH=f"{bindir}:{os.environ['PATH']}", DATA=args.data, RUN=args.run)
        r = subprocess.run([str(here / "submit.sh"), str(args.shards)], env=env, capture_output=True, text=True)
        print(r.stdout + r.stderr, end="")
        if r.returncode != 0:
            fail("submit.sh failed")
        calls = log.read_text().splitlines()
        if len(calls) != 2:
            fail(f"submit.sh ran sbatch {len(calls)} times, not 2: {calls}")
        if f"--array=0-{args.shards - 1}" not in calls[0].split() or not calls[0].endswith("replay.sbatch"):
            fail(f"the first sbatch is not the array 0-{args.shards - 1} of replay.sbatch: {calls[0]}")
        if "--dependency=afterok:1001" not in calls[1].split() or not calls[1].endswith("merge.sbatch"):
            fail(f"the second sbatch is not merge.sbatch after the array (afterok:1001): {calls[1]}")
    base = dict(os.environ, DATA=args.data, RUN=args.run, BINPICK=args.binpick, SLURM_ARRAY_JOB_ID="1001",
                SLURM_ARRAY_TASK_COUNT=str(args.shards))
    envs = [dict(base, SLURM_ARRAY_TASK_ID=str(i)) for i in range(args.shards)]
    if any(run_all([["bash", str(here / "replay.sbatch")]] * args.shards, envs)):
        fail("an array task failed")
    return run_all([["bash", str(here / "merge.sbatch")]], [base])[0]


def main():
    p = argparse.ArgumentParser()
    p.add_argument("scheduler", choices=["k8s", "slurm"])
    p.add_argument("--data", required=True)
    p.add_argument("--binpick", required=True)
    p.add_argument("--shards", type=int, required=True)
    p.add_argument("--run", required=True)
    args = p.parse_args()
    return k8s(args) if args.scheduler == "k8s" else slurm(args)


if __name__ == "__main__":
    sys.exit(main())
