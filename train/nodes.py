"""Control nodes for skinned Gaussians (`TrainConfig.motion` 'nodes' and 'auto'): found by tracking the optical flow,
then learned with the Gaussians.

Why: a native Gaussian moves on a straight line, so a turning part is drawn by a relay of Gaussians, each alive for
about a frame, and the times between frames show the hand-over. Motion shared by many Gaussians (SC-GS, Huang et al.
CVPR 2024) lets one Gaussian follow its part through every time it shows at (`splatreel.skinned`). The nodes start
from what the images show:

* at the flow step (`TrainConfig.flow_motion_at`), once the geometry of each frame is fitted, `node_count` nodes are
  drawn by farthest-point sampling among the opaque Gaussians of the middle frame (their positions there are the
  canonical frame);
* each node is tracked frame by frame, forwards and backwards from the middle: it moves by the rigid (Kabsch) fit of
  its `FIT_NEIGHBOURS` nearest Gaussians' optical-flow tracks (`train.motion.flow_tracks`, by the fine flow: the
  nodes' errors add up frame after frame) to the next frame (`splatreel.pointsets.rigid_fit`);
* every Gaussian is carried once from its own frame to the canonical frame (its mean and its conditional covariance)
  by the inverse blend of its nearest nodes there, and loses its native velocity;
* from then on the node poses at every key frame are parameters, with their own Adam, and an as-rigid-as-possible
  term (SC-GS's ARAP) keeps each node's offsets to its `RIGID_NEIGHBOURS` canonical neighbours turning with it.

Where one rigid motion per frame, fitted to the images (`train.pose_fit`; the nodes then tracked with `rigid`), carries
the middle frame's Gaussians to every frame, those alone serve the whole clip (`middle_template`): motion 'auto' does
this, and otherwise stays native; motion 'nodes' does it where it fits (`TrainConfig.node_template`) and otherwise
keeps every frame's Gaussians on the flow's nodes.

A dataset where no camera films consecutive frames (one camera per time) has no flow: motion 'nodes' then tracks
the nodes by the model's own motion (`track_nodes_by_motion`; the native motion, fitted by every view of the clip, is
the scene flow; most nodes go where Gaussians move with their neighbours, `coherent_travel`, and those on what stays
still are pinned), and each frame keeps its own Gaussians. The learned poses are then keyed every few frames
(`TrainConfig.node_key_every`): a pose per frame is fitted by one image and moves to fake its depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from splatreel import quaternion
from splatreel.covariance import (condition_on_time, covariance_4d_from_motion, decompose_covariance_4d,
                                  temporal_marginal)
from splatreel.datasets import Dataset
from splatreel.model import Gaussians4D
from splatreel.pointsets import farthest_point_subset, rigid_fit
from splatreel.skinned import SkinnedGaussians, nearest_nodes, skin_weights

from .initialize import knn, static_time
from .motion import FlowTracks, flow_tracks, nearest_key

#: A node moves by the rigid fit of this many nearest Gaussians' tracks.
FIT_NEIGHBOURS = 128
#: The as-rigid-as-possible term keeps each node's offsets to this many canonical neighbours.
RIGID_NEIGHBOURS = 8
#: Nodes are drawn among the Gaussians at least this opaque.
OPAQUE = 0.1
#: The one set of Gaussians for the clip keeps those within this many node spacings of a node (`middle_template`).
TEMPLATE_REACH = 3.0
#: Tracking by the model's own motion (`track_nodes_by_motion`): a Gaussian travels when it moves by more than this
#: share of the scene's rms radius within `MOTION_KEYS` keys of the middle; this share of the nodes go to those.
MOVING = 0.01
MOTION_KEYS = 2
MOVING_NODES = 0.75
#: A Gaussian's travel is the median displacement of this many nearest Gaussians (`coherent_travel`).
COHERENT_NEIGHBOURS = 16
#: This share of the still nodes go among the `NEAR_STILL` share of still Gaussians nearest to what moves (`_node_sites`).
NEAR_STILL_NODES = 0.75
NEAR_STILL = 0.25
#: Skin weights are recomputed every this many steps (the canonical means move) and after densification.
SKIN_EVERY = 100


def node_spacing(canonical: torch.Tensor) -> float:
    """The median distance from a node to its nearest other node: the blend weights' std-dev."""
    if len(canonical) < 2:
        return 1.0
    d, _ = nearest_nodes(canonical, canonical, 2)
    return float(d[:, 1].median().clamp_min(1e-6))


