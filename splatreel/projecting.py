"""Fused CPU projection of 3D Gaussians: `splatreel.rasterize.project_gaussians` and the conic in one numba pass,
with a hand-written backward.

The math is `project_gaussians` (EWA splatting with the reference clamp of the Jacobian, ``+EPS2D`` on the
diagonal) followed by `conics_from_cov2d`; `tests/test_projecting.py` holds this module to that torch composition
in values and gradients. Torch needs ~60 small tensor ops for it, plus a gather of the Gaussians in front of the
camera and a scatter of their gradients; here every row is projected where it lies and the rows not `front` get
inert outputs (centre 0, identity covariance and conic) and no gradient.

Backward, per Gaussian (Σ2 the 2D covariance, Q = Σ2⁻¹ the conic, J the clamped Jacobian, S = W Σ Wᵀ)::

    dΣ2 = -Q dQ Q,   dS = Jᵀ dΣ2 J,   dJ = 2 dΣ2 J S,   dΣ = Wᵀ dS W,   d mean = Wᵀ d(x, y, z)

with dQ and dΣ2 as symmetric matrices (an off-diagonal parameter appears twice, so each entry takes half).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ._kernels import CACHE_ENABLED
from .cameras import Camera
from .constants import EPS2D, FRUSTUM_CLAMP

from numba import njit, prange  # noqa: E402  (after _kernels configured numba's cache)

_F = np.float32
_ZERO, _HALF, _ONE, _TWO = _F(0.0), _F(0.5), _F(1.0), _F(2.0)
_EPS2D = _F(EPS2D)

_pjit = njit(parallel=True, cache=CACHE_ENABLED, nogil=True)
_ijit = njit(inline="always", cache=CACHE_ENABLED, nogil=True)


@_ijit
def _camera_space(means, cov, g, w2c, s):
    """(x, y, z) of Gaussian g in camera space; writes S = W Σ Wᵀ (symmetric part of Σ) to `s` (3x3)."""
    p = np.empty(3, np.float32)
    for i in range(3):
        p[i] = w2c[i, 0] * means[g, 0] + w2c[i, 1] * means[g, 1] + w2c[i, 2] * means[g, 2] + w2c[i, 3]
    ws = np.empty((3, 3), np.float32)  # W Σsym
    for i in range(3):
        for j in range(3):
            a = _ZERO
            for k in range(3):
                a += w2c[i, k] * _HALF * (cov[g, k, j] + cov[g, j, k])
            ws[i, j] = a
    for i in range(3):
        for j in range(3):
            a = _ZERO
            for k in range(3):
                a += ws[i, k] * w2c[j, k]
            s[i, j] = a
    return p[0], p[1], p[2]


@_ijit
def _jacobian(x, y, z, intr, lim):
    """(j00, j02, j11, j12, tx, ty, clamped_x, clamped_y) of the perspective Jacobian at the clamped x/z, y/z."""
    fx, fy = intr[0], intr[1]
    rx, ry = x / z, y / z
    cx_ = rx < lim[0] or rx > lim[1]
    cy_ = ry < lim[2] or ry > lim[3]
    tx = z * min(max(rx, lim[0]), lim[1])
    ty = z * min(max(ry, lim[2]), lim[3])
    return fx / z, -fx * tx / (z * z), fy / z, -fy * ty / (z * z), tx, ty, cx_, cy_


@_pjit
def project_forward(means, cov, front, w2c, intr, lim, out_means2d, out_depths, out_cov2d, out_conics):
    """EWA projection of every row (see the module doc); rows not `front` get centre 0, identity cov2d / conic."""
    for g in prange(means.shape[0]):
        s = np.empty((3, 3), np.float32)
        x, y, z = _camera_space(means, cov, g, w2c, s)
        out_depths[g] = z
        if not front[g]:
            out_means2d[g, 0], out_means2d[g, 1] = _ZERO, _ZERO
            out_cov2d[g, 0], out_cov2d[g, 1], out_cov2d[g, 2] = _ONE, _ZERO, _ONE
            out_conics[g, 0], out_conics[g, 1], out_conics[g, 2] = _ONE, _ZERO, _ONE
            continue
        j00, j02, j11, j12, _, _, _, _ = _jacobian(x, y, z, intr, lim)
        xx = j00 * j00 * s[0, 0] + _TWO * j00 * j02 * s[0, 2] + j02 * j02 * s[2, 2] + _EPS2D
        xy = j00 * j11 * s[0, 1] + j00 * j12 * s[0, 2] + j02 * j11 * s[1, 2] + j02 * j12 * s[2, 2]
        yy = j11 * j11 * s[1, 1] + _TWO * j11 * j12 * s[1, 2] + j12 * j12 * s[2, 2] + _EPS2D
        out_means2d[g, 0] = intr[0] * x / z + intr[2]
        out_means2d[g, 1] = intr[1] * y / z + intr[3]
        out_cov2d[g, 0], out_cov2d[g, 1], out_cov2d[g, 2] = xx, xy, yy
        det = xx * yy - xy * xy
        if det > _ZERO:
            inv_det = _ONE / det
            out_conics[g, 0], out_conics[g, 1], out_conics[g, 2] = yy * inv_det, -xy * inv_det, xx * inv_det
        else:  # degenerate (the rasterizer culls it): an inert conic keeps the backward finite
            out_conics[g, 0], out_conics[g, 1], out_conics[g, 2] = _ONE, _ZERO, _ONE


@_pjit
def project_backward(means, cov, front, w2c, intr, lim, conics, grad_means2d, grad_depths, grad_conics,
                     d_means, d_cov):
    """Gradients of `project_forward`'s centres, depths and conics with respect to the means and covariances."""
    for g in prange(means.shape[0]):
        s = np.empty((3, 3), np.float32)
        x, y, z = _camera_space(means, cov, g, w2c, s)
        dx, dy, dz = _ZERO, _ZERO, grad_depths[g]
        if front[g]:
            fx, fy = intr[0], intr[1]
            j00, j02, j11, j12, tx, ty, clamped_x, clamped_y = _jacobian(x, y, z, intr, lim)
            # conic -> 2D covariance: dΣ2 = -Q dQ Q (dQ symmetric, b's gradient split over both entries)
            qa, qb, qc = conics[g, 0], conics[g, 1], conics[g, 2]
            ga, gb, gc = grad_conics[g, 0], _HALF * grad_conics[g, 1], grad_conics[g, 2]
            m00, m01 = ga * qa + gb * qb, ga * qb + gb * qc  # dQ Q
            m10, m11 = gb * qa + gc * qb, gb * qb + gc * qc
            e00 = -(qa * m00 + qb * m10)
            e01 = -(qa * m01 + qb * m11)
            e11 = -(qb * m01 + qc * m11)
            # dS = Jᵀ E J and dJ = 2 E J S, with J = [[j00, 0, j02], [0, j11, j12]]
            jm = np.empty((2, 3), np.float32)
            jm[0, 0], jm[0, 1], jm[0, 2] = j00, _ZERO, j02
            jm[1, 0], jm[1, 1], jm[1, 2] = _ZERO, j11, j12
            e = np.empty((2, 2), np.float32)
            e[0, 0], e[0, 1], e[1, 0], e[1, 1] = e00, e01, e01, e11
            ds = np.empty((3, 3), np.float32)
            for i in range(3):
                for j in range(3):
                    ds[i, j] = (jm[0, i] * (e[0, 0] * jm[0, j] + e[0, 1] * jm[1, j])
                                + jm[1, i] * (e[1, 0] * jm[0, j] + e[1, 1] * jm[1, j]))
            js = np.empty((2, 3), np.float32)  # J S
            for r in range(2):
                for j in range(3):
                    js[r, j] = jm[r, 0] * s[0, j] + jm[r, 1] * s[1, j] + jm[r, 2] * s[2, j]
            dj00 = _TWO * (e[0, 0] * js[0, 0] + e[0, 1] * js[1, 0])
            dj02 = _TWO * (e[0, 0] * js[0, 2] + e[0, 1] * js[1, 2])
            dj11 = _TWO * (e[1, 0] * js[0, 1] + e[1, 1] * js[1, 1])
            dj12 = _TWO * (e[1, 0] * js[0, 2] + e[1, 1] * js[1, 2])
            z2 = z * z
            dtx = -fx / z2 * dj02
            dty = -fy / z2 * dj12
            dz += -fx / z2 * dj00 - fy / z2 * dj11 + _TWO * fx * tx / (z2 * z) * dj02 + _TWO * fy * ty / (z2 * z) * dj12
            if clamped_x:
                dz += tx / z * dtx  # tx = z * limit
            else:
                dx += dtx
            if clamped_y:
                dz += ty / z * dty
            else:
                dy += dty
            gu, gv = grad_means2d[g, 0], grad_means2d[g, 1]
            dx += fx / z * gu
            dy += fy / z * gv
            dz += -fx * x / z2 * gu - fy * y / z2 * gv
            # S = W Σ Wᵀ: dΣ = Wᵀ dS W
            wd = np.empty((3, 3), np.float32)
            for i in range(3):
                for j in range(3):
                    wd[i, j] = w2c[0, i] * ds[0, j] + w2c[1, i] * ds[1, j] + w2c[2, i] * ds[2, j]
            for i in range(3):
                for j in range(3):
                    d_cov[g, i, j] = wd[i, 0] * w2c[0, j] + wd[i, 1] * w2c[1, j] + wd[i, 2] * w2c[2, j]
        else:
            for i in range(3):
                for j in range(3):
                    d_cov[g, i, j] = _ZERO
        for i in range(3):
            d_means[g, i] = w2c[0, i] * dx + w2c[1, i] * dy + w2c[2, i] * dz


