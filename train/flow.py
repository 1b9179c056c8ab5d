"""Optical flow between a camera's consecutive frames, and the frames it interpolates half-way between them.

An image matrix (V views x F frames) shows each camera only at the F key times, yet the model is played, rendered
and exported at every time in between. There a native 4D Gaussian fades between its frames' copies unless something
says where the surface is at in-between times. The flow of each camera's video says it: the frame half-way between
two consecutive frames is synthesised the way flow-based video frame interpolation does (bidirectional backward
warping with occlusion-aware blending, as in Jiang et al., Super SloMo, CVPR 2018), and the trainer draws it like
a training image for a share of its steps (`TrainConfig.inbetween_share`). Interpolation is exact on smooth motion
and errs where the flow does (occlusion edges, large turns). Each frame comes with a trust map that leaves out of
the loss the pixels where neither frame's flow passes the round trip and the two frames disagree about what is
there: a guess, and the cause of most of the error.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from splatreel.datasets import Dataset, DatasetImage

from .data import camera_videos
from .evaluate import target_bytes

#: Forward-backward check: the other direction's flow must bring a pixel back within this many pixels (plus 5 % of
#: the flow) for the pixel to count as seen in both frames.
FLOW_ROUND_TRIP_PX = 1.0
#: Fixed-point iterations that invert "x0 + flow(x0) / 2 = x" for the pixel of each frame that lands on x half-way.
INVERT_ITERATIONS = 6
#: A pixel whose flow fails the round trip both ways is still trusted where the two frames, each warped to it, agree
#: within this (premultiplied colour and alpha, 0-1), as on a plain background. On the spinner sample at 256 px,
#: 0.05 leaves 2 % of the pixels out, and with them 54 % of the interpolated frames' error against true renders.
MIDWAY_AGREEMENT = 0.05
#: Weight of the smoothness term of DIS's variational refinement in the fine flow (the medium preset's: 20).
FINE_FLOW_SMOOTHNESS = 5.0
#: Points per row when `warp` samples a list of points (OpenCV's remap takes maps under 32767 wide).
REMAP_ROW = 4096


def optical_flow(a: np.ndarray, b: np.ndarray, fine: bool = False) -> np.ndarray:
    """``[H, W, 2]`` float32 flow from image `a` to image `b` (``[H, W, 3]`` uint8): pixel (x, y) of `a` is at
    (x, y) + flow in `b`. DIS (Kroeger et al. 2016), OpenCV's medium preset, on the grey images.

    `fine`: searched down to full resolution (the preset stops at half) and with a weaker smoothness term in the
    variational refinement (`FINE_FLOW_SMOOTHNESS`), four times the cost. On the spinner sample's box (about 70 px
    across, turning 24 degrees a frame) the preset's flow falls 14 % short of the true motion and ends 27 % of it
    off (medians), and a rigid fit of all its tracks turns 17 degrees a frame where the box turns 24; the fine flow
    5 % short, 19 % off, 20 degrees: the smoothing pulls the small object's flow towards the still background."""
    import cv2

    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    if fine:
        dis.setFinestScale(0)
        dis.setVariationalRefinementAlpha(FINE_FLOW_SMOOTHNESS)
    return dis.calc(cv2.cvtColor(a, cv2.COLOR_RGB2GRAY), cv2.cvtColor(b, cv2.COLOR_RGB2GRAY), None)


