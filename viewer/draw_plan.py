"""How the draw pass batches a frame's splats: pure numpy over the sort's screen boxes (`SortResult.boxes`), no GL.

Each batch of splats is drawn as GL points or instanced quads, whichever a cost model says is cheaper, in contiguous
runs (`splat_runs`). Front to back, a long order is drawn in stages (`draw_stages`); between stages the renderer
reads back which tiles of the image are saturated (`saturated_table`), and the Gaussians whose screen box lies
entirely in saturated tiles are skipped (`hidden_in_tiles`). An order sorted for an image of another resolution has
its boxes rescaled first (`rescaled_boxes`).
"""

from __future__ import annotations

import math

import numpy as np

from splatreel.cameras import Camera
from splatreel.constants import ALPHA_THRESHOLD, EPS2D
from splatreel.errors import GLError

from .sorting import SortResult

#: Front to back, splats are drawn in stages with early-stop masks in between; a stage has at least this many
#: Gaussians (the masks would cost more than they save) ...
MIN_STAGE = 2048
#: ... and fewer than this many visible Gaussians are drawn in one stage.
MIN_STAGED = 16384
#: Staging (and its read-backs, which stall the pipeline) only pays when at least this share of the visible
#: Gaussians is expected to lie behind saturated pixels (`SortResult.hideable`). Measured on llvmpipe: estimates
#: of 0.32-0.38 drew 10-30% faster in one stage, 0.63 and above 1.5-6x faster staged.
MIN_HIDEABLE = 0.5
#: Tile edge (pixels) of the saturation read-back used to skip hidden Gaussians.
OCCLUSION_TILE = 4
#: Modes drawn with points when the primitive allows; outlines and centres need the quad's own footprint.
POINT_MODES = ("color", "depth", "alpha", "speed", "lifespan", "fade")
#: What a quad costs more than a point, in shaded pixels (llvmpipe, 2 cores: ~1.2 us vs ~0.3 us per splat set-up,
#: ~3.4 ns per pixel); `splat_runs` weighs it against the points' extra pixels.
QUAD_EXTRA_COST = 260.0
#: At most this many alternating point/quad runs per batch; beyond, the batch is drawn as quads in one call.
MAX_RUNS = 16


def splat_runs(boxes: np.ndarray, mode: str, primitive: str, *, image_size: tuple[int, int], max_point: float,
               point_margin: int, max_viewport: int, stale: bool = False) -> list[tuple[int, int, str]]:
    """How to draw a batch of Gaussians (screen boxes `boxes`, see `SortResult`, in draw order) in render `mode`
    with splat `primitive` (`render_settings.PRIMITIVES`): contiguous runs ``(first, end, kind)``, kind one of
    "points", "quads" (instanced) or "overlay" (quads of the outline/centre modes).

    The context draws points up to `max_point` pixels wide, through a viewport reaching `point_margin` pixels past
    every edge of the `image_size` image, which must stay within `max_viewport`. "auto" draws as points every
    Gaussian that fits the largest point (with 2x headroom when the boxes are `stale`, i.e. sorted for another
    view), unless the cost model says quads are cheaper for the batch; the rest as quads. The model was measured
    on llvmpipe, in pixel-equivalents: a point shades its whole bounding square but costs little to set up; a quad
    shades only its oriented rectangle but costs `QUAD_EXTRA_COST` pixels more (two triangles, four vertices).
    Points win for small or round splats, quads for large elongated ones. Raises GLError (one line) when "points"
    cannot draw the batch.
    """
    n = boxes.shape[0]
    if mode not in POINT_MODES:
        return [(0, n, "overlay")]
    if primitive == "quads" or not n:
        return [(0, n, "quads")]
    if max(image_size) + 2 * point_margin > max_viewport:
        if primitive == "points":
            raise GLError(f"a {image_size[0]}x{image_size[1]} image is too large to draw with points on this "
                          f"context (viewport limit {max_viewport}); use the 'auto' or 'quads' primitive")
        return [(0, n, "quads")]
    side = 2.0 * np.maximum(boxes[:, 2], boxes[:, 3]) - 1.0  # the point size splat_draw.glsl asks for
    if primitive == "points":
        if float(side.max()) > max_point:
            raise GLError(f"splats up to {float(side.max()):.0f} px wide do not fit this context's points (at "
                          f"most {max_point:.0f} px); use the 'auto' or 'quads' primitive")
        return [(0, n, "points")]
    fits = side <= (0.5 if stale else 1.0) * max_point
    extra = float(np.sum(side[fits] ** 2, dtype=np.float64) - np.sum(boxes[fits, 4], dtype=np.float64))
    if not fits.any() or extra >= QUAD_EXTRA_COST * int(fits.sum()):
        return [(0, n, "quads")]
    change = np.flatnonzero(fits[1:] != fits[:-1]) + 1
    bounds = [0, *change.tolist(), n]
    if len(bounds) - 1 > MAX_RUNS:  # oversized splats scattered through the batch: one draw call instead
        return [(0, n, "quads")]
    return [(a, b, "points" if fits[a] else "quads") for a, b in zip(bounds[:-1], bounds[1:])]


