"""Back-to-front order of the Gaussians **at time t** (never of their static positions).

The depth of Gaussian i at time t is the camera-space z of its conditional mean mu_i + v_i (t - mu_t,i) (a skinned
model's: its canonical mean carried by its nodes), the same point the vertex shader projects. A Gaussian is dropped
from the order (not drawn at all) when it cannot cover a pixel at this (camera, t): its temporal marginal is <=
TEMPORAL_CULL, its opacity times that marginal is below ALPHA_THRESHOLD, its mean is at or in front of the near
plane (`Footprint.near_plane`, NEAR_PLANE by default), or a conservative bound of its footprint misses the image.
Survivors are argsorted by decreasing depth. Each also gets its screen box (from its projected 2D covariance,
computed as splat_preprocess.glsl and the trainer's rasterizer do, its opacity at t and the `Footprint` caps), which
the renderer uses to skip Gaussians hidden behind pixels that are already opaque and to choose between point and
quad splats.

`depth_order` is a fused numba key kernel plus a numba radix sort; both release the GIL, so the desktop app sorts
in a worker thread with the serial kernel (not competing with the rasterizer threads of a software GL), while a
caller that waits for the order (offline rendering) runs the key kernel on all cores; the tests hold it against the
trainer's projection. `AsyncSorter` runs sorts in a thread and always hands back the newest finished order, so
drawing never waits for a sort.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numba
import numpy as np

from splatreel.cameras import Camera
from splatreel.constants import (ALPHA_THRESHOLD, EPS2D, FRUSTUM_CLAMP, MAX_ALPHA, NEAR_PLANE, TEMPORAL_CULL,
                               TRANSMITTANCE_THRESHOLD)

from .skinning import posed
from .splats import SplatArrays

#: Tile edge (pixels) over which `hideable_fraction` sums optical depth.
DEPTH_TILE = 16
#: Marginal exp(-e) > TEMPORAL_CULL  <=>  e < -ln(TEMPORAL_CULL).
_MAX_EXPONENT = -math.log(TEMPORAL_CULL)


@dataclass(frozen=True)
class Footprint:
    """Which splats reach the screen and how far. By default as in the reference rasterizer: a Gaussian whose mean
    lies at or in front of NEAR_PLANE (camera depth) is not drawn, and each splat reaches out to where its alpha
    falls below ALPHA_THRESHOLD (about 3.3 std-devs for an opaque Gaussian). The two caps are the performance guards
    of web viewers (their maxStdDev, and a screen-radius cap against the fill-rate collapse of huge splats close to
    the camera), off by default since they change the image; so is a nearer `near_plane` (to fly close to or into a
    model without its Gaussians vanishing 0.2 units ahead; best with a screen-radius cap).

    Attributes:
        scale: multiplies every std-dev (1 = as trained).
        max_std_dev: largest reach in std-devs of the (scaled) Gaussian, inf = none (web viewers draw sqrt(8),
            2.83; sqrt(5), 2.24, is their fast setting).
        max_screen_radius: largest reach along the major axis, as a share of the image height (so the same at
            every resolution), inf = none.
        near_plane: camera depth at or before which Gaussians are not drawn (world units).
    """

    scale: float = 1.0
    max_std_dev: float = math.inf
    max_screen_radius: float = math.inf
    near_plane: float = NEAR_PLANE

    def __post_init__(self) -> None:
        for name in ("scale", "max_std_dev", "max_screen_radius", "near_plane"):
            given = getattr(self, name)
            try:
                value = float(given)
            except (TypeError, ValueError):
                value = math.nan
            if not value > 0 or (name in ("scale", "near_plane") and math.isinf(value)):
                what = "splat scale" if name == "scale" else name.replace("_", " ")
                raise ValueError(f"{what} must be a positive number, got {given}")
            object.__setattr__(self, name, value)


@dataclass(frozen=True)
class SortKey:
    """What an order depends on: the view (w2c, intrinsics, size), the time and the splats' `Footprint`."""

    w2c: bytes
    intrinsics: tuple[float, float, float, float, int, int]
    time: float
    footprint: Footprint

    @classmethod
    def of(cls, camera: Camera, t: float, footprint: Footprint = Footprint()) -> "SortKey":
        return cls(*view_key(camera), float(t), footprint)


