"""``splatreel train DATA --out CKPT``: fit native 4D Gaussians to a multi-view video dataset."""

from __future__ import annotations

import argparse

ORDER = 20
HELP = "fit 4D Gaussians to a multi-view video / image-matrix dataset"
DESCRIPTION = """Fit native 4D Gaussians to a dataset and write a splatreel checkpoint.

Layouts (auto-detected): dnerf (transforms_*.json), orbit (views/<v>/<f>.png + cameras.json), efficient4d
(<f>.png strips of 16 views), sv4d (*_v00k.mp4). The default preset, auto, reads the data (views per time, an open
floor or backdrop in the alpha, image size, a point cloud beside it), prints what it decided and why, and trains for
a time budget (--minutes); every decision has an option. Named presets: efficient4d (500 iterations, no
densification) and full (the official 4DGS schedule). Ctrl-C saves a resumable checkpoint; --resume continues it."""


def _ramp(text: str) -> tuple[tuple[float, int], ...]:
    try:
        pairs = [p.split(":") for p in text.split(",") if p]
        return tuple((float(f), int(k)) for f, k in pairs)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected FRACTION:FACTOR[,...] like 0.2:4,0.5:2, got {text!r}") from None


def add_args(p: argparse.ArgumentParser) -> None:
    from splatreel.argtypes import (argtype, count, fraction, non_negative_count, non_negative_number, parse_far_clip,
                                    positive_number)
    from splatreel.train.config import FAR_CLIP_AT, MOTIONS, NODE_TEMPLATES, PRESETS, SPLITS
    from splatreel.train.recipe import (CLIP_DURATION, FLOW_MOTION_AT, INBETWEEN_SHARE, MATRIX_MINUTES,
                                        ONE_VIEW_MINUTES, ONE_VIEW_NODE_KEY_EVERY, SCALE_RATIO_WEIGHT)

    p.add_argument("data", metavar="DATA", help="dataset folder")
    p.add_argument("--out", "-o", required=True, metavar="CKPT", help="output checkpoint (.safetensors)")
    p.add_argument("--preset", default="auto", choices=list(PRESETS),
                   help="; ".join(f"{k}: {v[0]}" for k, v in PRESETS.items()))
    budget = p.add_mutually_exclusive_group()
    budget.add_argument("--minutes", type=positive_number, metavar="M",
                        help="time budget: the run ends after M minutes, set-up included, and every schedule "
                             "stretches to it (default: the auto recipe's, "
                             f"{MATRIX_MINUTES:g} for an image matrix, {ONE_VIEW_MINUTES:g} for one camera per time)")
    budget.add_argument("--iters", type=count, help="run this many iterations instead of a time budget (the "
                                                  "preset's schedules scale with it; runs are then reproducible)")
    p.add_argument("--resume", action="store_true", help="continue the run saved in --out (bit for bit)")
    p.add_argument("--seed", type=non_negative_count, default=0, help="random seed (default 0)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out")
    p.add_argument("--layout", default="auto", choices=["auto", "dnerf", "orbit", "efficient4d", "sv4d"],
                   help="dataset layout (default: detect)")
    p.add_argument("--downscale", type=count, default=1, metavar="K", help="train on images K times smaller (default 1)")
    p.add_argument("--background", type=float, nargs=3, metavar=("R", "G", "B"),
                   help="background colour in [0,1] that RGBA images are composited on (default: the dataset "
                        "JSON's 'background', else the layout's convention: white for D-NeRF, Efficient4D and SV4D, "
                        "black for RGBA orbit data; a resumed run keeps its checkpoint's)")
    p.add_argument("--strict-alpha", action="store_true",
                   help="train on the alpha as given even where views contradict each other (default: transparent "
                        "pixels whose rays cross a surface other views see opaque get no loss)")
    p.add_argument("--far-clip", type=argtype(parse_far_clip), metavar="auto|none|D",
                   help="the camera depth the images' alpha was cut at (a renderer's far clip: a floor opaque up to "
                        "it, transparent past it): training and the test views are rendered with it. auto: where the "
                        f"views' alpha disagree, read off the model at {100 * FAR_CLIP_AT:g}%% of the run; none: "
                        "render everything (default: auto; a resumed run keeps its own)")
    p.add_argument("--num-gaussians", type=count, help="Gaussians at initialisation (default: the preset's; train prints it)")
    p.add_argument("--max-gaussians", type=count, help="cap on densification (default: the recipe's)")
    p.add_argument("--no-densify", action="store_true", help="keep the initial Gaussians (no clone, split or prune)")
    p.add_argument("--split", choices=SPLITS,
                   help="how densification splits a large Gaussian: space (the children keep its temporal extent, "
                        "so they stay seen by as many cameras) or spacetime (official 4DGS: they are also 1.6x "
                        "shorter-lived and scattered in time) (default: the preset's, space for auto; a resumed run keeps "
                        "its own)")
    p.add_argument("--init", choices=["auto", "ball", "frustum", "points"], default="auto",
                   help="initial Gaussians: in a ball carved by the masks, over the volume the cameras see, or on a "
                        "point cloud (default: the dataset's fused.ply / points3d.ply / COLMAP points3D when it has "
                        "one, else frustum for an open floor or backdrop, else ball)")
    p.add_argument("--init-points", metavar="FILE", help="point cloud (PLY or COLMAP points3D) to initialise on")
    p.add_argument("--scale-ratio-weight", type=non_negative_number, metavar="W",
                   help="penalty on Gaussians more than 10:1 anisotropic (default: the recipe's, "
                        f"{SCALE_RATIO_WEIGHT:g}; the named presets 0)")
    p.add_argument("--t-scale-init", type=positive_number, metavar="FRAMES",
                   help="initial temporal std-dev of the Gaussians, in frame intervals (default: the recipe's)")
    p.add_argument("--clip-duration", type=positive_number, metavar="UNITS",
                   help="length of the clip on the trainer's own time axis: a longer clip lets the Gaussians move "
                        f"with less tilt in space-time (default: the recipe's, {CLIP_DURATION:g}; the checkpoint keeps "
                        "the dataset's times; a resumed run keeps its own)")
    p.add_argument("--flow-motion-at", type=fraction, metavar="F",
                   help="at this share of the run, set every Gaussian's velocity once from the optical flow between "
                        "each camera's consecutive frames, lifted to 3D by the model's depth (default: the recipe's, "
                        f"{FLOW_MOTION_AT:g}; 0 = never; needs cameras that film consecutive frames, else it is "
                        "ignored with a note, save with --motion nodes, whose nodes are then tracked by the model's "
                        "own motion at this share)")
    p.add_argument("--inbetween-share", type=fraction, metavar="F",
                   help="share of the images a step draws that are frames optical flow interpolates half-way "
                        "between a camera's consecutive frames (default: the recipe's, "
                        f"{INBETWEEN_SHARE:g} for an image matrix; 0 = none; needs cameras that film consecutive "
                        "frames, else it is ignored with a note)")
    p.add_argument("--motion", choices=MOTIONS,
                   help="how the Gaussians move: linear (native 4DGS), quadratic (each also learns an acceleration, "
                        "so it can follow a curved path; exported where the format holds it), nodes (quadratic "
                        "until the flow step, then carried by control nodes tracked by the optical flow, so one "
                        "Gaussian follows its part through every time; with one camera per time, no flow: the nodes "
                        "are tracked by the model's own motion; "
                        "a skinned checkpoint) or auto (quadratic until the flow step; then, where one rigid motion "
                        "per frame, fitted to the images, carries the middle frame's Gaussians to every frame, nodes "
                        "carrying that one set for the whole clip, else quadratic on) (default: the recipe's, auto "
                        "for an image matrix, nodes for one camera per time; the named presets linear; a resumed "
                        "run keeps its own)")
    p.add_argument("--node-template", choices=NODE_TEMPLATES,
                   help="with nodes: keep only the middle frame's Gaussians, drawn at every time and carried by the "
                        "nodes, one set for the whole clip (on), never (off), or when the nodes carry them to every "
                        "frame and they draw every frame nearly as well as the middle one (auto) (default: auto; a "
                        "resumed run keeps its own)")
    p.add_argument("--node-key-every", type=count, metavar="K",
                   help="with nodes: key their learned poses every K frames (and at the last), the times between on "
                        "their spline; with one camera per time a pose keyed at every frame is fitted by one image "
                        f"and can fake its depth (default: the recipe's, {ONE_VIEW_NODE_KEY_EVERY} for one camera "
                        "per time, else 1; a resumed run keeps its own)")
    p.add_argument("--colour-tracks", choices=("on", "off"),
                   help="with nodes and one camera per time: follow the groups of nodes that the model's own motion "
                        "loses (a part it barely draws at the switch to nodes) by their colour in the images, "
                        "against each camera's median image (default: the recipe's, on for one camera per time; a "
                        "resumed run keeps its own)")
    p.add_argument("--static-share", type=fraction, metavar="F",
                   help="share of the initial Gaussians that start static, shared by every time (default 0: none; "
                        "measured on the floor sample, 0.3 brings back detail (SSIM up) at a lower PSNR)")
    p.add_argument("--init-mesh", metavar="FILE", help="initialise on the surface of this mesh (4DGen)")
    p.add_argument("--sh-degree", type=int, choices=range(4), help="spatial SH degree, 0-3 (default: the preset's; train prints it)")
    p.add_argument("--sh-degree-t", type=int, choices=range(3), help="time (Fourier) SH degree, 0-2 (default: the preset's)")
    p.add_argument("--static-iters", type=non_negative_count, help="first fit frame 0 with time frozen for this many iterations "
                                                     "(SV4D static-to-dynamic)")
    p.add_argument("--resolution-ramp", type=_ramp, metavar="F:K,...",
                   help="coarse-to-fine: train at 1/K resolution until fraction F of the iterations, e.g. 0.2:4,0.5:2")
    p.add_argument("--smooth-weight", type=non_negative_number, help="temporal smoothness weight (4DGen-style; 0 = off; default: the preset's)")
    p.add_argument("--no-confidence", action="store_true", help="disable Efficient4D's confidence weights")
    p.add_argument("--batch-size", type=count, help="images per step (default: the preset's; train prints it)")
    p.add_argument("--checkpoint-every", type=non_negative_count, metavar="N", help="also write a checkpoint every N iterations (default: the preset's; 0 = only at the end)")
    p.add_argument("--stop-at", type=count, metavar="N", help="stop after iteration N, leaving a resumable run")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"], help="compute device")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def config_from_args(args: argparse.Namespace, dataset=None, resumed: dict | None = None):
    """(TrainConfig, decisions): the preset (the auto recipe reads `dataset`) or the resumed run's stored config,
    then the command-line overrides."""
    import dataclasses

    from splatreel.train.config import TrainConfig, preset
    from splatreel.train.recipe import auto_recipe, read_traits

    decisions = []
    if resumed:
        cfg = TrainConfig.from_dict(resumed)
    elif args.preset == "auto":
        cfg, decisions = auto_recipe(read_traits(dataset))
    else:
        cfg = preset(args.preset)
    if args.iters and not resumed:
        cfg = dataclasses.replace(cfg.scaled(args.iters), minutes=None)
    elif args.iters:
        cfg = dataclasses.replace(cfg, iters=args.iters, minutes=None)
    if args.minutes:
        cfg = dataclasses.replace(cfg, minutes=args.minutes)
    over = {"seed": args.seed if not resumed else cfg.seed, "strict_alpha": args.strict_alpha or None,
            "num_gaussians": args.num_gaussians,
            "init_mesh": args.init_mesh, "sh_degree": args.sh_degree, "sh_degree_t": args.sh_degree_t,
            "static_iters": args.static_iters, "resolution_ramp": args.resolution_ramp,
            "smooth_weight": args.smooth_weight, "batch_size": args.batch_size,
            "checkpoint_every": args.checkpoint_every, "device": args.device,
            "lambda_scale_ratio": args.scale_ratio_weight, "t_scale_init_frames": args.t_scale_init,
            "static_share": args.static_share, "clip_duration": None if resumed else args.clip_duration,
            "flow_motion_at": args.flow_motion_at,
            "inbetween_share": args.inbetween_share, "motion": None if resumed else args.motion,
            "node_template": None if resumed else args.node_template,
            "node_key_every": None if resumed else args.node_key_every,
            "far_clip": None if resumed else args.far_clip,
            "colour_tracks": None if resumed or args.colour_tracks is None else args.colour_tracks == "on"}
    if args.no_confidence:
        over["confidence"] = False
    if args.init_points:
        over.update(init="points", init_points=args.init_points)
    elif args.init != "auto":
        over["init"] = args.init
    dens = {}
    if args.max_gaussians:
        dens["max_gaussians"] = args.max_gaussians
    if args.no_densify:
        dens["enabled"] = False
    if args.split and not resumed:
        dens["split"] = args.split
    if dens:
        over["densify"] = dataclasses.replace(cfg.densify, **dens)
    return dataclasses.replace(cfg, **{k: v for k, v in over.items() if v is not None}), decisions


