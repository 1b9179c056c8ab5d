"""Benchmark of the exporters: seconds and bytes for USD (each prim kind), meshes and PLY.

    python bench/export.py --json OUT.json [--gaussians 100000] [--frames 48] [--resolution 128]

The model is a synthetic native 4D model (a ball of Gaussians translating and spinning colours, SH degree 3 with
one cosine time degree, a tenth of them short-lived). The reference, measured in the same run, is slicing every
frame into numpy arrays (`iter_frames`), the work every exporter has to do; each row's ratio is its time over the
reference. Target (issue 5): USD splats + instancer of 100k Gaussians over 48 frames in under 30 s.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import torch

from splatreel import quaternion
from splatreel.covariance import covariance_3d, covariance_4d_from_motion, decompose_covariance_4d
from splatreel.export import frame_times, iter_frames
from splatreel.export.mesh import MeshOptions, write_mesh_sequence
from splatreel.export.ply import write_ply_sequence
from splatreel.export.usd import UsdOptions, write_usd
from splatreel.model import Gaussians4D

TARGET_SPLATS_INSTANCER_S = 30.0


def bench_model(n: int, seed: int = 0) -> Gaussians4D:
    """``n`` Gaussians in a unit ball moving at 0.5 units per unit time, SH degree 3 / time degree 1."""
    g = torch.Generator().manual_seed(seed)
    d = torch.float64
    dirs = torch.randn(n, 3, generator=g, dtype=d)
    means = dirs / dirs.norm(dim=1, keepdim=True) * torch.rand(n, 1, generator=g, dtype=d) ** (1 / 3)
    scale = 1.4 / n ** (1 / 3)  # std-dev ~0.7 x the mean spacing: neighbours overlap as in a trained model
    cov3 = covariance_3d(scale * (0.3 + torch.rand(n, 3, generator=g, dtype=d)),
                         quaternion.normalize(torch.randn(n, 4, generator=g, dtype=d)))
    velocity = torch.tensor([0.5, 0.0, 0.1], dtype=d).expand(n, 3)
    var_t = torch.full((n,), 10.0, dtype=d)
    var_t[: n // 10] = 0.01
    t_means = torch.full((n,), 0.5, dtype=d)
    t_means[: n // 10] = torch.rand(n // 10, generator=g, dtype=d)
    s, st, q_l, q_r = decompose_covariance_4d(covariance_4d_from_motion(cov3, velocity, var_t))
    return Gaussians4D(
        means=means, t_means=t_means, log_scales=s.log(), log_t_scales=st.log(), quats_l=q_l, quats_r=q_r,
        opacity_logits=torch.randn(n, generator=g, dtype=d) + 2, sh_dc=torch.randn(n, 1, 3, generator=g, dtype=d),
        sh_rest=0.1 * torch.randn(n, 31, 3, generator=g, dtype=d), sh_degree=3, sh_degree_t=1,
        time_range=(0.0, 1.0)).to(dtype=torch.float32)


def _warm_up() -> None:
    """Pay one-time costs (imports, USD plugin loading, numba compilation, torch's first ops) before timing."""
    small = bench_model(200, seed=1)
    two = frame_times(small.time_range, 2)
    with tempfile.TemporaryDirectory(prefix="splatreel-bench-warm-") as tmp:
        write_usd(small, Path(tmp) / "w.usdc", two)
        write_mesh_sequence(small, Path(tmp) / "m", two, MeshOptions(resolution=16))
        write_ply_sequence(small, Path(tmp) / "p", two)


def _size(paths) -> int:
    return sum(Path(p).stat().st_size for p in paths if Path(p).is_file())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", metavar="OUT", help="also write the results as JSON")
    parser.add_argument("--gaussians", type=int, default=100_000)
    parser.add_argument("--frames", type=int, default=48)
    parser.add_argument("--resolution", type=int, default=128, help="mesh grid resolution")
    parser.add_argument("--skip", default="", help="comma-separated case names to skip")
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's)")
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    load_before = os.getloadavg()[0]

    model = bench_model(args.gaussians)
    times = frame_times(model.time_range, args.frames)
    _warm_up()
    skip = set(filter(None, args.skip.split(",")))
    rows = []
    with tempfile.TemporaryDirectory(prefix="splatreel-bench-export-") as tmp:
        tmp = Path(tmp)

        def run(name, fn):
            if name in skip:
                return
            t0, c0 = time.perf_counter(), time.process_time()
            paths = fn(tmp / name)
            seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
            rows.append({"case": name, "seconds": seconds, "cpu_seconds": cpu, "bytes": _size(paths),
                         "files": len(paths), "load_avg_1min": os.getloadavg()[0]})
            print(f"  {name}: {seconds:.2f} s ({cpu:.2f} s CPU)", file=sys.stderr)

        def slice_all(out):
            for _ in iter_frames(model, times):
                pass
            return []

        run("reference: slice all frames", slice_all)
        for what in (("splats",), ("instancer",), ("points",), ("splats", "instancer")):
            run("usd " + "+".join(what),
                lambda out, what=what: [write_usd(model, out.with_suffix(".usdc"), times, UsdOptions(what=what))])
        run("mesh ply", lambda out: write_mesh_sequence(model, out, times, MeshOptions(resolution=args.resolution)))
        run("ply", lambda out: write_ply_sequence(model, out, times))

    ref = rows[0] if rows and rows[0]["case"].startswith("reference") else None
    for r in rows:
        r["ratio_to_reference"] = r["seconds"] / ref["seconds"] if ref else None
        r["cpu_ratio_to_reference"] = r["cpu_seconds"] / ref["cpu_seconds"] if ref else None
    target = next((r for r in rows if r["case"] == "usd splats+instancer"), None)
    print(f"\nexport benchmark: {args.gaussians:,} Gaussians (SH 3, time degree 1), {args.frames} frames, "
          f"mesh grid {args.resolution}, torch threads {torch.get_num_threads()}, "
          f"load average {load_before:.1f} -> {os.getloadavg()[0]:.1f}")
    print(f"{'case':<30} {'wall s':>8} {'x ref':>6} {'CPU s':>8} {'x ref':>6} {'MiB':>9} {'files':>6}")
    for r in rows:
        ratio = f"{r['ratio_to_reference']:.1f}" if ref else "-"
        cratio = f"{r['cpu_ratio_to_reference']:.1f}" if ref else "-"
        print(f"{r['case']:<30} {r['seconds']:>8.2f} {ratio:>6} {r['cpu_seconds']:>8.2f} {cratio:>6} "
              f"{r['bytes'] / 2**20:>9.1f} {r['files']:>6}")
    if target:
        ok = target["seconds"] < TARGET_SPLATS_INSTANCER_S
        print(f"target: usd splats+instancer < {TARGET_SPLATS_INSTANCER_S:.0f} s wall: "
              f"{'met' if ok else 'MISSED'} ({target['seconds']:.1f} s wall, {target['cpu_seconds']:.1f} s CPU)")
    if args.json:
        doc = {"benchmark": "export", "gaussians": args.gaussians, "frames": args.frames,
               "mesh_resolution": args.resolution, "sh_degree": 3, "sh_degree_t": 1,
               "target_usd_splats_instancer_s": TARGET_SPLATS_INSTANCER_S, "load_avg_1min_before": load_before,
               "machine": {"python": platform.python_version(), "torch_threads": torch.get_num_threads(),
                           "cpu": platform.processor() or platform.machine()},
               "rows": rows}
        Path(args.json).write_text(json.dumps(doc, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
