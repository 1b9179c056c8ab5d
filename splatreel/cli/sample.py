"""``splatreel sample NAME --out DIR``: render a procedural animated object to a D-NeRF layout dataset, or build a
model."""

from __future__ import annotations

import argparse

ORDER = 20
HELP = "render a procedural animated test object to a dataset (D-NeRF layout) and/or a 4D Gaussian model"
DESCRIPTION = """\
Render a procedural animated test object (see --list) from an orbit of cameras to a multi-view video dataset in
the D-NeRF layout: DIR/transforms_{train,test,val}.json, DIR/train/r_000.png ..., DIR/test/..., DIR/sample.json.
Training images are an image matrix of --views azimuths x --time-steps times (ordered by time, then view), or with
--one-camera-per-time one image per time, frame f by camera f mod --views (D-NeRF's monocular regime); test images
use other azimuths and elevations at times between the training frames. --model also writes a native 4D Gaussian
checkpoint built from the object's known motion (no training); --trained copies the bundled checkpoint that
`splatreel train` fitted to the sample's default dataset (samples marked 'trained' in --list).

The scene 'floor' has its own rig instead: moving objects above a white floor to the horizon, 12 fixed cameras
(11 around it, one straight down from above), ONE camera per time (frame i by camera i mod 12; test images at
those cameras, times between), and alpha that marks what lies nearer than a far clip, so the top camera's floor
is transparent while the side cameras' is opaque (on purpose). It takes --time-steps (default 96, at least 12),
--size (200), --test-views (12) and --fov (45); --views, --elevation and --radius do not apply to it. Its
--model is the scene's exact model (by default 5 Gaussians per pixel of --size; white background): the objects
from their known motion, the floor as static Gaussians where most cameras see it nearer than the far clip.
`splatreel eval` of it on the dataset gives the upper bound a trained model is compared with (pass the dataset's
--time-steps, --size and --fov).

examples:
  splatreel sample --list
  splatreel sample spinner --out data/spinner
  splatreel sample wave --out data/wave --views 8 --time-steps 24 --size 512
  splatreel sample walker --out data/walker-dnerf --views 12 --time-steps 96 --size 200 --one-camera-per-time
  splatreel sample morph --model morph.safetensors
  splatreel sample spinner --trained spinner.safetensors
  splatreel sample floor --out data/floor --time-steps 48
  splatreel sample floor --out data/floor --time-steps 48 --model floor.safetensors
"""


def add_args(p: argparse.ArgumentParser) -> None:
    from ..argtypes import count, finite_number, non_negative_count, positive_number

    p.add_argument("name", nargs="?", metavar="NAME", help="sample to render (see --list)")
    p.add_argument("--out", "-o", metavar="DIR",
                   help="dataset folder to write (may be left out with --model or --trained)")
    p.add_argument("--list", action="store_true", help="list the samples with a one-line description and exit")
    d = p.add_argument_group("dataset")
    # Defaults are None so that a scene can tell an option given from one left out (see _scene_config).
    d.add_argument("--views", type=count, default=None, help="training azimuths per frame, evenly spaced (default 16)")
    d.add_argument("--time-steps", type=count, default=None, metavar="N",
                   help="training times f/(N-1), f = 0..N-1; also the model's key times (default 16; floor: 96)")
    d.add_argument("--size", type=count, default=None, help="image width = height in pixels (default 256; floor: 200)")
    d.add_argument("--elevation", type=finite_number, default=None,
                   help="training elevation, degrees above the horizon (default 30)")
    d.add_argument("--radius", type=positive_number, default=None, help="camera distance from the origin (default 2.5)")
    d.add_argument("--fov", type=positive_number, default=None,
                   help="field of view in degrees (default 49.13: fx = 280 px at 256 px, as Efficient4D; floor: 45)")
    d.add_argument("--test-views", type=non_negative_count, default=None, help="number of test images (default 16; floor: 12)")
    d.add_argument("--one-camera-per-time", action="store_true",
                   help="film the way D-NeRF's captures do: frame f is seen by camera f mod --views alone, instead "
                        "of every camera at every frame (e.g. --views 12 --time-steps 96)")
    m = p.add_argument_group("model")
    m.add_argument("--model", metavar="MODEL.safetensors",
                   help="also write a 4D Gaussian checkpoint built from the sample's known motion")
    m.add_argument("--trained", metavar="CKPT.safetensors",
                   help="also copy the bundled trained checkpoint of the sample here")
    m.add_argument("--gaussians", type=count, default=None,
                   help="Gaussians in the model (default 20000; floor: 5 per pixel, 200000 at 200 px)")
    m.add_argument("--seed", type=non_negative_count, default=0, help="surface sampling seed of the model (default 0)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")


