"""Skinned 4D Gaussians: native 4D Gaussians in a canonical frame, carried to each time by control nodes.

Motion shared by many Gaussians, as in SC-GS (Huang et al., "SC-GS: Sparse-Controlled Gaussian Splatting for
Editable Dynamic Scenes", CVPR 2024): a few hundred control nodes each have a rigid pose at every key time, and a
Gaussian follows the blend of its nearest nodes' motions (linear blend skinning). A native Gaussian moves on its
own line and must hand over to another as a part turns; a skinned one follows the part, so one Gaussian serves
every time it shows at.

Shapes: N Gaussians, M nodes, F key times, K nodes per Gaussian. At time t, with node k's pose (p_k(t), R_k(t))
and canonical position c_k::

    mean(t) = sum_k w_k (R_k(t) (x - c_k) + p_k(t))        x: the Gaussian's canonical mean
    cov(t)  = A cov A^T,  A = sum_k w_k R_k(t)              cov: its native conditional covariance
    w_k     ∝ exp(-|x - c_k|^2 / (2 sigma^2)), over its K nodes nearest in the canonical frame

Between keys the node positions follow a uniform Catmull-Rom spline (a straight chord would cut the arc of a turning
part: 2 % of its radius half-way through a 24-degree turn) and the rotations a normalised lerp of the quaternions;
outside the keys the first or last pose holds. The temporal opacity and the colour stay native: the temporal mean
sets when a Gaussian shows, no longer where it is.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from . import quaternion
from .model import Gaussians3D, Gaussians4D, _check, take_rows

#: Nodes blended per Gaussian (SC-GS uses 4).
NODES_PER_GAUSSIAN = 4
#: Node tensors of a checkpoint, after the native ones.
NODE_TENSORS = ("node_canonical", "node_times", "node_positions", "node_rotations")
#: The skin's tensors of a checkpoint, when it holds one (written since 2026-12; older ones derive it on load): each
#: Gaussian's nodes (their indices as float32, exact below 2^24, as every checkpoint tensor is float) and weights.
SKIN_TENSORS = ("skin_nodes", "skin_weights")


def key_segments(times: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
    """For times `t` ``[T]``: the index i of the key segment [times[i], times[i+1]] holding each (clamped to the
    keys) and the share u in [0, 1] of the way through it."""
    times = times.to(torch.float64)
    t = t.to(times).clamp(float(times[0]), float(times[-1]))
    i = (torch.searchsorted(times, t.contiguous(), right=True) - 1).clamp(0, len(times) - 2)
    return i, (t - times[i]) / (times[i + 1] - times[i])


def catmull_rom(keys: Tensor, i: Tensor, u: Tensor) -> Tensor:
    """The uniform Catmull-Rom spline through `keys` ``[F, ...]`` in segment i at share u (`i`, `u`: ``[T]``;
    returns ``[T, ...]``)."""
    last = len(keys) - 1
    around = [keys[(i + d).clamp(0, last)] for d in (-1, 0, 1, 2)]
    return spline_segment(*around, i > 0, i + 2 <= last, u)


def spline_segment(p0: Tensor, p1: Tensor, p2: Tensor, p3: Tensor, has_before: Tensor, has_after: Tensor,
                   u: Tensor) -> Tensor:
    """The Catmull-Rom segment from p1 to p2 (``[T, ...]`` each, p0 and p3 their neighbours) at share u ``[T]``.
    Where there is no key before (`has_before` ``[T]`` False) or after, the missing neighbour is the reflection of
    the next key across the end one, so that the end segments bend like their neighbours."""
    shape = (-1,) + (1,) * (p1.dim() - 1)
    p0 = torch.where(has_before.view(shape), p0, 2 * p1 - p2)
    p3 = torch.where(has_after.view(shape), p3, 2 * p2 - p1)
    u = u.to(p1.dtype).view(shape)
    return 0.5 * (2 * p1 + (p2 - p0) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u ** 2
                  + (3 * p1 - p0 - 3 * p2 + p3) * u ** 3)


def nlerp(qi: Tensor, qj: Tensor, u: Tensor) -> Tensor:
    """Rotation matrices of the normalised lerp of quaternions `qi` to `qj` ``[T, ..., 4]`` at share u ``[T]``,
    along the shorter arc."""
    qj = torch.where((qi * qj).sum(-1, keepdim=True) < 0, -qj, qj)
    u = u.to(qi.dtype).view((-1,) + (1,) * (qi.dim() - 1))
    return quaternion.to_rotmat(quaternion.normalize(qi * (1 - u) + qj * u))


def node_poses(times: Tensor, positions: Tensor, rotations: Tensor, t: float) -> tuple[Tensor, Tensor]:
    """Every node's position ``[M, 3]`` and rotation matrix ``[M, 3, 3]`` at time `t`, from key poses ``[F, M, 3]``,
    ``[F, M, 4]`` at key times ``[F]`` (differentiable in the poses)."""
    if len(times) == 1:
        return positions[0], quaternion.to_rotmat(quaternion.normalize(rotations[0]))
    i, u = key_segments(times, torch.tensor([float(t)]))
    return catmull_rom(positions, i, u)[0], nlerp(rotations[i], rotations[i + 1], u)[0]


def nearest_nodes(nodes: Tensor, points: Tensor, k: int, chunk: int = 65536) -> tuple[Tensor, Tensor]:
    """Distances and indices ``[N, k]`` of each of `points` ``[N, 3]``'s `k` nearest `nodes` ``[M, 3]`` (exact,
    brute force in chunks of `chunk` points: M is a few hundred; fewer than k when M < k). Not differentiable."""
    k = min(k, len(nodes))
    with torch.no_grad():
        nodes = nodes.detach().to(points.device, points.dtype)
        found = [torch.cdist(rows, nodes).topk(k, dim=1, largest=False) for rows in torch.split(points.detach(), chunk)]
    if not found:
        return torch.zeros(0, k, dtype=points.dtype, device=points.device), \
            torch.zeros(0, k, dtype=torch.long, device=points.device)
    return torch.cat([d for d, _ in found]), torch.cat([j for _, j in found])


def skin_weights(points: Tensor, canonical: Tensor, sigma: float, k: int = NODES_PER_GAUSSIAN
                 ) -> tuple[Tensor, Tensor]:
    """Each point's `k` nearest nodes ``[N, k]`` (int64) and their blend weights ``[N, k]`` (Gaussian of the
    distance, std-dev `sigma`, summing to 1), in the canonical frame. Not differentiable."""
    d, idx = nearest_nodes(canonical, points.detach().to(torch.float32), k)
    w = torch.exp(-0.5 * (d / sigma) ** 2) + 1e-8  # a point far from every node still takes its nearest ones
    return idx, (w / w.sum(1, keepdim=True)).to(points.dtype)


def padded_skin(skin: tuple[Tensor, Tensor], k: int = NODES_PER_GAUSSIAN) -> tuple[Tensor, Tensor]:
    """A skin's nodes and weights (``[N, K]`` each) as ``[N, k]`` (`k` >= K): the columns past K (a model of fewer
    than k nodes) take node 0 at weight 0. The fixed layout of the GPU players (the viewer, the web page)."""
    nodes, weights = skin
    pad = (0, k - nodes.shape[1])
    return torch.nn.functional.pad(nodes, pad), torch.nn.functional.pad(weights, pad)


def gather_nodes(x: Tensor, nodes: Tensor) -> Tensor:
    """Rows `nodes` ``[N, K]`` of per-node `x` ``[M, ...]`` -> ``[N, K, ...]``. Through ``index_select``, whose
    gradient is an ``index_add`` that sums in a fixed order: the gradient of ``x[nodes]`` is an accumulating
    ``index_put``, whose threads add into a node in a varying order on the CPU, so two identical runs (or a run and
    its resumption) would drift apart by an ulp per step."""
    return x.index_select(0, nodes.reshape(-1)).reshape(nodes.shape + x.shape[1:])


def carry(means: Tensor, cov3: Tensor | None, nodes: Tensor, weights: Tensor, canonical: Tensor,
          positions: Tensor, rotations: Tensor) -> tuple[Tensor, Tensor | None]:
    """Canonical means ``[N, 3]`` and covariances ``[N, 3, 3]`` (or None) carried by their nodes ``[N, K]`` with
    `weights` ``[N, K]``: nodes' canonical positions ``[M, 3]`` and poses at the time, ``[M, 3]``, ``[M, 3, 3]``."""
    turn, at = gather_nodes(rotations, nodes), gather_nodes(positions, nodes)  # [N, K, 3, 3], [N, K, 3]
    offset = (means[:, None, :] - gather_nodes(canonical, nodes))[..., None]  # [N, K, 3, 1]
    moved = (weights[..., None] * ((turn @ offset)[..., 0] + at)).sum(1)
    if cov3 is None:
        return moved, None
    blend = (weights[..., None, None] * turn).sum(1)  # [N, 3, 3]
    return moved, blend @ cov3 @ blend.transpose(1, 2)


