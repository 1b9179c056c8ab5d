"""Benchmark of the procedural samples: dataset generation at the defaults and `build_model`.

    python bench/samples.py [--json OUT.json] [--samples spinner,wave,morph] [--gaussians 20000]

Rows, per sample:
* ``dataset``: `write_dataset` at the defaults (16 views x 16 frames + 16 test images at 256 px: 272 PNGs),
  reference = writing the same number of 256x256 RGBA PNGs of a fixed image with cv2 (the file output any
  dataset writer pays); ratio = dataset / reference. Target: under 30 s per sample on the 2-core machine.
* ``build_model``: `build_model(name, --gaussians)`, reference = one `decompose_covariance_4d` of as many random
  4D covariances (the core 4D math every builder pays); ratio = build / reference.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from splatreel.covariance import decompose_covariance_4d
from splatreel.samples import SAMPLES, DatasetConfig, MeshRenderer, build_model, write_dataset
from splatreel.samples.dataset import write_png

TARGET_DATASET_S = 30.0


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def png_reference(count: int, size: int, folder: Path) -> float:
    """Seconds to write `count` RGBA PNGs of one rendered-looking image (a disc with a soft edge)."""
    yy, xx = np.mgrid[:size, :size]
    r = np.hypot(xx - size / 2, yy - size / 2)
    img = np.zeros((size, size, 4), np.uint8)
    img[..., 0] = (xx * 255 // size).astype(np.uint8)
    img[..., 1] = (yy * 255 // size).astype(np.uint8)
    img[..., 2] = 128
    img[..., 3] = np.clip((0.3 * size - r) * 255, 0, 255).astype(np.uint8)
    folder.mkdir()
    return _timed(lambda: [write_png(folder / f"r_{i:03d}.png", img) for i in range(count)])


def decompose_reference(n: int) -> float:
    """Seconds for one `decompose_covariance_4d` of `n` random SPD 4x4 matrices (float64)."""
    g = torch.Generator().manual_seed(0)
    a = torch.randn(n, 4, 4, generator=g, dtype=torch.float64)
    cov = a @ a.transpose(-1, -2) + 1e-3 * torch.eye(4, dtype=torch.float64)
    return _timed(lambda: decompose_covariance_4d(cov))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", metavar="OUT", help="write the results as JSON")
    parser.add_argument("--samples", help="comma-separated sample names (default: all)")
    parser.add_argument("--gaussians", type=int, default=20000, help="Gaussians per built model (default 20000)")
    args = parser.parse_args(argv)
    names = args.samples.split(",") if args.samples else list(SAMPLES)
    config = DatasetConfig()
    images = config.views * config.frames + config.test_views

    renderer = MeshRenderer()  # context creation and shader compilation: once, outside the timings
    build_model(names[0], 500, frames=4)  # warm up torch
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        ref_png = png_reference(images, config.size, Path(tmp) / "reference")
        ref_dec = decompose_reference(args.gaussians)
        for name in names:
            s = _timed(lambda: write_dataset(name, Path(tmp) / name, config, renderer=renderer))
            rows.append({"sample": name, "task": "dataset", "seconds": s, "reference_s": ref_png,
                         "ratio": s / ref_png, "images": images, "images_per_s": images / s,
                         "target_s": TARGET_DATASET_S, "ok": s < TARGET_DATASET_S})
            s = _timed(lambda: build_model(name, args.gaussians))
            rows.append({"sample": name, "task": "build_model", "seconds": s, "reference_s": ref_dec,
                         "ratio": s / ref_dec, "gaussians": args.gaussians})
    renderer.release()

    print(f"{'sample':<8} {'task':<12} {'seconds':>8} {'reference':>10} {'ratio':>7}  notes")
    for r in rows:
        note = (f"{r['images']} images, {r['images_per_s']:.0f}/s, target < {TARGET_DATASET_S:.0f} s: "
                f"{'ok' if r['ok'] else 'MISSED'}") if r["task"] == "dataset" else f"{r['gaussians']:,} Gaussians"
        print(f"{r['sample']:<8} {r['task']:<12} {r['seconds']:>8.2f} {r['reference_s']:>10.2f} "
              f"{r['ratio']:>7.2f}  {note}")
    if args.json:
        out = {"benchmark": "samples", "machine": {"platform": platform.platform(), "python": sys.version.split()[0],
                                                  "gl_renderer": renderer.ctx.info.get("GL_RENDERER", "?")},
               "config": {"size": config.size, "views": config.views, "frames": config.frames,
                          "test_views": config.test_views, "gaussians": args.gaussians},
               "rows": rows}
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
