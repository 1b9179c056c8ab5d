"""How the renderer draws a frame (`RenderSettings`: mode, splat scale, SH degree, background, blending, splat
primitive, footprint caps, near plane, temporal fade) and what a frame cost (`FrameStats`), with the names of the
display modes, blending orders and splat primitives. Plain data, no GL: the CLI, the app and the headless renderer
build and read these.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from splatreel.constants import NEAR_PLANE
from splatreel.errors import GLError

if TYPE_CHECKING:
    from .sorting import Footprint

#: Display modes, in the order of the app's combo box.
RENDER_MODES: tuple[str, ...] = ("color", "depth", "alpha", "outlines", "centers", "speed", "lifespan", "fade")
_MODE_ALIASES = {"colour": "color", "rgb": "color", "centres": "centers", "points": "centers",
                 "ellipsoids": "outlines", "ellipses": "outlines", "velocity": "speed", "motion": "speed",
                 "lifetime": "lifespan", "duration": "lifespan", "temporal-opacity": "fade", "temporal": "fade",
                 "marginal": "fade", "fading": "fade"}
#: Modes that show a per-Gaussian value (camera depth, speed, visible time span, temporal opacity factor) through a
#: colour map over `RenderSettings.value_range`.
VALUE_MODES: tuple[str, ...] = ("depth", "speed", "lifespan", "fade")
#: How splats are blended; both give the reference composite (see `SplatRenderer`).
COMPOSITE_ORDERS: tuple[str, ...] = ("front-to-back", "back-to-front")
#: Splat primitives: "points" (one GL point per Gaussian, fastest on llvmpipe), "quads" (one instanced quad), or
#: "auto" (points where they can be drawn, see `draw_plan.splat_runs`).
PRIMITIVES: tuple[str, ...] = ("auto", "points", "quads")


def parse_mode(name: str) -> str:
    """Canonical render mode name; accepts British spellings and a few aliases."""
    mode = _MODE_ALIASES.get(str(name).lower(), str(name).lower())
    if mode not in RENDER_MODES:
        raise GLError(f"unknown render mode {name!r}; expected one of {', '.join(RENDER_MODES)}")
    return mode


@dataclass
class RenderSettings:
    """How to draw a frame.

    Attributes:
        mode: one of `RENDER_MODES`.
        splat_scale: multiplies every Gaussian's std-devs (1 = as trained).
        sh_degree: displayed SH degree (None = the model's).
        background: RGB in [0, 1] behind the splats.
        transparent: keep the background transparent (premultiplied colour + alpha) instead of compositing.
        value_range: (low, high) of the colour map of the depth mode (near, far camera depth), the speed mode
            (slow, fast, in world units per unit of model time), the lifespan mode (brief, long, in model time)
            and the fade mode (temporal opacity factor); None = the 2nd-98th percentile of the drawn depths of each
            frame (`render_frames` fixes one range for a whole video), 0 to the model's `splats.typical_speed`, 0
            to the model's time span, and 0 to 1.
        composite: "front-to-back" (under-blending in batches, pixels stop once their transmittance reaches
            TRANSMITTANCE_THRESHOLD, like the reference rasterizer) or "back-to-front" (over-blending, no early
            stop). Same image either way (to float rounding and the 1e-4 early-stop residue).
        primitive: one of `PRIMITIVES`; the same image either way, "auto" is the fast choice.
        max_std_dev: cap on how far a splat reaches, in std-devs (None = to the alpha cut-off, as the reference);
            see `Footprint`.
        max_screen_radius: cap on a splat's radius as a share of the image height (None = none).
        near_plane: Gaussians at or in front of this camera depth are not drawn (the trainer's NEAR_PLANE, 0.2).
        temporal_fade: one of `splatreel.constants.TEMPORAL_FADES`: "cut" (the reference: a Gaussian drops out once
            its temporal marginal falls to 0.05) or "smooth" (faded out over the marginal's last doubling, so that
            nothing pops as time plays).
    """

    mode: str = "color"
    splat_scale: float = 1.0
    sh_degree: int | None = None
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    transparent: bool = False
    value_range: tuple[float, float] | None = None
    composite: str = "front-to-back"
    primitive: str = "auto"
    max_std_dev: float | None = None
    max_screen_radius: float | None = None
    near_plane: float = NEAR_PLANE
    temporal_fade: str = "cut"

    def __post_init__(self) -> None:
        # imported here, not at the top: the CLI's option lists read this module's names without torch or numba
        from splatreel.covariance import check_fade

        self.mode = parse_mode(self.mode)
        try:
            check_fade(self.temporal_fade)
        except ValueError as exc:
            raise GLError(str(exc)) from None
        if self.primitive not in PRIMITIVES:
            raise GLError(f"unknown splat primitive {self.primitive!r}; expected one of {', '.join(PRIMITIVES)}")
        if self.composite not in COMPOSITE_ORDERS:
            raise GLError(f"unknown composite order {self.composite!r}; expected one of {', '.join(COMPOSITE_ORDERS)}")
        bg = tuple(float(x) for x in self.background)
        if len(bg) != 3 or not all(np.isfinite(bg)):
            raise GLError(f"background must be 3 finite numbers, got {self.background!r}")
        self.background = bg  # type: ignore[assignment]
        self.footprint  # checks the splat scale, the caps and the near plane

    @property
    def footprint(self) -> Footprint:
        """Which splats reach the screen and how far (`sorting.Footprint`): splat scale, caps and near plane.
        Raises GLError (one line) on a bad value, e.g. one typed into the app's panel."""
        from .sorting import Footprint  # numba: see __post_init__

        try:
            return Footprint(self.splat_scale, math.inf if self.max_std_dev is None else self.max_std_dev,
                             math.inf if self.max_screen_radius is None else self.max_screen_radius, self.near_plane)
        except ValueError as exc:
            raise GLError(str(exc)) from None


@dataclass
class FrameStats:
    """What a frame cost and drew: `total` Gaussians, `visible` after culling (time, near plane, frustum) and
    sorted, `drawn` after skipping those hidden behind opaque pixels."""

    sort_ms: float = 0.0
    draw_ms: float = 0.0
    upload_ms: float = 0.0
    visible: int = 0
    drawn: int = 0
    total: int = 0
    resorted: bool = False
    #: the colour map's range in the depth and speed modes
    value_range: tuple[float, float] = (0.0, 1.0)

    @property
    def frame_ms(self) -> float:
        return self.sort_ms + self.draw_ms + self.upload_ms

