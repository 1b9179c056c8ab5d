"""``splatreel batch JOBS --out DIR``: run the commands a jobs file lists on many inputs, N at a time."""

from __future__ import annotations

import argparse

ORDER = 70
HELP = "run a jobs file (train, eval, render, export ... on many inputs), several at a time, with a report"
DESCRIPTION = """Run the steps a jobs file lists for each input (train, convert, eval, render, export FORMAT), each
job in its own folder DIR/NAME, JOBS at a time in worker processes. DIR/report.json (and DIR/summary.csv with the
eval metrics) records every job's status, step timings, outputs and one-line error as it ends. Running the same
batch again skips the jobs that are done; --retry-failed runs the failed ones again. A failing job fails alone;
the command exits 1 if any job failed. The jobs file format is in the docs (Commands > batch).

examples:
  splatreel batch jobs.yaml --out runs/
  splatreel batch jobs.csv --out runs/ --workers 2 --threads 1
  splatreel batch jobs.yaml --out runs/ --retry-failed
"""


def add_args(p: argparse.ArgumentParser) -> None:
    from ..argtypes import count

    p.add_argument("jobs", metavar="JOBS", help="jobs file (.yaml/.yml or .csv)")
    p.add_argument("--out", "-o", required=True, metavar="DIR", help="folder of the jobs' folders and the report")
    p.add_argument("--workers", type=count, default=None, metavar="N",
                   help="jobs run at a time (default: the CPU cores / --threads)")
    p.add_argument("--threads", type=count, default=1, metavar="T",
                   help="CPU threads per job (default 1; workers x threads should fit the cores)")
    p.add_argument("--retry-failed", action="store_true", help="run the jobs that failed before again")
    p.add_argument("--ray", metavar="ADDRESS", default=None,
                   help="run each job as a task of the Ray cluster at ADDRESS (host:port, or 'auto'), each declaring "
                        "--threads CPUs; DIR and the inputs must be on a path every node sees (needs splatreel[ray])")
    p.add_argument("--dry-run", action="store_true", help="print each job's commands and run nothing")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    import os
    import shlex
    from pathlib import Path

    from ..batch import commands, read_jobs, run_batch

    jobs = read_jobs(args.jobs)
    if args.dry_run:
        for job in jobs:
            for cmd in commands(job, Path(args.out) / job.name):
                print(f"{job.name}: splatreel {shlex.join(cmd.argv)}")
        return 0
    workers = args.workers or max(1, (os.cpu_count() or 1) // args.threads)
    report = run_batch(jobs, args.out, workers=workers, threads=args.threads, retry_failed=args.retry_failed,
                       progress=not args.quiet, ray_address=args.ray)
    entries = [report["jobs"][j.name] for j in jobs if j.name in report["jobs"]]
    failed = [e for e in entries if e["status"] == "failed"]
    for e in failed:
        print(f"failed: {e['name']}: {e['error']}")
    print(f"{len(entries) - len(failed)} of {len(jobs)} job(s) done, {len(failed)} failed; report in "
          f"{Path(args.out) / 'report.json'}")
    return 1 if failed else 0
