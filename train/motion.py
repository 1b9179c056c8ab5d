"""Velocities from optical flow: give every Gaussian the motion the images show between consecutive frames.

Why: a native 4D Gaussian moves along a straight line (velocity ``Σ12 / Σtt``, `splatreel.covariance`), and the
photometric loss only pulls it within its own footprint. When a surface moves further between two frames than a
Gaussian is wide (a box turning 24° per frame moves its faces ~10 px at 256²), nothing pulls the Gaussian of one
frame towards where its surface went in the next: it fades out instead of moving, and in-between times show two
half-transparent copies. Optical flow sees those large displacements. So, once the model's geometry is fitted (a
share of the run in), each camera's consecutive frames give a dense 2D flow (OpenCV's DIS, Kroeger et al. 2016),
which the model's own depth lifts to 3D (scene flow, as in the flow-supervised dynamic Gaussians of Gao et al.,
GaussianFlow 2024, here used once to set the motion rather than as a loss):

* each Gaussian belongs to the training frame nearest its temporal mean and sits at its sliced position there;
* in every camera of that frame where it lies on the rendered surface (its depth within a few percent of the
  expected depth, inside the alpha), its pixel moves by the flow to the next (and the previous) frame, where the
  model's depth there gives a 3D point; flows that the backward flow does not bring back are dropped;
* its velocity is the mean over those cameras of (point - position) / time step; Gaussians no camera saw on the
  surface take the mean velocity of their nearest estimated neighbours at the same frame;
* the 4D covariance is rebuilt with the same conditional 3D covariance and temporal variance and the new velocity
  (`splatreel.covariance.covariance_4d_from_motion`), and the 4D mean moved so that the Gaussian stays where it was
  at its frame.

It needs cameras that film consecutive frames (an image matrix); a dataset with one camera per time has none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from splatreel.covariance import alive_at, condition_on_time, covariance_4d_from_motion, decompose_covariance_4d
from splatreel.datasets import Dataset
from splatreel.model import Gaussians4D
from splatreel.rasterize import rasterize

from .data import camera_videos
from .evaluate import target_bytes
from .flow import optical_flow, round_trip_ok, warp

#: A Gaussian is on the surface a camera sees when its depth is within this share of the rendered depth.
SURFACE_DEPTH_TOLERANCE = 0.03
#: Pixels count as covered where the rendered alpha is at least this.
COVERED_ALPHA = 0.5
#: Gaussians no camera saw take the mean velocity of this many nearest estimated ones at the same frame.
NEIGHBOURS = 4


def nearest_key(t_means: torch.Tensor, key_times: torch.Tensor) -> torch.Tensor:
    """``[N]`` index of the key time nearest each temporal mean (the frame a Gaussian belongs to)."""
    return torch.argmin((t_means.detach()[:, None] - key_times.to(t_means)[None]).abs(), 1)


@dataclass
class _Motion:
    """Each Gaussian's motion and where it is at the training frame nearest its temporal mean (float64)."""

    cov3: torch.Tensor  # [N, 3, 3] conditional 3D covariance
    velocity: torch.Tensor  # [N, 3]
    var_t: torch.Tensor  # [N]
    frame: np.ndarray  # [N] index into the frame times
    dt: torch.Tensor  # [N] that frame's time minus the temporal mean
    position: torch.Tensor  # [N, 3] the sliced mean at that frame
    acceleration: torch.Tensor  # [N, 3] (zeros for linear motion)

    @classmethod
    def of(cls, model: Gaussians4D, times: list[float]) -> "_Motion":
        cov3, velocity, var_t = condition_on_time(model.covariance_4d().detach().double())
        t = torch.tensor(times, dtype=torch.float64)
        t_means = model.t_means.detach().double()
        frame = nearest_key(t_means, t)
        dt = t[frame] - t_means
        a = model.accelerations_or_zeros().detach().double()
        position = model.means.detach().double() + velocity * dt[:, None] + 0.5 * a * dt[:, None] ** 2
        return cls(cov3, velocity, var_t, frame.numpy(), dt, position, a)


@dataclass
class _Render:
    depth: np.ndarray  # [H, W, 1]
    alpha: np.ndarray  # [H, W, 1]


