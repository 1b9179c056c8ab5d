"""Point sets: well-spread subsets (the procedural samples' surface points, the trainer's control nodes) and the
rigid motion that best takes one set onto another (the deforming-mesh exporter's carried vertices, the trainer's
tracked nodes)."""

from __future__ import annotations

import numpy as np


def farthest_point_subset(points: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """Indices ``(k,)`` of `count` well-spread rows of `points` ``(C, 3)`` by greedy farthest-point sampling
    (starting from a random row): each pick is the point farthest from all picks so far. O(count * C). Fewer than
    `count` (k) when the points hold fewer distinct positions: a repeated position is no new pick (control nodes
    drawn twice at one place would have a zero median spacing)."""
    count = min(count, len(points))
    x, y, z = (np.ascontiguousarray(points[:, k], dtype=np.float64) for k in range(3))
    picked = np.empty(count, dtype=np.int64)
    picked[0] = i = int(rng.integers(len(points)))
    dist = (x - x[i]) ** 2 + (y - y[i]) ** 2 + (z - z[i]) ** 2  # squared distance to the nearest pick
    d2, tmp = np.empty_like(dist), np.empty_like(dist)
    for k in range(1, count):
        i = int(dist.argmax())
        if dist[i] == 0.0:  # every point sits on a pick
            return picked[:k]
        picked[k] = i
        # in-place per coordinate: ~10x faster than summing a (C, 3) temporary
        np.subtract(x, x[i], out=d2)
        np.multiply(d2, d2, out=d2)
        for c in (y, z):
            np.subtract(c, c[i], out=tmp)
            np.multiply(tmp, tmp, out=tmp)
            d2 += tmp
        np.minimum(dist, d2, out=dist)
    return picked


def rigid_fit(before: np.ndarray, after: np.ndarray, weights: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The weighted least-squares rigid motion taking each of V point sets `before` ``[V, k, 3]`` onto `after`
    (Kabsch 1976 / Procrustes; `weights` ``[V, k]`` summing to 1, default uniform): rotations ``[V, 3, 3]`` and
    centroids ``[V, 3]`` before and after, with after ≈ rot (before - c0) + c1; and ``[V]`` bool, whether the points
    fix a rotation (spread over a plane at least, else the rotation is arbitrary)."""
    if weights is None:
        weights = np.full(before.shape[:2], 1.0 / before.shape[1])
    c0 = (weights[..., None] * before).sum(1)
    c1 = (weights[..., None] * after).sum(1)
    a, b = before - c0[:, None], after - c1[:, None]
    h = np.einsum("vk,vki,vkj->vij", weights, a, b)  # cross-covariance
    u, sv, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("vij,vjk->vik", vt.transpose(0, 2, 1), u.transpose(0, 2, 1))))
    fix = np.ones_like(sv)
    fix[:, 2] = d
    rot = np.einsum("vji,vj,vkj->vik", vt, fix, u)  # V diag(1, 1, d) Uᵀ
    return rot, c0, c1, sv[:, 1] > 1e-3 * np.maximum(sv[:, 0], 1e-30)
