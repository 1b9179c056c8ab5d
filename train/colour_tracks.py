"""Groups of control nodes that the model's own motion loses, followed by their colour in the images.

Why: with one camera per time the nodes are tracked by the model's own motion at the flow step
(`train.nodes.track_nodes_by_motion`), and a part the model does not draw yet there is lost. On the floor sample the
pendulum (a thin rod, its bob on 6 of 512 nodes) was tracked 0.73 units off, and exact tracks for it alone were worth
1.8 dB held out: at the flow step barely any Gaussian draws the bob, and those that do move half as far as it does.
The images still show it. Each frame's image differs from its camera's per-pixel median image (over that camera's
frames) where something moved, the way background subtraction finds moving objects:

* the moving nodes fall into groups, connected within two node spacings at the middle frame;
* a group takes its colour from the middle frame's image (the median colour of the changed pixels within `RADIUS`
  px of its centre's projection) and is looked for in every frame, outwards from the middle `GROW` frames at a
  time: within `WINDOW` px of its predicted centre's projection, the centroid of the changed pixels weighted by
  their closeness to that colour is a ray from the frame's camera;
* the group's centre at every frame is the least-squares point nearest those rays, held near the tracked
  frame-to-frame displacement (`HOLD`), smooth in time (`SMOOTH`) and anchored at the middle frame.

A group of at least `MIN_NODES` nodes takes its colour track only where it is lost and the colour track found it:
its centre lies on changed pixels at the middle frame (not a node of the floor beside a part), its tracked centre
falls off the changed pixels in over a tenth of the frames (`ON_CHANGED`: the colour centroid of a many-coloured
part such as a box is not its centre, so a part tracked on what moves is left alone) and off its own colour in over
`1 - ON_COLOUR` of them (a part that stays in place, which the median image holds, is not lost), and the colour
track falls on its colour more often, and in at least `FOUND` of the frames. The nodes pinned as still within
`JOIN_REACH` node spacings of such a group that lie on changed pixels at the middle frame join it (the pendulum's bob
at the top of its swing there moves too slowly to be told from the floor by the model's motion).

Measured on the floor sample (800 steps, held out; the walker filmed one camera per time takes no group): the bob's
group alone 24.92 and 24.54 dB (seeds 0 and 1) against 24.82 and 24.25 without; with the pinned node that joins it
25.52 and 24.97. A looser rule that also took lone nodes took three of the walker's nodes and cost it 0.2 dB.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch

from splatreel.cameras import Camera
from splatreel.datasets import Dataset

from .evaluate import view_target
from .nodes import TrackedNodes, node_spacing

#: Summed RGB difference from the camera's median image above which a pixel changed (something moved there).
TAU = 0.15
#: A pixel's closeness to its group's colour: exp(-d^2 / (2 SIGMA^2)) of their RGB distance d.
SIGMA = 0.08
#: Pixels: the search window around the predicted centre's projection, the radius the group's colour is taken in, and
#: frames searched per round outwards from the middle.
WINDOW, RADIUS, GROW = 12, 8, 4
#: The rule that takes a group's colour track (module doc).
ON_CHANGED, ON_COLOUR, MIN_NODES, FOUND = 0.9, 0.3, 2, 0.5
#: Weights of the least-squares centres: second differences in time, and the tracked frame-to-frame displacement.
SMOOTH, HOLD = 0.1, 1.0
#: Node spacings within which a node pinned as still, on changed pixels at the middle frame, joins a group taken.
JOIN_REACH = 3.0


@dataclass
class FrameImages:
    """What the search looks at, one camera per time.

    Attributes:
        frames: per frame, its camera, its image ``[H, W, 3]`` on the background and its camera's id.
        median: per camera id, its per-pixel median image over its frames.
    """

    frames: list[tuple[Camera, np.ndarray, str]]
    median: dict[str, np.ndarray]

    def changed(self, k: int, rows: slice = slice(None), cols: slice = slice(None)) -> np.ndarray:
        """Where frame k's image (the window `rows`, `cols`) differs from its camera's median image."""
        _, img, cam = self.frames[k]
        return np.abs(img[rows, cols] - self.median[cam][rows, cols]).sum(-1) > TAU


def frame_images(ds: Dataset, background: torch.Tensor) -> FrameImages | None:
    """Each frame's training image and each camera's median image; None unless every frame has one image."""
    times = np.asarray(ds.frame_times)
    frames: dict[int, tuple] = {}
    by_cam: dict[str, list[np.ndarray]] = {}
    for v in ds.train:
        k = int(np.argmin(np.abs(times - v.time)))
        if k in frames:
            return None  # more than one view per time: not this regime
        img = view_target(v, background)[0].numpy()
        frames[k] = (v.camera, img, v.view_id)
        by_cam.setdefault(v.view_id, []).append(img)
    if len(frames) != len(times):
        return None
    return FrameImages([frames[k] for k in range(len(times))],
                       {c: np.median(np.stack(imgs), 0) for c, imgs in by_cam.items()})


def node_groups(tracked: TrackedNodes, spacing: float) -> list[np.ndarray]:
    """The moving nodes of `tracked` in groups: connected within two node spacings at the middle frame."""
    from scipy.sparse.csgraph import connected_components

    moving = np.arange(len(tracked.canonical)) if tracked.still is None else np.nonzero(~tracked.still.numpy())[0]
    c = tracked.canonical.double().numpy()[moving]
    n, label = connected_components(np.linalg.norm(c[:, None] - c[None], axis=-1) < 2 * spacing, directed=False)
    return [moving[label == i] for i in range(n)]


def _pixel(cam: Camera, x: np.ndarray) -> tuple[int, int]:
    u, v = np.floor(cam.project(x[None])[0][0]).astype(int)  # pixel i spans [i, i + 1)
    return int(u), int(v)


def _window(img: np.ndarray, u: int, v: int, r: int) -> tuple[slice, slice] | None:
    rows = slice(max(v - r, 0), max(min(v + r + 1, img.shape[0]), 0))
    cols = slice(max(u - r, 0), max(min(u + r + 1, img.shape[1]), 0))
    return None if rows.stop <= rows.start or cols.stop <= cols.start else (rows, cols)


def on_changed(images: FrameImages, centres: np.ndarray, frames: list[int] | None = None) -> float:
    """The share of `frames` (default every one; `centres` ``[len(frames), 3]``) where a pixel within 1 px of the
    centre's projection differs from the median image."""
    frames = list(range(len(centres))) if frames is None else frames
    hits = []
    for k, x in zip(frames, centres):
        cam, img, _ = images.frames[k]
        w = _window(img, *_pixel(cam, x), 1)
        hits.append(w is not None and bool(images.changed(k, *w).any()))
    return float(np.mean(hits))


