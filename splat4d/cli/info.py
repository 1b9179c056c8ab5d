"""``splat4d info CKPT``: what a model file holds."""

from __future__ import annotations

import argparse
import json

ORDER = 10
HELP = "print what a checkpoint or model file holds (count, time range, bounds, SH degrees, size)"


def add_args(p: argparse.ArgumentParser) -> None:
    from ..importers import add_import_args

    p.add_argument("checkpoint", metavar="CKPT", help="model file: splat4d .safetensors checkpoint, or any file "
                   "the importers read (official 4DGS .pth, 4DGaussians/4DGen folder, 3DGS PLY, PLY folder/glob)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_import_args(p)


def summarize(path, **options) -> dict:
    """The facts `info` prints, as a JSON-able dict (`options`: import options for other tools' files)."""
    import glob
    from pathlib import Path

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
    return out


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
