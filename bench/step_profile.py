"""Where a training step's time goes: torch.profiler over full-resolution steps of the default recipe.

    python bench/step_profile.py DATA [--device auto|cpu|cuda] [--steps 20] [--profiled 3] [--rows 25] [--json OUT]

Sets a trainer up on the dataset DATA with the default recipe (`splatreel train DATA` without options), moves it
past the resolution ramp and the flow-based motion (their one-off work is not a step's), and times `--steps` steps
(synchronised on a GPU). Then it profiles `--profiled` more and prints the operators that took the most host time
and, on a GPU, the most device time, with the per-step counts of what a GPU path has to keep low: kernel launches,
host waits on the device (stream synchronisations, `item`, `nonzero`) and copies. The GPU's busy share (its
kernels' time over the step's wall time) says whether the step waits on the device or on the host.

The bench/train.py breakdown times phases of one image with a synchronisation between them; this script sees a
whole step as the trainer runs it.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import platform
import sys
import tempfile
import time
from pathlib import Path

from report import write_json  # bench/report.py, this script's neighbour

#: Operators counted per step (host waits, launches, copies).
COUNTED = ("cudaLaunchKernel", "cudaStreamSynchronize", "cudaMemcpyAsync", "aten::item", "aten::nonzero",
           "aten::copy_")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path, help="dataset folder (as `splatreel train` reads it)")
    ap.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"], help="compute device")
    ap.add_argument("--steps", type=int, default=20, help="steps timed without the profiler")
    ap.add_argument("--profiled", type=int, default=3, help="steps under the profiler")
    ap.add_argument("--rows", type=int, default=25, help="operators listed per table")
    ap.add_argument("--json", type=Path, help="write the results to this JSON file")
    args = ap.parse_args(argv)

    import torch
    from torch.profiler import ProfilerActivity, profile

    from splatreel.errors import SplatreelError
    from splatreel.rasterize import uses_gsplat
    from splatreel.train.data import load_dataset
    from splatreel.train.recipe import auto_recipe, read_traits
    from splatreel.train.trainer import Trainer

    t0 = time.perf_counter()
    try:
        ds = load_dataset(args.data)
    except SplatreelError as exc:
        print(f"bench/step_profile.py: {exc}", file=sys.stderr)
        return 2
    cfg, _ = auto_recipe(read_traits(ds))
    cfg = dataclasses.replace(cfg, minutes=None, device=args.device)
    with tempfile.TemporaryDirectory() as tmp:
        tr = Trainer(ds, cfg, Path(tmp) / "m.safetensors", progress=False)
        ramp_end = max((frac for frac, _ in cfg.resolution_ramp), default=0.0)
        tr.step = int(cfg.iters * max(ramp_end, cfg.flow_motion_at)) + 1
        tr._flow_motion_done = True  # its one-off optical flow is not a step's work
        cuda = tr.device.type == "cuda"
        sync = torch.cuda.synchronize if cuda else (lambda: None)
        tr.train_step()
        tr.train_step()
        sync()
        setup_s = time.perf_counter() - t0
        t = time.perf_counter()
        for _ in range(args.steps):
            tr.train_step()
        sync()
        step_ms = 1e3 * (time.perf_counter() - t) / args.steps
        activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
        with profile(activities=activities) as prof:
            for _ in range(args.profiled):
                tr.train_step()
            sync()
        n_gaussians = len(tr.params["means"])
    events = prof.key_averages()
    per_step = {k: 0.0 for k in COUNTED}
    for e in events:
        if e.key in per_step:
            per_step[e.key] = e.count / args.profiled
    device_ms = sum(e.self_device_time_total for e in events
                    if e.device_type == torch.autograd.DeviceType.CUDA) / 1e3 / args.profiled if cuda else None
    top = sorted(events, key=lambda e: e.self_cpu_time_total, reverse=True)[: args.rows]
    result = {
        "data": str(args.data), "device": torch.cuda.get_device_name() if cuda else platform.processor() or "cpu",
        "compositor": "gsplat" if uses_gsplat(tr.device) else "numba", "torch": torch.__version__,
        "threads": torch.get_num_threads(), "gaussians": n_gaussians, "batch_size": cfg.batch_size,
        "setup_seconds": round(setup_s, 1), "ms_per_step": round(step_ms, 2),
        "ms_per_image": round(step_ms / cfg.batch_size, 2),
        "device_busy_ms_per_step": None if device_ms is None else round(device_ms, 2),
        "per_step": {k: round(v, 1) for k, v in per_step.items()},
        "top_host_ops": [{"name": e.key, "self_host_ms_per_step": round(e.self_cpu_time_total / 1e3 / args.profiled, 3),
                          "calls_per_step": round(e.count / args.profiled, 1)} for e in top],
    }
    print(f"{result['device']} ({result['compositor']} compositing), {n_gaussians:,} Gaussians, "
          f"{cfg.batch_size} images a step; set-up {setup_s:.1f} s")
    busy = "" if device_ms is None else f"; the GPU busy {device_ms:.1f} ms of it ({100 * device_ms / step_ms:.0f} %)"
    print(f"{step_ms:.1f} ms a step, {step_ms / cfg.batch_size:.2f} ms an image{busy}")
    print("per step: " + ", ".join(f"{k} {v:.0f}" for k, v in per_step.items() if v))
    if cuda:
        print(events.table(sort_by="self_cuda_time_total", row_limit=args.rows))
    print(events.table(sort_by="self_cpu_time_total", row_limit=args.rows))
    if args.json:
        write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
