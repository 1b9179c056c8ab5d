"""Back-to-front order of the Gaussians **at time t** (never of their static positions).

The depth of Gaussian i at time t is the camera-space z of its conditional mean mu_i + v_i (t - mu_t,i), the same
point the vertex shader projects. A Gaussian is dropped from the order (not drawn at all) when it cannot cover a
pixel at this (camera, t): its temporal marginal is <= TEMPORAL_CULL, its opacity times that marginal is below
ALPHA_THRESHOLD, its mean is at or in front of the NEAR_PLANE, or a conservative bound of its footprint misses the
image. Survivors are argsorted by decreasing depth. Each also gets a conservative screen box (from the largest
eigenvalues of its covariance and of the Jacobian, and its opacity at t) that the renderer uses to skip Gaussians
hidden behind pixels that are already opaque.

`depth_order` is a fused numba kernel plus numpy's argsort; both release the GIL, so the desktop app sorts in a
worker thread (a parallel kernel was at most 1.3x faster on 2 cores: not worth competing with the rasterizer
threads of a software GL). `_depth_order_numpy` is its slow twin, used by tests. `AsyncSorter` runs sorts in a
thread and always hands back the newest finished order, so drawing never waits for a sort.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numba
import numpy as np

from splat4d.cameras import Camera
from splat4d.constants import ALPHA_THRESHOLD, EPS2D, NEAR_PLANE, TEMPORAL_CULL

from .splats import SplatArrays

#: Marginal exp(-e) > TEMPORAL_CULL  <=>  e < -ln(TEMPORAL_CULL).
_MAX_EXPONENT = -math.log(TEMPORAL_CULL)


@dataclass(frozen=True)
class SortKey:
    """What an order depends on: the view (w2c, intrinsics, size), the time and the splat scale."""

    w2c: bytes
    intrinsics: tuple[float, float, float, float, int, int]
    time: float
    scale: float

    @classmethod
    def of(cls, camera: Camera, t: float, scale: float = 1.0) -> "SortKey":
        return cls(np.asarray(camera.w2c, np.float64).tobytes(),
                   (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height), float(t), float(scale))


@dataclass(eq=False)
class SortResult:
    """An order and what it was computed for.

    Attributes:
        order: ``[V]`` uint32 indices of the V drawable Gaussians, back to front.
        boxes: ``[V, 3]`` float32 (u, v, r) per entry of `order`: the square [u - r, u + r] x [v - r, v + r]
            (pixels) holds every pixel that Gaussian can reach with alpha >= ALPHA_THRESHOLD.
        depth_range: (near, far) camera depth of the drawn means (2nd and 98th percentile), for depth display.
        key: the `SortKey` this order belongs to.
        ms: wall time of the sort in milliseconds.
        tag: whatever the requester attached (`AsyncSorter.request`), e.g. which model the order belongs to.
    """

    order: np.ndarray
    boxes: np.ndarray
    depth_range: tuple[float, float]
    key: SortKey | None
    ms: float
    tag: object = None

    @property
    def visible(self) -> int:
        return int(self.order.shape[0])


def _view_params(camera: Camera) -> np.ndarray:
    """[16] float64: w2c rows 0-2 (12), fx, fy, cx, cy."""
    return np.concatenate([np.asarray(camera.w2c[:3], np.float64).reshape(-1),
                           [camera.fx, camera.fy, camera.cx, camera.cy]])


@numba.njit(cache=True, nogil=True)
def _depth_keys(mean_t, motion, cov, view, t, width, height, scale, max_exp, alpha_min, near, eps2d, out, boxes):
    """out[i] = -depth of Gaussian i at t (+inf when culled, see module doc); boxes[i] = (u, v, half-extent) of a
    square in pixels that contains every pixel it can give alpha >= alpha_min."""
    n = mean_t.shape[0]
    fx, fy, cx, cy = view[12], view[13], view[14], view[15]
    for i in range(n):
        out[i] = np.inf
        dt = t - mean_t[i, 3]
        e = dt * dt * motion[i, 3]
        if not e < max_exp:
            continue
        o = cov[i, 6] * math.exp(-e)
        if not o >= alpha_min:
            continue
        px = mean_t[i, 0] + motion[i, 0] * dt
        py = mean_t[i, 1] + motion[i, 1] * dt
        pz = mean_t[i, 2] + motion[i, 2] * dt
        x = view[0] * px + view[1] * py + view[2] * pz + view[3]
        y = view[4] * px + view[5] * py + view[6] * pz + view[7]
        z = view[8] * px + view[9] * py + view[10] * pz + view[11]
        if not z > near:
            continue
        xz = x / z
        yz = y / z
        # largest eigenvalue of J J^T at the unclamped x/z, y/z: an upper bound for the clamped Jacobian
        a = fx * fx * (1.0 + xz * xz) / (z * z)
        c = fy * fy * (1.0 + yz * yz) / (z * z)
        b = fx * fy * xz * yz / (z * z)
        lam_j = 0.5 * (a + c) + math.sqrt(0.25 * (a - c) * (a - c) + b * b)
        s = cov[i, 7] * scale  # largest spatial std-dev
        ext = math.sqrt(2.0 * math.log(o / alpha_min)) * math.sqrt(lam_j * s * s + eps2d) + 1.0
        u = fx * xz + cx
        v = fy * yz + cy
        if u + ext < 0.0 or u - ext > width or v + ext < 0.0 or v - ext > height:
            continue
        out[i] = -z
        boxes[i, 0] = u
        boxes[i, 1] = v
        boxes[i, 2] = ext


def depth_order(splats: SplatArrays, camera: Camera, t: float, scale: float = 1.0) -> SortResult:
    """Sort the drawable Gaussians of `splats` back to front at time `t` (see module doc)."""
    start = time.perf_counter()
    n = len(splats)
    neg = np.empty(n, np.float32)
    boxes = np.empty((n, 3), np.float32)
    if n:
        _depth_keys(splats.mean_t, splats.motion, splats.cov, _view_params(camera), float(t), float(camera.width),
                    float(camera.height), float(scale), _MAX_EXPONENT, ALPHA_THRESHOLD, NEAR_PLANE, EPS2D, neg, boxes)
    return _finish(neg, boxes, SortKey.of(camera, t, scale), start)


def _finish(neg_depth: np.ndarray, boxes: np.ndarray, key: SortKey, start: float) -> SortResult:
    """Compact the finite keys and argsort them (ascending -depth = back to front)."""
    idx = np.flatnonzero(np.isfinite(neg_depth)).astype(np.uint32)
    keys = neg_depth[idx]
    perm = np.argsort(keys, kind="quicksort")
    order = idx[perm]
    if order.shape[0]:
        sorted_depth = -keys[perm]  # far .. near
        k = sorted_depth.shape[0] - 1
        depth_range = (float(sorted_depth[int(0.98 * k)]), float(sorted_depth[int(0.02 * k)]))
    else:
        depth_range = (NEAR_PLANE, 1.0)
    return SortResult(order=order, boxes=boxes[order], depth_range=depth_range, key=key,
                      ms=(time.perf_counter() - start) * 1e3)


def _depth_order_numpy(splats: SplatArrays, camera: Camera, t: float, scale: float = 1.0) -> SortResult:
    """Pure numpy twin of `depth_order` (slow; the reference in tests)."""
    start = time.perf_counter()
    m = splats.mean_t.astype(np.float64)
    mo = splats.motion.astype(np.float64)
    dt = t - m[:, 3]
    e = dt * dt * mo[:, 3]
    o = splats.cov[:, 6] * np.exp(-e)
    p = m[:, :3] + mo[:, :3] * dt[:, None]
    w2c = camera.w2c
    pc = p @ w2c[:3, :3].T + w2c[:3, 3]
    z = pc[:, 2]
    fx, fy = camera.fx, camera.fy
    with np.errstate(divide="ignore", invalid="ignore"):
        xz, yz = pc[:, 0] / z, pc[:, 1] / z
        a, c, b = fx ** 2 * (1 + xz ** 2) / z ** 2, fy ** 2 * (1 + yz ** 2) / z ** 2, fx * fy * xz * yz / z ** 2
        lam_j = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b ** 2)
        s = splats.cov[:, 7] * scale
        r = np.sqrt(2.0 * np.log(np.maximum(o, ALPHA_THRESHOLD) / ALPHA_THRESHOLD))
        ext = r * np.sqrt(lam_j * s * s + EPS2D) + 1.0
        u, v = fx * xz + camera.cx, fy * yz + camera.cy
        keep = ((e < _MAX_EXPONENT) & (o >= ALPHA_THRESHOLD) & (z > NEAR_PLANE) & (u + ext >= 0)
                & (u - ext <= camera.width) & (v + ext >= 0) & (v - ext <= camera.height))
    neg = np.where(keep, -z, np.inf).astype(np.float32)
    return _finish(neg, np.stack([u, v, ext], -1).astype(np.float32), SortKey.of(camera, t, scale), start)


class AsyncSorter:
    """Sorts in a background thread; the caller draws with the newest finished order meanwhile.

    ``request(splats, camera, t, scale, tag)`` replaces any pending request (only the latest view matters);
    ``poll()`` returns a new `SortResult` once, or None. The numba kernel releases the GIL, so the UI thread keeps
    running while a sort is in flight.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._pending: tuple | None = None
        self._result: SortResult | None = None
        self._busy = False
        self._closed = False
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._loop, name="splat4d-sort", daemon=True)
        self._thread.start()

    def request(self, splats: SplatArrays, camera: Camera, t: float, scale: float = 1.0, tag: object = None) -> None:
        with self._cond:
            self._pending = ((splats, camera, t, scale), tag)
            self._cond.notify()

    def poll(self) -> SortResult | None:
        with self._cond:
            if self._error is not None:
                err, self._error = self._error, None
                raise err
            res, self._result = self._result, None
            return res

    @property
    def idle(self) -> bool:
        with self._cond:
            return self._pending is None and not self._busy

    def wait(self, timeout: float = 30.0) -> SortResult | None:
        """Block until no sort is pending or running; return the newest result (or None)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while (self._pending is not None or self._busy) and time.monotonic() < deadline:
                self._cond.wait(0.01)
        return self.poll()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout=5.0)

    def _loop(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                (job, tag), self._pending = self._pending, None
                self._busy = True
            try:
                res = depth_order(*job)
                res.tag = tag
            except BaseException as exc:  # surfaced to the UI thread by poll()
                with self._cond:
                    self._error, self._busy = exc, False
                    self._cond.notify_all()
                continue
            with self._cond:
                self._result, self._busy = res, False
                self._cond.notify_all()
