"""Which Gaussians make a pixel, and what one Gaussian is (the desktop app's Inspect tool).

`SplatRenderer.pick` runs the renderer's own pre-pass on the Gaussians whose screen box holds the pixel and hands
their footprints (the records ``splat_draw.glsl`` draws) to `composite_pixel`, which evaluates the splat fragment
shader at that pixel and composites front to back as the reference rasterizer does. So the answer is what the
viewer draws there, Gaussian by Gaussian: the weights alpha_i T_i sum to the pixel's alpha and the weighted colours
to its colour.

`inspect_gaussian` / `describe` list one Gaussian's attributes at a time t from the model itself (its `slice`),
for the panel; a skinned Gaussian's temporal rows come from its native 4D Gaussian (`SkinnedGaussians.gaussians`),
plus the nodes that carry it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from splatreel.constants import ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_THRESHOLD
from splatreel.covariance import condition_on_time, temporal_factor, temporal_marginal, visible_span
from splatreel.model import Gaussians3D, Gaussians4D
from splatreel.skinned import SkinnedGaussians


@dataclass(frozen=True)
class PixelHit:
    """One Gaussian's part of a pixel.

    Attributes:
        index: the Gaussian's index in the model drawn (after any crop).
        alpha: its alpha at the pixel.
        weight: alpha * T, the transmittance left in front of it: its share of the pixel's colour.
        depth: camera depth of its mean at the time picked.
        color: its colour seen from the camera (rgb, before weighting).
    """

    index: int
    alpha: float
    weight: float
    depth: float
    color: tuple[float, float, float]


@dataclass(frozen=True)
class PixelStack:
    """Every Gaussian that adds to one pixel, front to back, and their composite.

    Attributes:
        pixel: (x, y), column and row from the top-left corner.
        hits: the contributing Gaussians, nearest first (weight > 0).
        alpha: the pixel's alpha, 1 - T = sum of the weights.
        color: the pixel's premultiplied colour, sum of weight * colour.
    """

    pixel: tuple[int, int]
    hits: tuple[PixelHit, ...]
    alpha: float
    color: tuple[float, float, float]

    @property
    def top(self) -> PixelHit | None:
        """The Gaussian that gives the pixel most of its colour (largest weight), or None over the background."""
        return max(self.hits, key=lambda h: h.weight) if self.hits else None

    @property
    def surface_depth(self) -> float | None:
        """Camera depth of the surface seen at the pixel: that of the Gaussian at which the accumulated weight
        first reaches half the pixel's alpha (the median depth of 3DGS surface extraction, taken relative to the
        alpha so that a translucent pixel has one too); None over the background."""
        half, total = 0.5 * self.alpha, 0.0
        for h in self.hits:
            total += h.weight
            if total >= half:
                return h.depth
        return None


def footprint_alpha(records: np.ndarray, pixel: tuple[float, float]) -> np.ndarray:
    """``[K]`` alpha of each pre-processed Gaussian at the pixel centre `pixel` (x, y, y down): the splat fragment
    shader's formula (splat_draw.glsl). `records`: ``[K, 16]`` float32 as the pre-pass writes them (centre, radius,
    depth; the two 2D axes in pixels per std-dev; rgb, opacity at t; the tile rectangle)."""
    r = np.asarray(records, np.float64)
    centre, axes, opacity, rect = r[:, 0:2], r[:, 4:8], r[:, 11], r[:, 12:16]
    culled = r[:, 2] <= 0.0
    # uv = [a1 a2]^-1 (p - c): the offset in std-devs along the principal axes
    a, c, b, d = axes[:, 0], axes[:, 1], axes[:, 2], axes[:, 3]  # columns a1 = (a, c), a2 = (b, d)
    det = a * d - b * c
    det = np.where(culled | (det == 0.0), 1.0, det)
    dx, dy = pixel[0] - centre[:, 0], pixel[1] - centre[:, 1]
    u, v = (d * dx - b * dy) / det, (a * dy - c * dx) / det
    r2 = u * u + v * v
    alpha = np.minimum(MAX_ALPHA, opacity * np.exp(-0.5 * r2))
    inside = (pixel[0] >= rect[:, 0]) & (pixel[1] >= rect[:, 1]) & (pixel[0] < rect[:, 2]) & (pixel[1] < rect[:, 3])
    # past the pre-pass's footprint radius (alpha < ALPHA_THRESHOLD unless a footprint cap cut it shorter)
    return np.where(culled | ~inside | (r2 > r[:, 2] ** 2), 0.0, alpha)


def composite_pixel(records: np.ndarray, indices: np.ndarray, pixel: tuple[int, int]) -> PixelStack:
    """Composite pre-processed Gaussians (`footprint_alpha`), given nearest first, at integer `pixel` (x, y):
    weight_i = alpha_i T_i, stopping before the Gaussian that would take T below TRANSMITTANCE_THRESHOLD, as the
    reference rasterizer does. `indices`: each record's Gaussian in the model."""
    x, y = int(pixel[0]), int(pixel[1])
    alpha = footprint_alpha(records, (x + 0.5, y + 0.5))
    hits, T, rgb = [], 1.0, np.zeros(3)
    for k in np.flatnonzero(alpha > 0.0):
        a = float(alpha[k])
        after = T * (1.0 - a)
        if after < TRANSMITTANCE_THRESHOLD:
            break
        color = tuple(float(v) for v in records[k, 8:11])
        hits.append(PixelHit(int(indices[k]), a, a * T, float(records[k, 3]), color))
        rgb += a * T * np.asarray(color)
        T = after
    return PixelStack((x, y), tuple(hits), 1.0 - T, tuple(float(v) for v in rgb))


