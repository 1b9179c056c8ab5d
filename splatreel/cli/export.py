"""``splatreel export FORMAT CKPT --out OUT``: the formats of the registry in `splatreel.formats` (OpenUSD, meshes,
3DGS PLY, glTF, a web player, .splatv, .4dgs)."""

from __future__ import annotations

import argparse

ORDER = 60
HELP = ("export a model to OpenUSD, meshes, 3DGS PLY, glTF, a static web player, .splatv or .4dgs, for other "
        "tools")
DESCRIPTION = HELP + """.

Frames (usd, mesh, ply, gltf): frame i of N (--frame-count) is at model time t0 + i (t1 - t0) / (N - 1), where
[t0, t1] is the model's time range or --start/--end (outside it: a warning); in USD, frame i is time code i and
--fps sets timeCodesPerSecond. The web player, .splatv and .4dgs hold the whole animation (no frame options).
Gaussians keep their model order at every frame; those invisible at a frame get opacity 0.
Run `splatreel export FORMAT --help` for a format's options."""

#: Frames exported when --frame-count is not given and the model has no keyframes of its own.
DEFAULT_FRAMES = 48


def _add_common(q: argparse.ArgumentParser, output: str) -> None:
    from ..argtypes import count, finite_number, positive_number
    from ._shared_options import add_crop_arg, add_up_arg

    q.add_argument("checkpoint", metavar="CKPT", help="model file (splatreel checkpoint or any imported format)")
    q.add_argument("--out", "-o", required=True, metavar=output, help="output file or folder")
    q.add_argument("--frame-count", type=count, default=None, metavar="N",
                   help=f"number of frames (default: the keyframe count of a keyframed model, else {DEFAULT_FRAMES})")
    q.add_argument("--fps", type=positive_number, default=24.0, help="frames per second of the exported sequence (default 24)")
    q.add_argument("--start", type=finite_number, default=None, metavar="T", help="model time of the first frame (default t0)")
    q.add_argument("--end", type=finite_number, default=None, metavar="T", help="model time of the last frame (default t1)")
    # USD's upAxis is Y or Z (https://openusd.org/release/api/group___usd_geom_up_axis__group.html)
    add_up_arg(q, ("y", "z"), default=None, dest="up_axis",
               help="the model's up axis, written as metadata; data is not rotated (default: the checkpoint's "
                    "provenance 'up_axis' if recorded, else y)")
    q.add_argument("--meters-per-unit", type=positive_number, default=1.0, help="scene units in metres (default 1)")
    add_crop_arg(q)
    q.add_argument("--force", action="store_true", help="overwrite an existing output")
    q.add_argument("--quiet", action="store_true", help="no progress bar")


def add_args(p: argparse.ArgumentParser) -> None:
    from ..export import exporters

    sub = p.add_subparsers(dest="exporter", metavar="FORMAT", required=True)
    for name, exporter in exporters().items():
        q = sub.add_parser(name, help=exporter.help, description=exporter.help + ".")
        _add_common(q, exporter.output)
        exporter.add_args(q)


def _human(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n}"


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..export import ExportError, exporters, frame_times
    from ..fileio import check_writable
    from ..formats import read_checkpoint
    from ._shared_options import apply_crop

    check_writable(args.out, args.force)  # refuse before loading anything
    writer = exporters()[args.exporter]
    if not writer.sampled and any(getattr(args, k) is not None for k in ("frame_count", "start", "end")):
        raise ExportError(f"export {writer.name} writes the whole animation; --frame-count, --start and --end do not "
                          "apply")
    ckpt = read_checkpoint(args.checkpoint)
    model = apply_crop(ckpt.model, args.crop)
    frames = args.frame_count if args.frame_count is not None else getattr(model, "num_frames", DEFAULT_FRAMES)
    times = frame_times(model.time_range, frames, args.start, args.end)
    args.provenance = dict(ckpt.provenance or {})
    args.background = ckpt.background
    args.progress = not args.quiet
    paths = writer.run(model, times, Path(args.out), args)
    size = sum(p.stat().st_size for p in paths if p.is_file())
    where = args.out if len(paths) > 1 else paths[0]
    t0, t1 = model.time_range
    span = (f"{len(times)} frames (t = {times[0]:g} .. {times[-1]:g})" if len(times) > 1 else
            f"1 frame (t = {times[0]:g})") if writer.sampled else f"the whole animation (t = {t0:g} .. {t1:g})"
    print(f"wrote {where}: {len(paths)} file{'s' * (len(paths) != 1)}, {_human(size)}, {span}, "
          f"{len(model):,} Gaussians")
    return 0
