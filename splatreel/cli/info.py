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
    """The facts `info` prints, as a JSON-able dict (`options`: import options for other tools' files).

    A valid splatreel checkpoint is read with NumPy (`splatreel.checkpoint_numpy`), so that ``info`` starts without
    torch; any other file, or one that is damaged, goes through `splatreel.formats.read_checkpoint`, which reads every
    format and names what is wrong."""
    from ..checkpoint_numpy import read_numpy_checkpoint

    ckpt = None if options else read_numpy_checkpoint(path)
    facts = _facts_of_numpy(ckpt) if ckpt is not None else _facts_of_model(path, options)
    return _summary(path, **facts)


def _facts_of_numpy(ckpt) -> dict:
    from ..checkpoint_numpy import KIND_TENSORS, bounds, sizes_and_opacities

    lo, hi = bounds(ckpt)
    std, opacity = sizes_and_opacities(ckpt)
    return dict(kind=ckpt.kind, count=len(ckpt), time_range=ckpt.time_range, lo=lo, hi=hi,
                sh_degree=ckpt.sh_degree, sh_degree_t=ckpt.sh_degree_t, rotation_convention=ckpt.rotation_convention,
                background=ckpt.background, dtype=ckpt.arrays[KIND_TENSORS[ckpt.kind][0]].dtype.name,
                format_version=ckpt.format_version, provenance=ckpt.provenance, training=ckpt.training,
                num_frames=len(ckpt.arrays["times"]) if ckpt.kind == "keyframed" else None, views=ckpt.views,
                std=std, opacity=opacity)


def _facts_of_model(path, options: dict) -> dict:
    from ..formats import read_checkpoint
    from ..model import model_bounds

    ckpt = read_checkpoint(path, **options)
    model = ckpt.model
    lo, hi = model_bounds(model)
    std, opacity = _sizes_and_opacities(model)
    return dict(kind=model.kind, count=len(model), time_range=model.time_range, lo=lo.numpy(), hi=hi.numpy(),
                sh_degree=model.sh_degree, sh_degree_t=getattr(model, "sh_degree_t", 0),
                rotation_convention=getattr(model, "rotation_convention", None), background=ckpt.background,
                dtype=str(next(iter(model.tensors().values())).dtype).replace("torch.", ""),
                format_version=ckpt.format_version, provenance=ckpt.provenance, training=ckpt.training,
                num_frames=model.num_frames if model.kind == "keyframed" else None, views=ckpt.views,
                std=std, opacity=opacity)


def _sizes_and_opacities(model):
    """(largest std-dev ``[N]``, opacity ``[N]``) as float64 arrays: the opacity at its temporal peak for native 4D
    models, at the middle key for keyframed ones."""
    import torch

    if not len(model):
        return None, None
    g = model.slice(0.5 * (model.time_range[0] + model.time_range[1]))  # 4D: the covariances do not change with t
    with torch.no_grad():
        if g.scales is not None:  # keyframed: the eigenvalues of R diag(s)^2 Rᵀ are s^2, read them exactly
            std = g.scales.double().max(-1).values.numpy()
        else:
            std = torch.linalg.eigvalsh(g.covariances.double()).clamp_min(0.0)[:, -1].sqrt().numpy()
        logits = getattr(model, "opacity_logits", None)
        opacity = (torch.sigmoid(logits) if logits is not None else g.opacities).double().numpy()
    return std, opacity


def _summary(path, *, kind, count, time_range, lo, hi, sh_degree, sh_degree_t, rotation_convention, background,
             dtype, format_version, provenance, training, num_frames, views, std, opacity) -> dict:
    import glob
    from pathlib import Path

    import numpy as np

    from ..cameras import views_to_json

    files = [Path(f) for f in glob.glob(str(path))] if not Path(path).exists() else [Path(path)]
    size = sum(f.stat().st_size for p in files for f in ([p] if p.is_file() else p.rglob("*")) if f.is_file())
    out = {
        "path": str(path), "kind": kind, "count": count,
        "time_range": list(time_range),
        "bounds_min": [round(float(x), 6) for x in lo], "bounds_max": [round(float(x), 6) for x in hi],
        "sh_degree": sh_degree, "sh_degree_t": sh_degree_t,
        "rotation_convention": rotation_convention,
        "background": list(background), "size_bytes": size,
        "dtype": dtype,
        "format_version": format_version, "provenance": provenance, "training": training,
    }
    if num_frames is not None:
        out["num_frames"] = num_frames
    out["training_views"] = len(views)
    out["training_cameras"] = len(views_to_json(views)["cameras"])  # each distinct camera once
    diagonal = float(np.linalg.norm(np.asarray(hi, np.float64) - np.asarray(lo, np.float64)))
    out.update(shape_stats(std, opacity, diagonal))
    return out


#: A Gaussian whose largest std-dev exceeds this share of the bounds' diagonal counts as large.
LARGE_SHARE = 0.1


def shape_stats(std, opacity, diagonal: float) -> dict:
    """Sizes and opacities of the Gaussians from each one's largest std-dev `std` and its `opacity` (``[N]``
    float64 arrays, None for no Gaussians): ``std_dev`` (median, 99th percentile, max), ``opacity`` (median, 99th
    percentile) and ``large`` (how many have a std-dev over LARGE_SHARE of the bounds' `diagonal`: the splats
    that fill the screen up close, see view/render --max-screen-radius)."""
    import numpy as np

    if std is None or not len(std):
        return {"std_dev": None, "opacity": None, "large": 0}

    def rounded(v) -> float:
        # 6 significant digits: the values come from float32 tensors, whose last digits differ between the NumPy
        # and the torch reading of the same file
        return float(f"{float(v):.6g}")

    def quantiles(x, *extra) -> dict:
        out = {"median": rounded(np.median(x)), "p99": rounded(np.quantile(x, 0.99))}
        return {**out, **{name: rounded(f(x)) for name, f in extra}}

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
