"""What the trainer would score with another motion model, measured before it is built: oracles and prototypes that
patch the trainer and run `bench/train.py` with it.

    python bench/motion_experiments.py EXPERIMENT [bench/train.py options: --samples spinner --iters 1400 --json OUT]

EXPERIMENT:
  rigid  (oracle, `spinner` sample only) every Gaussian is carried from its temporal mean to time t by the box's exact
         rigid motion (`splatreel.samples.objects.Spinner`): its mean and its conditional covariance turn and travel
         with the box. The temporal means are frozen (learning rate 0): the carried position depends on them, so one
         drifting under the opacity's gradient would turn its Gaussian off its surface (an earlier implementation that
         let them drift scored 23.9 dB). No velocities from optical flow; splits in space only.
  nodes  (prototype, any image matrix) motion shared across Gaussians by control nodes, as in SC-GS (Huang et al.,
         CVPR 2024): at the flow step (`--flow-motion-at`) 512 nodes are drawn (farthest-point sampling) among the
         Gaussians of the middle frame and tracked frame by frame, each by the rigid (Kabsch) fit of its 24 nearest
         Gaussians' optical-flow tracks (`splatreel.train.motion.flow_tracks`). Every Gaussian is then carried once
         to the nodes' canonical frame (the middle frame's; its mean and the spatial part of its 4D rotation), and
         from then on shown at time t by the blend of its 4 nearest nodes' rigid motions (linear blend skinning,
         Gaussian weights of the canonical distance); the node poses per key frame are learned with the Gaussians,
         Catmull-Rom between keys, and splits are in space only. The temporal means keep learning: they no longer
         move a Gaussian, only set when it shows.

Both replace the native conditional mean (and its quadratic term) by the carried one; the temporal opacity, the
colour and the conditional covariance's shape stay native. The patches are this script's alone: nothing in the
package imports it.
"""

from __future__ import annotations

import math
import runpy
import sys
import types
from pathlib import Path

import numpy as np
import torch

from splatreel import covariance as _covariance
from splatreel import quaternion
from splatreel.model import Gaussians4D, take_rows
from splatreel.samples.geometry import farthest_point_subset
from splatreel.train import strategy as _strategy
from splatreel.train import trainer as _trainer
from splatreel.train.motion import flow_tracks

NODES, NODE_NEIGHBOURS, FIT_NEIGHBOURS, RIGID_NEIGHBOURS = 512, 4, 24, 8
LR_NODE_POSITIONS, LR_NODE_ROTATIONS = 1e-4, 5e-4  # positions times the scene extent
#: weight of the as-rigid-as-possible term between neighbouring nodes (SC-GS's ARAP loss), on offsets measured in
#: node spacings
LAMBDA_RIGID = float(__import__("os").environ.get("SPLATREEL_NODES_RIGID", "0.1"))
_native_sliced = Gaussians4D._sliced
_state: dict = {"carry": None}  # carry(model, t, rows, cov3) -> (means, cov3), once the motion is on


def _carried_sliced(self, t, sh_degree_t, rows, means, cov3, velocity, marginal):
    if _state["carry"] is not None:
        means, cov3 = _state["carry"](self, t, rows, cov3)
    return _native_sliced(self, t, sh_degree_t, rows, means, cov3, velocity, marginal)


def _normalised_times(model: Gaussians4D, rows) -> torch.Tensor:
    """Each Gaussian's temporal mean as a share of the clip (the trainer's axis and the dataset's agree on it)."""
    t0, t1 = model.time_range
    tm = model.t_means.detach() if rows is None else take_rows(model.t_means.detach(), rows)
    return ((tm.double() - t0) / (t1 - t0)).clamp(0, 1)


def _split_in_space_only() -> None:
    """Densification's splits draw children along the spatial axes only, at the parent's temporal mean, once the
    motion carries the Gaussians: a 4D split would move a child along the native velocity, which the carried motion
    ignores. The recipe's ``split="space"`` is not enough: it still offsets a child's temporal mean along the time
    components of the tilted 4D axes, and the carried position depends on the temporal mean."""
    def rotation_4d(*args, **kwargs):
        r4 = _covariance.rotation_4d(*args, **kwargs)
        if _state["carry"] is None:
            return r4
        r4 = r4.clone()
        r4[:, 3, :] = 0.0
        r4[:, :3, 3] = 0.0
        return r4
    shim = types.SimpleNamespace(**{n: getattr(_covariance, n) for n in dir(_covariance) if not n.startswith("__")})
    shim.rotation_4d = rotation_4d
    _strategy.covariance = shim


