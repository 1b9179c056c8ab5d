"""Fused CPU slicing of native 4D Gaussians: the geometry of `Gaussians4D.slice` in one numba pass and its
hand-written backward.

The math is `splatreel.covariance` (the one statement of it: ``covariance_4d``, ``condition_on_time``,
``temporal_marginal``); this module computes exactly that, per Gaussian, without building the ``[N, 4, 4]``
intermediates torch needs. The torch composition costs about 40 small tensor ops forward and as many backward
(batched 4x4 products among them), and training slices every image of every step: fused, the slice of 30k live
Gaussians drops from ~17 ms (forward + backward, 2 cores) to ~1 ms. `tests/test_slicing.py` holds values and
gradients to the torch composition.

Per Gaussian, with q_l, q_r normalised, s = exp(log_scales), s_t = exp(log_t_scale)::

    R4 = L(q_l) Rbar(q_r), flipped on both axes under the 'current' convention;  M = R4 diag(s, s_t)
    Σ = M Mᵀ;  c = Σ[:3, 3];  w = Σ[3, 3]
    velocity = c / w;  cov3 = Σ[:3, :3] - c cᵀ / w
    dt = t - mu_t;  mean(t) = mu + velocity dt;  marginal = exp(-dt² / (2 w))

Only the rows listed are sliced (the live ones); their gradients are scattered straight into full-size arrays,
which spares the gather of every parameter and the scatter of its gradient.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ._kernels import CACHE_ENABLED
from .covariance import _ISOCLINIC_INDEX, _LEFT_SIGN, _RIGHT_CONJ_SIGN, parse_convention

from numba import njit, prange  # noqa: E402  (after _kernels configured numba's cache)

_INDEX = np.array(_ISOCLINIC_INDEX, np.int64)
_SIGN_L = np.array(_LEFT_SIGN, np.float32)
_SIGN_R = np.array(_RIGHT_CONJ_SIGN, np.float32)
_F = np.float32
_ZERO, _HALF, _ONE = _F(0.0), _F(0.5), _F(1.0)
_EPS = _F(1e-12)  # quaternion.normalize's floor on the norm

_pjit = njit(parallel=True, cache=CACHE_ENABLED, nogil=True)
_ijit = njit(inline="always", cache=CACHE_ENABLED, nogil=True)


@_ijit
def _unit(q, out):
    """out = q / max(|q|, eps); returns the (floored) norm."""
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    n = n if n > _EPS else _EPS
    for k in range(4):
        out[k] = q[k] / n
    return n


@_ijit
def _rotation(ql, qr, flip, lmat, bmat, r4):
    """Fill L(ql), Rbar(qr) and R4 (4x4 each) from unit quaternions."""
    for e in range(16):
        lmat[e // 4, e % 4] = _SIGN_L[e] * ql[_INDEX[e]]
        bmat[e // 4, e % 4] = _SIGN_R[e] * qr[_INDEX[e]]
    for i in range(4):
        for j in range(4):
            a = _ZERO
            for k in range(4):
                a += lmat[i, k] * bmat[k, j]
            if flip:
                r4[3 - i, 3 - j] = a
            else:
                r4[i, j] = a


@_ijit
def _factors(g, log_scales, log_t_scales, quats_l, quats_r, flip, ql, qr, lmat, bmat, r4, s, m):
    """Fill Gaussian g's unit quaternions, L(q_l), Rbar(q_r), R4, the std-devs s (x, y, z, t) and M = R4 diag(s);
    return the quaternions' norms (their backward divides by them)."""
    nl = _unit(quats_l[g], ql)
    nr = _unit(quats_r[g], qr)
    _rotation(ql, qr, flip, lmat, bmat, r4)
    for k in range(3):
        s[k] = np.exp(log_scales[g, k])
    s[3] = np.exp(log_t_scales[g])
    for i in range(4):
        for k in range(4):
            m[i, k] = r4[i, k] * s[k]
    return nl, nr


