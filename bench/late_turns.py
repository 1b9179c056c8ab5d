"""Each rigid group's turn searched by render and compare late in a run, once its Gaussians are sharp (the bench
experiment `late-turns` of `bench/motion_experiments.py`; not in the trainer).

Why: with one camera per time the control nodes are tracked by the model's own motion at the flow step, and that
motion misses turns: on the floor sample the box's nodes end about 100 degrees off its true turn, and learning the
key poses does not bring them back (the per-frame Gaussians absorb the error). An earlier fit of each part's turn
at the flow step (commit f34d185) came to 22 degrees: the template, the model's middle frame then, was too blurred.
Later in the run the middle frame's Gaussians of the box are sharp: on the floor's step-480 model (of 800) its exact
turn draws every frame better than the learned one, and a search outwards from the middle frame, frame by frame,
follows it to 12 degrees (median) where the learned nodes are 100 off.

So at a share of the run, per group of moving nodes (connected within two node spacings at the canonical frame,
`train.colour_tracks.node_groups`) of at least `MIN_NODES`:

* its template is the Gaussians nearest its nodes, sliced at the middle frame; the rest of each frame's slice is
  rendered once as the backdrop;
* outwards from the middle frame, each frame's turn is the previous frame's composed with a constant per-frame
  increment, chosen among the previous increment, none and the learned poses' own, then refined by random search
  in three shrinking rounds, each candidate scored over the next `POOL` frames (one camera each) at `FIT_SIZE` px;
  the group's centre at each frame stays the learned poses' (rigidly fitted);
* the group takes the searched turns if its template draws the clip's frames better with them than with the
  learned poses' rigid fit, key by key (`PER_KEY`: over the frames nearest each key); then its nodes' key poses
  turn rigidly about its centre, and every Gaussian nearest its nodes is moved in the canonical frame so that it
  stays about where the old poses drew it at its own time (its mean carried back by the new poses' rigid fit, its 4D
  covariance turned by the change of the fitted rotations).

Measured on the floor (seed 0, 800 steps, docs/benchmarks.md): the box's learned nodes end 24 degrees off (101 by
default), but held out 25.27 dB against 25.52: the views near the middle frame gain up to 3.9 dB, those far from it
lose up to 2.8. The re-seated Gaussians land 0.04 units from where they were at the median, 0.15 at the 95th
percentile (`moved_median`, `moved_p95` in the printed report, now taken with the skin derived from the new means,
as the trainer derives it after: 1.3-2.6 units at the 95th percentile of the box's, whose Gaussians take other
nodes). Re-seated by their own blend inverted (`EXACT_RESEAT`): 25.13; the search at 45 % of the run: 24.20.
Each re-seated Gaussian keeping its nodes and weights (`HOLD_SKIN`, `late-turns-hold`): 25.69, and with candidates
scored over 6 frames ahead (`LATE_TURNS_POOL=6` in the environment; over 3 the box is lost at frames 68-73): 26.14.
With the trainer's far clip, hold and 6 frames: 27.53 against 26.74 (search 277 s); stepping 3 frames at a time
(`LATE_TURNS_STRIDE=3`, search 54 s): 26.12.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import replace

import numpy as np
import torch

from splatreel import quaternion
from splatreel.covariance import decompose_covariance_4d
from splatreel.pointsets import rigid_fit
from splatreel.rasterize import rasterize
from splatreel.skinned import carry, nearest_nodes, node_poses, skin_weights
from splatreel.train import strategy
from splatreel.train.colour_tracks import node_groups
from splatreel.train.data import downscale_view
from splatreel.train.evaluate import view_target
from splatreel.train.motion import nearest_key
from splatreel.train.nodes import TrackedNodes

#: Fewest nodes a group needs for a search.
MIN_NODES = 16
#: The search renders at about this many pixels across, and scores a candidate over this many frames ahead (one
#: camera each: over 3, the floor's box is lost for 6 frames where one camera's view prefers a wrong turn).
FIT_SIZE = 100
POOL = int(os.environ.get("LATE_TURNS_POOL", 3))
#: The search steps this many frames at a time (the turn between constant per frame), scoring a candidate at every
#: STRIDE-th frame of its POOL ahead (at least one): 1 searches and scores every frame.
STRIDE = int(os.environ.get("LATE_TURNS_STRIDE", 1))
#: Random search rounds: (spread in degrees of the per-frame increment, candidates); `LATE_TURNS_CANDIDATES` in the
#: environment scales the candidates of every round (0.5: half).
ROUNDS = tuple((spread, max(1, round(count * float(os.environ.get("LATE_TURNS_CANDIDATES", 1)))))
               for spread, count in ((8.0, 24), (3.0, 16), (1.0, 8)))
#: A candidate is scored at every SCORE_EVERY-th frame of its POOL ahead (`LATE_TURNS_SCORE_EVERY`; the search still
#: steps STRIDE frames): 2 scores frames 2, 4, 6 of 6 ahead, half the renders.
SCORE_EVERY = int(os.environ.get("LATE_TURNS_SCORE_EVERY", 1))
#: A key takes the searched turns only where they draw its frames at most this share of the learned poses' error
#: (`LATE_TURNS_MARGIN`; 1: any gain).
MARGIN = float(os.environ.get("LATE_TURNS_MARGIN", 1))
#: Whether each key takes the searched turn on its own (True), or the group all of them or none.
PER_KEY = True
#: Whether the re-seating inverts each Gaussian's own blend of its nodes' poses (`late-turns-exact`: the linear
#: blend is affine in the canonical mean, so it inverts exactly for given weights, iterated with the weights) rather
#: than the group's rigid fit.
EXACT_RESEAT = False
#: The exact inverse is taken where both blends' smallest singular value is above this (a blend of agreeing turns: 1).
FIRM_BLEND = 0.8
#: Whether each re-seated Gaussian keeps the nodes and weights it had (`late-turns-hold`): inverted exactly for them,
#: and held through the trainer's later skin updates and densifications, instead of taking the nodes nearest its
#: new canonical mean.
HOLD_SKIN = False


def _rotvec(r: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(r).as_rotvec()


def _matrix(v: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(v).as_matrix()


def _rigid(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r, c0, c1, _ = rigid_fit(a[None], b[None])
    return r[0], c0[0], c1[0]


def _search(error, learned: dict, frames: int, mid: int, rng: np.random.Generator) -> dict:
    """Each frame's turn since the middle frame ``{k: [3, 3]}``, searched outwards from it (module doc): `error(turn,
    k)` scores a turn at frame k, `learned` holds the learned poses' rigid turns (a candidate increment)."""
    turns = {mid: np.eye(3)}
    for d in (1, -1):
        k, rate = mid, np.zeros(3)
        while 0 <= k + d < frames:
            base = turns[k]
            step = min(STRIDE, frames - 1 - k if d > 0 else k)
            ahead = [x for x in range(k + d * step, k + d * (max(POOL, step) + 1), d * step) if 0 <= x < frames]
            if step == 1:  # every SCORE_EVERY-th frame ahead, counted back from the farthest
                ahead = [x for x in ahead if (abs(ahead[-1] - k) - abs(x - k)) % SCORE_EVERY == 0]

            def score(inc: np.ndarray) -> float:
                return float(np.mean([error(_matrix(inc * abs(x - k)) @ base, x) for x in ahead]))
            best = min(((score(c), c) for c in (rate, np.zeros(3), _rotvec(learned[k + d * step] @ base.T) / step)),
                       key=lambda sc: sc[0])
            for spread, count in ROUNDS:
                around = best[1]
                for _ in range(count):
                    c = around + rng.normal(size=3) * np.radians(spread)
                    s = score(c)
                    if s < best[0]:
                        best = (s, c)
            rate = best[1]
            for j in range(1, step + 1):
                turns[k + d * j] = _matrix(rate * j) @ base
            k += d * step
    return turns


def _keys_taken(searched: list[float], kept: list[float]) -> list[bool]:
    """Per key, whether it takes the searched turns, from the per-key errors (`_key_errors`): they draw the frames
    nearest it better by `MARGIN` (`PER_KEY`), or all frames of the clip."""
    if not PER_KEY:
        return [bool(sum(searched) < MARGIN * sum(kept))] * len(kept)
    return [bool(s < MARGIN * k) for s, k in zip(searched, kept)]


def _key_errors(searched: np.ndarray, kept: np.ndarray, keys: list[int]) -> tuple[list[float], list[float]]:
    """Per key, the summed error of the frames nearest it with the searched turns and with the learned poses."""
    near = nearest_key(torch.arange(len(searched), dtype=torch.float64), torch.tensor(keys, dtype=torch.float64))
    return ([float(searched[near == ki].sum()) for ki in range(len(keys))],
            [float(kept[near == ki].sum()) for ki in range(len(keys))])


def _affine(idx: torch.Tensor, w: torch.Tensor, canonical: torch.Tensor, poses) -> tuple[torch.Tensor, torch.Tensor]:
    """The carry (`splatreel.skinned.carry`) of Gaussians with nodes `idx` and weights `w` ``[N, K]`` at node poses
    `poses` as x -> A x + b: ``A [N, 3, 3]``, ``b [N, 3]``, read off it (it is affine in the canonical mean)."""
    at = lambda p: carry(p, None, idx, w, canonical, *poses)[0]  # noqa: E731
    zero = torch.zeros(len(idx), 3, dtype=canonical.dtype)
    b = at(zero)
    return torch.stack([at(e.expand_as(zero)) - b for e in torch.eye(3, dtype=zero.dtype)], -1), b


def _firm(*blends: torch.Tensor) -> torch.Tensor:
    """``[N]``: where every blend's smallest singular value is above `FIRM_BLEND` (a blend of agreeing turns: 1);
    where nodes that turn apart share a Gaussian the blend is near singular and its inverse throws it far."""
    return torch.stack([torch.linalg.svdvals(a)[:, -1] > FIRM_BLEND for a in blends]).all(0)


def _inverse_blend(world: torch.Tensor, means: torch.Tensor, canonical: torch.Tensor, sigma: float, old, new,
                   rounds: int = 3) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Canonical means ``[N, 3]`` that the `new` node poses (positions, rotation matrices at one time) carry to
    `world`; per Gaussian the ``[N, 3, 3]`` map of its covariance from the old canonical frame to the new (the new
    blend's inverse after the old blend); and ``[N]`` where both blends are firm (`_firm`; elsewhere the caller
    keeps the rigid fit's). The carry is inverted for the weights of each estimate, `rounds` times."""
    a_old, _ = _affine(*skin_weights(means, canonical, sigma), canonical, old)
    x = means
    for _ in range(rounds):
        a_new, b_new = _affine(*skin_weights(x, canonical, sigma), canonical, new)
        x = torch.linalg.solve(a_new, (world - b_new)[..., None])[..., 0]
    return x, torch.linalg.solve(a_new, a_old), _firm(a_new, a_old)


def _held_inverse(world: torch.Tensor, skin: tuple[torch.Tensor, torch.Tensor], canonical: torch.Tensor, old, new
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """As `_inverse_blend`, for Gaussians that keep their `skin` (nodes, weights ``[N, K]``): one exact solve."""
    a_old, _ = _affine(*skin, canonical, old)
    a_new, b_new = _affine(*skin, canonical, new)
    return (torch.linalg.solve(a_new, (world - b_new)[..., None])[..., 0], torch.linalg.solve(a_new, a_old),
            _firm(a_new, a_old))


def _reseat(skinned, positions: torch.Tensor, rotations: torch.Tensor, key_times: torch.Tensor, times: list[float],
            canonical: torch.Tensor, group: np.ndarray, own: torch.Tensor) -> tuple[dict, torch.Tensor]:
    """The canonical-frame values (means and the 4D shape's tensors, for every Gaussian) that keep each Gaussian of
    `own` about where `skinned` (the old poses) drew it at its own frame once the nodes have the new key poses
    `positions`, `rotations`; and how far each of `own` then lands from there."""
    g4 = skinned.gaussians
    frame = nearest_key(g4.t_means, torch.tensor(times))
    changed = torch.nonzero(own)[:, 0]
    means = g4.means.detach().clone().double()
    cov4 = g4.covariance_4d().double()
    held = torch.zeros(len(g4), dtype=torch.bool)
    here = canonical[group].double().numpy()
    worlds = {}
    for k in frame[changed].unique().tolist():
        rows = changed[frame[changed] == k]
        p_old, _ = node_poses(key_times, skinned.node_positions, skinned.node_rotations, times[k])
        p_new, _ = node_poses(key_times, positions.float(), rotations.float(), times[k])
        # where the old poses carried them (the learned poses are no rigid motion, so not by the fit)
        (world, _), = skinned.centres([times[k]])
        worlds[k] = world[rows].double()
        # the carry maps the canonical frame to frame k: its rigid fit over the group's nodes, before and after
        r_old, _, _ = _rigid(here, p_old[group].double().numpy())
        r_new, a_new, b_new = _rigid(here, p_new[group].double().numpy())
        fitted = (worlds[k] - torch.from_numpy(b_new)) @ torch.from_numpy(r_new) + torch.from_numpy(a_new)
        q = torch.eye(4, dtype=torch.float64).repeat(len(rows), 1, 1)
        q[:, :3, :3] = torch.from_numpy(r_new.T @ r_old)
        if HOLD_SKIN or EXACT_RESEAT:
            poses = (node_poses(key_times, skinned.node_positions.double(), skinned.node_rotations.double(), times[k]),
                     node_poses(key_times, positions, rotations, times[k]))
            if HOLD_SKIN:
                exact, turn, firm = _held_inverse(worlds[k], tuple(x[rows].cpu() for x in skinned.skin),
                                                  canonical.double(), *poses)
                held[rows] = firm
            else:
                exact, turn, firm = _inverse_blend(worlds[k], means[rows], canonical.double(), skinned.node_sigma,
                                                   *poses)
            fitted[firm] = exact[firm]
            q[firm, :3, :3] = turn[firm]
        means[rows] = fitted
        cov4[rows] = q @ cov4[rows] @ q.transpose(-1, -2)
    scales, t_scales, q_l, q_r = decompose_covariance_4d(cov4[changed], g4.rotation_convention)
    values = {"means": means.float(), "log_scales": g4.log_scales.clone(), "log_t_scales": g4.log_t_scales.clone(),
              "quats_l": g4.quats_l.clone(), "quats_r": g4.quats_r.clone()}
    values["log_scales"][changed] = scales.clamp_min(1e-12).log().float()
    values["log_t_scales"][changed] = t_scales.clamp_min(1e-12).log().float()
    values["quats_l"][changed] = q_l.float()
    values["quats_r"][changed] = q_r.float()
    # the skin derived from the new means, as the trainer derives it once the poses change (`refit_turns`), save
    # where it is held
    skin = skin_weights(values["means"], canonical, skinned.node_sigma)
    skin = tuple(torch.where(held[:, None], old, new) for old, new in zip(skinned.skin, skin))
    after = replace(skinned, gaussians=replace(g4, **{k: v.to(g4.means) for k, v in values.items()}),
                    node_positions=positions.float(), node_rotations=rotations.float(), skin=skin)
    moved = torch.zeros(len(changed), dtype=torch.float64)
    for k, world in worlds.items():
        sel = frame[changed] == k
        (b, _), = after.centres([times[k]])
        moved[sel] = (world - b[changed[sel]].double()).norm(dim=1)
    return values, moved, held


def group_scorer(skinned, group: np.ndarray, own: torch.Tensor, views: dict, bg: torch.Tensor,
                 key_times: torch.Tensor, times: list[float]):
    """For one group of nodes (`group`) and the Gaussians nearest them (`own` ``[N]``): `error(turn, k)`, the mean
    L1 of frame k's training view (`views[k]`: camera and target) drawn with the group's middle-frame Gaussians
    turned by `turn` ``[3, 3]`` about the group's centre (carried where the learned poses carry it) over the rest of
    the frame's slice; the learned poses' rigid turns since the middle frame ``{k: [3, 3]}``; the group's nodes'
    middle-frame positions, rotations and centre; and the centre's place at every frame ``{k: [3]}``."""
    mid = len(times) // 2
    with torch.no_grad():
        p_mid, r_mid = node_poses(key_times, skinned.node_positions, skinned.node_rotations, times[mid])
        c_mid = p_mid[group].double().mean(0).numpy()
        s_mid = skinned.slice(times[mid])
        tpl = s_mid.select(own & s_mid.visible)
        backdrop, learned, centre = {}, {}, {}
        for k in range(len(times)):
            backdrop[k] = rasterize(skinned.slice(times[k]).select(~own), views[k][0], bg).rgb
            p_k, _ = node_poses(key_times, skinned.node_positions, skinned.node_rotations, times[k])
            r, a, b = _rigid(p_mid[group].double().numpy(), p_k[group].double().numpy())
            learned[k], centre[k] = r, b + r @ (c_mid - a)  # where the group's middle centre goes

    def error(turn: np.ndarray, k: int) -> float:
        cam, target = views[k]
        r = torch.from_numpy(turn).float()
        g = replace(tpl, means=(tpl.means - torch.from_numpy(c_mid).float()) @ r.T
                    + torch.from_numpy(centre[k]).float(), covariances=r @ tpl.covariances @ r.T, velocities=None)
        out = rasterize(g, cam, (0.0, 0.0, 0.0))
        return float(((out.rgb + (1 - out.alpha[..., None]) * backdrop[k]) - target).abs().mean())

    return error, learned, (p_mid, r_mid, c_mid), centre


def training_views(ds, bg: torch.Tensor) -> dict:
    """Each frame's training view at about `FIT_SIZE` px: ``{k: (camera, target)}`` (one camera per time)."""
    times = list(ds.frame_times)
    frame_of = nearest_key(torch.tensor([v.time for v in ds.train]), torch.tensor(times)).tolist()
    views = {}
    for v, k in zip(ds.train, frame_of):
        small = downscale_view(v, max(1, round(min(v.size) / FIT_SIZE)))
        views[k] = (small.camera, view_target(small, bg)[0])
    return views


def hold_skins() -> None:
    """Patch the trainer (`HOLD_SKIN`): the skin of the Gaussians `refit_turns` re-seats (`Nodes._held`: mask, nodes,
    weights per Gaussian) kept through its skin updates, following their rows through densification (a child takes
    its parent's), and written into the model it scores and saves."""
    import splatreel.train.trainer as trainer
    from splatreel.train import nodes as train_nodes

    skinned = train_nodes.Nodes.skinned

    def held_skinned(self, gaussians, step):
        before = self._skin
        out = skinned(self, gaussians, step)
        held = getattr(self, "_held", None)
        if held is not None and self._skin is not before:
            mask, idx, w = held
            count, at, (i, v) = self._skin
            self._skin = (count, at, (torch.where(mask[:, None], idx, i), torch.where(mask[:, None], w, v)))
            out = replace(out, skin=self._skin[2])
        return out

    densify = trainer.Trainer._maybe_densify

    def follow_rows(self):
        rows = {}
        inner = strategy.densify_and_prune

        def recorded(*args, **kwargs):
            out = inner(*args, **kwargs)
            rows["source"] = out["source"]
            return out
        strategy.densify_and_prune = recorded
        try:
            densify(self)
        finally:
            strategy.densify_and_prune = inner
        held = getattr(self.nodes, "_held", None) if self.nodes is not None else None
        if held is not None and "source" in rows:
            self.nodes._held = tuple(x[rows["source"]] for x in held)

    dataset_model = trainer.Trainer.dataset_model

    def held_dataset_model(self, trained=None):
        """The checkpoint's model with the trainer's skin (the held rows'), not the one its canonical means give."""
        out = dataset_model(self, trained)
        if trained is not None or getattr(self.nodes, "_held", None) is None:
            return out
        with torch.no_grad():  # the rows `dataset_model` keeps
            rows = trainer.model_on_dataset_time(self.native_model(), self.axis).drawn_in_clip()
        return replace(out, skin=tuple(x.detach()[rows].cpu() for x in self.model().skin))

    train_nodes.Nodes.skinned = held_skinned
    trainer.Trainer._maybe_densify = follow_rows
    trainer.Trainer.dataset_model = held_dataset_model


def refit_turns(trainer, seed: int = 0) -> list[dict]:
    """Search each rigid group's turns on `trainer`'s current model and apply those that draw better (module doc).
    Returns what happened per group searched."""
    nodes = trainer.nodes
    if nodes is None:
        return []
    t0 = time.perf_counter()
    ds, bg = trainer.ds, trainer.bg.detach().cpu()
    times = list(ds.frame_times)
    frames, mid = len(times), len(times) // 2
    keys = trainer._node_keys()
    key_times = nodes.key_times.cpu()
    model = trainer.model()
    canonical = nodes.canonical.cpu()
    still = None if nodes.still is None else nodes.still.cpu()
    # node_groups reads only the canonical positions and the still flags of the nodes it is given
    groups = node_groups(TrackedNodes(canonical[None].double(), torch.zeros(1, len(canonical), 4), 0, still),
                         nodes.sigma)
    positions = nodes.positions.detach().cpu().double()
    rotations = nodes.rotations.detach().cpu().double()
    views = training_views(ds, bg)
    skinned = replace(model, gaussians=model.gaussians.detach().to("cpu"), node_positions=positions.float(),
                      node_rotations=rotations.float())
    _, nearest = nearest_nodes(canonical, skinned.gaussians.means, 1)
    rng = np.random.default_rng(seed)
    report = []
    hold = torch.zeros(len(skinned.gaussians), dtype=torch.bool)
    old_skin = tuple(x.cpu() for x in skinned.skin)
    for group in groups:
        if len(group) < MIN_NODES:
            continue
        own = torch.isin(nearest[:, 0], torch.from_numpy(group))
        error, learned, (p_mid, r_mid, c_mid), centre = group_scorer(skinned, group, own, views, bg, key_times,
                                                                       times)

        with torch.no_grad():
            turns = _search(error, learned, frames, mid, rng)
            searched = np.array([error(turns[k], k) for k in range(frames)])
            kept = np.array([error(learned[k], k) for k in range(frames)])
        by_key = _key_errors(searched, kept, keys)
        take_key = _keys_taken(*by_key)
        report.append({"nodes": len(group), "gaussians": int(own.sum()), "taken": any(take_key),
                       "keys_taken": [k for k, take in zip(keys, take_key) if take],
                       "error_searched": round(float(searched.mean()), 5),
                       "error_learned": round(float(kept.mean()), 5),
                       "key_ratio": [round(a / max(b, 1e-12), 3) for a, b in zip(*by_key)]})
        if not any(take_key):
            continue
        with torch.no_grad():
            for ki, k in enumerate(keys):
                if take_key[ki]:  # the group turns rigidly about its centre from its middle-frame pose
                    r = torch.from_numpy(turns[k])
                    positions[ki, group] = (p_mid[group].double() - torch.from_numpy(c_mid)) @ r.T \
                        + torch.from_numpy(centre[k])
                    rotations[ki, group] = quaternion.from_rotmat(r[None] @ r_mid[group].double())
            values, moved, held = _reseat(skinned, positions, rotations, key_times, times, canonical, group, own)
            hold |= held
        strategy.replace_values(trainer.params, trainer.optimizer,
                                {k: v.to(trainer.device) for k, v in values.items()})
        skinned = replace(skinned, gaussians=replace(skinned.gaussians, **values),
                          node_positions=positions.float(), node_rotations=rotations.float())
        report[-1]["moved_median"] = round(float(moved.median()), 4)
        report[-1]["moved_p95"] = round(float(moved.quantile(0.95)), 4)
    if any(r["taken"] for r in report):
        with torch.no_grad():
            nodes.positions.copy_(positions.to(nodes.positions))
            nodes.rotations.copy_(rotations.to(nodes.rotations))
        for state in nodes.optimizer.state.values():  # the moments of the old poses
            for v in state.values():
                if torch.is_tensor(v) and v.dim() > 0:
                    v.zero_()
        nodes._skin = None
        if hold.any():
            nodes._held = (hold.to(trainer.device),) + tuple(x.to(trainer.device) for x in old_skin)
    print(f"late-turns at step {trainer.step}: {report} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr,
          flush=True)
    return report
