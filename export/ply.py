"""Standard 3DGS PLY sequences: one file per frame, in the layout of `splatreel.ply_layout` (graphdeco-inria
``GaussianModel.save_ply``: positions, zero normals, SH DC + channel-major rest, opacity logit, log scales,
quaternion w first).

The sequence writer keeps every Gaussian in model order at every frame (invisible ones with opacity logit(1e-6))
unless ``drop_invisible``, so a sequence re-imports with a fixed count.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Sequence

from splatreel.fileio import atomic_dir
from splatreel.ply_layout import OPACITY_EPS, ply_bytes, splats_to_ply_records

from .base import ExportError, SplatFrame, frame_file_name, iter_frames, manifest, resolve_up_axis


def frame_ply_bytes(frame: SplatFrame, drop_invisible: bool = False) -> bytes:
    """The 3DGS PLY of one frame; `drop_invisible` omits Gaussians the slice marks invisible."""
    keep = frame.visible if drop_invisible else slice(None)
    records = splats_to_ply_records(frame.means[keep], frame.quats[keep], frame.scales[keep],
                                    frame.opacities[keep], frame.sh[keep])
    return ply_bytes(records, [f"splatreel frame {frame.index} time {frame.time!r}"])


def write_ply_sequence(model, outdir: str | Path, times: Sequence[float], fps: float = 24.0,
                       drop_invisible: bool = False, force: bool = False, progress: bool = False,
                       up_axis: str = "Y") -> list[Path]:
    """Write ``OUTDIR/frame_%06d.ply`` for every time plus ``manifest.json`` (frame table, fps, SH degree, `up_axis`
    of the model's coordinates); the folder appears atomically.

    Returns:
        The paths of the written files (frames first, manifest last), under `outdir`.
    """
    outdir = Path(outdir)
    names = []
    with atomic_dir(outdir, force) as tmp:
        for frame in iter_frames(model, times, progress, desc="ply"):
            names.append(frame_file_name("frame", frame.index, "ply"))
            (tmp / names[-1]).write_bytes(frame_ply_bytes(frame, drop_invisible))
        (tmp / "manifest.json").write_bytes(manifest(
            "3dgs-ply-sequence", times, names, fps, time_range=list(model.time_range),
            sh_degree=int(model.sh_degree), stable_order=not drop_invisible, up_axis=up_axis,
            invisible=("dropped" if drop_invisible else f"kept with opacity logit({OPACITY_EPS:g})")))
    return [outdir / n for n in names] + [outdir / "manifest.json"]


def add_args(p: argparse.ArgumentParser) -> None:
    """The format's own options of ``splatreel export ply`` (its entry in `splatreel.formats`)."""
    p.add_argument("--drop-invisible", action="store_true",
                   help="omit Gaussians invisible at a frame (default: keep every Gaussian in model order, "
                        "invisible ones with ~zero opacity, so the sequence has a fixed count)")


def run(model, times, out, args) -> list[Path]:
    """``splatreel export ply``: write `model` at `times` to `out` as the parsed `args` say: a folder, or one
    ``.ply`` file when `out` is named so and one frame is asked for."""
    if Path(out).suffix.lower() == ".ply":
        if len(times) != 1:
            raise ExportError(f"{out}: export ply writes a folder of {len(times)} frames (frame_000000.ply ... and "
                              "manifest.json): give a folder name, or --frame-count 1 for one .ply file")
        from splatreel.fileio import atomic_write_bytes

        frame = next(iter_frames(model, times))
        return [atomic_write_bytes(out, frame_ply_bytes(frame, args.drop_invisible), args.force)]
    return write_ply_sequence(model, out, times, fps=args.fps, drop_invisible=args.drop_invisible,
                              force=args.force, progress=args.progress,
                              up_axis=resolve_up_axis(args.up_axis, getattr(args, "provenance", None)))
