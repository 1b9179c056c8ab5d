"""``splatreel info CKPT``: what a model file holds."""

from __future__ import annotations

import argparse
import json

ORDER = 10
HELP = "print what a checkpoint or model file holds (count, time range, bounds, SH degrees, size)"
#: How the table words a summary's ``motion`` (others as they are: ``linear``)
MOTION_TEXT = {"quadratic": "quadratic (each Gaussian has an acceleration)",
               "nodes": "nodes (skinned: each Gaussian follows the blend of its nearest control nodes)"}


def add_args(p: argparse.ArgumentParser) -> None:
    from ..importers import add_import_args

    p.add_argument("checkpoint", metavar="CKPT", help="model file: splatreel .safetensors checkpoint, or any file "
                   "the importers read (official 4DGS .pth, 4DGaussians/4DGen folder, 3DGS PLY, PLY folder/glob)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_import_args(p)


def summarize(path, **options) -> dict:
    """The facts `info` prints, as a JSON-able dict (`options`: import options for other tools' files).

    A splatreel checkpoint is verified (checksums, dtypes, finite values, recorded shapes) and summarised from the
    `splatreel.summary` its metadata stores, without torch. Other files, and checkpoints written before the summary
    was stored, are read by `splatreel.formats.read_checkpoint` and summarised from the model."""
    from pathlib import Path

    from ..checkpoint_file import SUFFIX, read_arrays

    meta = None
    if not options and Path(path).suffix == SUFFIX:
        meta, _ = read_arrays(path)
    if meta is not None and "summary" in meta:
        from ..checkpoint_file import recorded_views

        facts = dict(meta["summary"], background=meta.get("background", [0.0, 0.0, 0.0]),
                     format_version=meta["format_version"], provenance=meta.get("provenance", {}),
                     training=meta.get("training", {}), views=recorded_views(meta, path))
    else:
        facts = _facts_of_model(path, options)
    return _with_file_facts(path, facts)


def _facts_of_model(path, options: dict) -> dict:
    from ..formats import read_checkpoint
    from ..summary import model_summary

    ckpt = read_checkpoint(path, **options)
    return dict(model_summary(ckpt.model), background=list(ckpt.background), format_version=ckpt.format_version,
                provenance=ckpt.provenance, training=ckpt.training, views=ckpt.views)


def _with_file_facts(path, facts: dict) -> dict:
    """`facts` in the order info prints them, with the size on disk and the training views counted."""
    import glob
    from pathlib import Path

    from ..cameras import views_to_json

    files = [Path(f) for f in glob.glob(str(path))] if not Path(path).exists() else [Path(path)]
    size = sum(f.stat().st_size for p in files for f in ([p] if p.is_file() else p.rglob("*")) if f.is_file())
    views = facts.pop("views")
    out = {"path": str(path), **{k: facts[k] for k in ("kind", "count", "time_range", "bounds_min", "bounds_max",
                                                      "sh_degree", "sh_degree_t", "rotation_convention")},
           "background": list(facts["background"]), "size_bytes": size, "dtype": facts["dtype"],
           "format_version": facts["format_version"], "provenance": facts["provenance"],
           "training": facts["training"]}
    for key in ("num_frames", "motion", "num_nodes", "num_keys"):
        if key in facts:
            out[key] = facts[key]
    out["training_views"] = len(views)
    out["training_cameras"] = len(views_to_json(views)["cameras"])  # each distinct camera once
    out.update({k: facts[k] for k in ("std_dev", "opacity", "large")})
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
    if info["std_dev"]:
        sd, op = info["std_dev"], info["opacity"]
        rows += [("std-dev", f"median {sd['median']:.3g}, 99% {sd['p99']:.3g}, max {sd['max']:.3g} (largest axis)"),
                 ("opacity", f"median {op['median']:.3g}, 99% {op['p99']:.3g}")]
    if info["large"]:
        from ..summary import LARGE_SHARE

        rows.append(("large", f"{info['large']:,} Gaussians with a std-dev over {LARGE_SHARE:.0%} of the bounds' "
                              "diagonal (they fill the screen up close: view/render --max-screen-radius)"))
    if info["training_views"]:
        rows.append(("training views", f"{info['training_views']:,} from {info['training_cameras']:,} camera(s) "
                                        "(view/render --cameras this file)"))
    if info["rotation_convention"]:
        rows.append(("4D rotation", info["rotation_convention"]))
    if info.get("motion"):  # checkpoints from before accelerations have no entry (linear)
        rows.append(("motion", MOTION_TEXT.get(info["motion"], info["motion"])))
    if "num_frames" in info:
        rows.append(("keyframes", str(info["num_frames"])))
    if "num_nodes" in info:
        rows.append(("control nodes", f"{info['num_nodes']:,}, posed at {info['num_keys']} key times"))
    rows += [("background", fmt(info["background"])), ("dtype", info["dtype"]),
             ("size on disk", _human(info["size_bytes"])), ("format version", str(info["format_version"]))]
    for k, v in info["provenance"].items():
        if isinstance(v, list) and v and all(isinstance(x, str) for x in v):  # e.g. what an importer assumed
            rows += [(f"provenance.{k}" if i == 0 else "", x) for i, x in enumerate(v)]
        else:
            rows.append((f"provenance.{k}", json.dumps(v) if not isinstance(v, str) else v))
    if info["training"]:
        text = json.dumps(info["training"], sort_keys=True)
        rows.append(("training", text if len(text) <= 200 else text[:199] + "…  (--json prints all of it)"))
    width = max(len(r[0]) for r in rows)
    for k, v in rows:
        print(f"{k:<{width}}  {v}")
    return 0