def given_value(args: argparse.Namespace, option: str) -> str | None:
    """How `option` (e.g. '--minutes') was given on the command line, or None when it was left to the recipe."""
    value = getattr(args, option.lstrip("-").replace("-", "_"), None)
    if value is None or value is False or value == "auto":
        return None
    if value is True:
        return ""
    if option == "--resolution-ramp":
        return ",".join(f"{f:g}:{k}" for f, k in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def node_outcome_line(outcome: dict | None, motion: str) -> str | None:
    """What the switch to control nodes decided (`Trainer.node_outcome`), in one line; None when there was none."""
    if outcome is None:
        return None
    ratio, measure = (outcome["silhouette_ratio"], "silhouette error") if outcome.get("silhouette_ratio") \
        is not None else (outcome["template_ratio"], "error")
    fit = "" if ratio is None or ratio == float("inf") else \
        f" (its worst frame fitted: {ratio:.2f} times its {measure} at the middle frame)"
    if outcome.get("tracked_by") == "motion":
        colour = outcome.get("colour_tracks") or {}
        groups, joined = colour.get("groups", 0), colour.get("joined", 0)
        found = "" if not groups else (
            f"; {groups} group{'s' * (groups > 1)} of nodes it lost found again by colour in the images"
            + (f" ({joined} node{'s' * (joined > 1)} pinned as still joined)" if joined else ""))
        return ("control nodes tracked by the model's own motion carry each frame's Gaussians (no camera films "
                "consecutive frames: no optical flow)" + found)
    if outcome["template"]:
        return ("one set of Gaussians for the whole clip: one rigid motion per frame carries the middle frame's to "
                f"every frame{fit}; --node-template off to change")
    return ("every frame keeps its own Gaussians: one rigid motion per frame does not carry the middle frame's to "
            f"every frame{fit}" + ("; the motion stays quadratic" if motion == "auto" else ""))


def background_name(rgb) -> str:
    """'white', 'black' or 'R G B' for a background colour."""
    names = {(1.0, 1.0, 1.0): "white", (0.0, 0.0, 0.0): "black"}
    return names.get(tuple(float(x) for x in rgb), " ".join(f"{x:g}" for x in rgb))


def run(args: argparse.Namespace) -> int:
    import time

    started = time.perf_counter()  # a time budget covers the whole command
    from pathlib import Path

    from splatreel.checkpoint_file import read_metadata
    from splatreel.errors import SplatreelError
    from splatreel.train.alpha_conflicts import describe
    from splatreel.train.data import camera_videos, load_dataset
    from splatreel.train.trainer import Trainer

    if not args.resume:  # refuse before the dataset is read (that can take minutes)
        from splatreel.fileio import check_writable

        check_writable(args.out, args.force)
    resumed, recorded_bg = None, None
    if args.resume:
        if not Path(args.out).exists():
            raise SplatreelError(f"--resume: {args.out} does not exist")
        meta = read_metadata(args.out)
        resumed = meta.get("training") or None
        if resumed:
            run_facts = ("iteration", "dataset", "layout", "background_reason", "alpha_disagreement", "alpha_ignored",
                         "nodes")
            resumed = {k: v for k, v in resumed.items() if k not in run_facts}
        recorded_bg = meta.get("background")
    ds = load_dataset(args.data, layout=args.layout, downscale=args.downscale, background=args.background)
    cfg, decisions = config_from_args(args, ds, resumed)
    if recorded_bg is not None and args.background is None:  # a run keeps the background it started with
        ds.background, ds.background_reason = tuple(float(x) for x in recorded_bg), "the resumed checkpoint's"
    length = f"{cfg.minutes:g} minutes" if cfg.minutes else f"{cfg.iters} iterations"
    print(f"splatreel train: {ds.summary()}; preset {cfg.preset}, {length}" + (":" if decisions else ""))
    for d in decisions:
        # a count of iterations replaces the time budget
        instead = f"--iters {args.iters}" if d.option == "--minutes" and args.iters and not args.minutes else None
        print(f"  - {d.line(given_value(args, d.option), instead)}")
    unused = [o for o, v in (("--flow-motion-at", args.flow_motion_at and cfg.motion != "nodes"),
                             ("--inbetween-share", args.inbetween_share)) if v]
    if unused and not camera_videos(ds):  # what the user asked for; the recipe's own values are not news
        print(f"splatreel train: {' and '.join(unused)} ignored: no camera films two consecutive frames, so there is "
              "no flow to follow")
    print(f"splatreel train: background {background_name(ds.background)}: {ds.background_reason}"
          + ("" if ds.background_reason == "--background" else "; --background R G B to change"))
    trainer = Trainer(ds, cfg, args.out, resume=args.resume, force=args.force, progress=not args.quiet,
                      started=started)
    print(f"splatreel train: {describe(trainer.alpha_conflicts, cfg.strict_alpha, ds.train)}")
    try:
        result = trainer.run(stop_at=args.stop_at)
    except KeyboardInterrupt:
        print(f"splatreel train: interrupted at iteration {trainer.step}; saved {args.out} (continue with --resume)")
        return 130
    line = node_outcome_line(trainer.node_outcome, cfg.motion)
    if line and not args.resume:
        print(f"splatreel train: {line}")
    if trainer.far_clip is not None and trainer.alpha_conflicts.detected and not args.resume:
        print(f"splatreel train: {trainer.far_clip.describe()}")
    msg = f"splatreel train: wrote {result.out} ({result.n_gaussians:,} Gaussians, {result.iterations} iterations, " \
          f"{result.seconds:.1f} s)"
    done = trainer.finished()
    if not done:
        msg += "; stopped early, continue with --resume"
    print(msg)
    if done and ds.test:
        ev = trainer.evaluate_test()
        print(f"splatreel train: test views: PSNR {ev['psnr']:.2f} dB, SSIM {ev['ssim']:.4f} "
              f"({ev['num_views']} views)")
    return 0
