"""Numba CPU kernels of the tile rasterizer: binning, front-to-back compositing and its backward pass.

Everything here works on plain numpy arrays of *rendered* Gaussians (already projected, culled and sorted front to
back by `splatreel.rasterize`); M is their number, n the number of (tile, Gaussian) intersections, and every
float is float32. The math is the reference 3DGS one (graphdeco-inria/diff-gaussian-rasterization
``cuda_rasterizer/forward.cu`` ``renderCUDA`` and ``backward.cu``; gsplat ``gsplat/cuda/_torch_impl.py``
``_rasterize_to_pixels``):

* pixel (i, j) has its centre at (i + 0.5, j + 0.5); d = mean2d - centre;
* sigma = 1/2 (a dx^2 + c dy^2) + b dx dy with the conic (a, b, c) = inverse 2D covariance;
* alpha = min(MAX_ALPHA, opacity exp(-sigma)); skipped if sigma < 0 or alpha < ALPHA_THRESHOLD;
* front to back, C += f alpha T, T *= 1 - alpha, stopping (without this Gaussian) once T would drop to
  TRANSMITTANCE_THRESHOLD or below.

Kernels are parallel over 16x16 tiles: a tile is owned by one thread, which walks its depth-sorted Gaussian list
serially (the backward pass back to front). An object covers few tiles, often in one half of the image, and numba
splits a ``prange`` statically into equal runs of iterations, so the kernels loop over *bins* of tiles instead, one
per thread, filled by `balance_tiles` to near-equal work (without it two threads ran only 1.25x faster than one). Inside a tile a Gaussian visits only the pixel rows its
alpha >= 1/255 ellipse can reach (with a pixel of slack), and each such row is evaluated across the whole tile width
with the exact per-pixel test, branch-free so that LLVM vectorises it (the "scanline" design of the notes, §3.4,
with SIMD rows). The backward pass writes one gradient slot per intersection, summing the columns of a row in a
fixed tree order, and `reduce_slots` sums each Gaussian's slots in a fixed order: gradients are bit-identical from
run to run and for any thread count. No `fastmath`, and an own exp (`_exp_neg`): the forward and the backward pass
must take exactly the same per-pixel decisions, and IEEE arithmetic without contraction or reassociation
guarantees that.

Compiled code is cached on disk (numba ``cache=True``) under ``$NUMBA_CACHE_DIR`` if the user set it, else under
``$XDG_CACHE_HOME/splatreel/numba`` (``~/.cache/splatreel/numba``), so a read-only install compiles once per machine.
"""

from __future__ import annotations

import os
import tempfile

from splatreel.constants import ALPHA_THRESHOLD, MAX_ALPHA, TILE_SIZE, TRANSMITTANCE_THRESHOLD