@dataclass
class TrackedNodes:
    """Nodes tracked through the frames: positions ``[F, M, 3]`` and rotations from the canonical frame
    ``[F, M, 4]`` at each frame (float64); the canonical frame is frame `middle`'s. `still` ``[M]`` (bool, or None:
    none) marks nodes on what does not move, which stay put at every frame and are not learned."""

    positions: torch.Tensor
    rotations: torch.Tensor
    middle: int
    still: torch.Tensor | None = None

    @property
    def canonical(self) -> torch.Tensor:
        """``[M, 3]`` the nodes' canonical positions: where they are at frame `middle`."""
        return self.positions[self.middle]


def track_nodes(model: Gaussians4D, ds: Dataset, background: torch.Tensor, count: int, seed: int = 0,
                tracks: FlowTracks | None = None, rigid: bool = False) -> TrackedNodes | None:
    """`count` nodes among the middle frame's opaque Gaussians of `model` (on `ds`'s times), tracked to every frame
    (module doc) by `tracks` (default: the fine flow's); `rigid`: all of them by the rigid fit of every track of a
    frame (one rigid body). None when no camera films consecutive frames."""
    model = model.detach().to("cpu")
    if tracks is None:
        tracks = flow_tracks(model, ds, background.cpu(), fine=True)
    frames = len(ds.frame_times)
    if not tracks.count.any() or frames < 2:
        return None
    middle = frames // 2
    opaque = model.opacities.numpy() > OPAQUE
    points = tracks.position[(tracks.frame == middle) & opaque]
    if len(points) < 4:
        return None
    chosen = farthest_point_subset(points, count, np.random.default_rng(seed))
    m = len(chosen)
    pos = torch.zeros(frames, m, 3, dtype=torch.float64)
    rot = torch.zeros(frames, m, 3, 3, dtype=torch.float64)
    pos[middle], rot[middle] = torch.from_numpy(points[chosen]), torch.eye(3, dtype=torch.float64)
    for step, keys, ends, seen in ((1, range(middle, frames - 1), tracks.next_points, tracks.next_seen),
                                   (-1, range(middle, 0, -1), tracks.prev_points, tracks.prev_seen)):
        for k in keys:
            rows = np.nonzero((tracks.frame == k) & seen)[0]
            if len(rows) < 3:  # nothing seen moving on: the nodes hold their pose
                pos[k + step], rot[k + step] = pos[k], rot[k]
                continue
            if rigid:  # every node the same tracks: all of the frame's
                idx = np.broadcast_to(np.arange(len(rows)), (1, len(rows)))
            else:
                _, idx = nearest_nodes(torch.from_numpy(tracks.position[rows]), pos[k], FIT_NEIGHBOURS)
                idx = idx.numpy()  # each node's nearest tracks
            turn, cx, cy, _ = (torch.from_numpy(x) for x in rigid_fit(tracks.position[rows][idx], ends[rows][idx]))
            pos[k + step] = cy + (turn @ (pos[k] - cx)[..., None])[..., 0]
            rot[k + step] = turn @ rot[k]
    return TrackedNodes(pos, quaternion.from_rotmat(rot.reshape(-1, 3, 3)).reshape(frames, m, 4), middle)


def coherent_travel(points: np.ndarray, displacements: list[np.ndarray]) -> np.ndarray:
    """``[P]`` how far each of `points` ``[P, 3]`` moves with its neighbourhood: over `displacements` (each ``[P, 3]``,
    to another time), the largest norm of the per-axis median displacement of its `COHERENT_NEIGHBOURS` nearest
    points (itself included). A surface that moves carries its neighbours along; a floor fitted by one camera per
    time jitters each Gaussian its own way, and the median cancels that (on the floor sample a quarter of the
    floor's Gaussians travelled further than the threshold one by one, and FPS among them left 13-17 of 512 nodes
    on the three objects; with the median, 270-300)."""
    others, _ = knn(torch.from_numpy(points), COHERENT_NEIGHBOURS - 1)
    near = np.concatenate([np.arange(len(points))[:, None], others.numpy()], 1)
    return np.max([np.linalg.norm(np.median(d[near], axis=1), axis=1) for d in displacements], axis=0)