def on_colour(images: FrameImages, centres: np.ndarray, colour: np.ndarray) -> float:
    """The share of frames where a pixel within 1 px of the centre's projection has about `colour`."""
    hits = []
    for (cam, img, _), x in zip(images.frames, centres):
        w = _window(img, *_pixel(cam, x), 1)
        hits.append(w is not None and bool((np.linalg.norm(img[w] - colour, axis=-1) < 2 * SIGMA).any()))
    return float(np.mean(hits))


def group_colour(images: FrameImages, k: int, x: np.ndarray) -> np.ndarray | None:
    """The median colour of frame k's changed pixels within `RADIUS` px of x's projection (None: fewer than 3)."""
    cam, img, _ = images.frames[k]
    (u, v), = cam.project(x[None])[0]
    yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    near = images.changed(k) & ((xx + 0.5 - u) ** 2 + (yy + 0.5 - v) ** 2 < RADIUS ** 2)
    return np.median(img[near], 0) if near.sum() >= 3 else None


def _ray(images: FrameImages, k: int, x: np.ndarray, colour: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The ray (origin, unit direction) through the colour-weighted centroid of frame k's changed pixels near x."""
    cam, img, _ = images.frames[k]
    uv, z = cam.project(x[None])
    w = _window(img, *np.floor(uv[0]).astype(int).tolist(), WINDOW)
    if w is None:
        return None
    weight = images.changed(k, *w) * np.exp(-((img[w] - colour) ** 2).sum(-1) / (2 * SIGMA ** 2))
    if weight.sum() < 2.0:
        return None
    yy, xx = np.mgrid[w[0], w[1]]
    centroid = np.array([[(weight * xx).sum(), (weight * yy).sum()]]) / weight.sum() + 0.5  # pixel centres
    p = cam.unproject(centroid, z)[0]
    o = cam.c2w[:3, 3].astype(np.float64)
    return o, (p - o) / np.linalg.norm(p - o)


def _solve(rays: dict, lo: int, hi: int, anchor: tuple[int, np.ndarray], tracked_c: np.ndarray) -> np.ndarray:
    """Centres ``[F, 3]``: over frames lo..hi the least-squares points nearest `rays`, their displacements near the
    tracked ones, smooth, `anchor` (frame, centre) held; outside, moved by the tracked displacement from the ends."""
    n = hi - lo + 1
    rows, rhs = [], []

    def sel(i: int, m: np.ndarray = np.eye(3)) -> np.ndarray:
        a = np.zeros((3, 3 * n))
        a[:, 3 * i:3 * i + 3] = m
        return a
    for k, (o, d) in rays.items():
        if lo <= k <= hi:
            p = np.eye(3) - np.outer(d, d)  # the distance to the ray, squared: |p (x - o)|^2
            rows.append(sel(k - lo, p))
            rhs.append(p @ o)
    k, x = anchor
    rows.append(10.0 * sel(k - lo))
    rhs.append(10.0 * x)
    for i in range(n - 1):
        rows.append(HOLD * (sel(i + 1) - sel(i)))
        rhs.append(HOLD * (tracked_c[lo + i + 1] - tracked_c[lo + i]))
    for i in range(1, n - 1):
        rows.append(SMOOTH * (sel(i - 1) - 2 * sel(i) + sel(i + 1)))
        rhs.append(np.zeros(3))
    sol = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)[0].reshape(n, 3)
    return np.stack([sol[0] + tracked_c[k] - tracked_c[lo] if k < lo else
                     sol[-1] + tracked_c[k] - tracked_c[hi] if k > hi else sol[k - lo] for k in range(len(tracked_c))])