def describe(model, index: int, t: float, fade: str = "cut") -> list[tuple[str, str]]:
    """(label, value) rows describing Gaussian `index` of `model` at time `t`, for the app's Inspect panel: where
    it is, how it moves and fades, its size and opacity (with the temporal `fade` drawn). Computed from the model's
    own `slice`."""
    return inspect_gaussian(model, index, t, fade)[0]


def inspect_gaussian(model, index: int, t: float, fade: str = "cut") -> tuple[list[tuple[str, str]], Gaussians3D]:
    """(`describe`'s rows, the one-Gaussian slice they were read from) of Gaussian `index` at time `t`: the slice
    also gives the app the ellipsoid to draw. The opacity at t is the one drawn with the temporal `fade`
    (`splatreel.covariance.temporal_factor`)."""
    one = model.select(torch.tensor([int(index)]))
    native = native_gaussians(one)
    with torch.no_grad():
        g = one.slice(float(t))
        opacity = float(g.opacities[0])
        if native is not None:
            _, _, var_t = condition_on_time(native.covariance_4d())
            marginal = temporal_marginal(float(t), native.t_means, var_t)
            opacity = float(native.opacities[0] * temporal_factor(marginal, fade)[0])
        drawn = bool(g.visible[0]) and opacity >= ALPHA_THRESHOLD
        rows = [("index", f"{int(index):,} of {len(model):,}"),
                ("position", vector_text(g.means[0])),
                ("velocity", vector_text(g.velocities[0])),
                ("speed", f"{float(g.velocities[0].norm()):.4g}"),
                ("std-devs", vector_text(torch.linalg.eigvalsh(g.covariances[0].double()).clamp_min(0).sqrt().flip(0))),
                ("opacity at t", f"{opacity:.3f}" + ("" if drawn else "  (not drawn)"))]
        if native is not None:
            sd_t = math.sqrt(float(var_t[0]))
            rows += [("peak opacity", f"{float(native.opacities[0]):.3f} at t = {float(native.t_means[0]):.4g}"),
                     ("time std-dev", f"{sd_t:.4g}"),
                     ("drawn for", f"{float(visible_span(var_t)[0]):.4g} of {model.duration:.4g}")]
        if isinstance(one, SkinnedGaussians):
            rows.append(("nodes", carrying_nodes_text(one)))
        elif native is None:
            rows.append(("keyframes", f"{one.num_frames}"))
    return rows, g


def native_gaussians(model) -> Gaussians4D | None:
    """The native 4D Gaussians whose temporal mean and std-dev say when `model`'s Gaussians show: its own (native
    4D), those the nodes carry (skinned), None for a keyframed model (its keys' opacities say it)."""
    if isinstance(model, SkinnedGaussians):
        return model.gaussians
    return model if isinstance(model, Gaussians4D) else None


def carrying_nodes_text(one: SkinnedGaussians) -> str:
    """How many of a one-Gaussian skinned model's nodes carry it, and each one's blend weight, largest first:
    '4 of 40: #12 (52%), #3 (31%), ...'."""
    nodes, weights = one.skin
    order = weights[0].argsort(descending=True).tolist()
    shares = ", ".join(f"#{int(nodes[0, k])} ({float(weights[0, k]):.0%})" for k in order)
    return f"{nodes.shape[1]} of {one.num_nodes}: {shares}"


def peak_time(model, index: int) -> float:
    """When Gaussian `index` shows most: a native or skinned Gaussian's temporal mean (clamped to the time range), a
    keyframed one's most opaque key."""
    t0, t1 = model.time_range
    native = native_gaussians(model)
    if native is not None:
        return min(max(float(native.t_means[int(index)]), t0), t1)
    return float(model.times[int(model.opacities[:, int(index)].argmax())])


def vector_text(v) -> str:
    """A vector as '(x, y, z)' with 4 significant digits (the panel's and the status line's way)."""
    return "(" + ", ".join(f"{float(x):.4g}" for x in v) + ")"
