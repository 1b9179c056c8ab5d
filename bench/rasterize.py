"""Benchmark of the CPU rasterizer (`splatreel.rasterize`) against the dense pure-torch reference.

    python bench/rasterize.py --json OUT.json

For each case (N Gaussians x image size) it times the median wall-clock milliseconds of `rasterize` (forward) and of
forward + backward (``loss.backward()`` through projection, SH colours and the compositing kernels), then the dense
reference of the tests (`tests/dense_rasterizer.py`: every Gaussian against every pixel, float32 here) on a case that
fits in memory: the same Gaussians and camera, but only a band of image rows holding at most ``--ref-elements``
(pixel, Gaussian) pairs, rendered as a full image by both (a camera whose principal point is shifted). The speed-up
is measured on that band: a conservative figure, since the rasterizer's per-Gaussian work (projection, SH) does not
shrink with the band while the reference's cost is proportional to it. ``--ref-full`` runs the reference on the whole
image instead, in row chunks (minutes per case).

Scene: N Gaussians uniform in a unit ball seen from 3.6 units (50 degree FOV), std-devs log-uniform in
[0.006, 0.05] (about 0.5-4 px at 256x256), opacities uniform in [0.05, 0.95], SH degree 3 colours (``--sh-degree``).
The first call of each case (numba cache load, warm-up) is not timed. The 1-minute load average is recorded: other
processes on the machine slow both sides (the minimum over the repeats is reported too, as ``*_min_ms``, and
``--rounds R`` times every case R times, interleaved, keeping the round with the lowest median).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import torch  # noqa: E402
from tqdm import tqdm  # noqa: E402

from splatreel.cameras import Camera, look_at  # noqa: E402
from splatreel.covariance import covariance_3d  # noqa: E402
from splatreel.model import Gaussians3D  # noqa: E402
from splatreel.rasterize import rasterize  # noqa: E402


def make_scene(n: int, sh_degree: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """Leaf tensors (float32) of the benchmark scene; see the module doc."""
    gen = torch.Generator().manual_seed(seed)
    d = torch.randn(n, 3, generator=gen)
    means = d / d.norm(dim=1, keepdim=True) * torch.rand(n, 1, generator=gen) ** (1 / 3)
    log_s = torch.rand(n, 3, generator=gen) * (math.log(0.05) - math.log(0.006)) + math.log(0.006)
    cov = covariance_3d(torch.exp(log_s), torch.randn(n, 4, generator=gen))
    return {"means": means, "covariances": cov, "opacities": torch.rand(n, generator=gen) * 0.9 + 0.05,
            "sh": torch.randn(n, (sh_degree + 1) ** 2, 3, generator=gen) * 0.3}


def make_camera(size: int) -> Camera:
    return look_at((0.0, -3.5, 0.8), (0.0, 0.0, 0.0), "z", 50.0, size, size)


def band_camera(cam: Camera, rows: int) -> Camera:
    """The same camera rendering only `rows` rows around the image centre (a horizontal band of the image)."""
    top = (cam.height - rows) // 2
    return replace(cam, cy=cam.cy - top, height=rows)


def _leaves(scene: dict[str, torch.Tensor], sh_degree: int) -> Gaussians3D:
    t = {k: v.clone().requires_grad_() for k, v in scene.items()}
    return Gaussians3D(**t, visible=torch.ones(scene["means"].shape[0], dtype=torch.bool), sh_degree=sh_degree)


def _median_ms(samples: list[float]) -> float:
    return 1e3 * statistics.median(samples)


def time_rasterizer(scene, cam, sh_degree: int, repeats: int) -> tuple[float, float, float, float]:
    """(forward ms, forward + backward ms) medians over `repeats` after one warm-up call, then the two minima."""
    g = _leaves(scene, sh_degree)
    weights = torch.rand(cam.height, cam.width, 3, generator=torch.Generator().manual_seed(1))
    fwd, total = [], []
    for i in range(repeats + 1):
        t0 = time.perf_counter()
        out = rasterize(g, cam)
        t1 = time.perf_counter()
        ((out.rgb * weights).sum() + out.alpha.sum()).backward()
        t2 = time.perf_counter()
        if i:
            fwd.append(t1 - t0)
            total.append(t2 - t0)
    return _median_ms(fwd), _median_ms(total), 1e3 * min(fwd), 1e3 * min(total)


def time_reference(scene, cam, sh_degree: int, repeats: int, chunk_elements: float) -> float:
    """Forward + backward ms of the dense reference (row chunks of at most `chunk_elements` pairs)."""
    from dense_rasterizer import dense_render

    n = scene["means"].shape[0]
    rows_per_chunk = max(1, int(chunk_elements // (n * cam.width)))
    weights = torch.rand(cam.height, cam.width, 3, generator=torch.Generator().manual_seed(1))
    samples = []
    for _ in range(repeats):
        g = _leaves(scene, sh_degree)
        t0 = time.perf_counter()
        for r0 in range(0, cam.height, rows_per_chunk):
            r1 = min(cam.height, r0 + rows_per_chunk)
            out = dense_render(g, cam, rows=(r0, r1))
            ((out["rgb"] * weights[r0:r1]).sum() + out["alpha"].sum()).backward()
        samples.append(time.perf_counter() - t0)
    return _median_ms(samples)


def compile_times() -> dict[str, float]:
    """Seconds for import + first forward/backward with an empty numba cache (compiles), then with it filled."""
    code = ("import time; t0 = time.perf_counter(); import torch; t1 = time.perf_counter()\n"
            "from splatreel.rasterize import rasterize\n"
            "from splatreel.model import Gaussians3D; from splatreel.cameras import look_at\n"
            "g = Gaussians3D(means=torch.zeros(1, 3, requires_grad=True), covariances=0.01 * torch.eye(3)[None],"
            " opacities=torch.full((1,), 0.5), sh=torch.zeros(1, 1, 3), visible=torch.ones(1, dtype=torch.bool),"
            " sh_degree=0)\n"
            "out = rasterize(g, look_at((0, -3, 0), (0, 0, 0), 'z', 50, 32, 32)); out.rgb.sum().backward()\n"
            "print(time.perf_counter() - t1)")
    result = {}
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for key in ("cold_compile_s", "cached_s"):
            out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
            result[key] = round(float(out.stdout.strip().splitlines()[-1]), 2)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=Path, help="write the results to this JSON file")
    parser.add_argument("--counts", type=int, nargs="+", default=[20_000, 50_000, 200_000], help="Gaussian counts")
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 512], help="square image sizes")
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per case (median)")
    parser.add_argument("--rounds", type=int, default=1,
                        help="time the rasterizer in this many rounds over all cases and keep, per case, the round "
                             "with the lowest median forward+backward (robustness to other processes)")
    parser.add_argument("--ref-repeats", type=int, default=3, help="timed reference calls per case (median)")
    parser.add_argument("--ref-elements", type=float, default=3.2e7,
                        help="(pixel, Gaussian) pairs of the reference band (about 40 bytes each in memory)")
    parser.add_argument("--ref-full", action="store_true",
                        help="run the reference on the whole image (row chunks; minutes per case)")
    parser.add_argument("--sh-degree", type=int, default=3, choices=range(4), help="SH degree of the colours")
    parser.add_argument("--no-compile", action="store_true", help="skip measuring the first-compile time")
    args = parser.parse_args(argv)

    todo = [(n, s) for s in args.sizes for n in args.counts]

    def ref_camera(n: int, size: int) -> Camera:
        cam = make_camera(size)
        return cam if args.ref_full else band_camera(cam, max(1, min(size, int(args.ref_elements // (n * size)))))

    best: dict[tuple, tuple] = {}  # (n, size, camera height) -> timings of the round with the lowest median
    with tqdm(total=len(todo) * (args.rounds + 1), desc="rasterize bench", unit="case") as bar:
        for _ in range(args.rounds):
            for n, size in todo:
                scene = make_scene(n, args.sh_degree)
                band = ref_camera(n, size)
                for cam in [make_camera(size)] + ([band] if band.height < size else []):
                    timing = time_rasterizer(scene, cam, args.sh_degree, args.repeats) + (os.getloadavg()[0],)
                    key = (n, size, cam.height)
                    if key not in best or timing[1] < best[key][1]:
                        best[key] = timing
                bar.update()
        cases = []
        for n, size in todo:
            scene = make_scene(n, args.sh_degree)
            fwd, fwdbwd, fwd_min, fwdbwd_min, load = best[n, size, size]
            case = {"n": n, "size": size, "fwd_ms": round(fwd, 2), "fwdbwd_ms": round(fwdbwd, 2),
                    "fwd_min_ms": round(fwd_min, 2), "fwdbwd_min_ms": round(fwdbwd_min, 2)}
            ref_cam = ref_camera(n, size)
            ours_on_ref = best[n, size, ref_cam.height][1]
            ref = time_reference(scene, ref_cam, args.sh_degree, 1 if args.ref_full else args.ref_repeats,
                                 args.ref_elements)
            case.update({"ref_fwdbwd_ms": round(ref, 2), "speedup": round(ref / ours_on_ref, 1),
                         "ref_case": f"{n} Gaussians, {ref_cam.width}x{ref_cam.height} px",
                         "ours_on_ref_case_fwdbwd_ms": round(ours_on_ref, 2), "load_avg_1min": round(load, 2)})
            cases.append(case)
            bar.update()

    compile_info = {} if args.no_compile else compile_times()
    print(f"\nsplatreel rasterizer, {torch.get_num_threads()} torch threads, SH degree {args.sh_degree} "
          f"(median ms; reference = dense torch oracle on the case shown)")
    header = (f"{'N':>8} {'size':>5} {'fwd':>8} {'fwd+bwd':>9} {'(min)':>7} | {'reference case':>28} "
              f"{'ref fwd+bwd':>12} {'ours':>8} {'speed-up':>9} {'load':>5}")
    print(header)
    print("-" * len(header))
    for c in cases:
        print(f"{c['n']:>8} {c['size']:>5} {c['fwd_ms']:>8.1f} {c['fwdbwd_ms']:>9.1f} {c['fwdbwd_min_ms']:>7.1f} | "
              f"{c['ref_case']:>28} "
              f"{c['ref_fwdbwd_ms']:>12.1f} {c['ours_on_ref_case_fwdbwd_ms']:>8.1f} {c['speedup']:>8.1f}x "
              f"{c['load_avg_1min']:>5.2f}")
    if compile_info:
        print(f"numba: first call with an empty cache {compile_info['cold_compile_s']} s (compiles), "
              f"with the cache {compile_info['cached_s']} s (import + first forward/backward)")
    if args.json:
        payload = {"cases": cases, "compile": compile_info, "threads": torch.get_num_threads(),
                   "sh_degree": args.sh_degree, "cpu_count": os.cpu_count(), "rounds": args.rounds,
                   "repeats": args.repeats}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