def _given(args: argparse.Namespace, **values) -> dict:
    """The options among `values` (dest -> value) that were given on the command line (not left at None)."""
    return {k: v for k, v in values.items() if v is not None}


def _object_config(args: argparse.Namespace):
    from ..samples import DatasetConfig

    return DatasetConfig(**_given(args, views=args.views, frames=args.time_steps, size=args.size,
                                  elevation=args.elevation, radius=args.radius, fov=args.fov,
                                  test_views=args.test_views,
                                  one_camera_per_time=args.one_camera_per_time or None))


def _scene_config(args: argparse.Namespace):
    """The `FloorConfig` of the options given; the orbit options are refused for a scene."""
    from ..errors import SplatreelError
    from ..samples import FloorConfig

    orbit_only = {"--views": args.views, "--elevation": args.elevation, "--radius": args.radius,
                  "--one-camera-per-time": args.one_camera_per_time or None}
    given = [flag for flag, value in orbit_only.items() if value is not None]
    if given:
        raise SplatreelError(f"{', '.join(given)} do{'es' if len(given) == 1 else ''} not apply to sample "
                           f"{args.name!r}: it has its own fixed rig of 12 cameras; "
                           "it takes --time-steps, --size, --test-views and --fov")
    return FloorConfig(**_given(args, frames=args.time_steps, size=args.size, test_views=args.test_views,
                                fov=args.fov))


def run(args: argparse.Namespace) -> int:
    import time

    from ..errors import SplatreelError
    from ..fileio import check_writable
    from ..samples import SAMPLES, SCENES, TRAINED, build_model, get_sample, trained_checkpoint, write_dataset

    if args.list:
        listed = {**SAMPLES, **SCENES}
        width = max(len(n) for n in listed)
        for name, description in listed.items():
            print(f"{name:<{width}}  {description}{'  (trained checkpoint bundled)' if name in TRAINED else ''}")
        return 0
    if not args.name:
        raise SplatreelError(f"give a sample NAME ({', '.join([*SAMPLES, *SCENES])}) and an --out folder, --model "
                           "and/or --trained")
    get_sample(args.name)  # unknown name: one line listing the names
    if not args.out and not args.model and not args.trained:
        raise SplatreelError("nothing to write: give --out DIR, --model MODEL.safetensors and/or --trained CKPT")
    scene = args.name in SCENES
    config = _scene_config(args) if scene else _object_config(args)
    bundled = trained_checkpoint(args.name) if args.trained else None  # not bundled: fail before any work
    for path in (args.out, args.model, args.trained):  # fail before any work, not after
        if path:
            check_writable(path, args.force)

    if args.model:
        from ..checkpoint import save_checkpoint

        model = build_model(args.name, num_gaussians=args.gaussians, frames=config.frames, seed=args.seed,
                            config=config)
        # A scene's dataset is composited on white by the D-NeRF convention (train.data), so its model is scored
        # and drawn on white; the object models keep the black they always had.
        background = (1.0, 1.0, 1.0) if scene else (0.0, 0.0, 0.0)
        save_checkpoint(args.model, model, background=background,
                        provenance={"tool": "splatreel sample", "sample": args.name, "frames": config.frames,
                                    "seed": args.seed, "up_axis": "z"}, force=args.force)  # samples are +Z up
        print(f"wrote {args.model}: {len(model):,} Gaussians from sample {args.name!r}")
    if bundled is not None:
        from ..fileio import atomic_write_bytes

        atomic_write_bytes(args.trained, bundled.read_bytes(), force=args.force)
        print(f"wrote {args.trained}: the bundled checkpoint trained on sample {args.name!r}")
    if args.out:
        start = time.perf_counter()
        write_dataset(args.name, args.out, config, force=args.force, progress=True)
        n = config.frames if scene else config.views * config.frames
        print(f"wrote {args.out}: {n} training + {config.test_views} test images of sample {args.name!r} "
              f"({config.size}x{config.size}) in {time.perf_counter() - start:.1f} s")
    return 0
