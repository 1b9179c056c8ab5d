"""Each rigid part's turn, fitted by render and compare where one camera per time gives the nodes no turn.

Why: with one camera per time the nodes are tracked by the model's own motion (`train.nodes.track_nodes_by_motion`),
and native 4D Gaussians cannot turn their covariance with a turning face: such a face is drawn by a relay of
short-lived Gaussians that move less than the surface, and the nodes follow that relay. On the floor sample the box's
nodes turned 10 degrees where the box turned 45, and were 100 degrees off on average, while the parts' centres were
tracked well (0.08-0.10 units off). Learning the key poses by gradient does not mend it (each frame's own Gaussians
absorb the missing turn), but the images do tell the turn apart when asked: drawn by the middle frame's Gaussians of
the part, the exact turn scores better than any of 300 random turns at most frames.

So, per rigid part (`train.nodes.rigid_parts`) the part's Gaussians at the middle frame (its template) are turned
about the part's tracked centre, and the turn is fitted from the middle frame outwards in segments of `KEY_EVERY`
frames: each segment's turn since the previous key, interpolated along it at a constant rate, against the views of
every frame in the segment (one camera each, so several cameras per fit), by Adam from two starts (the previous
segment's rate, and none), keeping the better. The part's centre stays the tracked one. A part keeps the fitted
turns only where its template then draws the clip's frames better than with the tracked turns. This is the
analysis-by-synthesis of model-based tracking, with each segment seen by several cameras as in multi-view
render-and-compare pose refinement (e.g. Labbé et al., "CosyPose", ECCV 2020).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from splatreel import quaternion
from splatreel.datasets import Dataset
from splatreel.model import Gaussians3D, Gaussians4D
from splatreel.pointsets import rigid_fit
from splatreel.rasterize import rasterize
from splatreel.skinned import nearest_nodes

from .data import downscale_view
from .evaluate import view_target
from .motion import nearest_key
from .nodes import TrackedNodes, node_spacing
from .pose_fit import TEMPLATE_OPACITY, _skew

#: Frames per fitted segment: its cameras (one per frame) hold the segment's turn.
KEY_EVERY = 8
#: Adam steps per start of a segment's fit, views drawn per step, and the rate (radians; decaying tenfold).
FIT_STEPS = 40
FIT_VIEWS_PER_STEP = 4
FIT_LR = 0.05
#: Whether a segment's fit also moves the part's centre (in the template's rms radius per segment, at `FIT_LR`).
FIT_SHIFT = False
#: The fits render the training images downscaled by a whole factor to about this many pixels across.
FIT_SIZE = 100
#: Whether a part's template keeps only the Gaussians whose temporal mean is nearest the middle frame.
TEMPLATE_OWN_FRAME = False
#: Fewest template Gaussians a part needs for a fit.
MIN_TEMPLATE = 16


#: Rigid parts (`rigid_parts`): each moving node is linked to this many nearest moving nodes, a link holds while the
#: pair's tracked distance stays within `PART_TOLERANCE` of the canonical one (or of a node spacing), and parts of
#: fewer than `MIN_PART` nodes get no correction of their own.
PART_LINKS = 8
PART_TOLERANCE = 0.2
MIN_PART = 8


def rigid_parts(tracked: TrackedNodes) -> torch.Tensor:
    """``[M]`` the rigid part of each node (-1: none): the connected components of the moving nodes' neighbour
    links whose tracked length stays within `PART_TOLERANCE` of its canonical length at every frame."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pos = tracked.positions.numpy()
    moving = np.ones(pos.shape[1], bool) if tracked.still is None else ~tracked.still.numpy()
    rows = np.nonzero(moving)[0]
    labels = np.full(pos.shape[1], -1)
    if len(rows) < MIN_PART:
        return torch.from_numpy(labels)
    c = pos[tracked.middle, rows]
    _, j = nearest_nodes(torch.from_numpy(c), torch.from_numpy(c), PART_LINKS + 1)
    i, j = np.repeat(np.arange(len(rows)), j.shape[1] - 1), j[:, 1:].numpy().reshape(-1)
    length = np.linalg.norm(pos[:, rows[i]] - pos[:, rows[j]], axis=-1)  # [F, links]
    rest = length[tracked.middle]
    hold = np.abs(length - rest).max(0) <= PART_TOLERANCE * np.maximum(rest, node_spacing(torch.from_numpy(c)))
    _, comp = connected_components(coo_matrix((np.ones(int(hold.sum())), (i[hold], j[hold])),
                                              shape=(len(rows), len(rows))), directed=False)
    sizes = np.bincount(comp)
    big = np.nonzero(sizes >= MIN_PART)[0]
    renumber = np.full(len(sizes), -1)
    renumber[big] = np.arange(len(big))
    labels[rows] = renumber[comp]
    return torch.from_numpy(labels)


