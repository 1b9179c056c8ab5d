"""``splatreel render CKPT --out FILE``: render a model to video or images through EGL, with no display."""

from __future__ import annotations

import argparse

ORDER = 45
HELP = "render a model to a video (.mp4/.mov/.webm), PNG/EXR frames or one image, headless (orbit, spiral, path)"
DESCRIPTION = """Render a model offscreen (EGL; no display needed) along a camera trajectory.

Output by name: FILE.mp4 (H.264), FILE.mov (ProRes 422 HQ; 4444 with alpha), FILE.webm (VP9, alpha too),
FILE.png / FILE.exr (one image; EXR keeps alpha), or a folder name without a suffix (numbered frames,
--image-format png|exr). Existing outputs are kept unless --force.

examples:
  splatreel render --out sample.mp4                  (the bundled trained sample)
  splatreel render model.safetensors --out orbit.mp4
  splatreel render model.safetensors --out spin.mp4 --trajectory spiral --turns 2 --time-mode timelapse
  splatreel render model.safetensors --out frames --image-format exr --background transparent --frame-count 48
  splatreel render model.safetensors --out comp.mov --background transparent     (ProRes 4444 for editors)
  splatreel render model.safetensors --out core.mp4 --crop -0.5 -0.5 -0.5 0.5 0.5 0.5   (only what is in the box)
  splatreel render model.safetensors --out still.png --frame-count 1 --time 0.5 --azimuth 45
  splatreel render model.safetensors --out tour.mp4 --path tour.json
  splatreel render model.safetensors --out train_views.mp4 --cameras data/spinner --fps 10
  splatreel render model.safetensors --out orbit.mp4 --save-cameras orbit_cameras.json   (the same cameras elsewhere)
  splatreel render scene.safetensors --out pano.mp4 --projection equirect --path inside.json   (360° video)
"""


def add_args(p: argparse.ArgumentParser) -> None:
    from splatreel.viewer.options import add_look_args, argtype, parse_size, parse_vector
    from splatreel.viewer.panorama import PROJECTIONS
    from splatreel.argtypes import count, finite_number, non_negative_count, positive_number

    from ._shared_options import add_crop_arg, add_up_arg

    p.add_argument("checkpoint", metavar="CKPT", nargs="?", default=None,
                   help="model file (splatreel checkpoint or any importable format; default: the bundled sample)")
    p.add_argument("--out", "-o", required=True, metavar="FILE",
                   help="output: .mp4, .mov, .webm, .png, .exr, or a folder name for a frame sequence")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.add_argument("--save-cameras", metavar="JSON",
                   help="also write every frame's camera and model time as a nerfstudio camera path (ns-render "
                        "camera-path, the nerfstudio viewer; --path reads it back frame for frame)")
    g = p.add_argument_group("frames")
    g.add_argument("--size", type=argtype(parse_size), default=None, metavar="WxH",
                   help="image size in pixels (default: the camera path file's, else 1280x720, or 2048x1024 for "
                        "--projection equirect; even for .mp4 and .webm)")
    g.add_argument("--fps", type=positive_number, default=None,
                   help="frames per second (default: the camera path file's, else 30)")
    g.add_argument("--frame-count", type=count, default=None, metavar="N",
                   help="number of frames (default: 1 for a .png/.exr image, else --seconds x --fps, or the whole "
                        "camera path)")
    g.add_argument("--seconds", type=positive_number, default=4.0, help="video length for orbit/spiral (default 4)")
    g.add_argument("--image-format", choices=("png", "exr"), default="png", help="format of a frame folder")
    g.add_argument("--crf", type=non_negative_count, default=None,
                   help="constant quality of .mp4 (0 lossless .. 51) or .webm (0 .. 63); default 18")
    c = p.add_argument_group("camera")
    c.add_argument("--trajectory", choices=("orbit", "spiral", "path"), default=None,
                   help="camera motion (default orbit; path when --path or --cameras is given)")
    c.add_argument("--path", metavar="JSON", help="keyframed camera path file (format: the docs' Camera path page)")
    c.add_argument("--cameras", metavar="DATASET",
                   help="use the cameras of a training dataset as path: a D-NeRF layout folder or transforms json, "
                        "or a checkpoint trained by splatreel (it records its training cameras, any layout)")
    c.add_argument("--split", default="train", help="dataset split for --cameras (default train)")
    c.add_argument("--seconds-per-key", type=positive_number, default=0.5,
                   help="seconds between dataset cameras for --cameras (default 0.5)")
    c.add_argument("--elevation", type=finite_number, default=20.0, help="orbit elevation in degrees (default 20)")
    c.add_argument("--azimuth", type=finite_number, default=0.0, help="starting azimuth in degrees (default 0)")
    c.add_argument("--amplitude", type=finite_number, default=25.0,
                   help="spiral: elevation swing in degrees around --elevation (default 25)")
    c.add_argument("--turns", type=finite_number, default=1.0, help="full turns around the object (default 1)")
    c.add_argument("--distance", type=positive_number, default=None, help="camera distance (default: frame the model)")
    c.add_argument("--target", type=argtype(lambda s: parse_vector(s, 3, "target")), default=None,
                   metavar="X,Y,Z", help="point to orbit around (default: centre of the model)")
    c.add_argument("--fov", type=positive_number, default=40.0, help="vertical field of view in degrees (default 40)")
    c.add_argument("--projection", choices=PROJECTIONS, default=None,
                   help="equirect: 360° panoramas (2:1) seen from each camera's position, its view direction at "
                        "the centre, .mp4/.mov tagged as 360° video; --fov does not apply (default perspective, or "
                        "what the path file says)")
    add_up_arg(c)
    t = p.add_argument_group("scene time")
    t.add_argument("--time-mode", choices=("loop", "timelapse", "hold", "path"), default=None,
                   help="loop: the animation repeats every --loop-seconds; timelapse: one pass over the whole "
                        "video; hold: a fixed --time; path: the camera path's scene_time keys (default: path "
                        "when the path has them, hold with --time, else loop)")
    t.add_argument("--time", type=finite_number, default=None, help="model time for --time-mode hold")
    t.add_argument("--loop-seconds", type=positive_number, default=2.0,
                   help="video seconds per pass through the time range in loop mode (default 2)")
    s = p.add_argument_group("look")
    add_look_args(s)
    s.add_argument("--map-range", type=argtype(lambda s: parse_vector(s, 2, "--map-range")), default=None,
                   metavar="LO,HI", help="ends of the colour map of --mode depth (near,far camera depth), speed "
                                         "(slow,fast in world units per unit of model time), lifespan "
                                         "(brief,long in model time) or fade; default: the depths seen over the "
                                         "video, 0 to the model's 98th-percentile speed, 0 to the model's time "
                                         "span, 0 to 1")
    add_crop_arg(s, "; orbits frame what is left")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def request_of(args: argparse.Namespace):
    """The `RenderRequest` of the parsed options."""
    from splatreel.viewer.render_job import RenderRequest

    return RenderRequest(
        out=args.out, trajectory=args.trajectory, path_file=args.path, cameras=args.cameras, split=args.split,
        seconds_per_key=args.seconds_per_key, size=args.size, fps=args.fps, frame_count=args.frame_count,
        seconds=args.seconds, elevation=args.elevation, azimuth=args.azimuth, amplitude=args.amplitude,
        turns=args.turns, distance=args.distance, target=args.target, fov=args.fov, projection=args.projection,
        up=args.up, time_mode=args.time_mode, time=args.time, loop_seconds=args.loop_seconds)


