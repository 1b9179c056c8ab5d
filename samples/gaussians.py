"""A native 4D Gaussian model built directly from a sample's known motion (no training).

Used by the demo until a trained model exists, and by viewer / exporter tests that need a model whose motion is
known. Construction (`build_model`):

1. Surface points with fixed (face, barycentric) coordinates, so each point has a known trajectory ``p(t)``:
   random candidates (uniform by the face areas averaged over the animation), thinned by farthest-point sampling
   at mid-animation so the points are evenly spread (random points leave holes through which the unlit far side
   shows).
2. Key times ``k / (frames - 1)``, plus one extra key on each side where the object holds its first / last state.
   Every pair of consecutive keys is a segment; each point gets one Gaussian per segment:

   * temporal mean = segment midpoint, temporal std = half the segment length (neighbouring segments cross-fade;
     the summed temporal marginal varies by < 3 % over time, and the held end segments keep t = 0 and t = 1 as
     covered as any other key time);
   * conditional mean = midpoint of the chord ``p(t_a) .. p(t_b)`` and velocity = ``(p(t_b) - p(t_a)) / dt``, so
     the slice at a key time puts the Gaussian exactly on the surface point;
   * conditional covariance = a flat disc tangent to the surface at the segment's middle time, its std-dev 0.6 x
     the local point spacing (which follows how much each face stretches), thickness 0.1 x that;
   * colour = the sample's LIT colour (the renderer's world-space Lambert + ambient, `render.shade`) at the
     segment's middle time, as SH DC (degree 0, no time terms); opacity 0.95.

   The 4D parameters come from `splatreel.covariance.covariance_4d_from_motion` + `decompose_covariance_4d`
   ('current' rotation convention), time_range (0, 1).

The Gaussians are stored segment by segment (segment-major), so the model has exactly `num_gaussians` Gaussians
(the last segment may have a few points fewer).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import torch

from splatreel import sh
from splatreel.covariance import covariance_4d_from_motion, decompose_covariance_4d
from splatreel.model import Gaussians4D

from .geometry import Mesh, face_areas, farthest_point_subset, points_on_surface, sample_surface
from .render import shade

#: Tangent std-dev of a disc as a fraction of the local point spacing sqrt(area per point).
DISC_SIZE = 0.6
#: Normal std-dev of a disc as a fraction of its tangent std-dev.
DISC_THICKNESS = 0.1
#: Temporal std-dev as a fraction of the segment length.
TEMPORAL_STD = 0.5
OPACITY = 0.95
#: Random surface candidates per point kept by farthest-point sampling.
CANDIDATES_PER_POINT = 6
#: Gaussians and key times of an object's model unless told (`build_model`).
DEFAULT_GAUSSIANS = 20000
DEFAULT_FRAMES = 16


def segment_times(frames: int) -> np.ndarray:
    """``(frames + 2,)`` key times: ``k / (frames - 1)`` plus one held key before 0 and one after 1."""
    step = 1.0 / (frames - 1)
    return np.concatenate([[-step], np.arange(frames) * step, [1.0 + step]])


def disc_covariances(normals: np.ndarray, std: np.ndarray) -> np.ndarray:
    """``(N, 3, 3)`` flat-disc covariances: std-dev `std` ``(N,)`` in the tangent plane of unit `normals`
    ``(N, 3)``, ``DISC_THICKNESS * std`` along them."""
    nn = normals[:, :, None] * normals[:, None, :]
    var = (std * std)[:, None, None]
    return var * (np.eye(3) - nn) + (DISC_THICKNESS ** 2) * var * nn


def motion_model(mesh_at: Callable[[float], Mesh], num_gaussians: int, frames: int, seed: int,
                 disc_size: float = DISC_SIZE, opacity: float = OPACITY) -> Gaussians4D:
    """The model of the module doc for the animated mesh ``mesh_at(t)`` (fixed topology; held outside [0, 1]):
    exactly `num_gaussians` (>= 1) Gaussians over ``frames`` (>= 2) key times, surface sampling seeded by `seed`.
    `disc_size` and `opacity` replace `DISC_SIZE` and `OPACITY` (the floor scene uses smaller ones)."""
    keys = segment_times(frames)
    num_segments = len(keys) - 1
    step = 1.0 / (frames - 1)
    meshes = [mesh_at(t) for t in keys]  # the ends are held: mesh() clamps t to [0, 1]
    faces = meshes[0].faces
    mean_areas = np.mean([face_areas(m.vertices, faces) for m in meshes[1:-1]], axis=0)  # (F,)
    num_points = math.ceil(num_gaussians / num_segments)
    rng = np.random.default_rng(seed)
    face_ids, bary = sample_surface(mean_areas, CANDIDATES_PER_POINT * num_points, rng)
    middle = points_on_surface(mesh_at(0.5), face_ids, bary)[0]
    keep = farthest_point_subset(middle, num_points, rng)
    face_ids, bary = face_ids[keep], bary[keep]
    positions = np.stack([points_on_surface(m, face_ids, bary)[0] for m in meshes])  # (K, P, 3)
    spacing = math.sqrt(mean_areas.sum() / num_points)

    mids = 0.5 * (keys[:-1] + keys[1:])  # (S,)
    normals, colors, stds = [], [], []
    for t in mids:
        mesh = mesh_at(t)
        _, n, albedo = points_on_surface(mesh, face_ids, bary)
        stretch = face_areas(mesh.vertices, faces)[face_ids] / mean_areas[face_ids]
        normals.append(n)
        colors.append(shade(albedo, n))
        stds.append(disc_size * spacing * np.sqrt(stretch))
    normals, colors, stds = np.stack(normals), np.stack(colors), np.stack(stds)  # (S, P, 3), (S, P, 3), (S, P)

    def flat(a: np.ndarray) -> np.ndarray:  # (S, P, ...) -> (N, ...), segment-major, first N
        return a.reshape((-1,) + a.shape[2:])[:num_gaussians]

    means = flat(0.5 * (positions[:-1] + positions[1:]))
    velocities = flat((positions[1:] - positions[:-1]) / step)
    t_means = flat(np.broadcast_to(mids[:, None], (num_segments, num_points)))
    cov3 = disc_covariances(flat(normals), flat(stds))
    var_t = np.full(len(means), (TEMPORAL_STD * step) ** 2)

    cov4 = covariance_4d_from_motion(torch.from_numpy(cov3), torch.from_numpy(velocities), torch.from_numpy(var_t))
    scales, t_scales, q_l, q_r = decompose_covariance_4d(cov4, "current")
    n = len(means)
    f32 = dict(dtype=torch.float32)
    return Gaussians4D(
        means=torch.tensor(means, **f32), t_means=torch.tensor(t_means, **f32),
        log_scales=torch.log(scales.clamp_min(1e-12)).float(), log_t_scales=torch.log(t_scales).float(),
        quats_l=q_l.float(), quats_r=q_r.float(),
        opacity_logits=torch.full((n,), math.log(opacity / (1.0 - opacity)), **f32),
        sh_dc=torch.tensor(sh.rgb_to_sh(flat(colors)), **f32)[:, None, :], sh_rest=torch.zeros((n, 0, 3), **f32),
        sh_degree=0, sh_degree_t=0, time_range=(0.0, 1.0), rotation_convention="current")