def round_trip_ok(flow: np.ndarray, back: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``[...]`` bool: whether the pixels at `at` ``[..., 2]`` (x, y) move by `flow` and come back by `back` within
    `FLOW_ROUND_TRIP_PX` (plus 5 % of the flow): seen in both frames."""
    f = warp(flow, at)
    error = np.linalg.norm(f + warp(back, at + f), axis=-1)
    return error <= FLOW_ROUND_TRIP_PX + 0.05 * np.linalg.norm(f, axis=-1)


def warp(image: np.ndarray, at: np.ndarray) -> np.ndarray:
    """`image` ``[H, W, C]`` sampled bilinearly at `at` (x, y in the flow's pixel coordinates: pixel i's centre at
    i), clamped at the border: a grid ``[h, w, 2]`` gives ``[h, w, C]``, a list of points ``[N, 2]`` gives
    ``[N, C]``."""
    import cv2

    channels = image.shape[-1]
    grid = np.asarray(at, dtype=np.float32)
    points = len(grid) if grid.ndim == 2 else None
    if points is not None:  # OpenCV's maps are 2D and under 32767 wide: the points go in rows of REMAP_ROW
        rows = max(1, -(-points // REMAP_ROW))
        grid = np.concatenate([grid, np.zeros((rows * REMAP_ROW - points, 2), np.float32)]).reshape(rows, -1, 2)
    out = cv2.remap(np.ascontiguousarray(image, dtype=np.float32), np.ascontiguousarray(grid[..., 0]),
                    np.ascontiguousarray(grid[..., 1]), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out = out.reshape(*grid.shape[:2], channels)
    return out if points is None else out.reshape(-1, channels)[:points]


def midway_sources(flow: np.ndarray) -> np.ndarray:
    """``[H, W, 2]``: for every pixel x, the pixel x0 of the first frame that `flow` carries to x half-way
    (x0 + flow(x0) / 2 = x, by fixed-point iteration from x0 = x)."""
    h, w = flow.shape[:2]
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)), -1)
    x0 = grid.copy()
    for _ in range(INVERT_ITERATIONS):
        x0 = grid - 0.5 * warp(flow, x0)
    return x0


def interpolate_midway(a: np.ndarray, b: np.ndarray, shown_a: np.ndarray,
                       shown_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The frame half-way between `a` and `b` (``[H, W, C]`` float, premultiplied colour and alpha when there is
    one), from the flow between the images as shown, `shown_a`, `shown_b` (``[H, W, 3]`` uint8, composited on the
    background), and its ``[H, W]`` float32 trust (1 or 0). Each pixel takes the average of where it comes from in
    both frames, or the one frame that sees it where the other's flow fails the round trip (an occlusion). Where
    both fail, it takes the plain average, trusted only where the two agree (`MIDWAY_AGREEMENT`)."""
    fwd, bwd = optical_flow(shown_a, shown_b), optical_flow(shown_b, shown_a)
    from_a, from_b = midway_sources(fwd), midway_sources(bwd)
    ok_a, ok_b = round_trip_ok(fwd, bwd, from_a), round_trip_ok(bwd, fwd, from_b)
    warped_a, warped_b = warp(a, from_a), warp(b, from_b)
    seen_a, seen_b = ok_a.astype(np.float32)[..., None] + 1e-3, ok_b.astype(np.float32)[..., None] + 1e-3
    frame = (seen_a * warped_a + seen_b * warped_b) / (seen_a + seen_b)
    agree = np.abs(warped_a - warped_b).max(-1) < MIDWAY_AGREEMENT
    return frame, (ok_a | ok_b | agree).astype(np.float32)


def _premultiplied(view: DatasetImage) -> np.ndarray:
    rgb = view.image.astype(np.float32) / 255.0
    if view.alpha is None:
        return rgb
    a = view.alpha.astype(np.float32)[..., None] / 255.0
    return np.concatenate([rgb * a, a], -1)


@dataclass(frozen=True)
class InBetweenFrame:
    """A frame interpolated half-way between two consecutive frames of one camera, and where to trust it."""

    view: DatasetImage
    trust: np.ndarray  #: ``[H, W]`` float32 loss weight: 0 where the interpolation is a guess


def midway_view(a: DatasetImage, b: DatasetImage, background) -> InBetweenFrame:
    """A training image of `a`'s camera half-way in time between `a` and `b` (consecutive frames of one camera)."""
    out, trust = interpolate_midway(_premultiplied(a), _premultiplied(b), target_bytes(a, background),
                                    target_bytes(b, background))
    if a.alpha is None:
        image, alpha = out, None
    else:
        alpha = np.clip(out[..., 3], 0.0, 1.0)
        image = np.clip(out[..., :3] / np.maximum(alpha, 1e-6)[..., None], 0.0, 1.0)
        alpha = (alpha * 255 + 0.5).astype(np.uint8)
    image = (image * 255 + 0.5).astype(np.uint8)
    view = replace(a, image=image, alpha=alpha, time=0.5 * (a.time + b.time), name=f"{a.name} (in between)")
    return InBetweenFrame(view, trust)


def inbetween_views(ds: Dataset) -> list[InBetweenFrame]:
    """One interpolated image half-way between each pair of consecutive frames of every camera's video
    (`camera_videos`); none when no camera films consecutive frames. The pairs are interpolated on a thread per
    core (OpenCV and numpy release the GIL): this is set-up time that a time budget counts."""
    pairs = [(ds.train[i], ds.train[j]) for video in camera_videos(ds) for i, j in zip(video[:-1], video[1:])]
    with ThreadPoolExecutor(max_workers=max(1, os.cpu_count() or 1)) as pool:
        return list(pool.map(lambda pair: midway_view(*pair, ds.background), pairs))