def view_key(camera: Camera) -> tuple[bytes, tuple[float, float, float, float, int, int]]:
    """What a camera's view is, comparable with ==: its w2c bytes and (fx, fy, cx, cy, width, height)."""
    return (np.asarray(camera.w2c, np.float64).tobytes(),
            (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height))


@dataclass(eq=False)
class SortResult:
    """An order and what it was computed for.

    Attributes:
        order: ``[V]`` uint32 indices of the V drawable Gaussians, back to front.
        boxes: ``[V, 6]`` float32 (u, v, hx, hy, area, mass) per entry of `order`: the box [u - hx, u + hx] x
            [v - hy, v + hy] (pixels) holds every pixel that Gaussian can reach with alpha >= ALPHA_THRESHOLD,
            `area` is that of its quad along the principal axes out to the same cut-off, and `mass` its optical
            depth -ln(1 - alpha) integrated over the image (pixels); the renderer's cost models use the last two.
        depth_range: (near, far) camera depth of the drawn means (2nd and 98th percentile), for depth display.
        key: the `SortKey` this order belongs to.
        ms: wall time of the sort in milliseconds.
        hideable: rough share of the drawn Gaussians that lie behind saturated pixels in this view
            (`hideable_fraction`); computed here, once per order and off the render thread.
        tag: whatever the requester attached (`AsyncSorter.request`), e.g. which model the order belongs to.
    """

    order: np.ndarray
    boxes: np.ndarray
    depth_range: tuple[float, float]
    key: SortKey | None
    ms: float
    hideable: float = 0.0
    tag: object = None

    @property
    def visible(self) -> int:
        return int(self.order.shape[0])

    def needs_sort(self, camera: Camera, footprint: Footprint) -> bool:
        """Whether this order (e.g. the app's newest finished sort) cannot be drawn for `camera` with `footprint`:
        it was sorted with another footprint (just after a cap or the near plane changed: its boxes and culls bound
        nothing there), or with a screen-radius cap for another image size (the renderer's rescaling of boxes
        sorted at another resolution does not hold for those). Orders of another view are drawn as they are."""
        key = self.key
        if key is None:
            return False
        return key.footprint != footprint or (math.isfinite(footprint.max_screen_radius)
                                              and key.intrinsics[4:] != (camera.width, camera.height))


def _view_params(camera: Camera) -> np.ndarray:
    """[16] float64: w2c rows 0-2 (12), fx, fy, cx, cy."""
    return np.concatenate([np.asarray(camera.w2c[:3], np.float64).reshape(-1),
                           [camera.fx, camera.fy, camera.cx, camera.cy]])


@numba.njit(cache=True, nogil=True)
def _dilog(x):
    """Li2(x) = sum_k x^k / k^2 for x in [0, 1) to ~1e-5: the series directly below 1/2, above it through the
    reflection Li2(x) = pi^2/6 - ln(x) ln(1 - x) - Li2(1 - x), so 16 terms always suffice."""
    y = x if x <= 0.5 else 1.0 - x
    s, p = 0.0, 1.0
    for k in range(1, 17):
        p *= y
        s += p / (k * k)
    if x <= 0.5:
        return s
    return math.pi * math.pi / 6.0 - math.log(x) * math.log(y) - s


