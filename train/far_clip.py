"""The far clip a capture's alpha was cut at, read off a trained model's depth.

A renderer's alpha often marks what lies nearer than the camera's far clip (Blender's ``clip_end``), not what is
there: a floor that runs to the horizon is opaque up to the clip and transparent past it, and a camera looking
straight down from high above sees its whole floor transparent while the side cameras see it opaque.
`splatreel.train.alpha_conflicts` finds such views and takes their contradicted pixels out of the loss, so the
model learns the floor from the views that see it. Drawn at that camera, the model then shows a floor where the
image shows nothing: the disagreement is the capture's far clip, and rendering with it reproduces the images.

One depth explains it when the model's surfaces nearer than it are where the images are opaque and those beyond it
are where they are transparent. `far_clip_from_depths` scores each candidate depth by the pixels it gets wrong
(opaque image, model surface at or beyond the clip; transparent image, model surface nearer) and keeps the best
one (the most pixels explained less those lost) only when it explains most of the pixels the model draws and the
images leave empty (`EXPLAINED`) at the cost of few of the opaque ones (`COST`). Opaque and transparent are
`alpha_conflicts`' thresholds. Depths are the rasterizer's: camera-space z of the Gaussians' centres, so the clip
culls at that depth as the rasterizer's near plane does (`rasterize(..., far_plane=)`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from splatreel.datasets import DatasetImage
from splatreel.model import Model
from splatreel.errors import SplatreelError
from splatreel.rasterize import rasterize

from .alpha_conflicts import OPAQUE, TRANSPARENT

#: A pixel where the model's alpha reaches this is a model surface (at its expected depth).
DRAWN = 0.5
#: The clip is kept only when it explains this share of the drawn-but-transparent pixels ...
EXPLAINED = 0.5
#: ... and puts at most this share of the drawn opaque pixels beyond it (a surface the views see at grazing
#: angles, as a floor near the clip, is never drawn at exactly its depth).
COST = 0.05
#: Nothing to explain below this share of the drawn pixels (a model's edges always spill a little).
MIN_EMPTY_SHARE = 0.01
#: Candidate clip depths tried, spread over the quantiles of the drawn pixels' depths.
CANDIDATES = 1024


@dataclass(frozen=True)
class FarClip:
    """What `far_clip_from_depths` found: the clip depth (None: no clip explains the images), the share of the
    drawn-but-transparent pixels it explains and of the drawn opaque pixels it removes."""

    depth: float | None
    explained: float = 0.0
    cost: float = 0.0
    empty_share: float = 0.0  # drawn-but-transparent pixels over all drawn pixels
    given: bool = False  # the user's (--far-clip D), not read off the model

    def describe(self) -> str:
        if self.given:
            return f"far clip at camera depth {self.depth:g} (--far-clip)"
        if self.depth is None:
            return ("no far clip: the model's surfaces the images leave transparent are not all beyond one depth "
                    f"({100 * self.explained:.0f}% at best)")
        return (f"far clip at camera depth {self.depth:.3f} (it explains {100 * self.explained:.0f}% of the "
                f"surfaces the images leave transparent and removes {100 * self.cost:.2f}% of those they show; "
                "test views and the checkpoint's evaluation are rendered with it; --far-clip to change)")


def initial_far_clip(setting: str | float) -> FarClip | None:
    """What a run knows of the clip before it trains (`TrainConfig.far_clip`): nothing yet with 'auto' (None),
    that there is none with 'none', the given depth otherwise."""
    if setting == "auto":
        return None
    if setting == "none":
        return FarClip(None)
    try:
        depth = float(setting)
    except (TypeError, ValueError):
        depth = float("nan")
    if not (math.isfinite(depth) and depth > 0):
        raise SplatreelError(f"far_clip must be 'auto', 'none' or a positive camera depth, got {setting!r}")
    return FarClip(depth, given=True)


def far_clip_from_depths(depth: np.ndarray, drawn: np.ndarray, image_alpha: np.ndarray) -> FarClip:
    """The far clip of one capture from pixels of its views: the model's expected `depth`, whether the model draws
    a surface there (`drawn`, bool) and the image's alpha (0-255), all flat arrays of equal length."""
    depth, drawn, image_alpha = (np.asarray(x).reshape(-1) for x in (depth, drawn, image_alpha))
    near = np.sort(depth[drawn & (image_alpha >= OPAQUE)])  # surfaces the images show
    far = np.sort(depth[drawn & (image_alpha < TRANSPARENT)])  # surfaces the images leave empty
    empty_share = len(far) / max(len(near) + len(far), 1)
    if len(far) == 0 or len(near) == 0 or empty_share < MIN_EMPTY_SHARE:
        return FarClip(None, empty_share=empty_share)
    candidates = np.unique(np.quantile(np.concatenate([near, far]), np.linspace(0, 1, CANDIDATES)))
    lost = len(near) - np.searchsorted(near, candidates, side="left")  # opaque surfaces at or beyond the clip
    removed = len(far) - np.searchsorted(far, candidates, side="left")  # empty surfaces at or beyond it
    best = int(np.argmax(removed - lost))
    explained, cost = float(removed[best] / len(far)), float(lost[best] / len(near))
    if explained < EXPLAINED or cost > COST or removed[best] <= lost[best]:
        return FarClip(None, explained, cost, empty_share)
    clip = float(candidates[best])
    below = near[near < clip]  # midway between the farthest surface it keeps and the nearest one it removes
    return FarClip(0.5 * (float(below[-1]) + clip) if len(below) else clip, explained, cost, empty_share)


def estimate_far_clip(model: Model, views: list[DatasetImage], background) -> FarClip:
    """`far_clip_from_depths` over `views` (with alpha) rendered from `model` (in the views' own times)."""
    depths, drawn, alphas = [], [], []
    with torch.no_grad():
        for v in views:
            if v.alpha is None:
                continue
            out = rasterize(model.slice(v.time), v.camera, background)
            depths.append(out.depth.cpu().numpy().reshape(-1))
            drawn.append(out.alpha.cpu().numpy().reshape(-1) >= DRAWN)
            alphas.append(np.asarray(v.alpha).reshape(-1))
    if not depths:
        return FarClip(None)
    return far_clip_from_depths(np.concatenate(depths), np.concatenate(drawn), np.concatenate(alphas))