@_pjit
def slice_forward(rows, means, t_means, log_scales, log_t_scales, quats_l, quats_r, t, flip,
                  out_means, out_cov, out_velocity, out_marginal):
    """Slice rows `rows` of the raw parameters at time `t` (see the module doc) into the ``[M, ...]`` outputs."""
    for r in prange(rows.shape[0]):
        g = rows[r]
        # scratch allocated here, not in _factors: numba then keeps it out of the heap (2.5x faster)
        ql, qr = np.empty(4, np.float32), np.empty(4, np.float32)
        lmat, bmat, r4 = np.empty((4, 4), np.float32), np.empty((4, 4), np.float32), np.empty((4, 4), np.float32)
        s, m = np.empty(4, np.float32), np.empty((4, 4), np.float32)
        nl, nr = _factors(g, log_scales, log_t_scales, quats_l, quats_r, flip, ql, qr, lmat, bmat, r4, s, m)
        sig = np.empty((4, 4), np.float32)
        for i in range(4):
            for j in range(i, 4):
                a = _ZERO
                for k in range(4):
                    a += m[i, k] * m[j, k]
                sig[i, j] = a
                sig[j, i] = a
        w = sig[3, 3]
        dt = _F(t) - t_means[g]
        for i in range(3):
            v = sig[i, 3] / w
            out_velocity[r, i] = v
            out_means[r, i] = means[g, i] + v * dt
            for j in range(3):
                out_cov[r, i, j] = sig[i, j] - v * sig[j, 3]
        out_marginal[r] = np.exp(-_HALF * dt * dt / w)


@_pjit
def slice_backward(rows, t_means, log_scales, log_t_scales, quats_l, quats_r, t, flip, grad_means, grad_cov,
                   grad_velocity, grad_marginal, d_means, d_t_means, d_log_scales, d_log_t_scales, d_quats_l,
                   d_quats_r):
    """Gradients of `slice_forward` with respect to the raw parameters, written to rows `rows` of the full-size
    ``d_*`` arrays (rows are distinct, so threads never share one)."""
    for r in prange(rows.shape[0]):
        g = rows[r]
        # scratch allocated here, not in _factors: numba then keeps it out of the heap (2.5x faster)
        ql, qr = np.empty(4, np.float32), np.empty(4, np.float32)
        lmat, bmat, r4 = np.empty((4, 4), np.float32), np.empty((4, 4), np.float32), np.empty((4, 4), np.float32)
        s, m = np.empty(4, np.float32), np.empty((4, 4), np.float32)
        nl, nr = _factors(g, log_scales, log_t_scales, quats_l, quats_r, flip, ql, qr, lmat, bmat, r4, s, m)
        c = np.empty(3, np.float32)
        for i in range(3):
            a = _ZERO
            for k in range(4):
                a += m[i, k] * m[3, k]
            c[i] = a
        w = _ZERO
        for k in range(4):
            w += m[3, k] * m[3, k]
        dt = _F(t) - t_means[g]
        mg = np.exp(-_HALF * dt * dt / w)
        gk = grad_marginal[r]
        # upstream of the conditioned quantities; gv collects the velocity's (directly and through the mean)
        gv = np.empty(3, np.float32)
        g_dt = -gk * mg * dt / w
        for i in range(3):
            gm = grad_means[r, i]
            d_means[g, i] = gm
            gv[i] = grad_velocity[r, i] + gm * dt
            g_dt += gm * c[i] / w
        d_t_means[g] = -g_dt
        # H: gradient of the loss with respect to each entry of Σ as the forward read it (Σ11, Σ[:3, 3], Σ33)
        h = np.zeros((4, 4), np.float32)
        gsym = np.empty((3, 3), np.float32)
        for i in range(3):
            for j in range(3):
                gsym[i, j] = _HALF * (grad_cov[r, i, j] + grad_cov[r, j, i])
                h[i, j] = gsym[i, j]
        cgc = _ZERO
        gc = np.empty(3, np.float32)
        gv_c = _ZERO
        for i in range(3):
            a = _ZERO
            for j in range(3):
                a += gsym[i, j] * c[j]
            gc[i] = a
            cgc += c[i] * a
            gv_c += gv[i] * c[i]
        for i in range(3):
            h[i, 3] = gv[i] / w - _F(2.0) * gc[i] / w
        h[3, 3] = (gk * mg * _HALF * dt * dt - gv_c + cgc) / (w * w)
        # Σ = M Mᵀ: dM = (H + Hᵀ) M;  M = R4 diag(s): dR4 = dM diag(s), ds_k = sum_p dM[p, k] R4[p, k]
        da = np.empty((4, 4), np.float32)
        ds = np.zeros(4, np.float32)
        for p in range(4):
            for k in range(4):
                a = _ZERO
                for b in range(4):
                    a += (h[p, b] + h[b, p]) * m[b, k]
                ds[k] += a * r4[p, k]
                if flip:
                    da[3 - p, 3 - k] = a * s[k]
                else:
                    da[p, k] = a * s[k]
        for k in range(3):
            d_log_scales[g, k] = ds[k] * s[k]
        d_log_t_scales[g] = ds[3] * s[3]
        # A = L Rbar: dL = dA Rbarᵀ, dRbar = Lᵀ dA; each entry of L / Rbar is a signed quaternion component
        gl, gr = np.zeros(4, np.float32), np.zeros(4, np.float32)
        for e in range(16):
            i, j = e // 4, e % 4
            dl, db = _ZERO, _ZERO
            for k in range(4):
                dl += da[i, k] * bmat[j, k]
                db += lmat[k, i] * da[k, j]
            gl[_INDEX[e]] += _SIGN_L[e] * dl
            gr[_INDEX[e]] += _SIGN_R[e] * db
        # normalisation: d q = (d q̂ - q̂ (q̂ . d q̂)) / |q|
        dot_l = gl[0] * ql[0] + gl[1] * ql[1] + gl[2] * ql[2] + gl[3] * ql[3]
        dot_r = gr[0] * qr[0] + gr[1] * qr[1] + gr[2] * qr[2] + gr[3] * qr[3]
        for k in range(4):
            d_quats_l[g, k] = (gl[k] - ql[k] * dot_l) / nl
            d_quats_r[g, k] = (gr[k] - qr[k] * dot_r) / nr


