"""Train the `efficient4d` preset on each procedural sample at the default size and score the held-out views.

    python bench/train.py [--json OUT.json] [--samples spinner,wave,morph] [--iters N]

Prints a table and writes JSON: per sample `sample`, `seconds` (training only), `iters`, `n_gaussians`,
`test_psnr`, `test_ssim` (test views: other azimuths, other elevations, times between training frames).
Target on 2 cores: under 3 minutes per sample with test PSNR >= 30 dB.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", metavar="OUT", help="write results here")
    ap.add_argument("--samples", default=None, help="comma-separated sample names (default: all)")
    ap.add_argument("--iters", type=int, default=None, help="override the preset's iterations")
    args = ap.parse_args()

    import torch

    from splat4d.samples import SAMPLES
    from splat4d.samples.dataset import write_dataset
    from splat4d.train.config import preset
    from splat4d.train.data import load_dataset
    from splat4d.train.trainer import Trainer

    names = args.samples.split(",") if args.samples else list(SAMPLES)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            t = time.perf_counter()
            write_dataset(name, Path(tmp) / name)
            gen_s = time.perf_counter() - t
            ds = load_dataset(Path(tmp) / name)
            cfg = preset("efficient4d")
            if args.iters:
                cfg = cfg.scaled(args.iters)
            t = time.perf_counter()
            tr = Trainer(ds, cfg, Path(tmp) / f"{name}.safetensors", progress=True)
            res = tr.run()
            seconds = time.perf_counter() - t  # includes confidence maps and set-up
            ev = tr.evaluate_test()
            rows.append({"sample": name, "seconds": round(seconds, 2), "iters": res.iterations,
                         "n_gaussians": res.n_gaussians, "test_psnr": round(ev["psnr"], 3),
                         "test_ssim": round(ev["ssim"], 4), "train_psnr_ema": round(res.train_psnr, 3),
                         "generate_seconds": round(gen_s, 2)})
            print(rows[-1], flush=True)
    print(f"\n{'sample':<10}{'seconds':>9}{'iters':>7}{'gaussians':>11}{'test PSNR':>11}{'test SSIM':>11}")
    for r in rows:
        print(f"{r['sample']:<10}{r['seconds']:>9.1f}{r['iters']:>7}{r['n_gaussians']:>11,}{r['test_psnr']:>11.2f}"
              f"{r['test_ssim']:>11.4f}")
    if args.json:
        meta = {"machine": platform.processor() or platform.machine(), "threads": torch.get_num_threads(),
                "torch": torch.__version__}
        Path(args.json).write_text(json.dumps({"meta": meta, "results": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