def camera_arrays(camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(w2c ``[3, 4]``, (fx, fy, cx, cy), Jacobian limits (x lo, x hi, y lo, y hi)) as float32 arrays."""
    return (np.ascontiguousarray(np.asarray(camera.w2c, np.float64)[:3], dtype=np.float32),
            np.array([camera.fx, camera.fy, camera.cx, camera.cy], np.float32),
            np.array(camera.ray_limits(FRUSTUM_CLAMP - 1.0), np.float32))


def _np(x: Tensor) -> np.ndarray:
    return x.detach().contiguous().numpy()


class _Project(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, covariances, front, camera_np):
        n = means.shape[0]
        m, c, f = _np(means), _np(covariances), _np(front)
        means2d, depths = np.empty((n, 2), np.float32), np.empty(n, np.float32)
        cov2d, conics = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
        project_forward(m, c, f, *camera_np, means2d, depths, cov2d, conics)
        ctx.saved = (m, c, f, camera_np, conics)
        out = tuple(torch.from_numpy(a) for a in (means2d, depths, cov2d, conics))
        ctx.mark_non_differentiable(out[2])
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_means2d, grad_depths, _grad_cov2d, grad_conics):
        m, c, f, camera_np, conics = ctx.saved
        d_means, d_cov = np.empty_like(m), np.empty_like(c)
        project_backward(m, c, f, *camera_np, conics, _np(grad_means2d), _np(grad_depths), _np(grad_conics),
                         d_means, d_cov)
        return torch.from_numpy(d_means), torch.from_numpy(d_cov), None, None


def project_fused(means: Tensor, covariances: Tensor, front: Tensor, camera: Camera
                  ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """(means2d ``[N, 2]``, depths ``[N]``, cov2d ``[N, 3]`` (not differentiable), conics ``[N, 3]``) of float32 CPU
    ``[N, 3]`` means and ``[N, 3, 3]`` covariances; rows where `front` (``[N]`` bool) is False get centre 0 and
    identity cov2d / conic, and no gradient but that of their depth."""
    return _Project.apply(means, covariances, front, camera_arrays(camera))