def _np(x: Tensor) -> np.ndarray:
    return x.detach().contiguous().numpy()


class _Slice(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, t_means, log_scales, log_t_scales, quats_l, quats_r, rows, t, flip):
        m = rows.shape[0]
        arrays = [_np(x) for x in (means, t_means, log_scales, log_t_scales, quats_l, quats_r)]
        rows_np = _np(rows).astype(np.int64, copy=False)
        out_means, out_velocity = np.empty((m, 3), np.float32), np.empty((m, 3), np.float32)
        out_cov, out_marginal = np.empty((m, 3, 3), np.float32), np.empty(m, np.float32)
        slice_forward(rows_np, *arrays, float(t), bool(flip), out_means, out_cov, out_velocity, out_marginal)
        ctx.arrays, ctx.rows, ctx.t, ctx.flip = arrays[1:], rows_np, float(t), bool(flip)
        ctx.n = means.shape[0]
        return tuple(torch.from_numpy(a) for a in (out_means, out_cov, out_velocity, out_marginal))

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_means, grad_cov, grad_velocity, grad_marginal):
        n = ctx.n
        grads = (np.zeros((n, 3), np.float32), np.zeros(n, np.float32), np.zeros((n, 3), np.float32),
                 np.zeros(n, np.float32), np.zeros((n, 4), np.float32), np.zeros((n, 4), np.float32))
        slice_backward(ctx.rows, *ctx.arrays, ctx.t, ctx.flip, *(_np(x) for x in (grad_means, grad_cov,
                       grad_velocity, grad_marginal)), *grads)
        return (*(torch.from_numpy(a) for a in grads), None, None, None)


def slice_geometry(means: Tensor, t_means: Tensor, log_scales: Tensor, log_t_scales: Tensor, quats_l: Tensor,
                   quats_r: Tensor, rows: Tensor, t: float, convention: str = "current"
                   ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """(mean(t) ``[M, 3]``, cov3 ``[M, 3, 3]``, velocity ``[M, 3]``, marginal ``[M]``) of rows `rows` (``[M]``
    distinct indices) of the raw ``[N, ...]`` float32 CPU parameters; differentiable with respect to each of them
    (rows not listed get zero gradients)."""
    flip = parse_convention(convention) == "current"
    return _Slice.apply(means, t_means, log_scales, log_t_scales, quats_l, quats_r, rows, float(t), flip)
