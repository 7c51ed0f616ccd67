#!/usr/bin/env python3
"""Run a terratile pipeline as shard jobs on Dask distributed.

    python scale/dask_run.py PIPELINE.toml --work DIR [--shards N]
        [--scheduler ADDRESS | --workers N] [--terratile BIN] [--retries R]

The driver runs `terratile plan`, then each phase of the plan (count, keep, prepare,
finish) as one `client.map` of `terratile shard DIR --phase P --index K` subprocess calls,
each phase after all jobs of the one before, then `terratile merge DIR` as one more task.
Every job writes its result atomically, so a job that fails or whose worker dies is simply
run again (Dask's `retries` for a failing job; the scheduler reschedules the tasks of a lost
worker on its own, up to `distributed.scheduler.allowed-failures`). Jobs run where the
workers run: DIR, the pipeline, its inputs and the terratile binary must be at the same
paths on every worker (a shared file system on a cluster).

Without --scheduler, a LocalCluster of --workers processes (one thread each: every
terratile job is itself multi-threaded) is started and closed.
"""

import argparse
import json
import os
import subprocess
import sys
import time


def job(terratile, args):
    """One terratile command; raises with terratile's one-line error when it fails."""
    p = subprocess.run([terratile, "--quiet", *args], capture_output=True, text=True)
    if p.returncode != 0:
        line = (p.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise RuntimeError(f"terratile {' '.join(args)}: exit {p.returncode}: {line}")
    return p.stdout.strip()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pipeline")
    ap.add_argument("--work", required=True, help="work directory (shared by all jobs)")
    ap.add_argument("--shards", type=int, default=4, help="jobs per phase (default 4)")
    ap.add_argument("--scheduler", help="address of a running Dask scheduler")
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster workers (default 2)")
    ap.add_argument("--terratile", default="terratile", help="the terratile binary")
    ap.add_argument("--retries", type=int, default=3, help="retries of a failing job")
    a = ap.parse_args(argv)

    from dask.distributed import Client, LocalCluster

    work = os.path.abspath(a.work)
    t0 = time.time()
    plan = json.loads(
        job(a.terratile, ["plan", a.pipeline, "--out", work, "--shards", str(a.shards), "--json"])
    )
    times = [("plan", time.time() - t0)]
    cluster = None
    if a.scheduler:
        client = Client(a.scheduler)
    else:
        cluster = LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True)
        client = Client(cluster)
    try:
        for phase in plan["phases"]:
            t = time.time()
            futures = client.map(
                lambda k, phase=phase: job(
                    a.terratile, ["shard", work, "--phase", phase, "--index", str(k)]
                ),
                range(plan["jobs"]),
                key=[f"terratile-{phase}-{k}" for k in range(plan["jobs"])],
                retries=a.retries,
                pure=False,
            )
            client.gather(futures)
            times.append((phase, time.time() - t))
        t = time.time()
        merged = client.submit(
            job, a.terratile, ["merge", work], key="terratile-merge", retries=a.retries, pure=False
        ).result()
        times.append(("merge", time.time() - t))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    print(merged)
    print(
        f"{plan['jobs']} jobs per phase: "
        + ", ".join(f"{name} {s:.2f} s" for name, s in times)
        + f"; total {time.time() - t0:.2f} s"
    )
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except RuntimeError as e:
        print(f"dask_run: {e}", file=sys.stderr)
        sys.exit(2)
