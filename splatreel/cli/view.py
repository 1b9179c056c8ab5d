"""``splatreel view CKPT``: the interactive desktop viewer (glfw window + Dear ImGui panel)."""

from __future__ import annotations

import argparse

ORDER = 40
HELP = "open a model in the interactive viewer (play/scrub time, orbit/fly, render modes, camera paths)"
DESCRIPTION = """Open a model in a window with a Dear ImGui control panel.

mouse: left drag orbit (look in fly mode), right/middle drag pan, wheel zoom
keys:  W/A/S/D/Q/E fly (Shift: faster), Space play/pause, R reset view, F fly mode, P screenshot, Esc quit
Ctrl+click: inspect the Gaussians that make that pixel (Inspect panel)
Shift+drag: select the Gaussians that show in a rectangle (Shift+Alt+drag unselects); Delete deletes them,
Ctrl+Z undoes; the Edit panel saves the cleaned model (crop box and deletions)
Drop a model file on the window to open it. Needs a display (run under Xvfb on a server).

With no CKPT it opens the bundled trained 'spinner' sample.

examples:
  splatreel view
  splatreel view model.safetensors
  splatreel view model.safetensors --cameras data/spinner --background white
  splatreel view model.safetensors --path tour.json --paused --time 0.25
  splatreel view model.safetensors --crop -0.5 -0.5 0 0.5 0.5 1     (the panel's crop box on, at this box)
  splatreel view model.safetensors --paused --time 0.3 --inspect 640,360 --exit-after 2 --report px.json
      (which Gaussians make the window's centre pixel at t = 0.3, and the largest one's attributes)
  splatreel view model.safetensors --paused --time 0.3 --select 0,0,200,720   (the left edge's floaters selected)
"""


def add_args(p: argparse.ArgumentParser) -> None:
    from splatreel.argtypes import count, finite_number, positive_number
    from splatreel.viewer.options import add_look_args, argtype, parse_pixel, parse_positive, parse_rect, parse_size

    from ._shared_options import add_crop_arg, add_up_arg

    p.add_argument("checkpoint", metavar="CKPT", nargs="?", default=None,
                   help="model file (splatreel checkpoint or any importable format; default: the bundled sample)")
    p.add_argument("--size", type=argtype(parse_size), default=(1280, 720), metavar="WxH",
                   help="window size (default 1280x720)")
    add_up_arg(p, ("y", "z"), help="world up axis for orbiting")
    p.add_argument("--fov", type=positive_number, default=40.0, help="vertical field of view in degrees (default 40)")
    add_look_args(p, transparent=False)
    p.add_argument("--paused", action="store_true", help="start with playback paused")
    p.add_argument("--time", type=finite_number, default=None, help="model time to start at (default: mid-range)")
    p.add_argument("--loop-seconds", type=positive_number, default=2.0,
                   help="seconds per pass through the time range at speed 1 (default 2)")
    p.add_argument("--cameras", metavar="DATASET",
                   help="training dataset whose cameras can be snapped to: a D-NeRF layout folder or transforms "
                        "json, or a splatreel checkpoint recording them (default: those the model's own checkpoint "
                        "records, else its dataset folder)")
    p.add_argument("--split", default="train", help="dataset split for --cameras (default train)")
    p.add_argument("--path", metavar="JSON", help="camera path to load (play it from the panel)")
    p.add_argument("--play-path", action="store_true", help="start playing the --path camera path at once")
    add_crop_arg(p, " (start with the panel's crop box on, at this box)")
    p.add_argument("--screenshot-dir", default=".", help="folder for screenshots taken with P (default .)")
    p.add_argument("--no-vsync", action="store_true", help="draw as fast as possible")
    p.add_argument("--render-scale", type=positive_number, default=1.0, metavar="S",
                   help="draw S x the window's width and height (0.25-1 in steps of 1/8, default 1) and stretch "
                        "the image to the window: faster on a CPU")
    p.add_argument("--no-adaptive-resolution", action="store_true",
                   help="keep the full resolution while the view moves or the animation plays (by default fewer "
                        "pixels are drawn then when a frame would take over --frame-budget)")
    p.add_argument("--sharp-playback", action="store_true",
                   help="lower the resolution only while the camera moves, not while the animation plays")
    p.add_argument("--frame-budget", type=argtype(parse_positive), default=None, metavar="MS",
                   help="frame time the adaptive resolution aims for (default 40 ms)")
    p.add_argument("--inspect", type=argtype(parse_pixel), metavar="X,Y",
                   help="start with this window pixel inspected, as if Ctrl+clicked (column, row from the top left; "
                        "--report lists its Gaussians)")
    p.add_argument("--select", type=argtype(parse_rect), metavar="X0,Y0,X1,Y1",
                   help="start with the Gaussians whose centre shows in this window rectangle selected, as if "
                        "Shift+dragged (corners in pixels from the top left)")
    a = p.add_argument_group("automation (scripted captures, tests)")
    a.add_argument("--exit-after", type=count, default=None, metavar="FRAMES", help="close after this many frames")
    a.add_argument("--screenshot", metavar="PNG", help="with --exit-after: save the last frame here")
    a.add_argument("--report", metavar="JSON",
                   help="write frame count, times, the screenshot's camera, the --inspect pixel's Gaussians and the "
                        "--select count here")
    a.add_argument("--force", action="store_true", help="overwrite an existing --screenshot file")


