"""What the trainer would score with another motion model, measured before it is built: an oracle that patches the
trainer and runs `bench/train.py` with it.

    python bench/motion_experiments.py EXPERIMENT [bench/train.py options: --samples spinner --iters 1400 --json OUT]

EXPERIMENT:
  rigid  (oracle, `spinner` sample only) every Gaussian is carried from its temporal mean to time t by the box's exact
         rigid motion (`splatreel.samples.objects.Spinner`): its mean and its conditional covariance turn and travel
         with the box. The temporal means are frozen (learning rate 0): the carried position depends on them, so one
         drifting under the opacity's gradient would turn its Gaussian off its surface (an earlier implementation that
         let them drift scored 23.9 dB). No velocities from optical flow; splits in space only.

  nodes-exact  (oracle, `spinner` sample only) the trainer's `--motion nodes`, its node tracks replaced by the box's
         exact motion (the same nodes, posed at every key by the box's rotation and travel), then learned as usual:
         what better tracking could buy at most.

  floor-rigid  (oracle, `floor` sample only) every Gaussian near one of the floor scene's three moving objects at
         its temporal mean (the ball, the box, the pendulum: by distance to the part's mesh there) is carried from its
         temporal mean to time t by that object's exact rigid motion; the rest (floor, floaters) stay where they are.
         Temporal means frozen, as for `rigid`: what one rigid motion per object, shared by every Gaussian on it, could
         buy in the one-camera-per-time regime.

  floor-still  (oracle, `floor` sample only) the Gaussians away from the three objects (at their temporal means, as
         for `floor-rigid`) do not move, those near them keep the recipe's own motion: what a still floor alone buys.

  floor-tracks  (a readout, `floor` sample only) the recipe unchanged; its control nodes' poses scored against the
         exact motion of the part each node sits on at the middle frame, as tracked at the flow step (the colour
         tracks included) and as learned at the end of the run: mean position and rotation errors per part, and how
         far each part truly turned by the first frame beside how far its nodes did. Joined to another experiment with '+' it scores that one's nodes:
         `floor-nodes-exact+floor-tracks`.

  floor-nodes-exact  (oracle, `floor` sample only) the trainer's `--motion nodes` on the floor, its nodes' tracks
         (by the model's own motion) replaced by the exact motion of the part each node sits on at the middle frame
         (none within reach: still), then learned as usual: what better tracking could buy at most there.
         `floor-nodes-exact-ball`, `-box`, `-pendulum`, `-box-pendulum`: the nodes on those parts alone, the others
         as tracked; `floor-nodes-exact-pendulum-moving`: the pendulum's nodes that the tracking took for moving
         alone (those it pinned as still stay pinned).

  node-residual  the trainer's control nodes (`--motion nodes`, or motion `auto` where it uses them) carry each
         Gaussian from its native slice's mean at t (its canonical mean moved along its 4D shape's tilt in time)
         instead of from its canonical mean: each Gaussian may learn a linear motion of its own on top of its
         nodes' (none at the switch to nodes, where the tilt is taken out; learned from there), for parts the nodes
         do not follow. Built as a `train` option in commit ace306e and taken out again in 7c22c11.
         `node-residual-still`: only the Gaussians that take at least half their blend from nodes pinned as still
         (with one camera per time, those on what the tracking took for still), where nothing else moves them.

  late-turns  (a search, reads no truth) the recipe unchanged until 60 % of the run (`late-turns-45`: 45 %); then
         each group of at least 16 moving nodes has its turn at every frame searched by render and compare against
         its own sharp middle-frame Gaussians, outwards from the middle frame, and each node key takes the searched
         turn where it draws the frames nearest that key better than the learned poses; the group's Gaussians are
         moved in the canonical frame so that each stays where it was at its own time (`bench/late_turns.py`;
         `late-turns-exact`: by inverting each Gaussian's own blend of its nodes' poses, not the group's rigid fit;
         `late-turns-hold`: inverting it for the nodes and weights the Gaussian had, which it then keeps through
         the trainer's skin updates and densifications, instead of taking the nodes nearest its new canonical mean,
         and the evaluated model carries that skin). In the environment, `LATE_TURNS_POOL=N` scores each candidate
         turn over N frames ahead (default 3), and `LATE_TURNS_SNAPSHOT=FILE` saves the trainer (torch.save) where
         the search would start and exits, for offline probes.

The control-node prototype that was here is now `--motion nodes` (`splatreel.train.nodes`, `splatreel.skinned`);
its last version is in the history (commit e78221a) and its results in docs/benchmarks.md. So is the experiment
`colour-tracks` (commit c8d865f), now the trainer's `--colour-tracks` (`splatreel.train.colour_tracks`), which the
`floor-nodes-exact` oracles turn off.

It replaces the native conditional mean (and its quadratic term) by the carried one; the temporal opacity, the
colour and the conditional covariance's shape stay native. The patches are this script's alone: nothing in the
package imports it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import runpy
import sys
import types
from pathlib import Path

import numpy as np
import torch

from splatreel import covariance as _covariance
from splatreel import quaternion
from splatreel.model import Gaussians4D, take_rows
from splatreel.train import strategy as _strategy

_native_sliced = Gaussians4D._sliced
_state: dict = {"carry": None}  # carry(model, t, rows, means, cov3) -> (means, cov3), once the motion is on


def _carried_sliced(self, t, sh_degree_t, rows, means, cov3, velocity, marginal):
    if _state["carry"] is not None:
        means, cov3 = _state["carry"](self, t, rows, means, cov3)
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

    def carry(model, t, rows, native, cov3):
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


# --- nodes-exact: the trainer's control nodes, tracked without error -------------------------------------------------
def use_exact_nodes() -> list[str]:
    """`--motion nodes` with the tracking replaced by the spinner's exact motion: the same nodes (drawn among the
    middle frame's Gaussians), posed at every key by the box's own rotation and travel, then learned as usual. What
    better tracking could buy at most."""
    import splatreel.train.trainer as trainer
    from splatreel.samples.objects import Spinner
    from splatreel.train.nodes import TrackedNodes

    track = trainer.track_nodes
    box = Spinner()

    def exact(model, ds, background, count, seed=0):
        tracked = track(model, ds, background, count, seed)
        if tracked is None:
            return None
        times = np.asarray(ds.frame_times)
        share = (times - times[0]) / (times[-1] - times[0])
        here = share[tracked.middle]
        canonical = tracked.canonical - torch.from_numpy(box.center(here))
        positions, rotations = [], []
        for s in share:
            rot = torch.from_numpy(box.rotation(s) @ box.rotation(here).T)
            positions.append((rot @ canonical[..., None])[..., 0] + torch.from_numpy(box.center(s)))
            rotations.append(quaternion.from_rotmat(rot.expand(len(canonical), 3, 3).contiguous()))
        return TrackedNodes(torch.stack(positions), torch.stack(rotations), tracked.middle)

    trainer.track_nodes = exact
    return ["--set", "motion=nodes"]


# --- floor-rigid: the floor scene's objects' exact rigid motions ----------------------------------------------------
#: A Gaussian farther than this from every moving part (at its temporal mean) is floor or floater: static.
_PART_REACH = 0.12


class _FloorParts:
    """The floor scene's moving parts (`names`) and their exact rigid motions: at the pose times `grid` ``[G]``
    (shares of the clip), per part the rotations ``[G, 3, 3]`` and translations ``[G, 3]`` of the pose
    ``x(s) = R(s) x_ref + T(s)`` (x_ref: the part at s = 0) and a k-d tree of x_ref's vertices."""

    def __init__(self) -> None:
        from scipy.spatial import cKDTree

        from splatreel.pointsets import rigid_fit
        from splatreel.samples.floor import FloorScene

        scene = FloorScene()
        self.names = ("ball", "box", "pendulum")
        self.grid = np.linspace(0.0, 1.0, 1001)
        verts = {n: np.stack([scene.parts(float(s))[n].vertices for s in self.grid]) for n in self.names}
        self.rot, self.trans, self.trees = {}, {}, {}
        for n in self.names:
            ref = verts[n][0]
            r, c0, c1, _ = rigid_fit(np.broadcast_to(ref, verts[n].shape), verts[n])
            err = np.abs(np.einsum("gij,vj->gvi", r, ref - c0[0]) + c1[:, None] - verts[n]).max()
            assert err < 1e-6, (n, err)  # each part is rigid
            self.rot[n] = torch.from_numpy(r)
            self.trans[n] = torch.from_numpy(c1 - np.einsum("gij,j->gi", r, c0[0]))
            self.trees[n] = cKDTree(ref)
        self._key: tuple | None = None  # what `_parts` was found for: the means' storage, version and count
        self._parts = torch.empty(0, dtype=torch.long)

    def index(self, s: torch.Tensor) -> torch.Tensor:
        """The pose index nearest each share `s` of the clip (clamped to it)."""
        return (s.clamp(0, 1) * (len(self.grid) - 1)).round().long()

    def part(self, x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        """``[N]`` the part (index into `names`) nearest each point ``x [N, 3]`` at pose index ``g [N]``, -1 (static)
        when none is within `_PART_REACH`."""
        best = torch.full((len(x),), _PART_REACH, dtype=torch.float64)
        part = torch.full((len(x),), -1, dtype=torch.long)
        for p, n in enumerate(self.names):
            local = (self.rot[n][g].transpose(1, 2) @ (x - self.trans[n][g])[..., None])[..., 0]
            d = torch.from_numpy(self.trees[n].query(local.numpy())[0])
            nearer = d < best
            best[nearer], part[nearer] = d[nearer], p
        return part

    def node_motion(self, times, canonical: torch.Tensor, middle: int
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Nodes at `canonical` ``[M, 3]`` (their places at frame `middle` of the frames at `times`) carried by the
        exact motion of the part each sits on there: the part of each ``[M]`` (-1: none, the node stays), positions
        ``[F, M, 3]`` and turns since the middle frame ``[F, M, 3, 3]`` (float64)."""
        times = torch.as_tensor(times, dtype=torch.float64)
        g = self.index((times - times[0]) / (times[-1] - times[0]))
        mid = int(g[middle])
        x = canonical.double()
        part = self.part(x, torch.full((len(x),), mid))
        positions = x.expand(len(times), -1, -1).clone()
        turns = torch.eye(3, dtype=torch.float64).repeat(len(times), len(x), 1, 1)
        for p, n in enumerate(self.names):
            m = part == p
            r = self.rot[n][g] @ self.rot[n][mid].T  # [F, 3, 3] the part's turn since the middle frame
            positions[:, m] = (r[:, None] @ (x[m] - self.trans[n][mid])[None, :, :, None])[..., 0] \
                + self.trans[n][g][:, None]
            turns[:, m] = r[:, None]
        return part, positions, turns

    def parts_of(self, model, rows=None) -> torch.Tensor:
        """The part of each of `model`'s Gaussians (of `rows`) at its temporal mean, -1 static; recomputed when the
        means change."""
        key = (model.means.data_ptr(), model.means._version, len(model))
        if self._key != key:
            g = self.index(_normalised_times(model, None))
            self._key, self._parts = key, self.part(model.means.detach().double(), g)
        return self._parts if rows is None else take_rows(self._parts, rows)


def use_floor_rigid_oracle() -> list[str]:
    parts = _FloorParts()
    rot, trans = parts.rot, parts.trans

    def carry(model, t, rows, native, cov3):
        part = parts.parts_of(model, rows)
        t0, t1 = model.time_range
        g_i, g = parts.index(_normalised_times(model, rows)), int(parts.index(torch.tensor((t - t0) / (t1 - t0))))
        mu = model.means if rows is None else take_rows(model.means, rows)
        r_rel = torch.eye(3, dtype=torch.float64).repeat(len(part), 1, 1)
        shift = torch.zeros(len(part), 3, dtype=torch.float64)
        origin = torch.zeros(len(part), 3, dtype=torch.float64)
        for p, n in enumerate(parts.names):
            m = part == p
            r_rel[m] = rot[n][g] @ rot[n][g_i[m]].transpose(1, 2)
            origin[m], shift[m] = trans[n][g_i[m]], trans[n][g].expand(int(m.sum()), 3)
        r_rel = r_rel.to(mu.dtype)
        means = (r_rel @ (mu - origin.to(mu.dtype))[..., None])[..., 0] + shift.to(mu.dtype)
        return means, r_rel @ cov3 @ r_rel.transpose(1, 2)

    _state["carry"] = carry
    return ["--set", "lr_t_means=0"]


def use_floor_still_oracle() -> list[str]:
    """`floor-still`: the Gaussians away from the floor scene's moving objects (at their temporal means) do not move;
    those near them keep the recipe's own (quadratic) motion."""
    parts = _FloorParts()

    def carry(model, t, rows, native, cov3):
        still = parts.parts_of(model, rows) < 0
        mu = model.means if rows is None else take_rows(model.means, rows)
        return torch.where(still[:, None], mu, native), cov3

    _state["carry"] = carry
    return []


def use_floor_exact_nodes(only: tuple[str, ...] | None = None, moving_only: bool = False) -> list[str]:
    """`--motion nodes` on the floor, its node tracks (by the model's own motion) replaced by the scene's exact
    motion: the same nodes, each posed at every frame by the rigid motion of the part it sits on at the middle frame
    (none within reach: still, and pinned), then learned as usual. What better tracking could buy at most in this
    regime. `only`: the nodes on those parts alone, the others as tracked; `moving_only`: of those, the ones the
    tracking took for moving (the others stay pinned)."""
    import splatreel.train.flow_step as flow_step
    from splatreel.train.nodes import TrackedNodes

    parts = _FloorParts()
    track = flow_step.track_nodes_by_motion

    def exact(model, times, count, seed=0):
        tracked = track(model, times, count, seed)
        if tracked is None:
            return None
        part, positions, turns = parts.node_motion(times, tracked.canonical, tracked.middle)
        print(f"floor-nodes-exact: {[int((part == p).sum()) for p in range(len(parts.names))]} of {len(part)} nodes "
              f"on {', '.join(parts.names)}{'' if only is None else ', exact on ' + ' and '.join(only) + ' only'}",
              file=sys.stderr)
        rotations = quaternion.from_rotmat(turns.reshape(-1, 3, 3)).reshape(len(times), -1, 4)
        if only is None:
            return TrackedNodes(positions, rotations, tracked.middle, part < 0)
        mine = torch.isin(part, torch.tensor([parts.names.index(n) for n in only]))
        if moving_only and tracked.still is not None:
            mine &= ~tracked.still
        still = tracked.still.clone() if tracked.still is not None else torch.zeros(len(part), dtype=torch.bool)
        still[mine] = False
        return TrackedNodes(torch.where(mine[:, None], positions, tracked.positions),
                            torch.where(mine[:, None], rotations.to(tracked.rotations), tracked.rotations),
                            tracked.middle, still)

    flow_step.track_nodes_by_motion = exact
    return ["--set", "motion=nodes", "--set", "flow_motion_at=0.3", "--set", "node_template=off",
            "--set", "colour_tracks=False"]


def _angle(rot: torch.Tensor) -> torch.Tensor:
    """The angle in degrees of rotation matrices ``[..., 3, 3]``."""
    return torch.rad2deg(torch.arccos(((rot.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)))


def _score_poses(parts: _FloorParts, times, canonical: torch.Tensor, positions: torch.Tensor,
                 turned: torch.Tensor, middle: int) -> str:
    """How far node poses at every frame (positions ``[F, M, 3]``, rotation matrices ``[F, M, 3, 3]``; canonical
    ``[M, 3]`` at frame `middle`) are from the exact motion of the part each node sits on at the middle frame: per
    part, the mean position error (scene units) and rotation error (degrees) over the frames, and at the first frame
    the angle the part truly turned since the middle frame beside the angle the nodes turned."""
    part, exact, turns = parts.node_motion(times, canonical, middle)
    turned = turned.double()
    out = []
    for p, n in enumerate(parts.names):
        m = part == p
        if not m.any():
            continue
        err = (positions[:, m].double() - exact[:, m]).norm(dim=-1).mean()
        rel = turns[:, m].transpose(-1, -2) @ turned[:, m]
        out.append(f"{n} ({int(m.sum())} nodes): position {err:.3f}, rotation {_angle(rel).mean():.0f} deg, "
                   f"turned by frame 0 {_angle(turns[0, m][0]):.0f} deg (nodes {_angle(turned[0, m]).mean():.0f})")
    return "; ".join(out)


def use_floor_track_scores() -> list[str]:
    """`floor-tracks`: the recipe as it is, its node poses scored against the floor scene's exact motion when tracked
    (at the flow step) and when learned (at the end of the run); printed to stderr."""
    import atexit

    import splatreel.train.flow_step as flow_step
    import splatreel.train.trainer as trainer
    from splatreel.skinned import node_poses

    parts = _FloorParts()
    canonical = flow_step.to_canonical
    last: dict = {}

    def scored(model, key_times, tracked, sigma):
        turned = quaternion.to_rotmat(quaternion.normalize(tracked.rotations))
        print("floor-tracks, tracked: " + _score_poses(parts, key_times.tolist(), tracked.canonical,
                                                       tracked.positions, turned, tracked.middle), file=sys.stderr)
        return canonical(model, key_times, tracked, sigma)

    dataset_model = trainer.Trainer.dataset_model

    def keep_last(self, trained=None):
        if self.nodes is not None:  # the learned poses on the spline at every frame
            n = self.nodes
            poses = [node_poses(n.key_times.cpu(), n.positions.detach().cpu(), n.rotations.detach().cpu(), t)
                     for t in self.ds.frame_times]
            last.update(times=self.ds.frame_times, canonical=n.canonical.cpu(), middle=len(poses) // 2,
                        positions=torch.stack([p for p, _ in poses]), turned=torch.stack([r for _, r in poses]))
        return dataset_model(self, trained)

    def report() -> None:
        if last:
            print("floor-tracks, learned: " + _score_poses(parts, last["times"], last["canonical"],
                                                           last["positions"], last["turned"], last["middle"]),
                  file=sys.stderr)

    flow_step.to_canonical = scored
    trainer.Trainer.dataset_model = keep_last
    atexit.register(report)
    return []


def use_node_residual_motion(where: str = "all") -> list[str]:
    """`node-residual`: skinned Gaussians carried by their nodes from their native slice's mean at t (their canonical
    mean moved along their 4D shape's tilt in time) instead of from their canonical mean, so each may learn a linear
    motion of its own on top of its nodes' (the tilt is zero at the switch to nodes and learned from there).
    `node-residual-still` (`where` 'still'): only the Gaussians that take at least half their blend from nodes pinned
    as still, where nothing else would move them."""
    import splatreel.train.nodes as nodes_module
    from splatreel import skinned
    from splatreel.model import take_rows
    import splatreel.train.trainer as trainer_module

    def on_still(model, still) -> torch.Tensor | None:
        if still is None:
            return None
        nodes, weights = model.skin
        return (weights * still.to(weights.device)[nodes].to(weights)).sum(1) >= 0.5

    if where == "still":
        skinned_by = nodes_module.Nodes.skinned
        dataset_model = trainer_module.Trainer.dataset_model

        def skinned_with_mask(self, gaussians, step):
            model = skinned_by(self, gaussians, step)
            model.residual_rows = on_still(model, self.still)
            return model

        def dataset_model_with_mask(self, trained=None):
            model = dataset_model(self, trained)
            if self.nodes is not None:
                model.residual_rows = on_still(model, self.nodes.still)
                if model.residual_rows is not None:
                    print(f"node-residual-still: {int(model.residual_rows.sum()):,} of {len(model):,} Gaussians "
                          "move on their own", file=sys.stderr)
            return model
        nodes_module.Nodes.skinned = skinned_with_mask
        trainer_module.Trainer.dataset_model = dataset_model_with_mask

    def slice_with_residual(self, t, sh_degree_t=None, rows=None):
        native = self.gaussians.slice(t, sh_degree_t, rows)
        if rows is not None and rows.dtype == torch.bool:
            rows = rows.nonzero()[:, 0]
        own = native.means  # the rows' native means at t
        if where == "still":  # the others from their canonical means, as without residual motion
            mask = getattr(self, "residual_rows", None)
            mask = torch.zeros(len(own), dtype=torch.bool) if mask is None else (
                mask if rows is None else take_rows(mask, rows))
            canonical = self.gaussians.means if rows is None else take_rows(self.gaussians.means, rows)
            own = torch.where(mask.to(own.device)[:, None], own, canonical)
        means = own if rows is None else self.gaussians.means.index_put((rows,), own)
        # the model's own carry (fused kernel or torch) of these means in place of the canonical ones
        moving = dataclasses.replace(self, gaussians=dataclasses.replace(self.gaussians, means=means))
        moved, cov = moving._carrier(rows)(native.covariances, self.poses(t))
        return dataclasses.replace(native, means=moved, covariances=cov, velocities=None)

    skinned.SkinnedGaussians.slice = slice_with_residual
    return []


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


def use_late_turns(at: float = 0.6, exact: bool = False, hold: bool = False) -> list[str]:
    """`late-turns`: at share `at` of the run, each rigid group of moving nodes has its turns searched by render and
    compare against its sharp middle-frame Gaussians, and takes them where they draw better (`bench/late_turns.py`)."""
    import splatreel.train.trainer as trainer
    import late_turns
    from late_turns import refit_turns

    late_turns.EXACT_RESEAT = exact
    late_turns.HOLD_SKIN = hold
    if hold:
        late_turns.hold_skins()
    step = trainer.Trainer.train_step
    done: set[int] = set()

    def train_step(self):
        out = step(self)
        # once, at the schedule's position (a budgeted run's steps follow the clock), as the flow step is due
        if self.nodes is not None and id(self) not in done and self.vstep() >= at * self.cfg.iters:
            done.add(id(self))
            if os.environ.get("LATE_TURNS_SNAPSHOT"):  # the trainer as the search finds it, for offline probes
                torch.save(self, os.environ["LATE_TURNS_SNAPSHOT"], pickle_protocol=4)
                sys.exit(0)
            refit_turns(self, self.cfg.seed)
        return out

    trainer.Trainer.train_step = train_step
    return []


EXPERIMENTS = {"rigid": use_rigid_oracle, "nodes-exact": use_exact_nodes, "floor-rigid": use_floor_rigid_oracle,
               "floor-nodes-exact": use_floor_exact_nodes, "floor-still": use_floor_still_oracle,
               "floor-tracks": use_floor_track_scores,
               "node-residual": use_node_residual_motion,
               "node-residual-still": functools.partial(use_node_residual_motion, "still"),
               **{f"floor-nodes-exact-{'-'.join(n)}": functools.partial(use_floor_exact_nodes, n)
                  for n in (("ball",), ("box",), ("pendulum",), ("box", "pendulum"))},
               "floor-nodes-exact-pendulum-moving": functools.partial(use_floor_exact_nodes, ("pendulum",), True),
               "late-turns": use_late_turns, "late-turns-45": functools.partial(use_late_turns, 0.45),
               "late-turns-exact": functools.partial(use_late_turns, exact=True),
               "late-turns-hold": functools.partial(use_late_turns, hold=True)}


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        return
    names = sys.argv[1].split("+") if len(sys.argv) > 1 else []
    if not names or any(n not in EXPERIMENTS for n in names):
        sys.exit(f"usage: python bench/motion_experiments.py {{{','.join(EXPERIMENTS)}}}[+floor-tracks] "
                 "[bench/train.py options]")
    extra = [arg for n in names for arg in EXPERIMENTS[n]()]  # in order: floor-tracks last scores what came before
    Gaussians4D._sliced = _carried_sliced
    _keep_exact_models_native()
    _split_in_space_only()
    sys.argv = [str(Path(__file__).with_name("train.py"))] + sys.argv[2:] + extra
    runpy.run_path(sys.argv[0], run_name="__main__")


if __name__ == "__main__":
    main()
