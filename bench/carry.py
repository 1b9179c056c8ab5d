"""The fused CPU carry of skinned Gaussians (`splatreel.carrying`) against the torch composition it replaced.

    python bench/carry.py [--json OUT.json] [--model samples/spinner.safetensors] [--repeats 12]

For the model (default: the bundled sample, a skinned model; float32 on the CPU), at the sample's first training
camera's time: the median milliseconds of carrying every Gaussian by its nodes, forward and backward (the means,
covariances and node poses all recording gradients), by `splatreel.skinned.carry` (torch) and by
`splatreel.carrying.fused_carry`, timed in turn in the same run, and their ratio; then one training image of the
model as training draws it (slice, which carries by the fused kernel, + rasterize, forward and backward at 256 px),
to show the carry's share of an image before and after.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # cuda_path, report: this script's neighbours

from report import write_json  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def _median_ms(fn, repeats: int) -> float:
    fn()  # warm-up (and the kernels' compilation on an empty cache)
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(samples)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=ROOT / "samples" / "spinner.safetensors",
                    help="a skinned checkpoint (default: the bundled sample)")
    ap.add_argument("--repeats", type=int, default=12, help="timed runs of each (the median is reported)")
    ap.add_argument("--json", type=Path, help="write the results to this JSON file")
    args = ap.parse_args(argv)

    from cuda_path import time_step

    from splatreel.carrying import fused_carry
    from splatreel.checkpoint import load_checkpoint
    from splatreel.errors import SplatreelError
    from splatreel.samples import DatasetConfig, train_views
    from splatreel.skinned import carry

    try:
        model = load_checkpoint(args.model).model.to(dtype=torch.float32)
    except SplatreelError as exc:
        print(f"bench/carry.py: {exc}", file=sys.stderr)
        return 2
    if model.kind != "skinned":
        print(f"bench/carry.py: {args.model} holds a {model.kind} model, not a skinned one", file=sys.stderr)
        return 2
    view = train_views(DatasetConfig())[0]
    with torch.no_grad():
        cov = model.gaussians.slice(view.time).covariances
    nodes, weights = model.skin
    canonical = model.node_canonical.float()
    rows = torch.arange(len(model))

    def leaves():
        positions, turns = (x.float() for x in model.poses(view.time))
        return [x.detach().clone().requires_grad_() for x in (model.gaussians.means, cov, positions, turns)]

    def run_torch():
        means, c, positions, turns = leaves()
        moved, moved_cov = carry(means, c, nodes, weights, canonical, positions, turns)
        (moved.sum() + moved_cov.sum()).backward()

    def run_fused():
        means, c, positions, turns = leaves()
        moved, moved_cov = fused_carry(means, c, rows, nodes, weights, canonical, positions, turns)
        (moved.sum() + moved_cov.sum()).backward()

    torch_ms, fused_ms = _median_ms(run_torch, args.repeats), _median_ms(run_fused, args.repeats)
    image_ms = time_step(model, [view], torch.ones(3), torch.device("cpu"), args.repeats)
    result = {"model": str(args.model), "machine": platform.machine(), "threads": torch.get_num_threads(),
              "torch": torch.__version__, "gaussians": len(model), "nodes": model.num_nodes,
              "carry_torch_ms": round(torch_ms, 2), "carry_fused_ms": round(fused_ms, 2),
              "speedup": round(torch_ms / fused_ms, 2), "image_ms": round(image_ms, 2),
              "image_ms_with_torch_carry": round(image_ms - fused_ms + torch_ms, 2)}
    print(f"{len(model):,} skinned Gaussians on {model.num_nodes} nodes, {torch.get_num_threads()} threads")
    print(f"{'carry (forward + backward)':<30}{'ms':>10}")
    print(f"{'torch composition':<30}{torch_ms:>10.2f}")
    print(f"{'fused kernel':<30}{fused_ms:>10.2f}   ({torch_ms / fused_ms:.1f}x faster)")
    print(f"one training image at 256 px: {image_ms:.1f} ms (with the torch carry about "
          f"{result['image_ms_with_torch_carry']:.1f} ms)")
    if args.json:
        write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
