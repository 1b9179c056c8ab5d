"""Run the jobs of a jobs file (`splatreel.batch.jobs`), N at a time in worker processes, with a report.

Nothing lost, nothing twice: each job runs its commands in order in its own folder ``OUT/NAME/`` (every output is
written atomically by the command itself); ``OUT/report.json`` (and ``OUT/summary.csv`` with the eval metrics) is
rewritten atomically as each job ends, with its status, step timings, outputs and one-line error. Running the same
batch again skips the jobs that are done (their outputs still there) and, with ``retry_failed``, runs the failed
ones again. A failing job fails alone; Ctrl-C stops the workers and keeps what finished.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

from ..fileio import atomic_write_bytes, atomic_write_json
from .jobs import Job, commands

REPORT = "report.json"
SUMMARY = "summary.csv"
# LP_NUM_THREADS: Mesa llvmpipe, the OpenGL of render on a CPU, otherwise starts a thread per core
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS",
                    "LP_NUM_THREADS")


def limit_threads(threads: int) -> None:
    """Keep one worker to `threads` CPU threads (set before torch/numba start in the worker process)."""
    for name in THREAD_VARIABLES:
        os.environ[name] = str(threads)


def run_job(job: Job, folder: str, threads: int = 1) -> dict:
    """Run `job`'s commands in order (in this process) and return its report entry; the first failing command
    ends the job with its one-line error."""
    limit_threads(threads)
    import torch

    torch.set_num_threads(threads)
    from ..cli import main

    folder_path = Path(folder)
    folder_path.mkdir(parents=True, exist_ok=True)
    entry = {"name": job.name, "input": job.input, "status": "done", "steps": [], "error": None}
    started = time.time()
    for cmd in commands(job, folder_path):
        t0 = time.time()
        err, out = io.StringIO(), io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
                code = main(list(cmd.argv))
        except SystemExit as exc:  # a usage error in the jobs file's options
            code = exc.code if isinstance(exc.code, int) else 2
        except Exception as exc:  # noqa: BLE001  (a bug must not take the batch down: report it, go on)
            code, err = 1, io.StringIO(f"splatreel {cmd.step}: error: {type(exc).__name__}: {exc}")
        step = {"step": cmd.step, "seconds": round(time.time() - t0, 2), "output": str(cmd.output),
                "argv": list(cmd.argv)}
        entry["steps"].append(step)
        if code != 0:
            lines = [line for line in err.getvalue().splitlines() if "error" in line] or \
                err.getvalue().strip().splitlines() or [f"exit code {code}"]
            entry.update(status="failed", error=lines[-1].strip(), failed_step=cmd.step)
            break
        if cmd.step == "eval":
            result = json.loads(cmd.output.read_text())
            entry["metrics"] = {k: result.get(k) for k in ("psnr", "ssim", "num_views")}
    entry["seconds"] = round(time.time() - started, 2)
    return entry


def load_report(out: Path) -> dict:
    """The report of an earlier run into `out` (empty when there is none)."""
    path = out / REPORT
    if not path.exists():
        return {"jobs": {}}
    try:
        return json.loads(path.read_text())
    except ValueError:
        return {"jobs": {}}


def is_done(entry: dict | None) -> bool:
    """A job that finished and whose outputs are all still there."""
    return bool(entry and entry.get("status") == "done" and all(Path(s["output"]).exists() for s in entry["steps"]))


def write_report(out: Path, report: dict, order: list[str] | None = None) -> None:
    """``report.json`` and ``summary.csv`` (name, status, seconds, psnr, ssim, error), atomically; jobs in the jobs
    file's `order` (others after)."""
    import csv

    rank = {name: i for i, name in enumerate(order or [])}
    report["jobs"] = dict(sorted(report["jobs"].items(), key=lambda item: rank.get(item[0], len(rank))))
    atomic_write_json(out / REPORT, report, force=True)
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(["name", "status", "seconds", "psnr", "ssim", "error"])
    for name, entry in report["jobs"].items():
        metrics = entry.get("metrics") or {}
        writer.writerow([name, entry.get("status"), entry.get("seconds"), metrics.get("psnr"), metrics.get("ssim"),
                         entry.get("error") or ""])
    atomic_write_bytes(out / SUMMARY, buffer.getvalue().encode(), force=True)


