"""Real spherical harmonics (degrees 0-3) and the 4D "spherindrical" time terms, for numpy and torch.

This is the one place where colour-from-SH is defined. The basis, ordering and signs are the reference 3DGS ones
(graphdeco-inria/diff-gaussian-rasterization ``cuda_rasterizer/forward.cu`` ``computeColorFromSH``,
graphdeco-inria/gaussian-splatting ``utils/sh_utils.py``; the time terms: fudan-zvg/4d-gaussian-splatting
``utils/sh_utils.py`` ``eval_shfs_4d``); the GLSL shader follows the same formulas.

Layouts
-------
* Spatial SH coefficients: ``[..., K, 3]`` with ``K = (degree + 1)**2`` (coefficient-major, RGB last).
* 4D coefficients: ``[..., K * (degree_t + 1), 3]``; coefficient ``n * K + j`` multiplies
  ``cos(2 pi n tau / T) * Y_j(d)``, with ``tau = mu_t - t`` (relative to the Gaussian's own time centre) and
  ``T`` the model's time span. With K = 16 (degree 3) this is the official ``16 n + j`` layout.
* Colour = ``max(SH(d) + 0.5, 0)``.

Every function accepts numpy arrays or torch tensors and returns the same kind.
"""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np
import torch

Array = TypeVar("Array", np.ndarray, torch.Tensor)

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)
MAX_SH_DEGREE = 3
MAX_SH_DEGREE_T = 2


def num_sh_bases(degree: int) -> int:
    """Number of spatial SH coefficients per colour channel for `degree` (1, 4, 9, 16)."""
    if not 0 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"SH degree must be 0..{MAX_SH_DEGREE}, got {degree}")
    return (degree + 1) ** 2


def num_sh_coeffs(degree: int, degree_t: int = 0) -> int:
    """Coefficients per channel of a 4D colour: (degree+1)^2 * (degree_t+1)."""
    if not 0 <= degree_t <= MAX_SH_DEGREE_T:
        raise ValueError(f"SH time degree must be 0..{MAX_SH_DEGREE_T}, got {degree_t}")
    return num_sh_bases(degree) * (degree_t + 1)


def sh_degree_from_bases(k: int) -> int:
    """Inverse of `num_sh_bases`; raises ValueError for counts that are not (d+1)^2 with d <= 3."""
    for d in range(MAX_SH_DEGREE + 1):
        if (d + 1) ** 2 == k:
            return d
    raise ValueError(f"{k} SH coefficients per channel is not (degree+1)^2 for a degree 0..3")


def _stack(xs: list, like: Array) -> Array:
    if isinstance(like, torch.Tensor):
        return torch.stack(xs, dim=-1)
    return np.stack(xs, axis=-1)


def _normalize(v: Array) -> Array:
    if isinstance(v, torch.Tensor):
        return v / torch.linalg.vector_norm(v, dim=-1, keepdim=True).clamp_min(1e-12)
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def sh_basis(degree: int, dirs: Array) -> Array:
    """Real SH basis values Y_j(d) for j < (degree+1)^2.

    Args:
        degree: 0..3.
        dirs: ``[..., 3]`` view directions (normalised here).
    Returns:
        ``[..., (degree+1)^2]``.
    """
    num_sh_bases(degree)
    d = _normalize(dirs)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    out = [SH_C0 + 0.0 * x]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2.0 * zz - xx - yy), SH_C2[3] * xz, SH_C2[4] * (xx - yy)]
    if degree >= 3:
        out += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * xy * z,
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[4] * x * (4.0 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3.0 * yy),
        ]
    return _stack(out, x)


def eval_sh(degree: int, coeffs: Array, dirs: Array) -> Array:
    """Evaluate spatial SH: sum_j coeffs[..., j, :] * Y_j(dirs). No +0.5 offset, no clamp.

    Args:
        coeffs: ``[..., K, 3]`` with K >= (degree+1)^2 (extra coefficients are ignored, so a lower
            ``degree`` renders a model at reduced SH degree).
        dirs: ``[..., 3]``.
    Returns:
        ``[..., 3]``.
    """
    basis = sh_basis(degree, dirs)  # [..., B]
    b = basis.shape[-1]
    # [..., 1, B] @ [..., B, 3]: one batched matmul instead of a broadcast product and a sum (hot in training)
    return (basis[..., None, :] @ coeffs[..., :b, :])[..., 0, :]


def time_basis(degree_t: int, tau: Array, duration: float) -> Array:
    """Cosine time terms cos(2 pi n tau / T) for n = 0..degree_t.

    Args:
        tau: ``[...]`` = mu_t - t.
        duration: T = t1 - t0 of the model's time range (> 0).
    Returns:
        ``[..., degree_t + 1]``.
    """
    if duration <= 0:
        raise ValueError(f"time duration must be positive, got {duration}")
    cos = torch.cos if isinstance(tau, torch.Tensor) else np.cos
    return _stack([cos((2.0 * math.pi * n / duration) * tau) for n in range(degree_t + 1)], tau)


def collapse_time(coeffs4d: Array, degree: int, degree_t: int, tau: Array, duration: float) -> Array:
    """Fold the time terms into plain spatial SH at one time.

    ``c_j(t) = sum_n cos(2 pi n tau / T) * coeffs4d[..., n*K + j, :]``, so that
    ``eval_sh(degree, collapse_time(...), d)`` equals the 4D colour.

    Args:
        coeffs4d: ``[..., K*(degree_t+1), 3]``, K = (degree+1)^2.
        tau: ``[...]`` = mu_t - t.
    Returns:
        ``[..., K, 3]``.
    """
    k = num_sh_bases(degree)
    if coeffs4d.shape[-2] != k * (degree_t + 1):
        raise ValueError(f"expected {k * (degree_t + 1)} coefficients for degrees ({degree}, {degree_t}), "
                         f"got {coeffs4d.shape[-2]}")
    if degree_t == 0:
        return coeffs4d
    w = time_basis(degree_t, tau, duration)  # [..., n]
    out = coeffs4d[..., 0:k, :] * w[..., 0, None, None]
    for n in range(1, degree_t + 1):
        out = out + coeffs4d[..., n * k:(n + 1) * k, :] * w[..., n, None, None]
    return out


def sh_to_rgb(value: Array) -> Array:
    """Colour from an SH evaluation: value + 0.5, clamped at 0 (no upper clamp, as the reference)."""
    if isinstance(value, torch.Tensor):
        return (value + 0.5).clamp_min(0.0)
    return np.maximum(value + 0.5, 0.0)


def rgb_to_sh(rgb: Array) -> Array:
    """DC coefficient that reproduces `rgb` from every direction: (rgb - 0.5) / C0."""
    return (rgb - 0.5) / SH_C0
