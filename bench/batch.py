"""Wall time of ``splatreel batch`` on 8 small jobs: 1 and 2 local workers and a local Ray cluster (2 CPUs), with
the speed-up against 1 worker measured in the same run.

    python bench/batch.py [--json OUT.json] [--jobs 8] [--no-ray]

Each job renders a tiny procedural sample's exact model to a short video and exports it to PLY and glTF (a few
seconds of work, most of it start-up: importing torch in a fresh worker); the inputs are made once.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from splatreel.cli import main


def make_inputs(root: Path, jobs: int) -> Path:
    assert main(["sample", "wave", "--model", str(root / "wave.safetensors"), "--gaussians", "20000"]) == 0
    lines = ["defaults:", "  render: {size: 320x240, frame-count: 24}", "jobs:"]
    for i in range(jobs):
        lines += [f"  - name: job{i}", "    input: wave.safetensors", "    steps: [render, export ply, export gltf]",
                  "    export gltf: {frame-count: 1}"]
    (root / "jobs.yaml").write_text("\n".join(lines) + "\n")
    return root / "jobs.yaml"


def timed(argv: list[str]) -> float:
    start = time.perf_counter()
    code = main(argv)
    assert code == 0, argv
    return time.perf_counter() - start


def ray_cluster(tmp: Path):
    ray = shutil.which("ray", path=os.path.dirname(sys.executable)) or "ray"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_TMPDIR": str(tmp)}
    subprocess.run([ray, "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}", "--num-cpus=2",
                    "--include-dashboard=false", "--disable-usage-stats"], check=True, env=env, capture_output=True)
    return f"127.0.0.1:{port}", lambda: subprocess.run([ray, "stop", "--force"], env=env, capture_output=True)


def run(jobs: int, with_ray: bool) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        jobs_file = make_inputs(root, jobs)
        base = None
        for name, extra in (("1 worker", ["--workers", "1"]), ("2 workers", ["--workers", "2"])):
            seconds = timed(["batch", str(jobs_file), "--out", str(root / name.replace(" ", "-")), "--quiet", *extra])
            base = base or seconds
            rows.append({"mode": name, "jobs": jobs, "seconds": round(seconds, 2), "speedup": round(base / seconds, 2)})
        if with_ray:
            address, stop = ray_cluster(root / "ray")
            try:
                seconds = timed(["batch", str(jobs_file), "--out", str(root / "ray-out"), "--quiet", "--ray", address])
            finally:
                stop()
            rows.append({"mode": "Ray, 2 CPUs", "jobs": jobs, "seconds": round(seconds, 2),
                         "speedup": round(base / seconds, 2)})
    return rows


def main_cli() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", metavar="OUT", help="also write the rows as JSON")
    p.add_argument("--jobs", type=int, default=8)
    p.add_argument("--no-ray", action="store_true")
    args = p.parse_args()
    rows = run(args.jobs, not args.no_ray)
    print(f"{'mode':<14}{'jobs':>6}{'seconds':>10}{'speed-up':>10}")
    for r in rows:
        print(f"{r['mode']:<14}{r['jobs']:>6}{r['seconds']:>10.2f}{r['speedup']:>9.2f}x")
    if args.json:
        Path(args.json).write_text(json.dumps({"cpus": os.cpu_count(), "rows": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main_cli()