def run(args: argparse.Namespace) -> int:
    import statistics
    from pathlib import Path

    from splatreel.fileio import atomic_write_json, check_writable
    from splatreel.formats import read_checkpoint
    from splatreel.samples.trained import trained_checkpoint
    from splatreel.viewer.camera_path import nerfstudio_camera_path
    from splatreel.viewer.headless import render_to_file
    from splatreel.viewer.options import OptionError, look_settings
    from splatreel.viewer.render_job import check_request, load_camera_path, plan_render

    from ._shared_options import apply_crop

    request = check_request(request_of(args))
    if args.map_range is not None and not args.map_range[0] < args.map_range[1]:
        raise OptionError(f"--map-range needs LO < HI, got {args.map_range[0]:g},{args.map_range[1]:g}")
    if args.save_cameras:
        check_writable(args.save_cameras, args.force)
        if Path(args.save_cameras).resolve() == Path(args.out).resolve():
            raise OptionError(f"--save-cameras {args.save_cameras} is the --out file; give the cameras a file of "
                              "their own")
    ckpt = read_checkpoint(args.checkpoint or str(trained_checkpoint("spinner")))
    model = apply_crop(ckpt.model, args.crop)
    settings = look_settings(args, ckpt.background, value_range=args.map_range)
    job = plan_render(request, model, load_camera_path(request, model.time_range), settings)

    summary = render_to_file(model, args.out, job.cameras, job.times, job.settings, job.fps, args.image_format,
                             args.force, progress=False if args.quiet else "render", crf=args.crf,
                             equirect=job.equirect)
    if args.save_cameras:
        atomic_write_json(args.save_cameras, nerfstudio_camera_path(job.cameras, job.fps, job.times,
                                                                    model.time_range, job.projection, job.size),
                          args.force)
    median = lambda xs: statistics.median(xs) if xs else 0.0  # noqa: E731  (the first frame compiles kernels)
    width, height = job.size
    print(f"wrote {args.out}: {summary.frames} frame{'s' * (summary.frames != 1)} {width}x{height}"
          + (f" at {job.fps:g} fps" if summary.frames > 1 else "")
          + f", {len(model):,} Gaussians, median sort {median(summary.sort_ms):.1f} ms + draw "
            f"{median(summary.draw_ms):.1f} ms per frame" + (f"; cameras in {args.save_cameras}"
                                                             if args.save_cameras else ""))
    return 0