@numba.njit(cache=True, nogil=True, inline="always")
def _depth_key(i, mean_t, motion, accel, cov, view, t, width, height, s2, caps, lims, max_exp, alpha_min, max_alpha,
               near, eps2d, out, boxes):
    """out[i] = -depth of Gaussian i at t (+inf when culled, see module doc); boxes[i] = (u, v, half-width,
    half-height, quad area, optical mass): the pixel box holding every pixel it can give alpha >= alpha_min within
    the `caps` (largest radius in std-devs, in pixels along the major axis), the area of the quad along its axes
    out to that cut-off (what splat_draw.glsl draws), and its optical depth -ln(1 - alpha) integrated over the
    image plane (pixels; the uncapped Gaussian's). `lims`: `_frustum_limits`."""
    fx, fy, cx, cy = view[12], view[13], view[14], view[15]
    lim_x0, lim_x1, lim_y0, lim_y1 = lims
    out[i] = np.inf
    dt = t - mean_t[i, 3]
    e = dt * dt * motion[i, 3]
    if not e < max_exp:
        return
    o = cov[i, 6] * math.exp(-e)
    if not o >= alpha_min:
        return
    px = mean_t[i, 0] + (motion[i, 0] + 0.5 * accel[i, 0] * dt) * dt
    py = mean_t[i, 1] + (motion[i, 1] + 0.5 * accel[i, 1] * dt) * dt
    pz = mean_t[i, 2] + (motion[i, 2] + 0.5 * accel[i, 2] * dt) * dt
    x = view[0] * px + view[1] * py + view[2] * pz + view[3]
    y = view[4] * px + view[5] * py + view[6] * pz + view[7]
    z = view[8] * px + view[9] * py + view[10] * pz + view[11]
    if not z > near:
        return
    # the EWA projection of the trainer's rasterizer (and splat_preprocess.glsl): rows of J R, J at the
    # clamped x/z, y/z; Sigma_2D = (J R) Sigma (J R)^T + eps2d
    iz = 1.0 / z
    tx = min(max(x * iz, -lim_x0), lim_x1)
    ty = min(max(y * iz, -lim_y0), lim_y1)
    r0 = fx * iz * view[0] - fx * tx * iz * view[8]
    r1 = fx * iz * view[1] - fx * tx * iz * view[9]
    r2 = fx * iz * view[2] - fx * tx * iz * view[10]
    q0 = fy * iz * view[4] - fy * ty * iz * view[8]
    q1 = fy * iz * view[5] - fy * ty * iz * view[9]
    q2 = fy * iz * view[6] - fy * ty * iz * view[10]
    c00, c01, c02 = cov[i, 0] * s2, cov[i, 1] * s2, cov[i, 2] * s2
    c11, c12, c22 = cov[i, 3] * s2, cov[i, 4] * s2, cov[i, 5] * s2
    m0 = c00 * r0 + c01 * r1 + c02 * r2
    m1 = c01 * r0 + c11 * r1 + c12 * r2
    m2 = c02 * r0 + c12 * r1 + c22 * r2
    a = r0 * m0 + r1 * m1 + r2 * m2 + eps2d
    b = q0 * m0 + q1 * m1 + q2 * m2
    c = q0 * (c00 * q0 + c01 * q1 + c02 * q2) + q1 * (c01 * q0 + c11 * q1 + c12 * q2) \
        + q2 * (c02 * q0 + c12 * q1 + c22 * q2) + eps2d
    det = a * c - b * b
    if not det > 0.0:
        return
    rr = 2.0 * math.log(o / alpha_min)  # squared cut-off radius in std-devs
    # Footprint caps, as splat_preprocess.glsl: std-devs, then pixels along the major axis (sqrt(lambda_1) px)
    rr = min(rr, caps[0] * caps[0])
    if caps[1] < 1e30:  # (no screen cap: no lambda_1 to compute)
        rr = min(rr, caps[1] * caps[1] / (0.5 * (a + c) + math.sqrt(max(0.25 * (a - c) * (a - c) + b * b, 0.0))))
    hx = math.sqrt(rr * a) + 1.0  # + 1 px: float32 on the GPU, pixel-centre rounding
    hy = math.sqrt(rr * c) + 1.0
    u = fx * x * iz + cx
    v = fy * y * iz + cy
    if u + hx < 0.0 or u - hx > width or v + hy < 0.0 or v - hy > height:
        return
    out[i] = -z
    boxes[i, 0] = u
    boxes[i, 1] = v
    boxes[i, 2] = hx
    boxes[i, 3] = hy
    boxes[i, 4] = 4.0 * rr * math.sqrt(det)
    # optical depth -ln(1 - alpha) integrated over the plane: 2 pi sqrt(det) Li2(o) (alpha is capped at
    # max_alpha: so is o here, to stay finite)
    boxes[i, 5] = 2.0 * math.pi * math.sqrt(det) * _dilog(min(o, max_alpha))


@numba.njit(cache=True, nogil=True, inline="always")
def _frustum_limits(view, width, height, clamp):
    """The x/z and y/z bounds at which the EWA Jacobian is clamped (FRUSTUM_CLAMP times the half image)."""
    fx, fy, cx, cy = view[12], view[13], view[14], view[15]
    return (cx / fx + (clamp - 1.0) * 0.5 * width / fx, (width - cx) / fx + (clamp - 1.0) * 0.5 * width / fx,
            cy / fy + (clamp - 1.0) * 0.5 * height / fy, (height - cy) / fy + (clamp - 1.0) * 0.5 * height / fy)