def _node_sites(points: np.ndarray, travel: np.ndarray, count: int,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Indices of up to `count` node sites among `points` ``[P, 3]``, and which of them are still (bool).

    `MOVING_NODES` of them by farthest-point sampling among the points that travel (`travel` ``[P]``, how far each
    moves with its neighbours within a few keys of the middle, `coherent_travel`, above `MOVING` of the points' rms
    radius): sampled as one set, a floor or a backdrop many times the moving objects' size would take nearly every
    node, and each object a handful. The still nodes go `NEAR_STILL_NODES` among the `NEAR_STILL` share of still
    points nearest to what moves, the rest over all the still ones: a Gaussian takes its nearest nodes whatever they
    sit on, and with the still nodes spread to the horizon the floor around the objects took the objects' nodes
    (87 % of the floor sample's floor Gaussians had a tenth or more of their weight on them) and moved with them."""
    from scipy.spatial import cKDTree

    def spread(rows: np.ndarray, n: int) -> np.ndarray:
        return rows[farthest_point_subset(points[rows], n, rng)] if n > 0 and len(rows) else rows[:0]

    radius = float(np.sqrt(((points - points.mean(0)) ** 2).sum(1).mean()))
    moving = travel > MOVING * radius
    moves, stays = np.nonzero(moving)[0], np.nonzero(~moving)[0]
    if not len(moves) or not len(stays):
        chosen = spread(np.arange(len(points)), count)
        return chosen, ~moving[chosen]
    first = round(MOVING_NODES * count)
    near = round(NEAR_STILL_NODES * (count - first))
    gap = cKDTree(points[moves]).query(points[stays], workers=-1)[0]
    collar = spread(stays[gap <= np.quantile(gap, NEAR_STILL)], near)
    chosen = np.concatenate([spread(moves, first), collar,
                             spread(np.setdiff1d(stays, collar), count - first - len(collar))])
    return chosen, ~moving[chosen]


def track_nodes_by_motion(model: Gaussians4D, times: list[float], count: int, seed: int = 0) -> TrackedNodes | None:
    """`count` nodes among the opaque Gaussians of `model` alive at the middle key of `times`, tracked to every key
    by the model's own motion: between two neighbouring keys each node moves by the weighted rigid fit of its
    `FIT_NEIGHBOURS` nearest Gaussians alive at both (weight: opacity times the lesser temporal marginal), from
    their sliced means at the one key to those at the other. What a dataset with one camera per time allows, where
    no camera films consecutive frames: the native motion, fitted by every view of the clip, is the scene flow."""
    g = model.detach().to("cpu", torch.float64)
    frames = len(times)
    if frames < 2 or len(g) < 4:
        return None
    _, _, var_t = condition_on_time(g.covariance_4d())
    opacity = torch.sigmoid(g.opacity_logits).numpy()
    cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def at(k: int) -> tuple[np.ndarray, np.ndarray]:
        """The sliced means ``[N, 3]`` at key k and each Gaussian's weight there: opacity times temporal marginal."""
        if k not in cache:
            (means, _), = g.centres([times[k]])
            cache[k] = means.numpy(), opacity * temporal_marginal(times[k], g.t_means, var_t).numpy()
        return cache[k]

    middle = frames // 2
    where, weight = at(middle)
    floor = min(OPAQUE, 0.5 * float(weight.max()))  # early in a run none may be that opaque yet
    candidates = np.nonzero(weight > floor)[0]
    if len(candidates) < 4:
        return None
    probes = (max(middle - MOTION_KEYS, 0), min(middle + MOTION_KEYS, frames - 1))
    travel = coherent_travel(where[candidates], [at(j)[0][candidates] - where[candidates] for j in probes])
    chosen, still = _node_sites(where[candidates], travel, count, np.random.default_rng(seed))
    sites = where[candidates][chosen]
    m = len(sites)
    pos = torch.zeros(frames, m, 3, dtype=torch.float64)
    rot = torch.zeros(frames, m, 3, 3, dtype=torch.float64)
    pos[middle], rot[middle] = torch.from_numpy(sites), torch.eye(3, dtype=torch.float64)
    for step, keys in ((1, range(middle, frames - 1)), (-1, range(middle, 0, -1))):
        for k in keys:
            (p0, w0), (p1, w1) = at(k), at(k + step)
            if k != middle:  # the walk moves on (the middle starts the other way): a few keys held at a time
                del cache[k]
            w = np.minimum(w0, w1)
            rows = np.nonzero(w > floor)[0]
            if len(rows) < 3:  # nothing alive across the two keys: the nodes hold their pose
                pos[k + step], rot[k + step] = pos[k], rot[k]
                continue
            _, idx = nearest_nodes(torch.from_numpy(p0[rows]), pos[k], FIT_NEIGHBOURS)
            idx = idx.numpy()
            wk = w[rows][idx]
            turn, cx, cy, _ = (torch.from_numpy(x) for x in rigid_fit(p0[rows][idx], p1[rows][idx],
                                                                      wk / wk.sum(1, keepdims=True)))
            pos[k + step] = cy + (turn @ (pos[k] - cx)[..., None])[..., 0]
            rot[k + step] = turn @ rot[k]
    still = torch.from_numpy(still)
    pos[:, still], rot[:, still] = pos[middle, still], torch.eye(3, dtype=torch.float64)
    return TrackedNodes(pos, quaternion.from_rotmat(rot.reshape(-1, 3, 3)).reshape(frames, m, 4), middle, still)


def node_keys(frames: int, every: int) -> list[int]:
    """Indices of the frames the nodes' learned poses are keyed at: every `every`-th, and the last."""
    keys = list(range(0, frames, max(1, every)))
    return keys if keys[-1] == frames - 1 else keys + [frames - 1]


def to_canonical(model: Gaussians4D, key_times: torch.Tensor, nodes: TrackedNodes,
                 sigma: float) -> dict[str, torch.Tensor]:
    """Each Gaussian carried from its temporal mean to the canonical frame by the inverse blend of its nearest nodes
    at the key nearest that time: its new mean and 4D shape (``means``, ``log_scales``, ``log_t_scales``,
    ``quats_l``, ``quats_r``). The shape keeps the conditional covariance (turned back) and the temporal variance,
    without the native velocity: the nodes move the Gaussian now, and a 4D axis tilted in time would still place a
    split's children along a motion that no longer exists."""
    with torch.no_grad():
        g = model.detach().to("cpu", torch.float64)
        near = nearest_key(g.t_means, key_times)
        means, turns = torch.empty_like(g.means), torch.empty(len(g), 3, 3, dtype=torch.float64)
        for k in near.unique().tolist():
            rows = (near == k).nonzero()[:, 0]
            idx, w = skin_weights(g.means[rows], nodes.positions[k], sigma)
            r = quaternion.to_rotmat(quaternion.normalize(nodes.rotations[k]))[idx]  # [n, K, 3, 3]
            local = (r.transpose(-1, -2) @ (g.means[rows, None, :] - nodes.positions[k][idx])[..., None])[..., 0]
            means[rows] = (w[..., None] * (local + nodes.canonical[idx])).sum(1)
            q = nodes.rotations[k][idx]
            q = torch.where((q * q[:, :1]).sum(-1, keepdim=True) < 0, -q, q)  # one hemisphere before blending
            turns[rows] = quaternion.to_rotmat(quaternion.normalize((w[..., None] * q).sum(1)))
        cov3, _, var_t = condition_on_time(g.covariance_4d())
        cov3 = turns.transpose(1, 2) @ cov3 @ turns
        scales, t_scales, q_l, q_r = decompose_covariance_4d(
            covariance_4d_from_motion(cov3, torch.zeros_like(means), var_t), g.rotation_convention)
    return {"means": means, "log_scales": scales.clamp_min(1e-12).log(), "log_t_scales": t_scales.clamp_min(1e-12).log(),
            "quats_l": q_l, "quats_r": q_r}


def middle_template(t_means: torch.Tensor, means: torch.Tensor, key_times: torch.Tensor, middle: int,
                    time_range: tuple[float, float], nodes: torch.Tensor,
                    sigma: float) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """One set of Gaussians for the whole clip: the mask ``[N]`` of the Gaussians whose temporal mean is nearest key
    `middle` (the canonical frame's) and whose canonical mean lies within `TEMPLATE_REACH` node spacings `sigma` of
    a node (the nodes sit on the opaque surface: one further off is a floater, which the nodes would drag along to
    every time), and their new temporal means and log temporal std-devs: static (`train.initialize.static_time`),
    carried by the nodes."""
    near = nearest_key(t_means, key_times)
    reach, _ = nearest_nodes(nodes.to(means), means.detach(), 1)
    mask = (near == middle) & (reach[:, 0] <= TEMPLATE_REACH * sigma)
    k = int(mask.sum())
    t_mean, log_t_scale = static_time(time_range)
    return mask, {"t_means": t_means.new_full((k,), t_mean), "log_t_scales": t_means.new_full((k,), log_t_scale)}


def rigidity(canonical: torch.Tensor, positions: torch.Tensor, rotations: torch.Tensor, pairs: torch.Tensor,
             pair_weights: torch.Tensor, sigma: float) -> torch.Tensor:
    """As-rigid-as-possible: the weighted mean over keys and neighbour pairs ``[M, n]`` of the squared difference
    between a node's offset to its neighbour at the key and its canonical offset turned by the node's rotation, in
    node spacings."""
    offsets = canonical[pairs] - canonical[:, None, :]  # [M, n, 3]
    turn = quaternion.to_rotmat(quaternion.normalize(rotations))  # [F, M, 3, 3]
    turned = (turn[:, :, None] @ offsets[None, ..., None])[..., 0]  # [F, M, n, 3]
    moved = positions[:, pairs] - positions[:, :, None, :]
    return (pair_weights * ((moved - turned) ** 2).sum(-1)).mean() / sigma ** 2


class Nodes:
    """The nodes of a run, learned: key times ``[F]`` (the trainer's axis), canonical positions, key poses as
    parameters with their own Adam (save the `still` ones ``[M]``, pinned: they keep their poses), and the skin of the
    current Gaussians."""

    def __init__(self, key_times: torch.Tensor, canonical: torch.Tensor, positions: torch.Tensor,
                 rotations: torch.Tensor, sigma: float, lr_positions: float, lr_rotations: float, device,
                 still: torch.Tensor | None = None) -> None:
        self.key_times = key_times.to(device, torch.float32)
        self.still = None if still is None or not bool(still.any()) else still.to(device, torch.bool)
        self.canonical = canonical.to(device, torch.float32)
        self.sigma = float(sigma)
        self.positions = torch.nn.Parameter(positions.to(device, torch.float32).contiguous())
        self.rotations = torch.nn.Parameter(rotations.to(device, torch.float32).contiguous())
        self.optimizer = torch.optim.Adam([{"params": [self.positions], "lr": lr_positions},
                                           {"params": [self.rotations], "lr": lr_rotations}], eps=1e-15)
        d, j = nearest_nodes(self.canonical, self.canonical, RIGID_NEIGHBOURS + 1)
        self.pairs, self.pair_weights = j[:, 1:], torch.exp(-0.5 * (d[:, 1:] / self.sigma) ** 2)
        self._skin: tuple | None = None

    def skinned(self, gaussians: Gaussians4D, step: int) -> SkinnedGaussians:
        """`gaussians` (canonical) carried by these nodes, their skin recomputed when the count changed or every
        `SKIN_EVERY` steps."""
        if self._skin is None or self._skin[0] != len(gaussians) or step - self._skin[1] >= SKIN_EVERY:
            self._skin = (len(gaussians), step, skin_weights(gaussians.means, self.canonical, self.sigma))
        return SkinnedGaussians(gaussians, self.canonical, self.key_times, self.positions, self.rotations, self.sigma,
                                skin=self._skin[2], with_velocities=False)

    def current_skin(self, count: int) -> tuple[torch.Tensor, torch.Tensor] | None:
        """The skin the last `skinned` drew `count` Gaussians with (nodes, weights ``[N, K]``), None if none has."""
        return self._skin[2] if self._skin is not None and self._skin[0] == count else None

    def rigidity(self) -> torch.Tensor:
        return rigidity(self.canonical, self.positions, self.rotations, self.pairs, self.pair_weights, self.sigma)

    def step(self) -> None:
        if self.still is not None:  # no gradient, so no Adam moment: a still node's pose never moves
            for p in (self.positions, self.rotations):
                if p.grad is not None:
                    p.grad[:, self.still] = 0.0
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)

    def state_dict(self) -> dict:
        """What a resumed run needs: the tensors, the spacing, the optimizer's moments and the current skin."""
        skin = None if self._skin is None else {"count": self._skin[0], "step": self._skin[1],
                                                 "nodes": self._skin[2][0].cpu(), "weights": self._skin[2][1].cpu()}
        return {"key_times": self.key_times.cpu(), "canonical": self.canonical.cpu(), "sigma": self.sigma,
                "positions": self.positions.detach().cpu(), "rotations": self.rotations.detach().cpu(),
                "optimizer": self.optimizer.state_dict(), "skin": skin,
                "still": None if self.still is None else self.still.cpu()}

    @classmethod
    def from_state(cls, state: dict, lr_positions: float, lr_rotations: float, device) -> "Nodes":
        nodes = cls(state["key_times"], state["canonical"], state["positions"], state["rotations"], state["sigma"],
                    lr_positions, lr_rotations, device, state.get("still"))
        nodes.optimizer.load_state_dict(state["optimizer"])
        skin = state.get("skin")
        if skin:  # the skin of the interrupted run, so that the resumed one recomputes it at the same steps
            nodes._skin = (int(skin["count"]), int(skin["step"]),
                           (skin["nodes"].to(device), skin["weights"].to(device)))
        return nodes