def _render(model: Gaussians4D, view, background: torch.Tensor, var_t: torch.Tensor) -> _Render:
    out = rasterize(model.slice(view.time, rows=alive_at(view.time, model.t_means, var_t)), view.camera, background)
    return _Render(out.depth.numpy()[..., None], out.alpha.numpy()[..., None])


def _lift(positions: np.ndarray, view, render: _Render, flow: np.ndarray, back: np.ndarray, view_to,
          render_to: _Render) -> tuple[np.ndarray, np.ndarray]:
    """Where `positions` ``[N, 3]`` (at `view`'s time) are at `view_to`'s time as this camera's flow and the model's
    depth there say: (points ``[N, 3]``, valid ``[N]``)."""
    uv, z = view.camera.project(positions)  # pixel i spans [i, i + 1); the flow's pixel i is centred at i
    h, w = flow.shape[:2]
    inside = lambda p: (p[:, 0] >= 0) & (p[:, 0] < w) & (p[:, 1] >= 0) & (p[:, 1] < h)  # noqa: E731
    valid = (z > 0) & inside(uv)
    at = np.where(valid[:, None], uv, 0.5) - 0.5
    valid &= warp(render.alpha, at)[:, 0] >= COVERED_ALPHA
    depth = warp(render.depth, at)[:, 0]
    valid &= np.abs(z - depth) <= SURFACE_DEPTH_TOLERANCE * depth
    uv_to = uv + warp(flow, at)
    valid &= inside(uv_to) & round_trip_ok(flow, back, at)
    at_to = np.where(valid[:, None], uv_to, 0.5) - 0.5
    valid &= warp(render_to.alpha, at_to)[:, 0] >= COVERED_ALPHA
    points = view_to.camera.unproject(at_to + 0.5, warp(render_to.depth, at_to)[:, 0])
    return points, valid


@dataclass
class FlowTracks:
    """Where the training videos' optical flow carries each Gaussian of a model from the training frame nearest its
    temporal mean (float64): what `flow_velocities` averages, and what a motion fitted over several frames needs.

    Attributes:
        position: ``[N, 3]`` each Gaussian's sliced mean at its frame.
        frame: ``[N]`` that frame's index into the dataset's frame times.
        velocity_sum: ``[N, 3]`` sum of (point - position) / time step over every camera and direction that saw the
            Gaussian on the surface (backward steps count with their sign); ``count``: ``[N]`` how many.
        next_points, prev_points: ``[N, 3]`` the mean over cameras of where the flow brings it at the next / the
            previous frame; ``next_seen``, ``prev_seen``: ``[N]`` whether any camera did.
    """

    position: np.ndarray
    frame: np.ndarray
    velocity_sum: np.ndarray
    count: np.ndarray
    next_points: np.ndarray
    next_seen: np.ndarray
    prev_points: np.ndarray
    prev_seen: np.ndarray


def flow_tracks(model: Gaussians4D, ds: Dataset, background: torch.Tensor, fine: bool = False) -> FlowTracks:
    """Follow every Gaussian of `model` (on `ds`'s times) by the optical flow between the consecutive frames of each
    camera (module doc) to the neighbouring frames; `fine`: by the finer, slower flow (`train.flow.optical_flow`)."""
    model = model.detach()
    return _tracks(model, _Motion.of(model, ds.frame_times), ds, background, fine)