def run(args: argparse.Namespace) -> int:
    from splatreel.fileio import check_writable
    from splatreel.formats import read_checkpoint
    from splatreel.samples.trained import trained_checkpoint
    from splatreel.viewer.app import AppOptions, run_app
    from splatreel.viewer.camera_path import CameraPath, dataset_views
    from splatreel.viewer.controls import RESOLUTION_STEPS
    from splatreel.viewer.options import OptionError, look_settings, parse_background

    from ._shared_options import check_crop

    bg, transparent = parse_background(args.background)
    if transparent:
        raise OptionError("the window cannot show a transparent background; use `splatreel render` for alpha output")
    if args.screenshot and args.exit_after is None:
        raise OptionError("--screenshot needs --exit-after (press P for screenshots while viewing)")
    if args.play_path and not args.path:
        raise OptionError("--play-path needs --path")
    if args.exit_after is not None and args.exit_after < 1:
        raise OptionError(f"--exit-after must be at least 1, got {args.exit_after}")
    if args.screenshot:
        check_writable(args.screenshot, args.force)
    if args.inspect and not (args.inspect[0] < args.size[0] and args.inspect[1] < args.size[1]):
        raise OptionError(f"--inspect {args.inspect[0]},{args.inspect[1]} is outside the {args.size[0]}x"
                          f"{args.size[1]} window")
    if args.select:
        x0, y0, x1, y1 = args.select
        if max(x0, x1) <= 0 or max(y0, y1) <= 0 or min(x0, x1) >= args.size[0] or min(y0, y1) >= args.size[1]:
            raise OptionError(f"--select {x0:g},{y0:g},{x1:g},{y1:g} lies outside the {args.size[0]}x{args.size[1]} "
                              "window")
    if args.no_adaptive_resolution and (args.sharp_playback or args.frame_budget is not None):
        raise OptionError("--sharp-playback and --frame-budget tune the adaptive resolution, which "
                          "--no-adaptive-resolution turns off")
    if not any(abs(args.render_scale - step) < 1e-9 for step in RESOLUTION_STEPS):
        raise OptionError(f"--render-scale must be a multiple of 1/8 between 0.25 and 1 (0.25, 0.375, 0.5, ... 1), "
                          f"got {args.render_scale}")
    look = look_settings(args, (0.0, 0.0, 0.0))  # the app sets the checkpoint's background when it loads one
    options = AppOptions(size=args.size, up=args.up, fov=args.fov, settings=look, checkpoint_background=bg is None,
                         play=not args.paused, time=args.time, loop_seconds=args.loop_seconds, cameras=args.cameras,
                         split=args.split, camera_path=args.path, play_path=args.play_path,
                         screenshot_dir=args.screenshot_dir, vsync=not args.no_vsync, render_scale=args.render_scale,
                         adaptive_resolution=not args.no_adaptive_resolution,
                         frame_budget_ms=AppOptions.frame_budget_ms if args.frame_budget is None else args.frame_budget,
                         sharp_playback=args.sharp_playback, exit_after=args.exit_after,
                         screenshot=args.screenshot, report=args.report, force=args.force, crop=args.crop,
                         inspect=args.inspect, select=args.select)
    # fail with a one-line error before opening a window
    if args.path:
        CameraPath.load(args.path)
    if args.cameras:
        dataset_views(args.cameras, args.split)
    ckpt = read_checkpoint(args.checkpoint or str(trained_checkpoint("spinner")))
    check_crop(ckpt.model, args.crop)  # a bad box, or one that misses the model
    if args.time is not None:
        from splatreel.argtypes import warn_outside_time_range

        warn_outside_time_range(args.time, ckpt.model.time_range, "--time")
    report = run_app(ckpt, options)
    if args.exit_after is not None:
        print(f"drew {report['frames']} frame(s); time {report['time_start']:.3f} -> {report['time_end']:.3f}")
    return 0