def colour_track(images: FrameImages, middle: int, x0: np.ndarray, tracked_c: np.ndarray,
                 colour: np.ndarray) -> np.ndarray:
    """``[F, 3]`` a group's centre at every frame, found by its `colour` (module doc), from `x0` at frame `middle`;
    `tracked_c` ``[F, 3]`` its tracked centres."""
    frames = len(tracked_c)
    rays: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def look(k: int, x: np.ndarray) -> None:
        ray = _ray(images, k, x, colour)
        if ray is None:
            rays.pop(k, None)
        else:
            rays[k] = ray
    lo = hi = middle
    centres = x0 + tracked_c - tracked_c[middle]
    while lo > 0 or hi < frames - 1:
        nlo, nhi = max(lo - GROW, 0), min(hi + GROW, frames - 1)
        for k in list(range(nlo, lo)) + list(range(hi + 1, nhi + 1)):
            look(k, centres[k])
        lo, hi = nlo, nhi
        centres = _solve(rays, lo, hi, (middle, x0), tracked_c)
        for k in range(lo, hi + 1):  # again around the new centres
            if k != middle:
                look(k, centres[k])
        centres = _solve(rays, lo, hi, (middle, x0), tracked_c)
    return centres


def joining(images: FrameImages, tracked: TrackedNodes, group: np.ndarray, spacing: float) -> np.ndarray:
    """The nodes pinned as still within `JOIN_REACH` node spacings of `group` that lie on changed pixels at the
    middle frame."""
    if tracked.still is None:
        return np.zeros(0, int)
    can = tracked.canonical.double().numpy()
    pinned = np.nonzero(tracked.still.numpy())[0]
    near = np.linalg.norm(can[pinned, None] - can[None, group], axis=-1).min(1) < JOIN_REACH * spacing
    return np.array([j for j in pinned[near] if on_changed(images, can[j][None], [tracked.middle])], int)


