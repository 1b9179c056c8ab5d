"""Train the default recipe (``auto``, with its time budget) on each procedural sample at its default size and
score the held-out views beside two trivial baselines and the sample's exact model.

    python bench/train.py [--json OUT.json] [--samples spinner,wave,morph,texture,walker,floor,walker-dnerf]
                          [--minutes M] [--iters N] [--profile-steps K] [--device auto|cpu|cuda] [--datasets DIR]
                          [--checkpoints DIR] [--set FIELD=VALUE ...]

`walker-dnerf` is the walker filmed the way D-NeRF's captures are: 12 cameras at one elevation, 96 frames at 200 px,
frame f seen by camera f mod 12 alone (``splatreel sample walker --views 12 --time-steps 96 --size 200
--one-camera-per-time``): a deforming subject in the one-camera-per-time regime, without the floor scene's floor.

Prints a table and writes JSON: per sample `sample`, `regime`, `seconds` (the whole run, set-up included), `iters`,
`n_gaussians`, `test_psnr`, `test_ssim`, `test_psnr_on_black` (the same model and test views, both composited on
black instead of the dataset's white: a dark silhouette on white costs far more), `train_view_psnr` ("fit": every
8th training image, at its key time, where the test views are at in-between times), `upper_bound_psnr` (the exact
model, `splatreel sample NAME --model`, on the same test views), `needle_share` (Gaussians whose largest-to-smallest
axis ratio is above 10, on the 4D Gaussians' spatial scales), `sliced_needle_share` (the same for the 3D Gaussians
that slicing shows), `test_per_view` (each test view's camera, time, PSNR and `at_frame`: whether its time is a
training frame's or in between), the decisions of the recipe, `nodes` (with control nodes, what the switch to them
decided: `template`, one set of Gaussians for the clip; `template_ratio`, the carried template's worst colour loss over
a frame over its loss at the middle frame; `silhouette_ratio`, the same of its alpha, which decides where the images
have alpha), what the alpha-agreement test said, `far_clip` (the camera depth the capture's alpha was cut at,
where training found one: the test views and the fit are rendered at it), and the baselines' PSNR on the same test
views: `nearest_image_psnr` (the same camera's training image nearest in time; for test cameras that are not training
cameras, the nearest training camera's) and `median_image_psnr` (that camera's per-pixel median training image).
A model has to beat both by a wide margin.

`step` is the breakdown of the work per training image (full resolution, the final model) into slicing,
rasterizer forward, losses, backward, the regularisers and Adam, in milliseconds; a step renders `--batch-size`
images, and what it does once (finding the live Gaussians, the regularisers, the Adam update) is shared out among
them. On a CUDA device each phase is synchronised before it is timed.

`reference_ms` is a fixed piece of work timed beside each sample: the spinner sample's exact model (60,000 native
Gaussians) sliced and rasterized at the sample's first training camera at 256², forward and backward (median of 12).
This shared machine's speed drifts by a third between days, and more within one; step counts of runs at different
times compare through it.

`--datasets DIR` keeps the generated datasets in DIR/NAME and reads them from there when present (the GL renderer
that makes them is then not needed: a machine without a display driver can run datasets made elsewhere).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import math
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

#: Every this-many-th training image is scored for the fit (`train_view_psnr`).
FIT_EVERY = 8
ROOT = Path(__file__).resolve().parents[1]


def step_breakdown(trainer, repeats: int = 10) -> dict[str, float]:
    """Milliseconds per phase of the work per training image (full resolution, the trainer's current model; what a
    step does once is shared out among its images). Call it after the model was saved and scored: the timed steps
    update it."""
    import torch

    from splatreel.train.evaluate import view_target
    from splatreel.train.losses import image_loss
    from splatreel.rasterize import rasterize
    from splatreel.covariance import alive_at

    cfg, ds = trainer.cfg, trainer.ds
    sync = torch.cuda.synchronize if trainer.device.type == "cuda" else (lambda: None)
    phases = dict.fromkeys(("slice", "raster forward", "losses", "backward", "regularisers", "adam"), 0.0)
    for r in range(repeats):
        view = ds.train[(r * 7) % len(ds.train)]
        target, mask = view_target(view, ds.background, trainer.device)
        sync()
        t = time.perf_counter()
        model, native = trainer.model(), trainer.native_model()
        with torch.no_grad():
            var_t = native.covariance_4d()[:, 3, 3]
        sync()
        t_var = time.perf_counter() - t  # the trainer finds the live Gaussians once per step, not per image
        t = time.perf_counter() - t_var / cfg.batch_size
        g = model.slice(view.time, rows=alive_at(view.time, native.t_means.detach(), var_t))
        sync()
        t1 = time.perf_counter()
        out = rasterize(g, view.camera, trainer.bg, sh_degree=cfg.sh_degree)
        sync()
        t2 = time.perf_counter()
        loss = image_loss(out.rgb, out.alpha, target, mask, cfg.lambda_l1, cfg.lambda_dssim, cfg.lambda_mask)
        sync()
        t3 = time.perf_counter()
        loss.backward()
        sync()
        t4 = time.perf_counter()
        regularisers = trainer.regularisers(native, static=False)  # once per step, on every Gaussian
        if regularisers is not None:
            regularisers.backward()
        sync()
        t5 = time.perf_counter()
        trainer.optimizer.step()  # after the model was saved and scored: these steps change nothing reported
        if trainer.nodes is not None:
            trainer.nodes.step()
        sync()
        t6 = time.perf_counter()
        trainer.optimizer.zero_grad(set_to_none=True)
        for k, dt in zip(phases, (t1 - t, t2 - t1, t3 - t2, t4 - t3, (t5 - t4) / cfg.batch_size,
                                  (t6 - t5) / cfg.batch_size)):
            phases[k] += 1000.0 * dt / repeats
    return {k: round(v, 1) for k, v in phases.items()}


def reference_ms(device: str | None, repeats: int = 12) -> float:
    """Median milliseconds of a fixed piece of work: slicing and rasterizing the spinner sample's exact model (60,000
    native Gaussians, deterministic) at the sample's first training camera (256x256), forward and backward
    (`cuda_path.time_step`, after a warm-up). Timed beside each sample, it says how fast the machine was during that
    run: step counts from runs on different days compare through it (this shared machine's speed drifts by a third).
    Until 2026-11-28 the work was the bundled checkpoint's (59,095 native Gaussians, 62-66 ms on a quiet machine);
    it is the exact model now so that a re-bundled sample does not move it."""
    import torch
    from cuda_path import time_step  # bench/cuda_path.py, this script's neighbour

    from splatreel.samples import DatasetConfig, build_model, train_views
    from splatreel.train.trainer import pick_device

    view = train_views(DatasetConfig())[0]
    model = build_model("spinner", num_gaussians=60_000)
    background = torch.ones(3)
    return round(time_step(model, [view], background, pick_device(device or "auto"), repeats), 2)


def needle_share(trainer, ratio: float = 10.0) -> float:
    """Share of Gaussians whose largest spatial std-dev is more than `ratio` times their smallest (the 4D
    Gaussian's own spatial scales, which the anisotropy penalty acts on)."""
    ls = trainer.params["log_scales"].detach()
    return float(((ls.max(-1).values - ls.min(-1).values) > math.log(ratio)).float().mean())


def sliced_needle_share(trainer, ratio: float = 10.0) -> float:
    """The same for the 3D Gaussians that slicing shows (the conditional covariance, the same at every time): what
    the viewer draws."""
    import torch

    from splatreel.covariance import condition_on_time

    with torch.no_grad():
        var = torch.linalg.eigvalsh(condition_on_time(trainer.native_model().covariance_4d())[0]).clamp_min(1e-30)
    return float((var[:, -1] / var[:, 0] > ratio * ratio).float().mean())


def variants() -> dict:
    """Bench entries beyond the samples at their defaults: name -> (sample, its `DatasetConfig`)."""
    from splatreel.samples import DatasetConfig

    # the walker filmed the way D-NeRF's captures are (12 cameras, one per time): a deforming subject in the regime
    # the floor scene brings, without its floor
    return {"walker-dnerf": ("walker", DatasetConfig(views=12, frames=96, size=200, one_camera_per_time=True))}


def upper_bound(name: str, ds, frames: int | None = None) -> float | None:
    """Test PSNR of the sample's exact model (None when it cannot be built), keyed at `frames` times (None: its
    default), with as many Gaussians per key as at its default."""
    from splatreel.errors import SplatreelError
    from splatreel.samples import build_model
    from splatreel.samples.gaussians import DEFAULT_FRAMES, DEFAULT_GAUSSIANS, segment_times
    from splatreel.train.evaluate import evaluate

    def segments(n: int) -> int:  # an object's model has its Gaussians per key-time segment
        return len(segment_times(n)) - 1

    count = None if frames is None else round(DEFAULT_GAUSSIANS * segments(frames) / segments(DEFAULT_FRAMES))
    try:
        model = build_model(name, num_gaussians=count, frames=frames)
    except SplatreelError:
        return None
    return evaluate(model, ds.test, ds.background, progress=False)["psnr"]


def per_view_scores(ev: dict, ds) -> list[dict]:
    """Each test view's camera, time, PSNR and whether its time is a training frame's (the others are in between)."""
    frames = np.asarray(ds.frame_times, dtype=np.float64)
    return [{"view": p["view"], "time": round(float(p["time"]), 6), "psnr": round(p["psnr"], 3),
             "at_frame": bool(np.abs(frames - p["time"]).min() < 1e-6 * max(1.0, np.ptp(frames)))}
            for p in ev["per_view"]]


def config_overrides(items: list[str]) -> dict:
    """``FIELD=VALUE`` strings as TrainConfig fields and values (a Python literal, else the text itself); ValueError
    names the first that is not a field."""
    from splatreel.train.config import TrainConfig

    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    out = {}
    for item in items:
        field, sep, value = (x.strip() for x in item.partition("="))
        if not sep or field not in fields:
            raise ValueError(f"--set {item!r}: expected FIELD=VALUE with FIELD a TrainConfig field")
        try:
            out[field] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            out[field] = value
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", metavar="OUT", help="write results here")
    ap.add_argument("--samples", default=None, help="comma-separated sample names (default: all)")
    ap.add_argument("--minutes", type=float, default=None, help="override the recipe's time budget")
    ap.add_argument("--iters", type=int, default=None, help="run this many iterations instead of a time budget")
    ap.add_argument("--device", default=None, choices=["auto", "cpu", "cuda"],
                    help="compute device (default: the recipe's, 'auto')")
    ap.add_argument("--datasets", type=Path, metavar="DIR",
                    help="keep the generated datasets in DIR/NAME and read them from there when present")
    ap.add_argument("--checkpoints", type=Path, metavar="DIR",
                    help="keep each sample's checkpoint as DIR/NAME.safetensors, refusing one that exists (default: a "
                         "temporary folder)")
    ap.add_argument("--profile-steps", type=int, default=10, help="steps timed for the breakdown (0: skip)")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="override a field of the recipe's TrainConfig (a Python literal, e.g. inbetween_share=0); "
                         "repeatable")
    args = ap.parse_args()
    try:
        overrides = config_overrides(args.set)
    except ValueError as exc:
        ap.error(str(exc))

    import torch

    from splatreel.samples import SAMPLES, SCENES
    from splatreel.samples import write_dataset
    from splatreel.train.alpha_conflicts import describe
    from splatreel.train.data import load_dataset
    from splatreel.train.evaluate import baselines, evaluate
    from splatreel.train.recipe import auto_recipe, read_traits
    from splatreel.train.trainer import Trainer

    variant = variants()
    names = args.samples.split(",") if args.samples else [*SAMPLES, *SCENES, *variant]
    unknown = [n for n in names if n not in SAMPLES and n not in SCENES and n not in variant]
    if unknown:
        ap.error(f"unknown sample {unknown[0]!r}: one of {', '.join([*SAMPLES, *SCENES, *variant])}")
    if args.checkpoints:  # a kept checkpoint is the user's: never overwritten
        taken = [n for n in names if (args.checkpoints / f"{n}.safetensors").exists()]
        if taken:
            ap.error(f"{args.checkpoints / taken[0]}.safetensors already exists")
        try:
            args.checkpoints.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            ap.error(f"cannot write checkpoints to {args.checkpoints}: {exc.strerror}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            sample, config = variant.get(name, (name, None))
            data = (args.datasets or Path(tmp)) / name
            t = time.perf_counter()
            if not data.exists():
                write_dataset(sample, data, config)
            gen_s = time.perf_counter() - t
            ds = load_dataset(data)
            ref_ms = reference_ms(args.device)
            traits = read_traits(ds)
            cfg, decisions = auto_recipe(traits)
            if args.iters:
                cfg = dataclasses.replace(cfg.scaled(args.iters), minutes=None)
            elif args.minutes:
                cfg = dataclasses.replace(cfg, minutes=args.minutes)
            if args.device:
                cfg = dataclasses.replace(cfg, device=args.device)
            if overrides:
                cfg = dataclasses.replace(cfg, **overrides)
            t = time.perf_counter()
            tr = Trainer(ds, cfg, (args.checkpoints or Path(tmp)) / f"{name}.safetensors", progress=True)
            res = tr.run()
            seconds = time.perf_counter() - t  # includes the alpha test, confidence maps and set-up
            ev = tr.evaluate_test()
            model = tr.dataset_model()  # what the checkpoint holds
            clip = tr.far_clip_depth  # the capture's, where training found one
            on_black = evaluate(model, ds.test, (0.0, 0.0, 0.0), progress=False, far_clip=clip)["psnr"]
            fit = evaluate(model, ds.train[::FIT_EVERY], ds.background, progress=False, far_clip=clip)["psnr"]
            base = baselines(ds.test, ds.train, ds.background)
            bound = upper_bound(sample, ds, None if config is None else config.frames)
            rows.append({"sample": name, "regime": "one camera per time" if traits.one_view_per_time
                         else "image matrix", "seconds": round(seconds, 2), "minutes": cfg.minutes,
                         "iters": res.iterations, "n_gaussians": res.n_gaussians,
                         "test_psnr": round(ev["psnr"], 3), "test_ssim": round(ev["ssim"], 4),
                         "test_psnr_on_black": round(on_black, 3), "train_view_psnr": round(fit, 3),
                         "upper_bound_psnr": None if bound is None else round(bound, 3),
                         "nearest_image_psnr": round(base["nearest_image"], 3),
                         "median_image_psnr": round(base["median_image"], 3),
                         "needle_share": round(needle_share(tr), 4),
                         "sliced_needle_share": round(sliced_needle_share(tr), 4),
                         "decisions": [d.line() for d in decisions], "overrides": args.set,
                         "alpha": describe(tr.alpha_conflicts, cfg.strict_alpha, ds.train), "far_clip": clip,
                         "background": list(ds.background), "train_psnr_ema": round(res.train_psnr, 3),
                         "test_per_view": per_view_scores(ev, ds), "nodes": tr.node_outcome,
                         "generate_seconds": round(gen_s, 2), "device": str(tr.device), "reference_ms": ref_ms,
                         "step": step_breakdown(tr, args.profile_steps) if args.profile_steps else None})
            print(rows[-1], flush=True)
    print(f"\n{'sample':<9}{'regime':<21}{'seconds':>8}{'iters':>7}{'gaussians':>11}{'test PSNR':>10}"
          f"{'SSIM':>8}{'on black':>9}{'fit':>7}{'exact':>7}{'nearest':>9}{'median':>8}{'needles':>9}{'ref ms':>8}")
    for r in rows:
        bound = "-" if r["upper_bound_psnr"] is None else f"{r['upper_bound_psnr']:.2f}"
        print(f"{r['sample']:<9}{r['regime']:<21}{r['seconds']:>8.1f}{r['iters']:>7}{r['n_gaussians']:>11,}"
              f"{r['test_psnr']:>10.2f}{r['test_ssim']:>8.4f}{r['test_psnr_on_black']:>9.2f}"
              f"{r['train_view_psnr']:>7.2f}{bound:>7}"
              f"{r['nearest_image_psnr']:>9.2f}"
              f"{r['median_image_psnr']:>8.2f}{100 * r['needle_share']:>8.2f}%"
              f"{100 * r['sliced_needle_share']:>7.2f}%{r['reference_ms']:>8.1f}")
    if args.profile_steps:
        print("\nstep breakdown, ms per training image (full resolution, final model; the regularisers and Adam shared "
              "out over the batch)")
        keys = list(rows[0]["step"]) if rows else []
        print(f"{'sample':<9}" + "".join(f"{k:>16}" for k in keys) + f"{'total':>10}")
        for r in rows:
            print(f"{r['sample']:<9}" + "".join(f"{r['step'][k]:>16.1f}" for k in keys)
                  + f"{sum(r['step'].values()):>10.1f}")
    if args.json:
        meta = {"machine": platform.processor() or platform.machine(), "threads": torch.get_num_threads(),
                "cuda": torch.cuda.get_device_name() if torch.cuda.is_available() else None,
                "torch": torch.__version__}
        Path(args.json).write_text(json.dumps({"meta": meta, "results": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
