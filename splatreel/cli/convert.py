"""``splatreel convert INPUT --out CKPT``: write any readable model file as a splatreel checkpoint."""

from __future__ import annotations

import argparse

ORDER = 15
HELP = "convert an official 4DGS/Efficient4D checkpoint, a 4DGaussians/4DGen folder or 3DGS PLY(s) to a checkpoint"
DESCRIPTION = """\
Convert another tool's model into a splatreel checkpoint (.safetensors).

INPUT is one of:
  chkpnt30000.pth / model.pth     official 4DGS (main) or Efficient4D checkpoint, or the folder holding it
  output/<run>/                   4DGaussians or 4DGen output (point_cloud/iteration_N/ + deformation.pth),
                                  baked into --bake-frames keyframes
  point_cloud.ply                 one 3DGS PLY (static model)
  frames/  or  'frames/*.ply'     per-frame 3DGS PLYs (keyframes; quote the glob)
  model.safetensors               a splatreel checkpoint (re-saved)

Values a file does not store are assumed, printed and recorded in the checkpoint's provenance
(see `splatreel info CKPT`); give the import options below to set them.

examples:
  splatreel convert chkpnt30000.pth --out lego.safetensors --convention current --time-range 0 1
  splatreel convert efficient4d/model.pth --out e4d.safetensors          # legacy rotation, 0..15, white
  splatreel convert output/dnerf/lego --out lego4dgs.safetensors --bake-frames 50
  splatreel convert 'frames/*.ply' --out seq.safetensors --time-range 0 2
  splatreel convert model.safetensors --out tidy.safetensors --crop -1 -1 0 1 1 2   # drop floaters outside a box
"""


def add_args(p: argparse.ArgumentParser) -> None:
    from ..importers import add_import_args
    from ._shared_options import add_crop_arg, add_up_arg

    p.add_argument("input", metavar="INPUT", help="file, folder or quoted glob to convert")
    p.add_argument("--out", "-o", required=True, metavar="CKPT", help="output checkpoint (.safetensors)")
    p.add_argument("--force", action="store_true", help="overwrite CKPT if it exists")
    p.add_argument("--dtype", choices=("float32", "float64"), default="float32",
                   help="floating-point type of the stored tensors (default float32)")
    add_crop_arg(p)
    add_up_arg(p, ("y", "z"), default=None, dest="up_axis",
               help="the model's up axis, recorded in the checkpoint for the exporters (other tools' files do not "
                    "say; default: what the input records, else exporters assume y)")
    add_import_args(p)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import torch

    from ..checkpoint import save_checkpoint
    from ..checkpoint_file import SUFFIX
    from ..errors import SplatreelError
    from ..fileio import check_writable
    from ..formats import read_checkpoint
    from ..importers import import_options
    from ..model import CropBox
    from ._shared_options import apply_crop

    out = Path(args.out)
    if out.suffix != SUFFIX:
        raise SplatreelError(f"{out}: the output must be a {SUFFIX} file")
    check_writable(out, args.force)  # fail before a long import
    box = CropBox.of(args.crop) if args.crop is not None else None
    ckpt = read_checkpoint(args.input, **import_options(args))
    model = ckpt.model.to(dtype=getattr(torch, args.dtype))
    provenance = dict(ckpt.provenance) or {"source": str(Path(args.input).resolve()), "reader": "splatreel"}
    if args.up_axis is not None:
        provenance["up_axis"] = args.up_axis
    if box is not None:
        before = len(model)
        model = apply_crop(model, args.crop)
        provenance["crop"] = box.provenance(len(model), before)
    save_checkpoint(out, model, background=ckpt.background, provenance=provenance, training=ckpt.training,
                    force=args.force, views=ckpt.views)  # a crop or a new dtype keeps the training cameras
    t0, t1 = model.time_range
    print(f"wrote {out}: {model.kind}, {len(model):,} Gaussians, time {t0:g}..{t1:g}{_kind_details(model)}, "
          f"SH degree {model.sh_degree}")
    return 0


def _kind_details(model) -> str:
    """What the printed line adds for a model's kind: a keyframed model's keys, a skinned model's nodes."""
    if model.kind == "keyframed":
        return f", {model.num_frames} keyframes"
    if model.kind == "skinned":
        return f", {model.num_nodes:,} control nodes over {model.num_keys} key times"
    return ""