# --- rigid: the spinner's exact motion ------------------------------------------------------------------------------
def use_rigid_oracle() -> list[str]:
    from splatreel.samples.objects import Spinner

    box = Spinner()
    axis = torch.tensor(box.spin_axis, dtype=torch.float64)
    axis = axis / axis.norm()
    # the box's centre, tabled from the sample's own path (linear between 2,001 times: ~1e-7 off)
    table_s = np.linspace(0.0, 1.0, 2001)
    table = torch.from_numpy(np.stack([box.center(float(s)) for s in table_s]))

    def centre(s: torch.Tensor) -> torch.Tensor:
        x = s.clamp(0, 1) * (len(table_s) - 1)
        i = x.floor().long().clamp(max=len(table_s) - 2)
        w = (x - i)[:, None]
        return table[i] * (1 - w) + table[i + 1] * w

    def turn(angle: torch.Tensor) -> torch.Tensor:  # [G] -> [G, 3, 3] about the spin axis
        half = 0.5 * angle[:, None]
        return quaternion.to_rotmat(torch.cat([torch.cos(half), torch.sin(half) * axis], -1))

    # the box turns about its spin axis alone: rotation(s) rotation(s_i)^T is that turn (the tilt cancels)
    check = torch.from_numpy(box.rotation(0.7) @ box.rotation(0.2).T)
    assert torch.allclose(turn(torch.tensor([2 * math.pi * box.spin_turns * 0.5], dtype=torch.float64))[0], check,
                          atol=1e-9)

    def carry(model, t, rows, cov3):
        s_i = _normalised_times(model, rows)
        t0, t1 = model.time_range
        s = torch.full_like(s_i, (t - t0) / (t1 - t0)).clamp(0, 1)
        rot = turn(2 * math.pi * box.spin_turns * (s - s_i)).to(cov3.dtype)
        mu = model.means if rows is None else take_rows(model.means, rows)
        means = (rot @ (mu - centre(s_i).to(mu.dtype))[..., None])[..., 0] + centre(s).to(mu.dtype)
        return means, rot @ cov3 @ rot.transpose(1, 2)

    _state["carry"] = carry
    # the temporal means frozen, no velocities from the flow: recipe fields, set through bench/train.py
    return ["--set", "lr_t_means=0", "--set", "flow_motion_at=0"]


