"""``splatreel info CKPT``: what a model file holds."""

from __future__ import annotations

import argparse
import json

ORDER = 10
HELP = "print what a checkpoint or model file holds (count, time range, bounds, SH degrees, size)"


def add_args(p: argparse.ArgumentParser) -> None:
    from ..importers import add_import_args

    p.add_argument("checkpoint", metavar="CKPT", help="model file: splatreel .safetensors checkpoint, or any file "
                   "the importers read (official 4DGS .pth, 4DGaussians/4DGen folder, 3DGS PLY, PLY folder/glob)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_import_args(p)


def summarize(path, **options) -> dict:
    """The facts `info` prints, as a JSON-able dict (`options`: import options for other tools' files)."""
    import glob
    from pathlib import Path

    import numpy as np

    from ..cameras import views_to_json
    from ..formats import load_model
    from ..model import model_bounds

    ckpt = load_model(path, **options)
    model = ckpt.model
    lo, hi = model_bounds(model)
    files = [Path(f) for f in glob.glob(str(path))] if not Path(path).exists() else [Path(path)]
    size = sum(f.stat().st_size for p in files for f in ([p] if p.is_file() else p.rglob("*")) if f.is_file())
    out = {
        "path": str(path), "kind": model.kind, "count": len(model),
        "time_range": list(model.time_range),
        "bounds_min": [round(float(x), 6) for x in lo], "bounds_max": [round(float(x), 6) for x in hi],
        "sh_degree": model.sh_degree, "sh_degree_t": getattr(model, "sh_degree_t", 0),
        "rotation_convention": getattr(model, "rotation_convention", None),
        "background": list(ckpt.background), "size_bytes": size,
        "dtype": str(next(iter(model.tensors().values())).dtype).replace("torch.", ""),
        "format_version": ckpt.format_version, "provenance": ckpt.provenance, "training": ckpt.training,
    }
    if model.kind == "keyframed":
        out["num_frames"] = model.num_frames
    out["training_views"] = len(ckpt.views)
    out["training_cameras"] = len(views_to_json(ckpt.views)["cameras"])  # each distinct camera once
    out.update(shape_stats(model, float(np.linalg.norm(np.asarray(hi, np.float64) - np.asarray(lo, np.float64)))))
    return out


#: A Gaussian whose largest std-dev exceeds this share of the bounds' diagonal counts as large.
LARGE_SHARE = 0.1


def shape_stats(model, diagonal: float) -> dict:
    """Sizes and opacities of the Gaussians: ``std_dev`` (each one's largest std-dev: median, 99th percentile,
    max), ``opacity`` (at its temporal peak for native 4D models, at the middle key for keyframed ones: median,
    99th percentile) and ``large`` (how many have a std-dev over LARGE_SHARE of the bounds' `diagonal`: the splats
    that fill the screen up close, see view/render --max-screen-radius)."""
    import numpy as np
    import torch

    if not len(model):
        return {"std_dev": None, "opacity": None, "large": 0}
    g = model.slice(0.5 * (model.time_range[0] + model.time_range[1]))  # 4D: the covariances do not change with t
    with torch.no_grad():
        std = torch.linalg.eigvalsh(g.covariances.double()).clamp_min(0.0)[:, -1].sqrt().numpy()
        logits = getattr(model, "opacity_logits", None)
        opacity = (torch.sigmoid(logits) if logits is not None else g.opacities).double().numpy()

    def quantiles(x, *extra) -> dict:
        out = {"median": float(np.median(x)), "p99": float(np.quantile(x, 0.99))}
        return {**out, **{name: float(f(x)) for name, f in extra}}

    return {"std_dev": quantiles(std, ("max", np.max)), "opacity": quantiles(opacity),
            "large": int((std > LARGE_SHARE * diagonal).sum())}


def _human(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return str(n)


def run(args: argparse.Namespace) -> int:
    from ..importers import import_options

    info = summarize(args.checkpoint, **import_options(args))
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    fmt = lambda v: "(" + ", ".join(f"{x:.3f}" for x in v) + ")"  # noqa: E731
    rows = [
        ("file", info["path"]), ("kind", info["kind"]), ("gaussians", f"{info['count']:,}"),
        ("time range", f"{info['time_range'][0]:g} .. {info['time_range'][1]:g}"),
        ("bounds", f"{fmt(info['bounds_min'])} .. {fmt(info['bounds_max'])}"),
        ("SH degree", f"{info['sh_degree']} (time degree {info['sh_degree_t']})"),
    ]
    if info["std_dev"]:
        sd, op = info["std_dev"], info["opacity"]
        rows += [("std-dev", f"median {sd['median']:.3g}, 99% {sd['p99']:.3g}, max {sd['max']:.3g} (largest axis)"),
                 ("opacity", f"median {op['median']:.3g}, 99% {op['p99']:.3g}")]
    if info["large"]:
        rows.append(("large", f"{info['large']:,} Gaussians with a std-dev over {LARGE_SHARE:.0%} of the bounds' "
                              "diagonal (they fill the screen up close: view/render --max-screen-radius)"))
    if info["training_views"]:
        rows.append(("training views", f"{info['training_views']:,} from {info['training_cameras']:,} camera(s) "
                                        "(view/render --cameras this file)"))
    if info["rotation_convention"]:
        rows.append(("4D rotation", info["rotation_convention"]))
    if "num_frames" in info:
        rows.append(("keyframes", str(info["num_frames"])))
    rows += [("background", fmt(info["background"])), ("dtype", info["dtype"]),
             ("size on disk", _human(info["size_bytes"])), ("format version", str(info["format_version"]))]
    for k, v in info["provenance"].items():
        if isinstance(v, list) and v and all(isinstance(x, str) for x in v):  # e.g. what an importer assumed
            rows += [(f"provenance.{k}" if i == 0 else "", x) for i, x in enumerate(v)]
        else:
            rows.append((f"provenance.{k}", json.dumps(v) if not isinstance(v, str) else v))
    if info["training"]:
        rows.append(("training", json.dumps(info["training"], sort_keys=True)[:200]))
    width = max(len(r[0]) for r in rows)
    for k, v in rows:
        print(f"{k:<{width}}  {v}")
    return 0
