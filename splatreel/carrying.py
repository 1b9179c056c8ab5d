"""Fused CPU carry of skinned Gaussians: `splatreel.skinned.carry` in one numba pass and its hand-written backward.

The math is `splatreel.skinned.carry` (the one statement of it); this module computes exactly that per Gaussian,
without the ``[N, K, 3, 3]`` intermediates torch builds. The torch composition costs about 30 tensor ops forward and
as many backward, batched 3x3 products among them, and training carries every image of every step: for 25k
Gaussians blending 4 nodes each it took ~100 ms forward and backward on 2 cores, as much as the rasterizer.
`tests/test_carrying.py` holds values and gradients to the torch composition.

Per Gaussian i with canonical mean x, covariance C, nodes n_k and weights w_k, nodes' canonical positions c, poses
(p, R) at the time::

    A = sum_k w_k R_{n_k};  mean = sum_k w_k (R_{n_k} (x - c_{n_k}) + p_{n_k});  cov = A C Aᵀ

Backward, with upstream gradients g (mean) and G (cov)::

    dx = Aᵀ g;  dC = Aᵀ G A;  dA = G A Cᵀ + Gᵀ A C
    dp_{n_k} += w_k g;  dR_{n_k} += w_k (g (x - c_{n_k})ᵀ + dA)

The per-Gaussian part runs in parallel; the sums into the nodes run serially in Gaussian order, so the gradients are
the same from run to run (a resumed run equals an uninterrupted one). The skin (nodes, weights) and the nodes'
canonical positions get no gradient: they are not trained.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ._kernels import CACHE_ENABLED

from numba import njit, prange  # noqa: E402  (after _kernels configured numba's cache)

_F = np.float32
_ZERO = _F(0.0)

_pjit = njit(parallel=True, cache=CACHE_ENABLED, nogil=True)
_jit = njit(cache=CACHE_ENABLED, nogil=True)
_ijit = njit(inline="always", cache=CACHE_ENABLED, nogil=True)


@_ijit
def _offset(means, g, canonical, j):
    """x - c_j of Gaussian g and node j, as three floats."""
    return means[g, 0] - canonical[j, 0], means[g, 1] - canonical[j, 1], means[g, 2] - canonical[j, 2]


@_pjit
def carry_forward(rows, means, cov, nodes, weights, canonical, positions, turns, with_cov, out_means, out_cov,
                  out_blend):
    """Carry Gaussians `rows` of the full-size `means` (``[N, 3]``, or wider: columns 0-2 are read); `cov`, `nodes`,
    `weights` are already the rows' (``[m, ...]``). Writes the ``[m, ...]`` outputs (`out_cov` only `with_cov`) and,
    unless `out_blend` is empty (a caller without a backward pass), each row's blend A."""
    for r in prange(rows.shape[0]):
        g = rows[r]
        a = np.zeros((3, 3), np.float32)
        m = np.zeros(3, np.float32)
        for k in range(nodes.shape[1]):
            j = int(nodes[r, k])  # indices, or the viewer's float32 attribute copy of them
            w = weights[r, k]
            o0, o1, o2 = _offset(means, g, canonical, j)
            for p in range(3):
                m[p] += w * (turns[j, p, 0] * o0 + turns[j, p, 1] * o1 + turns[j, p, 2] * o2 + positions[j, p])
                for q in range(3):
                    a[p, q] += w * turns[j, p, q]
        for p in range(3):
            out_means[r, p] = m[p]
        if out_blend.shape[0]:  # kept for the backward pass only
            for p in range(3):
                for q in range(3):
                    out_blend[r, p, q] = a[p, q]
        if with_cov:
            ac = np.empty((3, 3), np.float32)  # A C
            for p in range(3):
                for q in range(3):
                    s = _ZERO
                    for b in range(3):
                        s += a[p, b] * cov[r, b, q]
                    ac[p, q] = s
            for p in range(3):
                for q in range(3):
                    s = _ZERO
                    for b in range(3):
                        s += ac[p, b] * a[q, b]
                    out_cov[r, p, q] = s