# --- nodes: flow-tracked control nodes ------------------------------------------------------------------------------
def _kabsch(x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rotations ``[M, 3, 3]`` with y - cy ≈ R (x - cx) for point sets ``[M, n, 3]``, and the centroids."""
    cx, cy = x.mean(1, keepdim=True), y.mean(1, keepdim=True)
    u, _, vt = torch.linalg.svd((x - cx).transpose(1, 2) @ (y - cy))
    d = torch.sign(torch.linalg.det(vt.transpose(1, 2) @ u.transpose(1, 2)))
    flip = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    return vt.transpose(1, 2) @ flip @ u.transpose(1, 2), cx[:, 0], cy[:, 0]


def _catmull_rom(keys: torch.Tensor, i: int, u: float) -> torch.Tensor:
    """The uniform Catmull-Rom spline through `keys` ``[F, ...]`` between keys i and i + 1 at `u` in [0, 1]; the
    missing neighbour at either end is the reflection of the next key across the last."""
    last = len(keys) - 1
    p1, p2 = keys[i], keys[min(i + 1, last)]
    p0 = keys[i - 1] if i > 0 else 2 * p1 - p2
    p3 = keys[i + 2] if i + 2 <= last else 2 * p2 - p1
    return 0.5 * (2 * p1 + (p2 - p0) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u ** 2
                  + (3 * p1 - p0 - 3 * p2 + p3) * u ** 3)


class NodeGraph:
    """Control nodes: a canonical position each ``[M, 3]`` (where tracking found it at the middle frame, fixed) and a
    pose at each key frame (positions ``[F, M, 3]``, rotations ``[F, M, 4]`` from the canonical frame, learned).
    Between keys the positions follow a Catmull-Rom spline (a chord would cut the arc of a turning part: 2 % of the
    radius half-way through a 24-degree turn) and the rotations a normalised lerp.

    The Gaussians are stored in the canonical frame (`to_canonical`, once): a Gaussian at time t is
    sum_k w_k (R_k(t) (x - c_k) + p_k(t)) over its nearest nodes k, so its temporal mean only sets when it shows."""

    def __init__(self, key_s: torch.Tensor, positions: torch.Tensor, rotations: torch.Tensor, extent: float):
        from scipy.spatial import cKDTree

        self.key_s = key_s.double()
        self.canonical = positions[len(positions) // 2].float().clone()
        self.positions = torch.nn.Parameter(positions.float())
        self.rotations = torch.nn.Parameter(rotations.float())
        self.optimizer = torch.optim.Adam([{"params": [self.positions], "lr": LR_NODE_POSITIONS * extent},
                                           {"params": [self.rotations], "lr": LR_NODE_ROTATIONS}], eps=1e-15)
        middle = self.canonical.double().numpy()
        self.tree = cKDTree(middle)
        self.sigma = float(np.median(self.tree.query(middle, k=2)[0][:, 1]))
        self._skin: dict = {}

    def pose(self, s: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Every node's position ``[M, 3]`` and rotation matrix ``[M, 3, 3]`` at clip share `s`."""
        s = min(max(float(s), float(self.key_s[0])), float(self.key_s[-1]))
        i = int((torch.searchsorted(self.key_s, torch.tensor([s], dtype=torch.float64), right=True) - 1)
                .clamp(0, len(self.key_s) - 2))
        u = (s - float(self.key_s[i])) / float(self.key_s[i + 1] - self.key_s[i])
        qi, qj = self.rotations[i], self.rotations[i + 1]
        qj = torch.where((qi * qj).sum(-1, keepdim=True) < 0, -qj, qj)
        return _catmull_rom(self.positions, i, u), quaternion.to_rotmat(quaternion.normalize(qi * (1 - u) + qj * u))

    def rigidity(self) -> torch.Tensor:
        """As-rigid-as-possible: at every key, each node's offset to its `RIGID_NEIGHBOURS` canonical neighbours is
        its canonical offset turned by the node's rotation (squared residual in node spacings, weighted by the
        canonical distance)."""
        if not hasattr(self, "_rigid_pairs"):
            d, j = self.tree.query(self.canonical.double().numpy(), k=RIGID_NEIGHBOURS + 1)
            self._rigid_pairs = (torch.from_numpy(j[:, 1:]),
                                 torch.from_numpy(np.exp(-0.5 * (d[:, 1:] / self.sigma) ** 2)).float())
        j, w = self._rigid_pairs
        offsets = self.canonical[j] - self.canonical[:, None, :]  # [M, n, 3]
        rot = quaternion.to_rotmat(quaternion.normalize(self.rotations))  # [F, M, 3, 3]
        turned = (rot[:, :, None] @ offsets[None, ..., None])[..., 0]  # [F, M, n, 3]
        moved = self.positions[:, j] - self.positions[:, :, None, :]
        return (w * ((moved - turned) ** 2).sum(-1)).mean() / self.sigma ** 2

    def weights(self, points: np.ndarray, tree) -> tuple[torch.Tensor, torch.Tensor]:
        d, idx = tree.query(points, k=NODE_NEIGHBOURS)
        w = np.exp(-0.5 * (d.reshape(len(points), -1) / self.sigma) ** 2) + 1e-8
        return (torch.from_numpy(idx.reshape(len(points), -1)),
                torch.from_numpy(w / w.sum(1, keepdims=True)).float())

    def skin(self, model: Gaussians4D) -> tuple[torch.Tensor, torch.Tensor]:
        """Each Gaussian's `NODE_NEIGHBOURS` nearest nodes in the canonical frame ``[N, K]`` and their weights
        (cached per model; `forget` after the Gaussians moved)."""
        key = (len(model), model.means.data_ptr())
        if key not in self._skin:
            self._skin = {key: self.weights(model.means.detach().double().cpu().numpy(), self.tree)}
        return self._skin[key]

    def forget(self) -> None:
        self._skin = {}

    def to_canonical(self, model: Gaussians4D) -> tuple[torch.Tensor, torch.Tensor]:
        """Each Gaussian's mean and spatial rotation (canonical to its own time) ``[N, 3]``, ``[N, 3, 3]``, carried
        back to the canonical frame from its temporal mean by the inverse blend of the nodes nearest it there."""
        from scipy.spatial import cKDTree

        with torch.no_grad():
            s = _normalised_times(model, None)
            near = torch.argmin((s[:, None] - self.key_s[None]).abs(), 1).numpy()
            mu = model.means.detach().float()
            means, turns = torch.empty_like(mu), torch.empty(len(mu), 3, 3)
            for k in np.unique(near):
                rows = np.nonzero(near == k)[0]
                nodes, w = self.weights(mu[rows].double().numpy(), cKDTree(self.positions[k].double().numpy()))
                p, r = self.pose(float(self.key_s[k]))
                p, r, c = p[nodes], r[nodes], self.canonical[nodes]
                local = (r.transpose(-1, -2) @ (mu[rows, None, :] - p)[..., None])[..., 0] + c
                means[rows] = (w[..., None] * local).sum(1)
                q = self.rotations[k][nodes]
                q = torch.where((q * q[:, :1]).sum(-1, keepdim=True) < 0, -q, q)
                turns[rows] = quaternion.to_rotmat(quaternion.normalize((w[..., None] * q).sum(1)))
        return means, turns

    def carry(self, model: Gaussians4D, t: float, rows, cov3: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        nodes, weights = self.skin(model)
        pick = (lambda x: x) if rows is None else (lambda x: take_rows(x, rows))  # noqa: E731
        mu, nodes, weights = pick(model.means), pick(nodes), pick(weights)
        t0, t1 = model.time_range
        p_now, r_now = self.pose((t - t0) / (t1 - t0))
        p_now, r_now, c = p_now[nodes], r_now[nodes], self.canonical[nodes]
        means = (weights[..., None] * ((r_now @ (mu[:, None, :] - c)[..., None])[..., 0] + p_now)).sum(1)
        rot = (weights[..., None, None] * r_now).sum(1)
        return means, rot @ cov3 @ rot.transpose(1, 2)


def _turned_4d(quats_l: torch.Tensor, quats_r: torch.Tensor, turn: torch.Tensor, convention: str):
    """The 4D rotations' quaternion pairs after a spatial turn ``[N, 3, 3]`` (R4 -> diag(turn, 1) R4): a turn of
    the x, y, z axes is q v conj(q) on the quaternion v = (t, ...) read in the convention's axis order."""
    if convention == "current":  # R4[i, j] = A[3-i, 3-j]: x, y, z are the quaternion's k, j, i
        flip = torch.tensor([[0.0, 0, 1], [0, 1, 0], [1, 0, 0]], dtype=turn.dtype)
        q = quaternion.from_rotmat(flip @ turn @ flip)
    else:  # legacy: R4 = A, where t is not the real part: no conjugation turns x, y, z alone (not the default)
        raise NotImplementedError("the nodes experiment needs the 'current' 4D rotation convention")
    return quaternion.multiply(q, quats_l), quaternion.multiply(q, quats_r)


def track_nodes(trainer) -> NodeGraph | None:
    """Nodes drawn among the middle frame's Gaussians and tracked to every frame by the Kabsch fits of their nearest
    Gaussians' flow tracks; None when no camera films consecutive frames (one camera per time)."""
    from scipy.spatial import cKDTree

    model = trainer.model().to("cpu")
    tracks = flow_tracks(model, trainer.ds, trainer.bg.cpu())
    if not tracks.count.any():
        return None
    frames = len(trainer.ds.frame_times)
    middle = frames // 2
    opaque = model.opacities.detach().numpy() > 0.1
    points = tracks.position[(tracks.frame == middle) & opaque]
    chosen = farthest_point_subset(points, NODES, np.random.default_rng(0))
    n = len(chosen)
    pos = torch.zeros(frames, n, 3, dtype=torch.float64)
    rot = torch.zeros(frames, n, 3, 3, dtype=torch.float64)
    pos[middle], rot[middle] = torch.from_numpy(points[chosen]), torch.eye(3, dtype=torch.float64)
    for step, keys, ends, seen in ((1, range(middle, frames - 1), tracks.next_points, tracks.next_seen),
                                   (-1, range(middle, 0, -1), tracks.prev_points, tracks.prev_seen)):
        for k in keys:
            rows = np.nonzero((tracks.frame == k) & seen)[0]
            _, idx = cKDTree(tracks.position[rows]).query(pos[k].numpy(), k=FIT_NEIGHBOURS)
            turn, cx, cy = _kabsch(torch.from_numpy(tracks.position[rows][idx]), torch.from_numpy(ends[rows][idx]))
            pos[k + step] = cy + (turn @ (pos[k] - cx)[..., None])[..., 0]
            rot[k + step] = turn @ rot[k]
    t0, t1 = trainer.time_range
    key_s = (torch.tensor(trainer.ds.frame_times, dtype=torch.float64) - t0) / (t1 - t0)
    quats = quaternion.from_rotmat(rot.reshape(-1, 3, 3)).reshape(frames, n, 4)
    return NodeGraph(key_s, pos, quats, trainer.extent)


def use_nodes() -> list[str]:
    def set_flow_motion(self):
        self._flow_motion_done = True
        graph = track_nodes(self)
        if graph is None:
            print("[nodes] no camera films consecutive frames: the native motion stays", flush=True)
            return 0
        model = self.model().to("cpu")
        means, turns = graph.to_canonical(model)
        quats_l, quats_r = _turned_4d(model.quats_l.detach(), model.quats_r.detach(), turns.transpose(1, 2),
                                      self.cfg.rotation_convention)
        _strategy.replace_values(self.params, self.optimizer, {"means": means.to(self.device),
                                                               "quats_l": quats_l.to(self.device),
                                                               "quats_r": quats_r.to(self.device)})
        self.node_graph = graph
        _state["carry"] = graph.carry
        _state["tracked"] = (graph.positions.detach().clone(), graph.rotations.detach().clone())
        print(f"[nodes] {graph.positions.shape[1]} nodes tracked over {graph.positions.shape[0]} frames; the "
              "Gaussians moved to their canonical frame", flush=True)
        return 1

    native_step = _trainer.Trainer.train_step

    def train_step(self):
        out = native_step(self)
        graph = getattr(self, "node_graph", None)
        if graph is not None:
            if LAMBDA_RIGID:
                (LAMBDA_RIGID * graph.rigidity()).backward()
            graph.optimizer.step()
            graph.optimizer.zero_grad(set_to_none=True)
            if self.step % 100 == 0:
                graph.forget()
        return out

    native_run = _trainer.Trainer.run

    def run(self, *args, **kwargs):
        result = native_run(self, *args, **kwargs)
        graph, out = getattr(self, "node_graph", None), _dump_path()
        if graph is not None and out is not None:  # the node poses, tracked and learned, for a look beside the truth
            torch.save({"key_s": graph.key_s, "canonical": graph.canonical, "tracked": _state["tracked"],
                        "learned": (graph.positions.detach(), graph.rotations.detach()),
                        "time_range": self.time_range}, out)
        return result

    _trainer.Trainer.set_flow_motion = set_flow_motion
    _trainer.Trainer.train_step = train_step
    _trainer.Trainer.run = run
    return []


def _dump_path() -> Path | None:
    """OUT.nodes.pt beside the bench's ``--json OUT.json``."""
    if "--json" not in sys.argv:
        return None
    return Path(sys.argv[sys.argv.index("--json") + 1]).with_suffix(".nodes.pt")


class _NativeGaussians4D(Gaussians4D):
    """A sample's exact model: the bench's upper bound, which the experiment's motion must not carry."""
    _sliced = _native_sliced


def _keep_exact_models_native() -> None:
    import dataclasses

    import splatreel.samples as samples

    build = samples.build_model

    def build_model(*args, **kwargs):
        model = build(*args, **kwargs)
        if not isinstance(model, Gaussians4D):
            return model
        return _NativeGaussians4D(**{f.name: getattr(model, f.name) for f in dataclasses.fields(model) if f.init})
    samples.build_model = build_model


EXPERIMENTS = {"rigid": use_rigid_oracle, "nodes": use_nodes}


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] not in EXPERIMENTS:
        sys.exit(f"usage: python bench/motion_experiments.py {{{','.join(EXPERIMENTS)}}} [bench/train.py options]")
    extra = EXPERIMENTS[sys.argv[1]]()
    Gaussians4D._sliced = _carried_sliced
    _keep_exact_models_native()
    _split_in_space_only()
    sys.argv = [str(Path(__file__).with_name("train.py"))] + sys.argv[2:] + extra
    runpy.run_path(sys.argv[0], run_name="__main__")


if __name__ == "__main__":
    main()
