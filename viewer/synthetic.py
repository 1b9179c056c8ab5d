"""Synthetic native 4D models with known motion, for benchmarks, tests and trying the viewer without data.

`synthetic_model` places Gaussians in a ball, gives each a random 3D shape, a constant velocity and a temporal
extent, and turns that into native 4D parameters through `splatreel.covariance.covariance_4d_from_motion` and
`decompose_covariance_4d`, so slicing the result reproduces exactly the motion that was asked for.
"""

from __future__ import annotations

import torch

from splatreel import quaternion, sh
from splatreel.covariance import covariance_3d, covariance_4d_from_motion, decompose_covariance_4d
from splatreel.model import Gaussians4D


def synthetic_model(num_gaussians: int, seed: int = 0, radius: float = 0.5, scale: float = 0.01,
                    speed: float = 0.2, lifetime: float = 0.35, sh_degree: int = 1, sh_degree_t: int = 0,
                    time_range: tuple[float, float] = (0.0, 1.0), convention: str = "current") -> Gaussians4D:
    """A cloud of moving, fading 4D Gaussians.

    Args:
        num_gaussians: N.
        radius: the means fill a ball of this radius at their temporal centres.
        scale: median spatial std-dev (log-normal spread of +-0.5 in log space per axis).
        speed: std-dev of each velocity component, in units per unit of time.
        lifetime: median temporal std-dev as a fraction of the time range.
        sh_degree, sh_degree_t: colour degrees; coefficients beyond the first are small random values.
    """
    g = torch.Generator().manual_seed(seed)
    n = num_gaussians
    t0, t1 = time_range
    dtype = torch.float64

    def randn(*shape):
        return torch.randn(*shape, generator=g, dtype=dtype)

    def rand(*shape):
        return torch.rand(*shape, generator=g, dtype=dtype)

    direction = quaternion.normalize(randn(n, 3))
    means = direction * (radius * rand(n, 1) ** (1.0 / 3.0))
    scales = scale * torch.exp(0.5 * randn(n, 3))
    cov3 = covariance_3d(scales, quaternion.normalize(randn(n, 4)))
    velocity = speed * randn(n, 3)
    var_t = ((lifetime * (t1 - t0)) * torch.exp(0.3 * randn(n))) ** 2
    scales3, scale_t, q_l, q_r = decompose_covariance_4d(covariance_4d_from_motion(cov3, velocity, var_t),
                                                         convention)
    m = sh.num_sh_coeffs(sh_degree, sh_degree_t)
    rgb = 0.15 + 0.7 * rand(n, 3)
    return Gaussians4D(
        means=means.float(), t_means=(t0 + (t1 - t0) * rand(n)).float(), log_scales=torch.log(scales3).float(),
        log_t_scales=torch.log(scale_t).float(), quats_l=q_l.float(), quats_r=q_r.float(),
        opacity_logits=(0.5 + randn(n)).float(), sh_dc=sh.rgb_to_sh(rgb)[:, None, :].float(),
        sh_rest=(0.05 * randn(n, m - 1, 3)).float(), sh_degree=sh_degree, sh_degree_t=sh_degree_t,
        time_range=time_range, rotation_convention=convention)

