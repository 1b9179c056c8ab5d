"""Node groups followed in the images by their colour, for `bench/motion_experiments.py colour-tracks`.

With one camera per time, the trainer tracks its control nodes by the model's own motion at the flow step. A part the
model does not draw yet (the floor scene's pendulum bob at the flow step) is then lost. The images still show it:
each frame's image differs from its camera's per-pixel median image (over that camera's frames) where something
moved. Each group of moving nodes (connected within two node spacings at the middle frame) takes its colour from the
middle frame's image (the median colour of the changed pixels within `RADIUS` px of its centre), and is looked for in
every frame, outwards from the middle frame `GROW` frames at a time: within `WINDOW` px of the predicted centre's
projection, the centroid of the changed pixels weighted by their closeness to that colour. Each found centroid is a
ray from its frame's camera; the group's centre at every frame is the least-squares point nearest those rays, held
near the tracked frame-to-frame displacement, smooth in time, and anchored at the middle frame.

A group of at least `MIN_NODES` nodes takes its colour track only where its centre falls on changed pixels at the
middle frame (not a node of the floor beside a part), its tracked centre falls off them in over a tenth of the
frames (`ON_CHANGED`: the colour centroid of a many-coloured part such as a box is not its centre, so a part tracked
on what moves is left alone) and off its own colour in over `1 - ON_COLOUR` of them (a part that stays in place,
which the median image holds, is not lost), and the colour track falls on its colour more often, and in at least
`FOUND` of the frames (a colour track that mostly misses its colour has not found the part). Generic in that it
reads no truth; tuned on the floor sample (probe: the bob's four nodes 0.09 units from the truth on average, 0.85 as
tracked).
"""

from __future__ import annotations

import numpy as np
import torch

TAU = 0.15  # summed RGB difference from the median image that counts as changed
SIGMA = 0.08  # colour closeness (RGB distance) of a pixel to its group's colour
WINDOW, RADIUS, GROW = 12, 8, 4
ON_CHANGED = 0.9
ON_COLOUR = 0.3
MIN_NODES = 2
FOUND = 0.5
SMOOTH, HOLD = 0.1, 1.0


def frame_images(ds, background, frames: int):
    """Per frame (one camera per time): its camera, image [H, W, 3] on `background`, and each camera's median image."""
    from splatreel.train.evaluate import view_target

    times = np.asarray(ds.frame_times)
    views, by_cam = {}, {}
    for v in ds.train:
        k = int(np.argmin(np.abs(times - v.time)))
        if k in views:
            return None  # more than one view per time: not this regime
        img = view_target(v, background)[0].numpy()
        views[k] = (v.camera, img, v.view_id)
        by_cam.setdefault(v.view_id, []).append(img)
    if len(views) != frames:
        return None
    median = {c: np.median(np.stack(imgs), 0) for c, imgs in by_cam.items()}
    return views, median


def groups(tracked, spacing: float) -> list[np.ndarray]:
    """The moving nodes of `tracked` in groups: connected within two node spacings at the middle frame."""
    from scipy.sparse.csgraph import connected_components

    moving = np.nonzero(~tracked.still.numpy())[0] if tracked.still is not None else np.arange(len(tracked.canonical))
    c = tracked.canonical.double().numpy()[moving]
    n, label = connected_components(np.linalg.norm(c[:, None] - c[None], axis=-1) < 2 * spacing, directed=False)
    return [moving[label == i] for i in range(n)]


def _changed(img, median):
    """Where `img` differs from its camera's `median` image: something moved there."""
    return np.abs(img - median).sum(-1) > TAU


def _around(centres, views, frames=None):
    """Per frame (`frames`, default every one): its image, camera and the 3 x 3 pixels around its centre's projection
    (empty off the image)."""
    for k, x in zip(range(len(centres)) if frames is None else frames, centres):
        cam, img, c = views[k]
        u, v = np.floor(cam.project(x[None])[0][0]).astype(int)  # pixel i spans [i, i + 1)
        yield img, c, (slice(max(v - 1, 0), max(v + 2, 0)), slice(max(u - 1, 0), max(u + 2, 0)))


def on_changed(centres, views, median, frames=None) -> float:
    """The share of `frames` (default every one) where a pixel within 1 px of the centre's projection differs from
    the median image."""
    return float(np.mean([img[w].size > 0 and bool(_changed(img[w], median[c][w]).any())
                          for img, c, w in _around(centres, views, frames)]))


def on_colour(centres, views, colour) -> float:
    """The share of frames where a pixel within 1 px of the centre's projection has about `colour`."""
    return float(np.mean([img[w].size > 0 and bool((np.linalg.norm(img[w] - colour, axis=-1) < 2 * SIGMA).any())
                          for img, c, w in _around(centres, views)]))


