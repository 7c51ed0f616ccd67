#!/usr/bin/env python3
"""Run a terratile pipeline as shard jobs on Dask distributed.

    python scale/dask_run.py PIPELINE.toml --work DIR [--shards N]
        [--scheduler ADDRESS | --workers N] [--terratile BIN] [--retries R] [--profile]

The driver runs `terratile plan`, then each phase of the plan (count, keep, prepare,
finish) as one `client.map` of `terratile shard DIR --phase P --index K` subprocess calls,
each phase after all jobs of the one before, then `terratile merge DIR` as one more task.
(Phases are not chained as task dependencies: a lost worker would then take the small
results of its finished jobs with it and the scheduler would run those jobs again.) Every
job writes its result atomically, so a job that fails or whose worker dies is simply run
again (Dask's `retries` for a failing job; the scheduler reschedules the tasks of a lost
worker on its own, up to `distributed.scheduler.allowed-failures`). Jobs run where the
workers run: DIR, the pipeline, its inputs and the terratile binary must be at the same
paths on every worker (a shared file system on a cluster).

Without --scheduler, a LocalCluster of --workers processes (one thread each: every
terratile job is itself multi-threaded) is started while `terratile plan` runs, and closed
at the end. --profile prints each job's worker, start and end (seconds since the driver
started) and CPU seconds (user + system of the terratile process).
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time


def job(terratile, args):
    """One terratile command; raises with terratile's one-line error when it fails.
    Returns (stdout, start, end, CPU seconds, worker host:pid).
    """
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.time()
    p = subprocess.run([terratile, "--quiet", *args], capture_output=True, text=True)
    end = time.time()
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (used.ru_utime - before.ru_utime) + (used.ru_stime - before.ru_stime)
    if p.returncode != 0:
        line = (p.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise RuntimeError(f"terratile {' '.join(args)}: exit {p.returncode}: {line}")
    return p.stdout.strip(), start, end, cpu, f"{os.uname().nodename}:{os.getpid()}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pipeline")
    ap.add_argument("--work", required=True, help="work directory (shared by all jobs)")
    ap.add_argument("--shards", type=int, default=4, help="jobs per phase (default 4)")
    ap.add_argument("--scheduler", help="address of a running Dask scheduler")
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster workers (default 2)")
    ap.add_argument("--terratile", default="terratile", help="the terratile binary")
    ap.add_argument("--retries", type=int, default=3, help="retries of a failing job")
    ap.add_argument("--profile", action="store_true", help="print every job's times")
    a = ap.parse_args(argv)

    t0 = time.time()
    work = os.path.abspath(a.work)
    # The plan runs while Dask is imported and the cluster starts (both take seconds).
    planning = subprocess.Popen(
        [a.terratile, "--quiet", "plan", a.pipeline, "--out", work,
         "--shards", str(a.shards), "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    from dask.distributed import Client, LocalCluster

    cluster = None
    client = None
    try:
        if a.scheduler:
            client = Client(a.scheduler)
        else:
            cluster = LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True)
            client = Client(cluster)
        t_cluster = time.time() - t0
        out, err = planning.communicate()
        if planning.returncode != 0:
            line = (err.strip().splitlines() or ["(no message)"])[-1]
            raise RuntimeError(f"terratile plan: exit {planning.returncode}: {line}")
        plan = json.loads(out)
        t_plan = time.time() - t0
        jobs = plan["jobs"]
        done = {}
        for phase in plan["phases"]:
            futures = client.map(
                lambda k, phase=phase: job(
                    a.terratile, ["shard", work, "--phase", phase, "--index", str(k)]
                ),
                range(jobs),
                key=[f"terratile-{phase}-{k}" for k in range(jobs)],
                retries=a.retries,
                pure=False,
            )
            done[phase] = client.gather(futures)
        merged = client.submit(
            job, a.terratile, ["merge", work], key="terratile-merge", retries=a.retries, pure=False
        ).result()
    finally:
        if planning.poll() is None:
            planning.kill()
            planning.wait()
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    print(merged[0])
    # Per phase: from its first job's start to its last job's end.
    spans = []
    for phase, rs in done.items():
        spans.append((phase, max(r[2] for r in rs) - min(r[1] for r in rs)))
    spans.append(("merge", merged[2] - merged[1]))
    cpu = sum(r[3] for rs in done.values() for r in rs) + merged[3]
    print(
        f"{jobs} jobs per phase: "
        + ", ".join(f"{name} {s:.2f} s" for name, s in spans)
        + f"; cluster up at {t_cluster:.2f} s, plan done at {t_plan:.2f} s"
        + f"; jobs' CPU {cpu:.2f} s"
        + f"; total {time.time() - t0:.2f} s"
    )
    if a.profile:
        for phase, rs in [*done.items(), ("merge", [merged])]:
            for k, r in enumerate(rs):
                print(
                    f"  {phase} {k}: {r[4]} {r[1] - t0:7.2f} -> {r[2] - t0:7.2f} s "
                    f"wall {r[2] - r[1]:6.2f} cpu {r[3]:6.2f}"
                )
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except RuntimeError as e:
        print(f"dask_run: {e}", file=sys.stderr)
        sys.exit(2)