@_pjit
def carry_backward_gaussians(rows, cov, blend, grad_means, grad_cov, with_cov, d_means, d_cov, d_blend):
    """dx (into rows `rows` of the full-size `d_means`), dC and dA (``[m, ...]``) of each carried Gaussian."""
    for r in prange(rows.shape[0]):
        g = rows[r]
        for q in range(3):
            s = _ZERO
            for p in range(3):
                s += blend[r, p, q] * grad_means[r, p]
            d_means[g, q] = s
        if not with_cov:
            continue
        ga = np.empty((3, 3), np.float32)  # G A
        gta = np.empty((3, 3), np.float32)  # Gᵀ A
        for p in range(3):
            for q in range(3):
                s, t = _ZERO, _ZERO
                for b in range(3):
                    s += grad_cov[r, p, b] * blend[r, b, q]
                    t += grad_cov[r, b, p] * blend[r, b, q]
                ga[p, q] = s
                gta[p, q] = t
        for p in range(3):
            for q in range(3):
                s = _ZERO  # (Aᵀ G A)[p, q]
                for b in range(3):
                    s += blend[r, b, p] * ga[b, q]
                d_cov[r, p, q] = s
                s = _ZERO  # (G A Cᵀ + Gᵀ A C)[p, q]
                for b in range(3):
                    s += ga[p, b] * cov[r, q, b] + gta[p, b] * cov[r, b, q]
                d_blend[r, p, q] = s


@_jit
def carry_backward_nodes(rows, means, nodes, weights, canonical, grad_means, d_blend, d_positions, d_turns):
    """The nodes' sums dp and dR, in Gaussian order (serial: deterministic)."""
    for r in range(rows.shape[0]):
        g = rows[r]
        for k in range(nodes.shape[1]):
            j = int(nodes[r, k])  # indices, or the viewer's float32 attribute copy of them
            w = weights[r, k]
            o0, o1, o2 = _offset(means, g, canonical, j)
            for p in range(3):
                gp = w * grad_means[r, p]
                d_positions[j, p] += gp
                d_turns[j, p, 0] += gp * o0 + w * d_blend[r, p, 0]
                d_turns[j, p, 1] += gp * o1 + w * d_blend[r, p, 1]
                d_turns[j, p, 2] += gp * o2 + w * d_blend[r, p, 2]


def _np(x: Tensor) -> np.ndarray:
    return x.detach().contiguous().numpy()


class _Carry(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, cov, positions, turns, rows, nodes, weights, canonical):
        with_cov = cov is not None
        m = rows.shape[0]
        arrays = [_np(x) for x in (rows, means)]
        cov_np = _np(cov) if with_cov else np.zeros((0, 3, 3), np.float32)
        skin = [_np(nodes), _np(weights), _np(canonical), _np(positions), _np(turns)]
        out_means, out_blend = np.empty((m, 3), np.float32), np.empty((m, 3, 3), np.float32)
        out_cov = np.empty((m, 3, 3), np.float32) if with_cov else np.zeros((0, 3, 3), np.float32)
        carry_forward(*arrays, cov_np, *skin, with_cov, out_means, out_cov, out_blend)
        ctx.saved = (*arrays, cov_np, *skin[:3], out_blend)
        ctx.with_cov, ctx.n, ctx.nodes = with_cov, means.shape[0], positions.shape[0]
        return torch.from_numpy(out_means), (torch.from_numpy(out_cov) if with_cov else None)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_means, grad_cov):
        rows, means, cov, nodes, weights, canonical, blend = ctx.saved
        m = rows.shape[0]
        gm = _np(grad_means) if grad_means is not None else np.zeros((m, 3), np.float32)
        with_cov = ctx.with_cov and grad_cov is not None
        gc = _np(grad_cov) if with_cov else np.zeros((0, 3, 3), np.float32)
        d_means = np.zeros((ctx.n, 3), np.float32)
        d_cov = np.zeros((m, 3, 3), np.float32) if with_cov else np.zeros((0, 3, 3), np.float32)
        d_blend = np.zeros((m, 3, 3), np.float32)
        carry_backward_gaussians(rows, cov, blend, gm, gc, with_cov, d_means, d_cov, d_blend)
        d_positions, d_turns = np.zeros((ctx.nodes, 3), np.float32), np.zeros((ctx.nodes, 3, 3), np.float32)
        carry_backward_nodes(rows, means, nodes, weights, canonical, gm, d_blend, d_positions, d_turns)
        return (torch.from_numpy(d_means), torch.from_numpy(d_cov) if with_cov else None,
                torch.from_numpy(d_positions), torch.from_numpy(d_turns), None, None, None, None)


def fused_carry(means: Tensor, cov3: Tensor | None, rows: Tensor, nodes: Tensor, weights: Tensor, canonical: Tensor,
                positions: Tensor, turns: Tensor) -> tuple[Tensor, Tensor | None]:
    """`splatreel.skinned.carry` of rows `rows` (``[m]`` distinct indices) of the full-size canonical `means`
    ``[N, 3]``, with the rows' `cov3` ``[m, 3, 3]`` (or None), `nodes` and `weights` ``[m, K]``; float32 CPU tensors.
    Differentiable in `means` (rows not listed get zero gradients), `cov3`, `positions` and `turns`."""
    return _Carry.apply(means, cov3, positions, turns, rows.to(torch.int64), nodes.to(torch.int64), weights,
                        canonical)