def _colour(views, median, k, x):
    cam, img, c = views[k]
    (u, v), = cam.project(x[None])[0]
    yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    near = _changed(img, median[c]) & ((xx + 0.5 - u) ** 2 + (yy + 0.5 - v) ** 2 < RADIUS ** 2)
    return np.median(img[near], 0) if near.sum() >= 3 else None


def _centroid(views, median, k, x, colour):
    cam, img, c = views[k]
    uv, z = cam.project(x[None])
    u, v = uv[0]
    y0, y1 = int(max(v - WINDOW, 0)), int(min(v + WINDOW + 1, img.shape[0]))
    x0, x1 = int(max(u - WINDOW, 0)), int(min(u + WINDOW + 1, img.shape[1]))
    if y1 <= y0 or x1 <= x0:
        return None
    win = img[y0:y1, x0:x1]
    w = _changed(win, median[c][y0:y1, x0:x1]) * np.exp(-((win - colour) ** 2).sum(-1) / (2 * SIGMA ** 2))
    if w.sum() < 2.0:
        return None
    yy, xx = np.mgrid[y0:y1, x0:x1]
    p = cam.unproject(np.array([[(w * xx).sum() / w.sum(), (w * yy).sum() / w.sum()]]) + 0.5, z)[0]  # centres
    o = cam.c2w[:3, 3].astype(np.float64)
    return o, (p - o) / np.linalg.norm(p - o)


def _solve(rays, lo, hi, anchor, tracked_c):
    """Centres over frames [lo, hi] nearest the rays, displacements near the tracked ones, smooth; tracked outside."""
    n = hi - lo + 1
    rows, rhs = [], []

    def sel(i, m=np.eye(3)):
        a = np.zeros((3, 3 * n))
        a[:, 3 * i:3 * i + 3] = m
        return a
    for k, (o, d) in rays.items():
        if lo <= k <= hi:
            p = np.eye(3) - np.outer(d, d)
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


def colour_track(views, median, middle: int, x0: np.ndarray, tracked_c: np.ndarray, colour: np.ndarray):
    """The group's centre at every frame, found by its colour (module doc)."""
    frames = len(tracked_c)
    rays = {}

    def look(k, x):
        ray = _centroid(views, median, k, x, colour)
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
        for k in range(lo, hi + 1):
            if k != middle:
                look(k, centres[k])
        centres = _solve(rays, lo, hi, (middle, x0), tracked_c)
    return centres


def retrack(tracked, ds, background, log) -> torch.Tensor:
    """`tracked`'s positions with each group that its track loses moved by its colour track (module doc)."""
    from splatreel.train.nodes import node_spacing

    frames = tracked.positions.shape[0]
    found = frame_images(ds, background, frames)
    positions = tracked.positions.clone()
    if found is None:
        log("colour-tracks: not one camera per time; nodes as tracked")
        return positions
    views, median = found
    found_groups = groups(tracked, float(node_spacing(tracked.canonical)))
    log(f"colour-tracks: {len(found_groups)} groups of moving nodes")
    for group in found_groups:
        tracked_c = tracked.positions[:, group].double().mean(1).numpy()
        x0 = tracked.canonical[group].double().mean(0).numpy()
        if len(group) < MIN_NODES or not on_changed(x0[None], views, median, frames=[tracked.middle]):
            continue  # a lone node, or not on anything that moves at the middle frame
        colour = _colour(views, median, tracked.middle, x0)
        tracked_on_changed = on_changed(tracked_c, views, median)
        tracked_on_colour = on_colour(tracked_c, views, colour)
        if tracked_on_changed >= ON_CHANGED or tracked_on_colour >= ON_COLOUR:
            continue  # its track stays on what moves, or on its own colour (a part that stays put in the images)
        centres = colour_track(views, median, tracked.middle, x0, tracked_c, colour)
        found_on_colour = on_colour(centres, views, colour)
        taken = found_on_colour > tracked_on_colour and found_on_colour >= FOUND
        log(f"colour-tracks: group of {len(group)} nodes, colour {[round(float(c), 2) for c in colour]}: as tracked "
            f"on changed pixels {tracked_on_changed:.2f}, on its colour {tracked_on_colour:.2f}; by colour on its "
            f"colour {found_on_colour:.2f}: {'taken' if taken else 'kept'}")
        if taken:
            shift = torch.from_numpy(centres - tracked_c).to(positions)
            shift[tracked.middle] = 0  # the canonical frame stays where it was
            positions[:, group] += shift[:, None]
    return positions
