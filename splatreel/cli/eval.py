"""``splatreel eval CKPT DATA``: render a dataset's test views and score them."""

from __future__ import annotations

import argparse

ORDER = 25
HELP = "render a dataset's test views with a model and report PSNR / SSIM per view and averaged"


def add_args(p: argparse.ArgumentParser) -> None:
    from splatreel.argtypes import argtype, count, parse_far_clip

    p.add_argument("checkpoint", metavar="CKPT", help="model file")
    p.add_argument("data", metavar="DATA", help="dataset folder")
    p.add_argument("--out", "-o", metavar="JSON", help="also write the results as JSON to this file")
    p.add_argument("--split", choices=["test", "train"], default="test",
                   help="which views to render (default: test; datasets without test views need train)")
    p.add_argument("--downscale", type=count, default=1, metavar="K",
                   help="evaluate at 1/K resolution (default 1; use the --downscale the model was trained at)")
    p.add_argument("--layout", default="auto", choices=["auto", "dnerf", "orbit", "efficient4d", "sv4d"],
                   help="dataset layout (default auto: detected from the folder, as train does)")
    p.add_argument("--background", type=float, nargs=3, metavar=("R", "G", "B"),
                   help="background colour (default: the checkpoint's)")
    p.add_argument("--far-clip", type=argtype(parse_far_clip), default="auto", metavar="auto|none|D",
                   help="cull what lies at or beyond this camera depth, as the images' alpha was cut (default auto: "
                        "the far clip the checkpoint's training found, if any; none: render everything)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")


def run(args: argparse.Namespace) -> int:
    from splatreel.errors import DatasetError
    from splatreel.fileio import atomic_write_json, check_writable
    from splatreel.formats import read_checkpoint
    from splatreel.train.data import load_dataset
    from splatreel.train.evaluate import evaluate

    if args.out:
        check_writable(args.out, args.force)
    ck = read_checkpoint(args.checkpoint)
    ds = load_dataset(args.data, layout=args.layout, downscale=args.downscale)
    views = ds.test if args.split == "test" else ds.train
    if not views:
        raise DatasetError(f"{args.data}: no {args.split} views (use --split train for generated data)")
    bg = tuple(args.background) if args.background else ck.background
    far = {"auto": ck.training.get("far_clip_depth"), "none": None}.get(args.far_clip, args.far_clip)
    res = evaluate(ck.model, views, bg, progress=True, far_clip=far)
    res.update({"checkpoint": str(args.checkpoint), "dataset": str(args.data), "split": args.split,
                "downscale": args.downscale})
    clip = "" if far is None else f"  (far clip at depth {far:g})"
    print(f"{args.split} views: {res['num_views']}  PSNR {res['psnr']:.2f} dB  SSIM {res['ssim']:.4f}  "
          f"({res['seconds']:.1f} s){clip}")
    if args.out:
        atomic_write_json(args.out, res, force=args.force)
    return 0