@dataclass
class SkinnedGaussians:
    """Native 4D Gaussians stored in the nodes' canonical frame, and the control nodes that carry them.

    Attributes:
        gaussians: the native 4D Gaussians (`Gaussians4D`); their spatial means and covariances are canonical, their
            temporal means and scales set when each shows, their colours are native.
        node_canonical: ``[M, 3]`` each node's position in the canonical frame.
        node_times: ``[F]`` strictly increasing key times, in the units of the Gaussians' `time_range`.
        node_positions: ``[F, M, 3]`` each node's position at each key.
        node_rotations: ``[F, M, 4]`` each node's rotation from the canonical frame at each key, w first,
            unnormalised (normalised on use).
        node_sigma: the std-dev of the blend weights' Gaussian of the distance (world units).
        skin: each Gaussian's nodes ``[N, K]`` and weights ``[N, K]``; derived from the canonical means when None
            (a trainer passes its own, kept between densifications, and the checkpoint records it).
    """

    gaussians: Gaussians4D
    node_canonical: Tensor
    node_times: Tensor
    node_positions: Tensor
    node_rotations: Tensor
    node_sigma: float
    skin: tuple[Tensor, Tensor] | None = None
    #: Whether `slice` gives the carried means' velocities (two more carries; a trainer, which draws no velocities,
    #: turns them off).
    with_velocities: bool = True

    TENSORS = Gaussians4D.TENSORS + NODE_TENSORS
    OPTIONAL_TENSORS = Gaussians4D.OPTIONAL_TENSORS + SKIN_TENSORS

    def __post_init__(self) -> None:
        self.node_sigma = float(self.node_sigma)
        self._validate_nodes()  # the Gaussians validated themselves when made (a trainer makes this every step)
        if self.skin is None:
            self.skin = skin_weights(self.gaussians.means, self.node_canonical, self.node_sigma)
        else:
            self._validate_skin()

    def __len__(self) -> int:
        return len(self.gaussians)

    @property
    def kind(self) -> str:
        return "skinned"

    @property
    def time_range(self) -> tuple[float, float]:
        return self.gaussians.time_range

    @property
    def duration(self) -> float:
        return self.gaussians.duration

    @property
    def sh_degree(self) -> int:
        return self.gaussians.sh_degree

    @property
    def sh_degree_t(self) -> int:
        return self.gaussians.sh_degree_t

    @property
    def rotation_convention(self) -> str:
        return self.gaussians.rotation_convention

    @property
    def num_nodes(self) -> int:
        return self.node_canonical.shape[0]

    @property
    def num_keys(self) -> int:
        return self.node_times.shape[0]

    def validate(self) -> None:
        """Raise ModelError naming the first tensor whose shape or dtype is wrong."""
        self.gaussians.validate()
        self._validate_nodes()

    def _validate_nodes(self) -> None:
        m = self.node_canonical.shape[0] if self.node_canonical.dim() == 2 else -1
        f = self.node_times.shape[0] if self.node_times.dim() == 1 else -1
        _check(m >= 1 and self.node_canonical.shape[-1] == 3,
               f"node_canonical has shape {list(self.node_canonical.shape)}, expected [M, 3] with M >= 1")
        _check(f >= 1, f"node_times must be a 1-D tensor of key times, got shape {list(self.node_times.shape)}")
        for name, shape in (("node_positions", (f, m, 3)), ("node_rotations", (f, m, 4))):
            v = getattr(self, name)
            _check(tuple(v.shape) == shape, f"{name} has shape {list(v.shape)}, expected {list(shape)}")
        for name in NODE_TENSORS:
            _check(getattr(self, name).dtype in (torch.float32, torch.float64),
                   f"{name} has dtype {getattr(self, name).dtype}, expected float32/64")
        _check(bool((self.node_times[1:] > self.node_times[:-1]).all()), "node key times must be strictly increasing")
        _check(self.node_sigma > 0, f"node_sigma must be positive, got {self.node_sigma}")

    def _validate_skin(self) -> None:
        nodes, weights = self.skin
        n = len(self.gaussians)
        _check(nodes.dim() == 2 and nodes.shape[0] == n and nodes.shape[1] >= 1 and weights.shape == nodes.shape,
               f"the skin has nodes {list(nodes.shape)} and weights {list(weights.shape)}, expected [{n}, K] each")
        _check(not nodes.is_floating_point() and bool(((nodes >= 0) & (nodes < self.num_nodes)).all()),
               f"the skin's node indices must be integers in [0, {self.num_nodes})")

    def poses(self, t: float) -> tuple[Tensor, Tensor]:
        """Every node's position ``[M, 3]`` and rotation ``[M, 3, 3]`` at time `t`."""
        return node_poses(self.node_times, self.node_positions, self.node_rotations, t)

    def slice(self, t: float, sh_degree_t: int | None = None, rows: Tensor | None = None) -> Gaussians3D:
        """The 3D Gaussians at time `t` (differentiable), as `Gaussians4D.slice` (opacity, colour, visibility and
        `rows` alike) with the means and covariances carried by the nodes. `velocities` are the carried means'
        central difference over a thousandth of the clip (None without `with_velocities`)."""
        native = self.gaussians.slice(t, sh_degree_t, rows)
        carried = self._carrier(rows)
        moved, cov = carried(native.covariances, self.poses(t))
        if not self.with_velocities:
            return replace(native, means=moved, covariances=cov, velocities=None)
        with torch.no_grad():
            h = 1e-3 * (self.duration or 1.0)
            ahead, behind = carried(None, self.poses(t + h))[0], carried(None, self.poses(t - h))[0]
        return replace(native, means=moved, covariances=cov, velocities=(ahead - behind) / (2 * h))

    def _carrier(self, rows: Tensor | None):
        """A function (cov3 of the rows or None, node poses) -> `carry` of Gaussians `rows` (all when None; a bool
        mask or indices): for float32 CPU tensors the fused kernel of `splatreel.carrying` (the same math in one
        pass), else the torch composition."""
        all_means = self.gaussians.means
        if rows is not None and rows.dtype == torch.bool:
            rows = rows.nonzero()[:, 0]
        nodes, weights = (x if rows is None else take_rows(x, rows) for x in self.skin)
        weights, canonical = weights.to(all_means), self.node_canonical.to(all_means)
        if all_means.device.type == "cpu" and all_means.dtype == torch.float32 and not (
                canonical.requires_grad or weights.requires_grad):
            from .carrying import fused_carry  # numba: imported on first use, not with the model

            rows = torch.arange(len(all_means)) if rows is None else rows
            return lambda cov3, poses: fused_carry(all_means, cov3, rows, nodes, weights, canonical,
                                                   *(x.to(all_means) for x in poses))
        means = all_means if rows is None else take_rows(all_means, rows)
        return lambda cov3, poses: carry(means, cov3, nodes, weights, canonical, *(x.to(means) for x in poses))

    def centres(self, times) -> list[tuple[Tensor, Tensor]]:
        """``(means [N, 3], visible [N])`` of `slice(t)` for each t in `times` (see `Gaussians4D.centres`)."""
        carried = self._carrier(None)
        with torch.no_grad():
            return [(carried(None, self.poses(float(t)))[0], visible)
                    for (_, visible), t in zip(self.gaussians.centres(times), times)]

    def anchors(self) -> Tensor:
        """``[N, 3]`` where each Gaussian is when it shows most: carried to its temporal mean (clamped to the keys)."""
        g = self.gaussians
        nodes, weights = self.skin
        if self.num_keys == 1:
            positions = self.node_positions[0][nodes]
            turns = quaternion.to_rotmat(quaternion.normalize(self.node_rotations[0][nodes]))
        else:  # a spline per (Gaussian, node) pair, in the segment of the Gaussian's temporal mean
            i, u = key_segments(self.node_times, g.t_means.detach())
            last = self.num_keys - 1
            key = lambda d: self.node_positions[(i + d).clamp(0, last)[:, None], nodes]  # noqa: E731  [N, K, 3]
            positions = spline_segment(key(-1), key(0), key(1), key(2), i > 0, i + 2 <= last, u)
            turns = nlerp(self.node_rotations[i[:, None], nodes], self.node_rotations[i[:, None] + 1, nodes], u)
        offset = (g.means[:, None, :] - self.node_canonical.to(g.means)[nodes])[..., None]
        return (weights[..., None] * ((turns.to(g.means) @ offset)[..., 0] + positions.to(g.means))).sum(1)

    def drawn_in_clip(self) -> Tensor:
        return self.gaussians.drawn_in_clip()

    def tensors(self) -> dict[str, Tensor]:
        """The native tensors, then the nodes' (`NODE_TENSORS`) and the skin's (`SKIN_TENSORS`)."""
        nodes, weights = self.skin
        return {**self.gaussians.tensors(), **{name: getattr(self, name) for name in NODE_TENSORS},
                "skin_nodes": nodes.to(torch.float32), "skin_weights": weights}

    def metadata(self) -> dict:
        return {**self.gaussians.metadata(), "node_sigma": self.node_sigma}

    @classmethod
    def from_tensors(cls, tensors: dict[str, Tensor], meta: dict) -> "SkinnedGaussians":
        native = {k: v for k, v in tensors.items() if k not in NODE_TENSORS + SKIN_TENSORS}
        skin = None
        if all(k in tensors for k in SKIN_TENSORS):
            nodes = tensors["skin_nodes"]
            _check(bool((nodes == nodes.round()).all()), "the skin's node indices must be whole numbers")
            skin = (nodes.to(torch.int64), tensors["skin_weights"])
        return cls(Gaussians4D.from_tensors(native, meta), *(tensors[k] for k in NODE_TENSORS),
                   node_sigma=float(meta["node_sigma"]), skin=skin)

    def to(self, device=None, dtype=None) -> "SkinnedGaussians":
        nodes, weights = self.skin
        return replace(self, gaussians=self.gaussians.to(device, dtype),
                       **{k: getattr(self, k).to(device=device, dtype=dtype) for k in NODE_TENSORS},
                       skin=(nodes.to(device), weights.to(device=device, dtype=dtype)))

    def detach(self) -> "SkinnedGaussians":
        return replace(self, gaussians=self.gaussians.detach(),
                       **{k: getattr(self, k).detach() for k in NODE_TENSORS})

    def select(self, mask: Tensor) -> "SkinnedGaussians":
        """The Gaussians where `mask` (``[N]`` bool or indices) holds; every node stays."""
        return replace(self, gaussians=self.gaussians.select(mask), skin=tuple(take_rows(x, mask) for x in self.skin))