def _writable(path: str) -> bool:
    try:
        os.makedirs(path, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
        return True
    except OSError:
        return False


def default_cache_dir() -> str:
    """``$XDG_CACHE_HOME/splatreel/numba``, ``XDG_CACHE_HOME`` defaulting to ``~/.cache``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "splatreel", "numba")


def _configure_cache() -> bool:
    """Point numba's cache at a writable user directory unless the user chose one; False if caching is impossible.

    Must run before the kernels below are decorated (numba picks the cache location at decoration time).
    """
    if not os.environ.get("NUMBA_CACHE_DIR"):
        user = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
        candidates = [default_cache_dir(), os.path.join(tempfile.gettempdir(), f"splatreel-numba-{user}")]
        chosen = next((c for c in candidates if _writable(c)), None)
        if chosen is None:
            return False
        os.environ["NUMBA_CACHE_DIR"] = chosen
    from numba.core import config
    config.reload_config()  # numba may have been imported before the variable was set
    return _writable(os.environ["NUMBA_CACHE_DIR"])


CACHE_ENABLED = _configure_cache()

import numba  # noqa: E402  (after the cache directory is configured)
import numpy as np  # noqa: E402
from llvmlite import ir as llvm_ir  # noqa: E402
from numba import njit, prange  # noqa: E402
from numba.core import types  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

#: Channels composited per Gaussian: r, g, b and camera-space depth (for the expected-depth image).
NUM_CHANNELS = 4
#: Gradient slot layout per intersection / per Gaussian: d mean2d (2), d conic (3), d channels (4), d opacity (1).
NUM_GRADS = 2 + 3 + NUM_CHANNELS + 1
#: Columns of the packed per-Gaussian rows the kernels read: centre (u, v), conic (a, b, c), opacity, the 4
#: channels, then what the row spans need: ext_y (half height of the alpha >= 1/255 ellipse, pixels),
#: det = ac - b^2, 2 a s_max with s_max = ln(255 opacity), b / a and 1 / a. 16 float32 = one cache line.
COL_U, COL_V, COL_A, COL_B, COL_C, COL_O, COL_F = 0, 1, 2, 3, 4, 5, 6
COL_EXTY, COL_DET, COL_2AS, COL_BA, COL_INVA = 10, 11, 12, 13, 14
PACKED = 16

_F = np.float32
# Typed constants: a Python float in a float32 expression would promote it to float64.
_ZERO, _HALF, _ONE, _TWO = _F(0.0), _F(0.5), _F(1.0), _F(2.0)
_ALPHA_MIN = _F(ALPHA_THRESHOLD)
_ALPHA_MAX = _F(MAX_ALPHA)
_T_MIN = _F(TRANSMITTANCE_THRESHOLD)
_DISC_SLACK = _F(1e-3)  # `_rows_touched`: relative slack of the row test
_TILE = TILE_SIZE
_TILE_PIXELS = TILE_SIZE * TILE_SIZE
#: Work of a tile beyond its Gaussians (reading and writing its pixels), in units of one Gaussian, for `balance_tiles`.
_TILE_OVERHEAD = 2

_jit = njit(cache=CACHE_ENABLED, nogil=True)
_pjit = njit(parallel=True, cache=CACHE_ENABLED, nogil=True)


# --- binning -----------------------------------------------------------------------------------------------------
@_jit
def bin_tiles(rects, num_tiles, tiles_x):
    """Counting sort of (tile, Gaussian) pairs into per-tile lists; Gaussians must be in front-to-back order.

    Args:
        rects: ``[R, 4]`` int32 tile rectangle per Gaussian (x0, x1, y0, y1), end exclusive (may be empty).
        num_tiles: tiles_x * tiles_y.
    Returns:
        tile_offsets ``[num_tiles + 1]`` int64: tile t's list is ``flat_ids[tile_offsets[t]:tile_offsets[t+1]]``.
        flat_ids ``[n]`` int32: Gaussian (rank) of each intersection, front to back within a tile.
        isect_slots ``[n]`` int64: where each intersection's gradient goes in the Gaussian-major slot array.
        gauss_offsets ``[R + 1]`` int64: Gaussian r owns slots ``gauss_offsets[r]:gauss_offsets[r+1]``.
    """
    m = rects.shape[0]
    counts = np.zeros(num_tiles + 1, np.int64)
    gauss_offsets = np.zeros(m + 1, np.int64)
    for g in range(m):
        area = 0
        for ty in range(rects[g, 2], rects[g, 3]):
            for tx in range(rects[g, 0], rects[g, 1]):
                counts[ty * tiles_x + tx + 1] += 1
                area += 1
        gauss_offsets[g + 1] = gauss_offsets[g] + area
    tile_offsets = np.cumsum(counts)
    n = tile_offsets[num_tiles]
    flat_ids = np.empty(n, np.int32)
    isect_slots = np.empty(n, np.int64)
    cursor = tile_offsets[:num_tiles].copy()
    for g in range(m):
        slot = gauss_offsets[g]
        for ty in range(rects[g, 2], rects[g, 3]):
            for tx in range(rects[g, 0], rects[g, 1]):
                t = ty * tiles_x + tx
                pos = cursor[t]
                cursor[t] = pos + 1
                flat_ids[pos] = g
                isect_slots[pos] = slot
                slot += 1
    return tile_offsets, flat_ids, isect_slots, gauss_offsets


@_jit
def balance_tiles(work, num_bins):
    """Deal the tiles into `num_bins` bins of near-equal total `work` (``[num_tiles]`` int64 estimates, e.g. list
    lengths): heaviest tile first, each to the bin with the least work so far (longest-processing-time rule).
    Returns (bin_offsets ``[num_bins + 1]`` int64, bin_tiles ``[num_tiles]`` int64): bin b holds the tiles
    ``bin_tiles[bin_offsets[b]:bin_offsets[b+1]]``. Every tile lands in exactly one bin."""
    n = work.shape[0]
    order = np.argsort(-work, kind="mergesort")  # stable: equal work keeps tile order, so bins are reproducible
    load = np.zeros(num_bins, np.int64)
    owner = np.empty(n, np.int64)
    sizes = np.zeros(num_bins + 1, np.int64)
    for t in order:
        b = np.argmin(load)
        owner[t] = b
        load[b] += work[t] + _TILE_OVERHEAD
        sizes[b + 1] += 1
    bin_offsets = np.cumsum(sizes)
    bin_tiles = np.empty(n, np.int64)
    cursor = bin_offsets[:num_bins].copy()
    for t in order:
        bin_tiles[cursor[owner[t]]] = t
        cursor[owner[t]] += 1
    return bin_offsets, bin_tiles


def tile_bins(work):
    """`balance_tiles` into one bin per thread numba uses now (call inside `num_threads`)."""
    return balance_tiles(np.ascontiguousarray(work, dtype=np.int64), max(1, numba.get_num_threads()))


@_jit
def backward_work(last_ids, tiles_x, tiles_y):
    """``[tiles]`` int64 work of each tile's backward pass: 1 + the deepest list position any of its pixels
    composited (`composite_forward`'s ``out_last``); the backward walk starts there."""
    height, width = last_ids.shape
    work = np.zeros(tiles_x * tiles_y, np.int64)
    for py in range(height):
        for px in range(width):
            t = (py // _TILE) * tiles_x + px // _TILE
            work[t] = max(work[t], last_ids[py, px] + 1)
    return work


def pack_gaussians(means2d, conics, channels, opacities, s_max, ext_y):
    """``[R, PACKED]`` float32 rows (one 64-byte cache line per Gaussian, columns ``COL_*``) from per-Gaussian
    float32 arrays already in front-to-back order: means2d ``[R, 2]``, conics ``[R, 3]``, channels ``[R, 4]``,
    opacities, s_max and ext_y ``[R]``."""
    packed = np.zeros((means2d.shape[0], PACKED), np.float32)
    a, b, c = conics[:, 0], conics[:, 1], conics[:, 2]
    packed[:, COL_U:COL_V + 1] = means2d
    packed[:, COL_A:COL_C + 1] = conics
    packed[:, COL_O] = opacities
    packed[:, COL_F:COL_F + NUM_CHANNELS] = channels
    packed[:, COL_EXTY] = ext_y
    packed[:, COL_DET] = a * c - b * b
    packed[:, COL_2AS] = _TWO * a * s_max
    packed[:, COL_BA] = b / a
    packed[:, COL_INVA] = _ONE / a
    return packed


# --- exp ----------------------------------------------------------------------------------------------------------
# exp(-sigma) in float32 arithmetic (Cephes expf: range reduction by ln 2 split in two, degree-5 polynomial, scale
# by 2^-n built from its bits; max relative error 1.4 ulp). Unlike the libm call numba makes for np.exp it
# vectorises, and it is plain IEEE operations, so the forward and backward kernels compute bit-identical alphas.
_LOG2E = _F(1.4426950408889634)
_LN2_HI, _LN2_LO = _F(0.693359375), _F(-2.12194440e-4)
_P0, _P1, _P2 = _F(1.9875691500e-4), _F(1.3981999507e-3), _F(8.3334519073e-3)
_P3, _P4, _P5 = _F(4.1665795894e-2), _F(1.6666665459e-1), _F(5.0000001201e-1)
_EXP_MAX = _F(87.0)  # exp(-87) ~ 1.6e-38, the smallest scale kept normal; larger sigma is clamped to it


@intrinsic
def _float_from_bits(typingctx, bits):
    """Reinterpret an int32 as a float32 (LLVM bitcast)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], llvm_ir.FloatType())
    return types.float32(types.int32), codegen


@njit(inline="always", cache=CACHE_ENABLED)
def _exp_neg(sigma):
    """exp(-sigma) for float32 sigma, with sigma clamped to [0, 87]. Branch-free (selects only)."""
    s = sigma if sigma > _ZERO else _ZERO
    s = s if s < _EXP_MAX else _EXP_MAX
    n = np.floor(s * _LOG2E + _HALF)  # exp(-s) = 2^-n exp(r), |r| <= ln2 / 2, n in [0, 126]
    r = (n * _LN2_HI - s) + n * _LN2_LO
    p = ((((_P0 * r + _P1) * r + _P2) * r + _P3) * r + _P4) * r + _P5
    return (p * r * r + r + _ONE) * _float_from_bits((np.int32(127) - np.int32(n)) << np.int32(23))


# --- shared per-pair geometry ------------------------------------------------------------------------------------
@_jit
def _rows_touched(gauss, g, x0, y0, x1, y1, rows):
    """Write to `rows` the pixel rows of the tile [x0, x1) x [y0, y1) that may hold pixels of Gaussian g passing
    the alpha test; return how many. Rows are evaluated whole; this only skips the others.

    The alpha >= 1/255 ellipse spans |dy| <= ext_y, and on the row at offset dy the columns
    i = u - 0.5 - dx with dx = (-b dy +- sqrt(2 a s_max - det dy^2)) / a. A row whose discriminant is negative
    has no pixel below s_max (its smallest sigma, det dy^2 / 2a, is larger), so it is skipped: a third of the
    rows of the small Gaussians of a trained model. Slack, so that rounding never drops a pixel the exact test
    would accept: one pixel on every side, and a discriminant may be short by 0.1% of 2 a s_max.
    """
    v, ext_y = gauss[g, COL_V], gauss[g, COL_EXTY]
    lo = max(np.floor(v - _HALF - ext_y) - _ONE, _F(y0))
    hi = min(np.ceil(v - _HALF + ext_y) + _ONE, _F(y1 - 1))
    count = 0
    if lo > hi:
        return count
    for py in range(int(lo), int(hi) + 1):
        dy = v - (_F(py) + _HALF)
        disc = gauss[g, COL_2AS] - gauss[g, COL_DET] * dy * dy
        half = np.sqrt(max(disc, _ZERO)) * gauss[g, COL_INVA]
        centre = gauss[g, COL_U] - _HALF + gauss[g, COL_BA] * dy
        if (disc >= -_DISC_SLACK * gauss[g, COL_2AS] and np.floor(centre - half) - _ONE <= _F(x1 - 1)
                and np.ceil(centre + half) + _ONE >= _F(x0)):
            rows[count] = py
            count += 1
    return count


@njit(inline="always", cache=CACHE_ENABLED)
def _tile_bounds(tile, tiles_x, width, height):
    """Pixel bounds (x0, y0, x1, y1), end exclusive, of tile number `tile` (row-major)."""
    x0, y0 = (tile % tiles_x) * _TILE, (tile // tiles_x) * _TILE
    return x0, y0, min(x0 + _TILE, width), min(y0 + _TILE, height)


@njit(inline="always", cache=CACHE_ENABLED)
def _unpack(gauss, g):
    """(u, v, a, b, c, opacity, f0, f1, f2, f3) of packed Gaussian g."""
    return (gauss[g, COL_U], gauss[g, COL_V], gauss[g, COL_A], gauss[g, COL_B], gauss[g, COL_C], gauss[g, COL_O],
            gauss[g, COL_F], gauss[g, COL_F + 1], gauss[g, COL_F + 2], gauss[g, COL_F + 3])


@njit(inline="always", cache=CACHE_ENABLED)
def _pixel_alpha(a, b, c, o, dx, dy):
    """(sigma, exp(-sigma), o exp(-sigma), alpha) at offset d = mean - pixel centre: the one place both passes
    evaluate a Gaussian, so that they take the same decisions."""
    sigma = _HALF * (a * dx * dx + c * dy * dy) + b * dx * dy
    vis = _exp_neg(sigma)
    ov = o * vis
    return sigma, vis, ov, (ov if ov < _ALPHA_MAX else _ALPHA_MAX)


# The per-row loops below run over all the tile's columns (a runtime trip count), branch-free (selects only), with
# unsigned indices (no negative-index wraparound) and per-pixel state in separate arrays, so that LLVM vectorises
# them (AVX2/AVX-512). Every pixel gets the exact alpha test; the row/column ranges only skip rows.


# --- forward -----------------------------------------------------------------------------------------------------
@_pjit
def composite_forward(gauss, background, tile_offsets, flat_ids, bin_offsets, bin_tiles, width, height, tiles_x,
                      out_channels, out_transmittance, out_last):
    """Front-to-back compositing of every tile.

    Args:
        gauss: ``[R, PACKED]`` rows from `pack_gaussians`.
        background ``[4]``: added as T_final * background.
        tile_offsets, flat_ids: from `bin_tiles`.
        bin_offsets, bin_tiles: from `balance_tiles` (every tile exactly once).
    Writes:
        out_channels ``[H, W, 4]``: sum f alpha T + T_final background.
        out_transmittance ``[H, W]``: T_final.
        out_last ``[H, W]`` int32: position, in its tile's list, of the last Gaussian composited (-1: none).
    """
    for b in prange(bin_offsets.shape[0] - 1):
        for j in range(bin_offsets[b], bin_offsets[b + 1]):
            _forward_tile(bin_tiles[j], gauss, background, tile_offsets, flat_ids, width, height, tiles_x,
                          out_channels, out_transmittance, out_last)


@njit(inline="always", cache=CACHE_ENABLED, nogil=True)
def _forward_tile(tile, gauss, background, tile_offsets, flat_ids, width, height, tiles_x, out_channels,
                  out_transmittance, out_last):
    """`composite_forward` of one tile."""
    x0, y0, x1, y1 = _tile_bounds(tile, tiles_x, width, height)
    nx = x1 - x0
    num_px = nx * (y1 - y0)
    trans = np.ones(_TILE_PIXELS, np.float32)
    acc = np.zeros((NUM_CHANNELS, _TILE_PIXELS), np.float32)  # one contiguous row per channel
    acc0, acc1, acc2, acc3 = acc[0], acc[1], acc[2], acc[3]
    last = np.full(_TILE_PIXELS, -1, np.int32)
    done = np.zeros(_TILE_PIXELS, np.int32)
    rows = np.empty(_TILE, np.int64)
    num_done = 0
    start = tile_offsets[tile]
    for k in range(start, tile_offsets[tile + 1]):
        if num_done == num_px:
            break  # every pixel of the tile is saturated
        g = flat_ids[k]
        u, v, a, b, c, o, f0, f1, f2, f3 = _unpack(gauss, g)
        rank = np.int32(k - start)
        for r in range(_rows_touched(gauss, g, x0, y0, x1, y1, rows)):
            dy = v - (_F(rows[r]) + _HALF)
            row = np.uint64((rows[r] - y0) * _TILE)
            stopped = 0
            for i in range(nx):
                p = row + np.uint64(i)
                dx = u - (_F(x0 + i) + _HALF)
                sigma, _, _, alpha = _pixel_alpha(a, b, c, o, dx, dy)
                t = trans[p]
                t_next = t * (_ONE - alpha)
                hit = (sigma >= _ZERO) & (alpha >= _ALPHA_MIN) & (done[p] == 0)
                stop = hit & (t_next <= _T_MIN)  # saturates: this Gaussian is excluded, the pixel is done
                take = hit & (t_next > _T_MIN)
                w = alpha * t if take else _ZERO
                acc0[p] += w * f0
                acc1[p] += w * f1
                acc2[p] += w * f2
                acc3[p] += w * f3
                trans[p] = t_next if take else t
                last[p] = rank if take else last[p]
                done[p] = 1 if stop else done[p]
                stopped += 1 if stop else 0
            num_done += stopped
    for py in range(y0, y1):
        for px in range(x0, x1):
            p = (py - y0) * _TILE + (px - x0)
            t = trans[p]
            out_channels[py, px, 0] = acc0[p] + t * background[0]
            out_channels[py, px, 1] = acc1[p] + t * background[1]
            out_channels[py, px, 2] = acc2[p] + t * background[2]
            out_channels[py, px, 3] = acc3[p] + t * background[3]
            out_transmittance[py, px] = t
            out_last[py, px] = last[p]


# --- backward ----------------------------------------------------------------------------------------------------
@_pjit
def composite_backward(gauss, background, tile_offsets, flat_ids, isect_slots, bin_offsets, bin_tiles, width, height,
                       tiles_x, transmittance, last_ids, grad_channels, grad_alpha, out_slots):
    """Gradients of `composite_forward` per intersection, back to front from each pixel's last Gaussian.

    With T_k the transmittance in front of Gaussian k and S the channels composited behind it::

        dC/dalpha_k = f_k T_k - (S + T_final bg) / (1 - alpha_k),   dA/dalpha_k = T_final / (1 - alpha_k)

    T_k is recovered from T_final by division (alpha <= 0.99 keeps it stable). When the 0.99 clamp is active, sigma
    and the opacity get no gradient. Each (tile, Gaussian) slot of ``out_slots [n, NUM_GRADS]`` is written exactly
    once: (d u, d v, d a, d b, d c, d f_0..3, d opacity), with d b the full dx dy coefficient. Per-column partial
    sums are added up in a fixed tree order, so the result does not depend on threads.

    Args:
        transmittance, last_ids: ``[H, W]`` from `composite_forward`.
        grad_channels ``[H, W, 4]``, grad_alpha ``[H, W]``: incoming gradients of out_channels and 1 - T_final.
        bin_offsets, bin_tiles: from `balance_tiles` (every tile exactly once).
    """
    for b in prange(bin_offsets.shape[0] - 1):
        for j in range(bin_offsets[b], bin_offsets[b + 1]):
            _backward_tile(bin_tiles[j], gauss, background, tile_offsets, flat_ids, isect_slots, width, height,
                           tiles_x, transmittance, last_ids, grad_channels, grad_alpha, out_slots)


@njit(inline="always", cache=CACHE_ENABLED, nogil=True)
def _backward_tile(tile, gauss, background, tile_offsets, flat_ids, isect_slots, width, height, tiles_x,
                   transmittance, last_ids, grad_channels, grad_alpha, out_slots):
    """`composite_backward` of one tile."""
    x0, y0, x1, y1 = _tile_bounds(tile, tiles_x, width, height)
    nx = x1 - x0
    trans = np.ones(_TILE_PIXELS, np.float32)
    behind = np.zeros((NUM_CHANNELS, _TILE_PIXELS), np.float32)  # channels composited behind, per pixel
    behind0, behind1, behind2, behind3 = behind[0], behind[1], behind[2], behind[3]
    grad = np.zeros((NUM_CHANNELS, _TILE_PIXELS), np.float32)  # dL/d(output channels), per pixel
    grad0, grad1, grad2, grad3 = grad[0], grad[1], grad[2], grad[3]
    # dL/dalpha_k gets (T_final dL/dA - T_final bg . dL/dC) / (1 - alpha_k): the per-pixel factor below
    grad_final = np.zeros(_TILE_PIXELS, np.float32)
    last = np.full(_TILE_PIXELS, -1, np.int32)
    columns = np.zeros((NUM_GRADS, _TILE), np.float32)  # per-column partial sums of one slot
    rows = np.empty(_TILE, np.int64)
    k_max = -1
    for py in range(y0, y1):
        for px in range(x0, x1):
            p = (py - y0) * _TILE + (px - x0)
            t_final = transmittance[py, px]
            d0, d1 = grad_channels[py, px, 0], grad_channels[py, px, 1]
            d2, d3 = grad_channels[py, px, 2], grad_channels[py, px, 3]
            trans[p] = t_final
            grad0[p], grad1[p], grad2[p], grad3[p] = d0, d1, d2, d3
            bg_dot = background[0] * d0 + background[1] * d1 + background[2] * d2 + background[3] * d3
            grad_final[p] = t_final * (grad_alpha[py, px] - bg_dot)
            last[p] = last_ids[py, px]
            k_max = max(k_max, last_ids[py, px])
    start = tile_offsets[tile]
    for kk in range(k_max, -1, -1):
        k = start + kk
        g = flat_ids[k]
        u, v, a, b, c, o, f0, f1, f2, f3 = _unpack(gauss, g)
        rank = np.int32(kk)
        columns[:, :] = _ZERO
        for r in range(_rows_touched(gauss, g, x0, y0, x1, y1, rows)):
            dy = v - (_F(rows[r]) + _HALF)
            row = np.uint64((rows[r] - y0) * _TILE)
            for i in range(nx):
                col = np.uint64(i)
                p = row + col
                dx = u - (_F(x0 + i) + _HALF)
                sigma, vis, ov, alpha = _pixel_alpha(a, b, c, o, dx, dy)
                hit = (last[p] >= rank) & (sigma >= _ZERO) & (alpha >= _ALPHA_MIN)
                ra = _ONE / (_ONE - alpha)
                t_behind = trans[p]
                t = t_behind * ra if hit else t_behind  # T_k, the transmittance in front of this Gaussian
                trans[p] = t
                w = alpha * t if hit else _ZERO
                d0, d1, d2, d3 = grad0[p], grad1[p], grad2[p], grad3[p]
                s0, s1, s2, s3 = behind0[p], behind1[p], behind2[p], behind3[p]
                g_alpha = ((f0 * t - s0 * ra) * d0 + (f1 * t - s1 * ra) * d1 + (f2 * t - s2 * ra) * d2
                           + (f3 * t - s3 * ra) * d3 + grad_final[p] * ra)
                behind0[p] = s0 + f0 * w
                behind1[p] = s1 + f1 * w
                behind2[p] = s2 + f2 * w
                behind3[p] = s3 + f3 * w
                unclamped = hit & (ov <= _ALPHA_MAX)
                g_sigma = -ov * g_alpha if unclamped else _ZERO
                columns[0, col] += g_sigma * (a * dx + b * dy)
                columns[1, col] += g_sigma * (b * dx + c * dy)
                columns[2, col] += _HALF * g_sigma * dx * dx
                columns[3, col] += g_sigma * dx * dy
                columns[4, col] += _HALF * g_sigma * dy * dy
                columns[5, col] += w * d0
                columns[6, col] += w * d1
                columns[7, col] += w * d2
                columns[8, col] += w * d3
                columns[9, col] += vis * g_alpha if unclamped else _ZERO
        half = _TILE // 2
        while half > 0:  # fixed pairwise order
            for j in range(NUM_GRADS):
                for i in range(half):
                    columns[j, i] += columns[j, i + half]
            half //= 2
        s = isect_slots[k]
        for j in range(NUM_GRADS):
            out_slots[s, j] = columns[j, 0]


@_pjit
def reduce_slots(slots, gauss_offsets, order, out):
    """``out[order[r]] = sum of slots[gauss_offsets[r]:gauss_offsets[r+1]]`` (in slot order, float64 accumulation):
    per-Gaussian gradients back in the caller's index order. Rows of `out` not in `order` are left alone."""
    m = gauss_offsets.shape[0] - 1
    width = slots.shape[1]
    for r in prange(m):
        acc = np.zeros(width, np.float64)
        for s in range(gauss_offsets[r], gauss_offsets[r + 1]):
            for j in range(width):
                acc[j] += slots[s, j]
        for j in range(width):
            out[order[r], j] = np.float32(acc[j])


def max_threads() -> int:
    """Threads numba may use (``NUMBA_NUM_THREADS``, by default the number of cores)."""
    return numba.config.NUMBA_NUM_THREADS


class num_threads:
    """Context manager running the kernels with `n` threads (None: leave numba's setting alone)."""

    def __init__(self, n: int | None):
        self.n = n
        self.saved: int | None = None

    def __enter__(self) -> "num_threads":
        if self.n is not None:
            self.saved = numba.get_num_threads()
            numba.set_num_threads(max(1, min(int(self.n), max_threads())))
        return self

    def __exit__(self, *exc) -> None:
        if self.saved is not None:
            numba.set_num_threads(self.saved)
