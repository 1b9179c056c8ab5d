"""``splat4d sample NAME OUT``: render a procedural animated object to a D-NeRF layout dataset, or build a model."""

from __future__ import annotations

import argparse

ORDER = 20
HELP = "render a procedural animated test object to a dataset (D-NeRF layout) and/or a 4D Gaussian model"
DESCRIPTION = """\
Render a procedural animated test object (see --list) from an orbit of cameras to a multi-view video dataset in
the D-NeRF layout: OUT/transforms_{train,test,val}.json, OUT/train/r_000.png ..., OUT/test/..., OUT/sample.json.
Training images are an image matrix of --views azimuths x --frames times (ordered by time, then view); test images
use other azimuths and elevations at times between the training frames. --model also writes a native 4D Gaussian
checkpoint built from the object's known motion (no training); --trained copies the bundled checkpoint that
`splat4d train` fitted to the sample's default dataset (samples marked 'trained' in --list).

examples:
  splat4d sample --list
  splat4d sample spinner data/spinner
  splat4d sample wave data/wave --views 8 --frames 24 --size 512
  splat4d sample morph --model morph.safetensors
  splat4d sample spinner --trained spinner.safetensors
"""


def add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", nargs="?", metavar="NAME", help="sample to render (see --list)")
    p.add_argument("out", nargs="?", metavar="OUT", help="dataset folder to write (may be left out with --model)")
    p.add_argument("--list", action="store_true", help="list the samples with a one-line description and exit")
    d = p.add_argument_group("dataset")
    d.add_argument("--views", type=int, default=16, help="training azimuths per frame, evenly spaced (default 16)")
    d.add_argument("--frames", type=int, default=16,
                   help="training times f/(frames-1); also the model's key times (default 16)")
    d.add_argument("--size", type=int, default=256, help="image width = height in pixels (default 256)")
    d.add_argument("--elevation", type=float, default=30.0,
                   help="training elevation, degrees above the horizon (default 30)")
    d.add_argument("--radius", type=float, default=2.5, help="camera distance from the origin (default 2.5)")
    d.add_argument("--fov", type=float, default=None,
                   help="field of view in degrees (default 49.13: fx = 280 px at 256 px, as Efficient4D)")
    d.add_argument("--test-views", type=int, default=16, help="number of test images (default 16)")
    m = p.add_argument_group("model")
    m.add_argument("--model", metavar="MODEL.safetensors",
                   help="also write a 4D Gaussian checkpoint built from the object's motion")
    m.add_argument("--trained", metavar="CKPT.safetensors",
                   help="also copy the bundled trained checkpoint of the sample here")
    m.add_argument("--gaussians", type=int, default=20000, help="Gaussians in the model (default 20000)")
    m.add_argument("--seed", type=int, default=0, help="surface sampling seed of the model (default 0)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")


def run(args: argparse.Namespace) -> int:
    import time

    from ..errors import Splat4DError
    from ..fileio import check_writable
    from ..samples import SAMPLES, TRAINED, DatasetConfig, build_model, get_sample, trained_checkpoint, write_dataset

    if args.list:
        width = max(len(n) for n in SAMPLES)
        for name, description in SAMPLES.items():
            print(f"{name:<{width}}  {description}{'  (trained checkpoint bundled)' if name in TRAINED else ''}")
        return 0
    if not args.name:
        raise Splat4DError(f"give a sample NAME ({', '.join(SAMPLES)}) and an OUT folder, --model and/or --trained")
    get_sample(args.name)  # unknown name: one line listing the names
    if not args.out and not args.model and not args.trained:
        raise Splat4DError("nothing to write: give an OUT folder, --model MODEL.safetensors and/or --trained CKPT")
    bundled = trained_checkpoint(args.name) if args.trained else None  # not bundled: fail before any work
    config = DatasetConfig(views=args.views, frames=args.frames, size=args.size, elevation=args.elevation,
                           radius=args.radius, fov=DatasetConfig.fov if args.fov is None else args.fov,
                           test_views=args.test_views)
    for path in (args.out, args.model, args.trained):  # fail before any work, not after
        if path:
            check_writable(path, args.force)

    if args.model:
        from ..checkpoint import save_checkpoint

        model = build_model(args.name, num_gaussians=args.gaussians, frames=args.frames, seed=args.seed)
        save_checkpoint(args.model, model, provenance={"tool": "splat4d sample", "sample": args.name,
                                                       "frames": args.frames, "seed": args.seed},
                        force=args.force)
        print(f"wrote {args.model}: {len(model):,} Gaussians from sample {args.name!r}")
    if bundled is not None:
        from ..fileio import atomic_write_bytes

        atomic_write_bytes(args.trained, bundled.read_bytes(), force=args.force)
        print(f"wrote {args.trained}: the bundled checkpoint trained on sample {args.name!r}")
    if args.out:
        start = time.perf_counter()
        write_dataset(args.name, args.out, config, force=args.force, progress=True)
        n = config.views * config.frames
        print(f"wrote {args.out}: {n} training + {config.test_views} test images of sample {args.name!r} "
              f"({config.size}x{config.size}) in {time.perf_counter() - start:.1f} s")
    return 0