class LookedAt(NamedTuple):
    """A group whose colour track was looked for (its track lost): its node count, whether the colour track was
    taken, and the shares it was judged by (module doc)."""

    nodes: int
    taken: bool
    tracked_on_changed: float
    tracked_on_colour: float
    found_on_colour: float


@dataclass
class ColourTracks:
    """What `follow_lost_groups` did.

    Attributes:
        nodes: the nodes, each group taken moved by its colour track and the pinned nodes that join it set free.
        groups: the groups whose colour track was looked for.
        joined: nodes pinned as still that joined a group taken.
    """

    nodes: TrackedNodes
    groups: list[LookedAt]
    joined: int

    @property
    def taken(self) -> int:
        return sum(g.taken for g in self.groups)

    def outcome(self) -> dict:
        """JSON-able, as the trainer records it (`Trainer.node_outcome`): ``{"groups": taken, "joined": ...,
        "looked_at": [[nodes, taken, the three shares], ...]}``."""
        return {"groups": self.taken, "joined": self.joined,
                "looked_at": [[g.nodes, bool(g.taken), *(round(float(x), 3) for x in g[2:])] for g in self.groups]}


def follow_lost_groups(tracked: TrackedNodes, ds: Dataset, background: torch.Tensor) -> ColourTracks:
    """`tracked` (one camera per time) with each group its track lost moved by its colour track (module doc);
    `tracked` unchanged unless every frame of `ds` has one training image."""
    images = frame_images(ds, background.detach().cpu().float())
    if images is None:
        return ColourTracks(tracked, [], 0)
    positions = tracked.positions.clone()
    still = None if tracked.still is None else tracked.still.clone()
    spacing = node_spacing(tracked.canonical)
    mid, looked, joined = tracked.middle, [], 0
    for group in node_groups(tracked, spacing):
        tracked_c = tracked.positions[:, group].double().mean(1).numpy()
        x0 = tracked.canonical[group].double().mean(0).numpy()
        if len(group) < MIN_NODES or not on_changed(images, x0[None], [mid]):
            continue  # a lone node, or not on anything that moves at the middle frame
        colour = group_colour(images, mid, x0)
        if colour is None:
            continue
        tracked_on_changed = on_changed(images, tracked_c)
        tracked_on_colour = on_colour(images, tracked_c, colour)
        if tracked_on_changed >= ON_CHANGED or tracked_on_colour >= ON_COLOUR:
            continue  # its track stays on what moves, or on its own colour (a part that stays put in the images)
        centres = colour_track(images, mid, x0, tracked_c, colour)
        found_on_colour = on_colour(images, centres, colour)
        taken = found_on_colour > tracked_on_colour and found_on_colour >= FOUND
        looked.append(LookedAt(len(group), taken, tracked_on_changed, tracked_on_colour, found_on_colour))
        if not taken:
            continue
        extra = joining(images, tracked, group, spacing)
        if len(extra):
            still[extra] = False
            joined += len(extra)
        shift = torch.from_numpy(centres - tracked_c).to(positions)
        shift[mid] = 0  # the canonical frame stays where it was
        positions[:, np.concatenate([group, extra])] += shift[:, None]
    if still is not None and not bool(still.any()):
        still = None
    return ColourTracks(TrackedNodes(positions, tracked.rotations, mid, still), looked, joined)
