"""The CUDA path against the CPU path: the same images and gradients, and the time of one training image on each.

    python bench/cuda_path.py [--json OUT.json] [--model samples/spinner.safetensors] [--size 256] [--views 6]

Needs a CUDA device (it says so in one line and exits 2 without one). For the model (default: the bundled sample,
with its recorded training cameras, each at its own time), rendered at `--size`:

* parity: per view, PSNR between the image rendered with every tensor on the CUDA device and the one rendered on
  the CPU (both float32), and the largest alpha difference; then, for the same loss (a fixed random weighting of
  the colours plus the alpha), the relative L2 error of each 4D parameter's CUDA gradient against its CPU gradient.
  The CPU path is what every test holds against the dense reference, so this is the check that the CUDA path
  computes the same model.
* speed: median milliseconds of slice + rasterize forward + backward of one image on each device (CUDA timings
  synchronised), after a warm-up, and their ratio.
* `--profile N`: the N torch operators (and kernels) that took the most time on the device over a few images, from
  `torch.profiler`, to see where a step's time goes there.

(The file is not called ``cuda.py``: run as a script, its folder comes first on ``sys.path``, and torch's own
``import cuda.bindings`` would find it.)

Which compositor ran on the CUDA device is reported: gsplat's `rasterize_to_pixels` when gsplat is importable
(``pip install splatreel[cuda]``), else the numba kernels on the host with the tensors copied there and back.
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

from report import write_json  # bench/report.py, this script's neighbour

import torch

ROOT = Path(__file__).resolve().parents[1]


def _leaves(model, device):
    """The model on `device`, float32, every per-Gaussian tensor a leaf that records its gradient."""
    m = model.to(device=device, dtype=torch.float32)
    if m.kind == "skinned":  # what training learns: the canonical Gaussians (the nodes carry them)
        return replace(m, gaussians=_leaves(m.gaussians, device))
    return replace(m, **{k: v.detach().clone().requires_grad_() for k, v in m.tensors().items()})


def _render(model, view, background, device):
    from splatreel.rasterize import rasterize

    return rasterize(model.slice(view.time), view.camera, background.to(device))


def _sync(device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def parity(model, views, background, cuda) -> dict:
    """Image PSNR and alpha difference per view, and per-parameter relative gradient error over all views."""
    cpu = torch.device("cpu")
    per_view, grads = [], {}
    for i, view in enumerate(views):
        weights = torch.rand(view.camera.height, view.camera.width, 3, generator=torch.Generator().manual_seed(i))
        outs = []
        for device in (cpu, cuda):
            m = _leaves(model, device)
            out = _render(m, view, background, device)
            ((out.rgb * weights.to(device)).sum() + out.alpha.sum()).backward()
            outs.append((out.rgb.detach().cpu(), out.alpha.detach().cpu(),
                         {k: v.grad.cpu() for k, v in m.tensors().items() if v.grad is not None}))
        (rgb_c, a_c, g_c), (rgb_g, a_g, g_g) = outs
        mse = float(((rgb_c - rgb_g) ** 2).mean())  # unclamped (`train.losses.psnr` clamps one side to [0, 1])
        per_view.append({"time": round(view.time, 4), "psnr": math.inf if mse == 0 else round(-10 * math.log10(mse), 2),
                         "alpha_max_diff": float((a_c - a_g).abs().max())})
        for k in g_c:
            num, den = grads.setdefault(k, [0.0, 0.0])
            grads[k] = [num + float(((g_c[k] - g_g[k]) ** 2).sum()), den + float((g_c[k] ** 2).sum())]
    rel = {k: round(math.sqrt(n / d), 6) if d > 0 else None for k, (n, d) in grads.items()}
    return {"views": per_view, "min_psnr": min(v["psnr"] for v in per_view), "grad_rel_error": rel}


def time_step(model, views, background, device, repeats: int) -> float:
    """Median ms of slice + rasterize forward + backward per image (views in turn), after one warm-up pass."""
    m = _leaves(model, device)
    samples = []
    for r in range(repeats + len(views)):
        view = views[r % len(views)]
        _sync(device)
        t0 = time.perf_counter()
        out = _render(m, view, background, device)
        (out.rgb.sum() + out.alpha.sum()).backward()
        _sync(device)
        if r >= len(views):
            samples.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(samples)


def profile_step(model, views, background, device, rows: int) -> str:
    """`torch.profiler`'s table of the `rows` most expensive operators over one image per view (after a warm-up)."""
    from torch.profiler import ProfilerActivity, profile

    m = _leaves(model, device)
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    for _ in range(2):  # the first pass warms up; the table is the second's
        with profile(activities=activities) as prof:
            for view in views:
                out = _render(m, view, background, device)
                (out.rgb.sum() + out.alpha.sum()).backward()
            _sync(device)
    key = "self_cuda_time_total" if device.type == "cuda" else "self_cpu_time_total"
    return prof.key_averages().table(sort_by=key, row_limit=rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", type=Path, help="write the results to this JSON file")
    ap.add_argument("--model", type=Path, default=ROOT / "samples" / "spinner.safetensors", help="checkpoint")
    ap.add_argument("--size", type=int, default=256, help="image size (the recorded cameras are rescaled)")
    ap.add_argument("--views", type=int, default=6, help="recorded training views used (spread over the list)")
    ap.add_argument("--repeats", type=int, default=20, help="timed images per device (median)")
    ap.add_argument("--profile", type=int, default=0, metavar="N",
                    help="print the N operators that took the most time on the device (torch.profiler)")
    ap.add_argument("--device", default="cuda", help="the device held against the CPU ('cpu' checks this script)")
    args = ap.parse_args(argv)

    from splatreel.checkpoint import load_checkpoint
    from splatreel.errors import SplatreelError
    from splatreel.rasterize import uses_gsplat

    cuda = torch.device(args.device)
    if cuda.type == "cuda" and not torch.cuda.is_available():
        print("bench/cuda_path.py: no CUDA device (torch.cuda.is_available() is False)", file=sys.stderr)
        return 2
    try:
        ckpt = load_checkpoint(args.model)
    except SplatreelError as exc:
        print(f"bench/cuda_path.py: {exc}", file=sys.stderr)
        return 2
    if not ckpt.views:
        print(f"bench/cuda_path.py: {args.model} records no training cameras", file=sys.stderr)
        return 2
    step = max(1, len(ckpt.views) // args.views)
    views = [replace(v, camera=v.camera.resized(args.size, args.size)) for v in ckpt.views[::step][:args.views]]
    background = torch.tensor(ckpt.background, dtype=torch.float32)
    model = ckpt.model

    par = parity(model, views, background, cuda)
    cpu_ms = time_step(model, views, background, torch.device("cpu"), args.repeats)
    cuda_ms = time_step(model, views, background, cuda, args.repeats)
    name = torch.cuda.get_device_name(cuda) if cuda.type == "cuda" else cuda.type
    result = {"device": name, "torch": torch.__version__,
              "compositor": "gsplat" if uses_gsplat(cuda) else "numba on the host", "model": str(args.model),
              "n_gaussians": len(model), "size": args.size, "cpu_threads": torch.get_num_threads(),
              "machine": platform.processor() or platform.machine(), **par,
              "cpu_ms": round(cpu_ms, 2), "cuda_ms": round(cuda_ms, 2), "speedup": round(cpu_ms / cuda_ms, 2)}

    print(f"{result['device']}, torch {result['torch']}, compositor on CUDA: {result['compositor']}; "
          f"{len(model):,} Gaussians at {args.size}x{args.size}, {len(views)} views")
    print(f"image PSNR {cuda} vs CPU: min {par['min_psnr']} dB "
          f"(per view {', '.join(str(v['psnr']) for v in par['views'])}); alpha max diff "
          f"{max(v['alpha_max_diff'] for v in par['views']):.2e}")
    print(f"gradient relative L2 error, {cuda} vs CPU:")
    for k, v in par["grad_rel_error"].items():
        print(f"  {k:<16}{v}")
    print(f"\n{'device':<8}{'slice+fwd+bwd ms':>18}\n{'cpu':<8}{cpu_ms:>18.2f}\n{str(cuda):<8}{cuda_ms:>18.2f}"
          f"\nspeed-up {cpu_ms / cuda_ms:.2f}x ({torch.get_num_threads()} CPU threads)")
    if args.profile:
        print(profile_step(model, views, background, cuda, args.profile))
    if args.json:
        write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
