"""Unit-quaternion algebra on torch tensors. Quaternions are ``[..., 4]`` in **w-first** order (w, x, y, z)."""

from __future__ import annotations

import torch
from torch import Tensor


def normalize(q: Tensor) -> Tensor:
    """q / |q| (as torch.nn.functional.normalize, eps 1e-12): the activation of stored quaternions."""
    return q / torch.linalg.vector_norm(q, dim=-1, keepdim=True).clamp_min(1e-12)


def to_rotmat(q: Tensor) -> Tensor:
    """``[..., 4]`` quaternions (normalised here) -> ``[..., 3, 3]`` rotation matrices."""
    w, x, y, z = normalize(q).unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(q.shape[:-1] + (3, 3))


def from_rotmat(m: Tensor) -> Tensor:
    """``[..., 3, 3]`` proper rotation matrices -> ``[..., 4]`` unit quaternions with w >= 0.

    Uses the four candidate formulas and keeps, per matrix, the one with the largest denominator
    (numerically stable for every rotation, including 180 degrees).
    """
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    cands = torch.stack([
        torch.stack([1 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01], -1),
        torch.stack([m21 - m12, 1 + m00 - m11 - m22, m01 + m10, m02 + m20], -1),
        torch.stack([m02 - m20, m01 + m10, 1 - m00 + m11 - m22, m12 + m21], -1),
        torch.stack([m10 - m01, m02 + m20, m12 + m21, 1 - m00 - m11 + m22], -1),
    ], -2)  # [..., 4 candidates, 4]; candidate i has 4 q_i^2 as its i-th entry
    diag = torch.stack([cands[..., i, i] for i in range(4)], -1)
    best = diag.argmax(-1)
    q = torch.gather(cands, -2, best[..., None, None].expand(best.shape + (1, 4))).squeeze(-2)
    q = normalize(q)
    return torch.where(q[..., :1] < 0, -q, q)


def multiply(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product a ⊗ b."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], -1)


def slerp(q0: Tensor, q1: Tensor, w: Tensor | float) -> Tensor:
    """Spherical linear interpolation along the shorter arc; ``w`` in [0, 1] broadcasts over ``[...]``."""
    q0, q1 = normalize(q0), normalize(q1)
    w = torch.as_tensor(w, dtype=q0.dtype, device=q0.device)
    if w.dim() < q0.dim():
        w = w[..., None]
    dot = (q0 * q1).sum(-1, keepdim=True)
    q1 = torch.where(dot < 0, -q1, q1)
    dot = dot.abs().clamp(max=1.0)
    theta = torch.acos(dot)
    sin = torch.sin(theta)
    near = sin < 1e-6  # nearly equal: fall back to normalised lerp
    safe = torch.where(near, torch.ones_like(sin), sin)
    a = torch.where(near, 1 - w, torch.sin((1 - w) * theta) / safe)
    b = torch.where(near, w, torch.sin(w * theta) / safe)
    return normalize(a * q0 + b * q1)