def rescaled_boxes(order: SortResult, camera: Camera) -> np.ndarray:
    """The screen boxes of `order` (`SortResult.boxes`) in the pixels of `camera`'s image when the order was sorted
    for an image of another resolution (the app lowers it while the view moves): centres map through the two
    cameras' intrinsics; a half-size h = sqrt(rr (s^2 + EPS2D)) + 1 px (`sorting._depth_key`, s the footprint's
    std-dev in pixels) becomes at most k (h - 1) + 1 + sqrt(rr EPS2D (1 - k^2)) when s scales by k (the EPS2D blur
    does not scale; rr <= 2 ln(1 / ALPHA_THRESHOLD)); areas and masses scale with kx ky. A std-dev cap leaves rr
    alone; a screen-radius cap does not (it reshapes a splat whose major axis changes with kx / ky), so `render`
    sorts such orders again instead. Same-size orders are returned as they are."""
    key = order.key
    if key is None or key.intrinsics[4:] == (camera.width, camera.height):
        return order.boxes
    fx, fy, cx, cy = key.intrinsics[:4]
    kx, ky = camera.fx / fx, camera.fy / fy
    rr_eps = 2.0 * math.log(1.0 / ALPHA_THRESHOLD) * EPS2D
    b = order.boxes.copy()
    b[:, 0] = (b[:, 0] - cx) * kx + camera.cx
    b[:, 1] = (b[:, 1] - cy) * ky + camera.cy
    b[:, 2] = (b[:, 2] - 1.0) * kx + 1.0 + math.sqrt(rr_eps * max(0.0, 1.0 - kx * kx))
    b[:, 3] = (b[:, 3] - 1.0) * ky + 1.0 + math.sqrt(rr_eps * max(0.0, 1.0 - ky * ky))
    b[:, 4:6] *= kx * ky
    return b


def draw_stages(count: int) -> list[tuple[int, int]]:
    """[first, end) draw stages of a front-to-back order: the nearest 1/128, then each stage as long as all before
    it (1/128, 1/64, ... 1/2, the rest); stages shorter than MIN_STAGE are merged into the next."""
    if count < MIN_STAGED:
        return [(0, count)]
    ends = [count >> k for k in range(7, 0, -1)] + [count]
    out, first = [], 0
    for end in ends:
        if end - first >= MIN_STAGE or end == count:
            out.append((first, end))
            first = end
    return out


def saturated_table(saturated: np.ndarray) -> np.ndarray:
    """Summed-area table ``[ty + 1, tx + 1]`` of `saturated` tile flags given top row first.

    The tiles are counted from the image's lower-left corner (GL's origin), so when the height is not a multiple of
    OCCLUSION_TILE the top row of tiles hangs over the image top by `pad` pixels; `hidden_in_tiles` shifts boxes by
    that.
    """
    table = np.zeros((saturated.shape[0] + 1, saturated.shape[1] + 1), np.int32)
    table[1:, 1:] = saturated.cumsum(0).cumsum(1)
    return table


def hidden_in_tiles(boxes: np.ndarray, table: np.ndarray, height: int) -> np.ndarray:
    """``[M]`` bool: the screen box (u, v, hx, hy, ...) of each Gaussian lies entirely in saturated tiles (`table`,
    from `saturated_table` for an image `height` pixels high)."""
    th, tw = table.shape[0] - 1, table.shape[1] - 1
    pad = th * OCCLUSION_TILE - height  # tiles start at the bottom edge: shift y (top-down) by the overhang
    u, v, hx, hy = boxes[:, 0], boxes[:, 1] + pad, boxes[:, 2], boxes[:, 3]
    x0 = np.clip(np.floor((u - hx) / OCCLUSION_TILE), 0, tw - 1).astype(np.int64)
    x1 = np.clip(np.floor((u + hx) / OCCLUSION_TILE), 0, tw - 1).astype(np.int64) + 1
    y0 = np.clip(np.floor((v - hy) / OCCLUSION_TILE), 0, th - 1).astype(np.int64)
    y1 = np.clip(np.floor((v + hy) / OCCLUSION_TILE), 0, th - 1).astype(np.int64) + 1
    count = table[y1, x1] - table[y0, x1] - table[y1, x0] + table[y0, x0]
    return count == (x1 - x0) * (y1 - y0)