def pending_jobs(jobs: list[Job], report: dict, retry_failed: bool) -> list[Job]:
    """The jobs to run: not done (or done with outputs gone), and failed ones only with `retry_failed`."""
    todo = []
    for job in jobs:
        entry = report["jobs"].get(job.name)
        if is_done(entry) or (entry and entry.get("status") == "failed" and not retry_failed):
            continue
        todo.append(job)
    return todo


def run_batch(jobs: list[Job], out: str | Path, workers: int = 1, threads: int = 1, retry_failed: bool = False,
              progress: bool = True, ray_address: str | None = None) -> dict:
    """Run `jobs` into `out` (see module doc): in `workers` local processes, or as tasks of the Ray cluster at
    `ray_address` (each declaring `threads` CPUs; `out` must be a path every node sees). Returns the report
    (``jobs``: name -> entry)."""
    from tqdm import tqdm

    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    report = load_report(out)
    report.setdefault("jobs", {})
    order = [job.name for job in jobs]
    todo = pending_jobs(jobs, report, retry_failed)
    counts = {"done": sum(is_done(report["jobs"].get(n)) for n in order)}
    counts["failed"] = sum((report["jobs"].get(j.name) or {}).get("status") == "failed" for j in jobs
                           if j not in todo)
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc="batch", unit="job", disable=not progress)
    bar.set_postfix(done=counts["done"], failed=counts["failed"], left=len(todo))

    def finished(job: Job, entry: dict, left: int) -> None:
        report["jobs"][job.name] = entry
        counts["done" if entry["status"] == "done" else "failed"] += 1
        write_report(out, report, order)
        bar.update(1)
        bar.set_postfix(done=counts["done"], failed=counts["failed"], left=left)

    try:
        if ray_address is None:
            _run_local(todo, out, workers, threads, finished)
        else:
            _run_ray(todo, out, ray_address, threads, finished)
    finally:
        write_report(out, report, order)
        bar.close()
    return report


def _failed(job: Job, exc: BaseException) -> dict:
    return {"name": job.name, "input": job.input, "status": "failed", "steps": [],
            "error": f"the worker stopped: {type(exc).__name__}: {exc}"}


def _run_local(todo: list[Job], out: Path, workers: int, threads: int, finished) -> None:
    import multiprocessing

    # spawn: each worker starts clean (no forked torch/OpenMP state)
    with ProcessPoolExecutor(max_workers=max(1, workers), mp_context=multiprocessing.get_context("spawn")) as pool:
        pending = {pool.submit(run_job, job, str(out / job.name), threads): job for job in todo}
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    job = pending.pop(future)
                    try:
                        entry = future.result()
                    except Exception as exc:  # noqa: BLE001  (a worker that died)
                        entry = _failed(job, exc)
                    finished(job, entry, len(pending))
        except KeyboardInterrupt:
            pool.shutdown(wait=False, cancel_futures=True)
            raise


def _run_ray(todo: list[Job], out: Path, address: str, threads: int, finished) -> None:
    """Each job a Ray task declaring `threads` CPUs (``ray[default]``, the optional extra ``splatreel[ray]``)."""
    try:
        import ray
    except ImportError:
        from ..errors import SplatreelError

        raise SplatreelError("--ray needs Ray: pip install 'splatreel[ray]'") from None
    ray.init(address=address, logging_level="ERROR", log_to_driver=False)
    try:
        task = ray.remote(num_cpus=threads)(run_job)
        pending = {task.remote(job, str(out / job.name), threads): job for job in todo}
        try:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    job = pending.pop(ref)
                    try:
                        entry = ray.get(ref)
                    except Exception as exc:  # noqa: BLE001  (a task or node that died)
                        entry = _failed(job, exc)
                    finished(job, entry, len(pending))
        except KeyboardInterrupt:
            for ref in pending:
                ray.cancel(ref, force=True)
            raise
    finally:
        ray.shutdown()
