"""Train the default recipe on each procedural sample at its default size and score the held-out views beside two
trivial baselines.

    python bench/train.py [--json OUT.json] [--samples spinner,wave,morph,floor] [--iters N]

Prints a table and writes JSON: per sample `sample`, `regime`, `seconds` (training only, set-up included),
`iters`, `n_gaussians`, `test_psnr`, `test_ssim`, `alpha` (what the alpha-agreement test said), and the baselines'
PSNR on the same test views: `nearest_image_psnr` (the same camera's training image nearest in time; for test
cameras that are not training cameras, the nearest training camera's) and `median_image_psnr` (that camera's
per-pixel median training image). A model has to beat both by a wide margin.

Regimes: the image-matrix samples (16 views x 16 frames at 256 px; test views at other azimuths, elevations and
times between the training frames) and `floor` (12 fixed cameras, one camera per time, a floor whose alpha the
views disagree on; test views at the training cameras, times between).
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

    from splat4d.samples import SAMPLES, SCENES
    from splat4d.samples.dataset import write_dataset
    from splat4d.train.alpha_conflicts import describe
    from splat4d.train.config import preset
    from splat4d.train.data import load_dataset
    from splat4d.train.evaluate import baselines
    from splat4d.train.trainer import Trainer

    names = args.samples.split(",") if args.samples else [*SAMPLES, *SCENES]
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
            seconds = time.perf_counter() - t  # includes the alpha test, confidence maps and set-up
            ev = tr.evaluate_test()
            base = baselines(ds.test, ds.train, ds.background)
            one_per_time = len(ds.frame_times) == len(ds.train)
            rows.append({"sample": name, "regime": "one camera per time" if one_per_time else "image matrix",
                         "seconds": round(seconds, 2), "iters": res.iterations, "n_gaussians": res.n_gaussians,
                         "test_psnr": round(ev["psnr"], 3), "test_ssim": round(ev["ssim"], 4),
                         "nearest_image_psnr": round(base["nearest_image"], 3),
                         "median_image_psnr": round(base["median_image"], 3),
                         "alpha": describe(tr.alpha_conflicts, cfg.strict_alpha, ds.train),
                         "background": list(ds.background), "train_psnr_ema": round(res.train_psnr, 3),
                         "generate_seconds": round(gen_s, 2)})
            print(rows[-1], flush=True)
    print(f"\n{'sample':<10}{'regime':<21}{'seconds':>9}{'iters':>7}{'gaussians':>11}{'test PSNR':>11}"
          f"{'test SSIM':>11}{'nearest img':>13}{'median img':>12}")
    for r in rows:
        print(f"{r['sample']:<10}{r['regime']:<21}{r['seconds']:>9.1f}{r['iters']:>7}{r['n_gaussians']:>11,}"
              f"{r['test_psnr']:>11.2f}{r['test_ssim']:>11.4f}{r['nearest_image_psnr']:>13.2f}"
              f"{r['median_image_psnr']:>12.2f}")
    if args.json:
        meta = {"machine": platform.processor() or platform.machine(), "threads": torch.get_num_threads(),
                "torch": torch.__version__}
        Path(args.json).write_text(json.dumps({"meta": meta, "results": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