def _tracks(model: Gaussians4D, motion: _Motion, ds: Dataset, background: torch.Tensor,
            fine: bool = False) -> FlowTracks:
    """`flow_tracks` of a detached `model` whose `_Motion` is at hand."""
    frame_of, position = motion.frame, motion.position.numpy()
    var_t = motion.var_t.to(model.t_means.dtype)
    rank = {t: k for k, t in enumerate(ds.frame_times)}
    n = len(model)
    total, count = np.zeros((n, 3)), np.zeros(n)
    ends = {1.0: (np.zeros((n, 3)), np.zeros(n)), -1.0: (np.zeros((n, 3)), np.zeros(n))}  # next, previous frame
    with torch.no_grad():
        for video in camera_videos(ds):
            renders: dict[int, _Render] = {}  # one video's depth and alpha at a time: memory stays small
            for i, j in zip(video[:-1], video[1:]):
                vi, vj = ds.train[i], ds.train[j]
                for k in (i, j):
                    if k not in renders:
                        renders[k] = _render(model, ds.train[k], background, var_t)
                ci, cj = target_bytes(vi, background), target_bytes(vj, background)
                fwd, bwd = optical_flow(ci, cj, fine), optical_flow(cj, ci, fine)
                dt = vj.time - vi.time
                for src, dst, f, b, sign in ((i, j, fwd, bwd, 1.0), (j, i, bwd, fwd, -1.0)):
                    rows = np.nonzero(frame_of == rank[ds.train[src].time])[0]
                    points, valid = _lift(position[rows], ds.train[src], renders[src], f, b, ds.train[dst],
                                          renders[dst])
                    rows, points = rows[valid], points[valid]
                    np.add.at(total, rows, sign * (points - position[rows]) / dt)
                    np.add.at(count, rows, 1.0)
                    np.add.at(ends[sign][0], rows, points)
                    np.add.at(ends[sign][1], rows, 1.0)
    (next_sum, next_n), (prev_sum, prev_n) = ends[1.0], ends[-1.0]
    mean = lambda s, c: np.where(c[:, None] > 0, s / np.maximum(c, 1.0)[:, None], position)  # noqa: E731
    return FlowTracks(position, frame_of, total, count, mean(next_sum, next_n), next_n > 0, mean(prev_sum, prev_n),
                      prev_n > 0)


def flow_velocities(model: Gaussians4D, ds: Dataset, background: torch.Tensor,
                    tracks: FlowTracks | None = None) -> tuple[torch.Tensor, int]:
    """``[N, 3]`` velocity of every Gaussian of `model` (on `ds`'s times) from optical flow between the
    consecutive frames of each camera (module doc; `tracks`: the model's `flow_tracks` when already at hand), and how
    many Gaussians a camera saw on the surface (the rest took their neighbours' velocity; all keep their own when no
    Gaussian was seen)."""
    from scipy.spatial import cKDTree

    model = model.detach()
    motion = _Motion.of(model, ds.frame_times)
    if tracks is None:
        tracks = _tracks(model, motion, ds, background)
    frame_of, position, count = tracks.frame, tracks.position, tracks.count
    seen = count > 0
    estimate = np.zeros((len(model), 3))
    estimate[seen] = tracks.velocity_sum[seen] / count[seen, None]
    out = (motion.velocity + motion.acceleration * motion.dt[:, None]).numpy()  # the velocity at the frame
    out[seen] = estimate[seen]
    for k in np.unique(frame_of):  # the unseen take their estimated neighbours' mean, frame by frame
        here = frame_of == k
        known, unknown = np.nonzero(here & seen)[0], np.nonzero(here & ~seen)[0]
        if len(known) == 0 or len(unknown) == 0:
            continue
        nn = min(NEIGHBOURS, len(known))
        _, idx = cKDTree(position[known]).query(position[unknown], k=nn)
        idx = idx.reshape(len(unknown), nn)
        out[unknown] = estimate[known][idx].mean(1)
    return torch.from_numpy(out).to(model.means.dtype), int(seen.sum())


def with_velocities(model: Gaussians4D, velocity: torch.Tensor, times: list[float]) -> dict[str, torch.Tensor]:
    """New values of the geometry parameters (``means``, ``log_scales``, ``log_t_scales``, ``quats_l``,
    ``quats_r``) for Gaussians moving at `velocity` ``[N, 3]``: the same conditional 3D covariance and temporal
    variance, and the same position at the frame of `times` nearest each one's temporal mean. With accelerations
    (kept), `velocity` is the velocity at that frame."""
    motion = _Motion.of(model, times)
    a, dt = motion.acceleration, motion.dt[:, None]
    v = velocity.double() - a * dt
    means = motion.position - v * dt - 0.5 * a * dt * dt  # the position at the frame stays
    scales, scale_t, q_l, q_r = decompose_covariance_4d(
        covariance_4d_from_motion(motion.cov3, v, motion.var_t), model.rotation_convention)
    tiny = torch.finfo(torch.float64).tiny
    dtype = model.means.dtype
    return {"means": means.to(dtype), "log_scales": scales.clamp_min(tiny).log().to(dtype),
            "log_t_scales": scale_t.clamp_min(tiny).log().to(dtype), "quats_l": q_l.to(dtype),
            "quats_r": q_r.to(dtype)}