def _rotvec_turn(rate: torch.Tensor, share: float) -> torch.Tensor:
    return torch.linalg.matrix_exp(_skew(rate * share))


def _frame_views(ds: Dataset, background: torch.Tensor, times: list[float]) -> list[list]:
    rank = {t: k for k, t in enumerate(times)}
    views: list[list] = [[] for _ in times]
    for v in ds.train:
        if v.time in rank:
            small = downscale_view(v, max(1, round(min(v.size) / FIT_SIZE)))
            views[rank[v.time]].append((small.camera, view_target(small, background)[0]))
    return views


def _without(s: Gaussians3D, keep: torch.Tensor) -> Gaussians3D:
    return replace(s.select(keep), velocities=None)


class _PartScene:
    """What the fits draw: per frame and view the scene without the parts (rendered once), and per part its
    template at the middle frame; `error` draws one part turned and moved over the rest of one frame's view."""

    def __init__(self, model: Gaussians4D, tracked: TrackedNodes, parts: torch.Tensor, views: list[list],
                 times: list[float], background: torch.Tensor) -> None:
        canonical = tracked.canonical.to(torch.float32)
        in_part = parts >= 0
        self.views = views
        self.rest: list[list[torch.Tensor]] = []
        with torch.no_grad():
            for k, t in enumerate(times):
                s = model.slice(float(t))
                _, j = nearest_nodes(tracked.positions[k].to(torch.float32), s.means, 1)
                rest = _without(s, s.visible & ~in_part[j[:, 0]])
                self.rest.append([rasterize(rest, cam, background).rgb for cam, _ in views[k]])
            s = model.slice(float(times[tracked.middle]))
            _, j = nearest_nodes(canonical, s.means, 1)
            owner = parts[j[:, 0]]
            own = nearest_key(model.t_means, torch.tensor(times)) == tracked.middle if TEMPLATE_OWN_FRAME else True
            self.templates = [_without(s, s.visible & (s.opacities > TEMPLATE_OPACITY) & (owner == p) & own)
                              for p in range(int(parts.max()) + 1)]

    def error(self, p: int, turn: torch.Tensor, centre_from: torch.Tensor, centre_to: torch.Tensor, k: int,
              i: int) -> torch.Tensor:
        tpl = self.templates[p]
        g = replace(tpl, means=(tpl.means - centre_from) @ turn.T + centre_to,
                    covariances=turn @ tpl.covariances @ turn.T)
        cam, target = self.views[k][i]
        out = rasterize(g, cam, (0.0, 0.0, 0.0))
        return ((out.rgb + (1 - out.alpha[..., None]) * self.rest[k][i]) - target).abs().mean()

    def frame_error(self, p: int, turn: torch.Tensor, centre_from: torch.Tensor, centre_to: torch.Tensor,
                    k: int) -> torch.Tensor:
        return sum(self.error(p, turn, centre_from, centre_to, k, i) for i in range(len(self.views[k]))) / max(
            len(self.views[k]), 1)