# The key kernel twice: serial, for a sort thread running beside the GL rasterizer's threads (`AsyncSorter`), and
# over all cores, for a caller that waits for the order with nothing else running (`SplatRenderer.sort`). Two
# functions rather than two builds of one: numba's cache keys a build by its function, not by its flags.
@numba.njit(cache=True, nogil=True)
def _depth_keys(mean_t, motion, accel, cov, view, t, width, height, scale, caps, max_exp, alpha_min, max_alpha, near,
                eps2d, clamp, out, boxes):
    """`_depth_key` for every Gaussian."""
    lims = _frustum_limits(view, width, height, clamp)
    for i in range(mean_t.shape[0]):
        _depth_key(i, mean_t, motion, accel, cov, view, t, width, height, scale * scale, caps, lims, max_exp,
                   alpha_min, max_alpha, near, eps2d, out, boxes)


@numba.njit(cache=True, nogil=True, parallel=True)
def _depth_keys_parallel(mean_t, motion, accel, cov, view, t, width, height, scale, caps, max_exp, alpha_min, max_alpha,
                         near, eps2d, clamp, out, boxes):
    """`_depth_keys` on all cores (the same result)."""
    lims = _frustum_limits(view, width, height, clamp)
    for i in numba.prange(mean_t.shape[0]):
        _depth_key(i, mean_t, motion, accel, cov, view, t, width, height, scale * scale, caps, lims, max_exp,
                   alpha_min, max_alpha, near, eps2d, out, boxes)


def depth_order(splats: SplatArrays, camera: Camera, t: float, footprint: Footprint = Footprint(),
                parallel: bool = False) -> SortResult:
    """Sort the drawable Gaussians of `splats` back to front at time `t` (see module doc), drawn with `footprint`;
    `parallel` computes the keys on all cores (the same result). A skinned model's Gaussians are first carried to
    `t` by their nodes (`skinning.posed`)."""
    start = time.perf_counter()
    splats = posed(splats, t)
    n = len(splats)
    neg = np.empty(n, np.float32)
    boxes = np.empty((n, 6), np.float32)
    if n:
        kernel = _depth_keys_parallel if parallel else _depth_keys
        kernel(splats.mean_t, splats.motion, splats.accel, splats.cov, _view_params(camera), float(t),
               float(camera.width), float(camera.height), footprint.scale, footprint_caps(footprint, camera.height),
               _MAX_EXPONENT, ALPHA_THRESHOLD, MAX_ALPHA, footprint.near_plane, EPS2D, FRUSTUM_CLAMP, neg, boxes)
    return _finish(neg, boxes, SortKey.of(camera, t, footprint), start)


def footprint_caps(footprint: Footprint, height: int) -> tuple[float, float]:
    """(largest radius in std-devs, largest radius in pixels of an image `height` high) of `footprint`: what the
    key kernel and splat_preprocess.glsl clamp the cut-off radius with (1e30 for none: GLSL has no infinity)."""
    return (min(footprint.max_std_dev, 1e30), min(footprint.max_screen_radius * height, 1e30))


def _finish(neg_depth: np.ndarray, boxes: np.ndarray, key: SortKey, start: float) -> SortResult:
    """Compact the finite keys and sort them (ascending -depth = back to front; ties in index order)."""
    order, boxes = _radix_order(neg_depth.view(np.uint32), boxes)
    if order.shape[0]:
        sorted_depth = -neg_depth[order]  # far .. near
        k = sorted_depth.shape[0] - 1
        depth_range = (float(sorted_depth[int(0.98 * k)]), float(sorted_depth[int(0.02 * k)]))
    else:
        depth_range = (key.footprint.near_plane, 1.0)
    hideable = hideable_fraction(boxes, key.intrinsics[4], key.intrinsics[5])
    return SortResult(order=order, boxes=boxes, depth_range=depth_range, key=key,
                      ms=(time.perf_counter() - start) * 1e3, hideable=hideable)


#: Bits per pass of `_radix_order`: three passes cover a 32-bit key (measured faster than four of 8 bits).
_RADIX_BITS = 11


