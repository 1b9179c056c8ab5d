"""Parsing of the options shared by ``splatreel view`` and ``splatreel render`` (sizes, colours, vectors), and the
options that set how splats are drawn (`add_look_args`, `look_settings`)."""

from __future__ import annotations

import argparse
import math

from splatreel.argtypes import OptionError, argtype, parse_positive  # noqa: F401  (the viewer's options use them)

_NAMED_COLORS = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0), "grey": (0.5, 0.5, 0.5),
                 "gray": (0.5, 0.5, 0.5)}


def parse_size(text: str) -> tuple[int, int]:
    """'1280x720' -> (1280, 720)."""
    parts = str(text).lower().replace("*", "x").split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        raise OptionError(f"size must look like WIDTHxHEIGHT (e.g. 1280x720), got {text!r}") from None
    if not (0 < w <= 16384 and 0 < h <= 16384):
        raise OptionError(f"size must be between 1x1 and 16384x16384, got {text!r}")
    return w, h


def parse_vector(text: str, n: int = 3, what: str = "vector") -> tuple[float, ...]:
    """'0,0,1' -> (0.0, 0.0, 1.0)."""
    try:
        v = tuple(float(x) for x in str(text).replace(" ", "").split(","))
    except ValueError:
        v = ()
    if len(v) != n or not all(math.isfinite(x) for x in v):
        raise OptionError(f"{what} must be {n} comma-separated numbers, got {text!r}")
    return v


def parse_pixel(text: str) -> tuple[int, int]:
    """'640,360' -> (640, 360): a pixel's column and row from the top-left corner."""
    v = parse_vector(text, 2, "pixel")
    if not all(x >= 0 and x == int(x) for x in v):
        raise OptionError(f"pixel must be two whole numbers X,Y from the top-left corner, got {text!r}")
    return int(v[0]), int(v[1])


def parse_rect(text: str) -> tuple[float, float, float, float]:
    """'10,20,300,200' -> (10.0, 20.0, 300.0, 200.0): two opposite corners of a rectangle of pixels, x then y from
    the top-left corner."""
    x0, y0, x1, y1 = parse_vector(text, 4, "rectangle")
    if min(x0, y0, x1, y1) < 0 or x0 == x1 or y0 == y1:
        raise OptionError(f"rectangle must be two opposite corners X0,Y0,X1,Y1 (pixels from the top left, not "
                          f"negative, of non-zero width and height), got {text!r}")
    return x0, y0, x1, y1


def parse_background(text: str | None) -> tuple[tuple[float, float, float] | None, bool]:
    """(rgb or None for "the checkpoint's", transparent) from 'white', 'black', 'transparent', 'r,g,b' in [0, 1]
    or '#rrggbb'."""
    if text is None:
        return None, False
    t = str(text).strip().lower()
    if t in ("transparent", "none", "alpha"):
        return (0.0, 0.0, 0.0), True
    if t in _NAMED_COLORS:
        return _NAMED_COLORS[t], False
    if t.startswith("#") and len(t) == 7:
        try:
            return tuple(int(t[i:i + 2], 16) / 255.0 for i in (1, 3, 5)), False  # type: ignore[return-value]
        except ValueError:
            pass
    rgb = parse_vector(t, 3, "background") if "," in t else None
    if rgb is None or not all(0.0 <= x <= 1.0 for x in rgb):
        raise OptionError(f"background must be white, black, grey, transparent, #rrggbb or r,g,b in [0, 1], "
                          f"got {text!r}")
    return rgb, False  # type: ignore[return-value]


def add_footprint_args(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """Which splats reach the screen and how far (`splatreel.viewer.sorting.Footprint`): the near plane and the
    performance guards, the trainer's by default (other values change the image)."""
    from splatreel.constants import NEAR_PLANE
    from splatreel.constants import TEMPORAL_FADES

    parser.add_argument("--near-plane", type=argtype(parse_positive), default=NEAR_PLANE, metavar="D",
                        help=f"Gaussians closer to the camera than this depth are not drawn (default {NEAR_PLANE:g}, "
                             "as the trainer); lower it to fly close to or into a model, best with "
                             "--max-screen-radius")
    parser.add_argument("--temporal-fade", choices=TEMPORAL_FADES, default="cut",
                        help="how a Gaussian leaves the scene at the end of its time window: cut (default, the "
                             "trainer's: dropped once its temporal opacity falls to 0.05 of its peak, a small "
                             "pop) or smooth (faded to 0 over its last doubling, no pop)")
    parser.add_argument("--max-std-dev", type=argtype(parse_positive), default=None, metavar="SIGMAS",
                        help="draw each splat out to at most this many std-devs: fewer pixels to shade, harder "
                             "edges on large splats (web viewers draw 2.83 = sqrt 8; 2.24 = sqrt 5 is their fast "
                             "setting); default: out to alpha 1/255, as the trainer (about 3.3 for opaque ones)")
    parser.add_argument("--max-screen-radius", type=argtype(parse_positive), default=None, metavar="SHARE",
                        help="cap each splat's radius at this share of the image height (e.g. 0.25), against "
                             "huge splats close to the camera filling the screen; default: no cap")


def add_look_args(parser: argparse.ArgumentParser | argparse._ArgumentGroup, transparent: bool = True) -> None:
    """How the splats are drawn (`RenderSettings`): --background, --mode, --sh-degree, --splat-scale, the footprint
    options and --composite. `transparent`: whether the command can write a transparent background. Read the
    values back with `look_settings`."""
    from .render_settings import COMPOSITE_ORDERS, RENDER_MODES

    colours = "white, black, grey, transparent" if transparent else "white, black, grey"
    parser.add_argument("--background", default=None,
                        help=f"{colours}, #rrggbb or r,g,b (default: the checkpoint's)")
    # no argparse choices: parse_mode also takes aliases (colour, points, ...) and names the modes in its error
    parser.add_argument("--mode", default="color",
                        help=f"{', '.join(RENDER_MODES[:-1])} or {RENDER_MODES[-1]} (default color)")
    parser.add_argument("--sh-degree", type=int, default=None, help="draw at a lower SH degree")
    parser.add_argument("--splat-scale", type=float, default=1.0, help="scale every Gaussian (default 1)")
    add_footprint_args(parser)
    parser.add_argument("--composite", choices=COMPOSITE_ORDERS, default=COMPOSITE_ORDERS[0],
                        help=f"blending order (default {COMPOSITE_ORDERS[0]}; the same image either way, "
                             "front-to-back stops saturated pixels early)")


def look_settings(args: argparse.Namespace, checkpoint_background: tuple[float, float, float],
                  value_range: tuple[float, float] | None = None):
    """The `RenderSettings` of the options `add_look_args` added: --background, else `checkpoint_background`;
    `value_range`: the colour map's ends (render's --map-range)."""
    from .render_settings import RenderSettings

    bg, transparent = parse_background(args.background)
    return RenderSettings(mode=args.mode, splat_scale=args.splat_scale, sh_degree=args.sh_degree,
                          background=bg if bg is not None else checkpoint_background, transparent=transparent,
                          composite=args.composite, value_range=value_range, max_std_dev=args.max_std_dev,
                          max_screen_radius=args.max_screen_radius, near_plane=args.near_plane,
                          temporal_fade=args.temporal_fade)