def _fit_part(scene: _PartScene, p: int, centres: torch.Tensor, middle: int, rng: np.random.Generator
              ) -> tuple[torch.Tensor, torch.Tensor]:
    """Part p's fitted turns since the middle frame ``[F, 3, 3]`` and centres ``[F, 3]`` (module doc), from its
    tracked centres `centres` ``[F, 3]``."""
    frames = len(centres)
    tpl = scene.templates[p].means
    radius = float((tpl - tpl.mean(0)).norm(dim=1).pow(2).mean().sqrt().clamp_min(1e-6))
    turns = torch.eye(3).repeat(frames, 1, 1)
    offsets = torch.zeros(frames, 3)  # the fitted centres less the tracked ones
    for direction, last in ((1, frames - 1), (-1, 0)):
        prev, prev_rate = middle, torch.zeros(3)
        while prev != last:
            key = min(prev + KEY_EVERY, last) if direction > 0 else max(prev - KEY_EVERY, last)
            span = abs(key - prev)
            seg = [(k, i) for k in range(prev + direction, key + direction, direction)
                   for i in range(len(scene.views[k]))]

            def pose(rate: torch.Tensor, shift: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
                share = abs(k - prev) / span
                return (_rotvec_turn(rate, share) @ turns[prev],
                        centres[k] + offsets[prev] + radius * share * shift)

            def loss(rate: torch.Tensor, shift: torch.Tensor, pairs) -> torch.Tensor:
                total = 0.0
                for k, i in pairs:
                    turn, centre = pose(rate, shift, k)
                    total = total + scene.error(p, turn, centres[middle], centre, k, i)
                return total / len(pairs)

            best = None
            for start in (prev_rate * span / KEY_EVERY, torch.zeros(3)):
                rate = start.clone().requires_grad_(True)
                shift = torch.zeros(3, requires_grad=FIT_SHIFT)
                opt = torch.optim.Adam([rate, shift] if FIT_SHIFT else [rate], lr=FIT_LR)
                decay = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 0.1 ** (s / max(FIT_STEPS - 1, 1)))
                for _ in range(FIT_STEPS):
                    pick = rng.choice(len(seg), min(FIT_VIEWS_PER_STEP, len(seg)), replace=False)
                    value = loss(rate, shift, [seg[j] for j in pick])
                    opt.zero_grad(set_to_none=True)
                    value.backward()
                    opt.step()
                    decay.step()
                with torch.no_grad():
                    score = float(loss(rate, shift, seg)) if seg else 0.0
                if best is None or score < best[0]:
                    best = (score, rate.detach().clone(), shift.detach().clone())
            _, rate, shift = best
            with torch.no_grad():
                for k in range(prev + direction, key + direction, direction):
                    turns[k], centre = pose(rate, shift, k)
                    offsets[k] = centre - centres[k]
            prev, prev_rate = key, rate * KEY_EVERY / span
    return turns, centres + offsets


def fit_part_turns(model: Gaussians4D, ds: Dataset, background: torch.Tensor, tracked: TrackedNodes,
                   parts: torch.Tensor, seed: int = 0) -> tuple[TrackedNodes, list[bool]]:
    """`tracked` with each rigid part's nodes (``parts [M]``, -1: none) moved rigidly by its fitted turns about its
    tracked centre (module doc), where those draw the frames better than the tracked turns; `model` on `ds`'s
    times. Also, per part, whether it took the fitted turns."""
    count = int(parts.max()) + 1 if len(parts) else 0
    if count == 0:
        return tracked, []
    model = model.detach().to("cpu")
    background = background.detach().cpu().to(torch.float32)
    times = list(ds.frame_times)
    scene = _PartScene(model, tracked, parts, _frame_views(ds, background, times), times, background)
    rng = np.random.default_rng(seed)
    positions, rotations = tracked.positions.clone(), tracked.rotations.clone()
    middle, frames = tracked.middle, len(times)
    taken = []
    for p in range(count):
        nodes = parts == p
        if len(scene.templates[p]) < MIN_TEMPLATE:
            taken.append(False)
            continue
        track = tracked.positions[:, nodes]  # [F, m, 3]
        centres = track.mean(1).to(torch.float32)
        turns, fitted_centres = _fit_part(scene, p, centres, middle, rng)
        tracked_turns = torch.from_numpy(rigid_fit(np.broadcast_to(track[middle].numpy(), track.shape),
                                                   track.numpy())[0]).to(torch.float32)
        with torch.no_grad():
            fitted_error = sum(float(scene.frame_error(p, turns[k], centres[middle], fitted_centres[k], k))
                               for k in range(frames))
            tracked_error = sum(float(scene.frame_error(p, tracked_turns[k], centres[middle], centres[k], k))
                                for k in range(frames))
        taken.append(fitted_error < tracked_error)
        if not taken[-1]:
            continue
        turns64, centres64 = turns.to(torch.float64), fitted_centres.to(torch.float64)
        local = track[middle] - centres[middle].to(torch.float64)
        positions[:, nodes] = local @ turns64.transpose(1, 2) + centres64[:, None]
        rotations[:, nodes] = quaternion.from_rotmat(turns64)[:, None].expand(-1, int(nodes.sum()), -1)
    return replace(tracked, positions=positions, rotations=rotations), taken