@numba.njit(cache=True, nogil=True)
def _radix_order(bits, boxes):
    """(order, boxes[order]): the indices of the finite float32 keys (given as their bits) in ascending key order,
    ties in index order (a stable LSD radix sort), and their rows of `boxes` gathered in that order. At 1M keys it
    took 60-70 ms where numpy's quicksort argsort plus np.take took about 95 ms and its stable argsort 185 ms."""
    n = bits.shape[0]
    idx = np.empty(n, np.uint32)
    keys = np.empty(n, np.uint32)
    m = 0
    for i in range(n):
        b = bits[i]
        if (b & np.uint32(0x7F800000)) != np.uint32(0x7F800000):  # finite: not inf or nan
            # IEEE order as unsigned order: flip every bit of a negative number, only the sign bit of the others
            keys[m] = ~b if b & np.uint32(0x80000000) else b | np.uint32(0x80000000)
            idx[m] = i
            m += 1
    keys, idx = keys[:m], idx[:m]
    keys2, idx2 = np.empty_like(keys), np.empty_like(idx)
    radix = 1 << _RADIX_BITS
    mask = np.uint32(radix - 1)
    for shift in range(0, 32, _RADIX_BITS):
        count = np.zeros(radix + 1, np.int64)
        for k in range(m):
            count[((keys[k] >> np.uint32(shift)) & mask) + 1] += 1
        if count.max() == m:  # one bucket holds every key: this digit orders nothing
            continue
        for d in range(radix):
            count[d + 1] += count[d]
        for k in range(m):
            d = (keys[k] >> np.uint32(shift)) & mask
            j = count[d]
            keys2[j] = keys[k]
            idx2[j] = idx[k]
            count[d] = j + 1
        keys, keys2 = keys2, keys
        idx, idx2 = idx2, idx
    out = np.empty((m, boxes.shape[1]), boxes.dtype)
    for k in range(m):
        i = idx[k]
        for c in range(boxes.shape[1]):
            out[k, c] = boxes[i, c]
    return idx, out


def hideable_fraction(boxes: np.ndarray, width: int, height: int) -> float:
    """Rough share of the Gaussians (screen boxes of a `SortResult`) that lie behind saturated pixels.

    Sums each Gaussian's optical mass (column 5: -ln(1 - alpha) integrated over the image) into the
    DEPTH_TILE-pixel tile of its centre. A pixel saturates (the reference rasterizer stops) at optical depth
    D* = -ln(TRANSMITTANCE_THRESHOLD); in a tile of optical depth D > D*, the share of its Gaussians beyond that
    point is about 1 - D*/D, if their mass is spread evenly in depth.
    """
    if not boxes.shape[0]:
        return 0.0
    return _hideable(boxes, -(-int(width) // DEPTH_TILE), -(-int(height) // DEPTH_TILE), float(DEPTH_TILE),
                     -math.log(TRANSMITTANCE_THRESHOLD))


@numba.njit(cache=True, nogil=True)
def _hideable(boxes, nx, ny, tile, saturating):
    """`hideable_fraction` in one pass over the boxes plus one over the tiles (numpy's bincount route took
    20 ms at 1M Gaussians)."""
    depth = np.zeros(nx * ny)
    count = np.zeros(nx * ny)
    for i in range(boxes.shape[0]):
        tx = min(max(int(math.floor(boxes[i, 0] / tile)), 0), nx - 1)
        ty = min(max(int(math.floor(boxes[i, 1] / tile)), 0), ny - 1)
        depth[ty * nx + tx] += boxes[i, 5]
        count[ty * nx + tx] += 1.0
    behind = 0.0
    for k in range(nx * ny):
        d = depth[k] / (tile * tile)
        if d > saturating:
            behind += count[k] * (1.0 - saturating / d)
    return behind / boxes.shape[0]


class AsyncSorter:
    """Sorts in a background thread; the caller draws with the newest finished order meanwhile.

    ``request(splats, camera, t, footprint, tag)`` replaces any pending request (only the latest view matters);
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
        self._thread = threading.Thread(target=self._loop, name="splatreel-sort", daemon=True)
        self._thread.start()

    def request(self, splats: SplatArrays, camera: Camera, t: float, footprint: Footprint = Footprint(),
                tag: object = None) -> None:
        with self._cond:
            self._pending = ((splats, camera, t, footprint), tag)
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
