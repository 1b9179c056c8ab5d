"""The moderngl splat renderer (OpenGL 3.3 core; the same code draws on EGL without a display and in a window).

Per frame, three GL passes:

1. **pre-pass** (``shaders/splat_preprocess.glsl``): one vertex-shader invocation per drawn Gaussian evaluates the
   model at time t and projects it; the Gaussians are fed as GL_POINTS through an index buffer holding the depth
   order at t (`splatreel.viewer.sorting`), and transform feedback writes their 2D footprints in that order. Doing
   this once per Gaussian instead of once per quad corner is what makes a software rasterizer (Mesa llvmpipe)
   usable.
2. **draw** (``splat_draw.glsl``): one splat per footprint, a GL point sprite over its bounding box or an
   instanced quad along its axes, whichever is cheaper (`draw_plan.splat_runs`; quads always for the
   outline/centre modes and for Gaussians larger than the biggest point), premultiplied alpha into a float32
   target cleared to 0, so colour = sum c a T and alpha = 1 - T exactly as the reference rasterizer composites.
   Either back to front (ONE, ONE_MINUS_SRC_ALPHA), or (default) front to back (ONE_MINUS_DST_ALPHA, ONE). Front
   to back and when enough Gaussians can be hidden (`SortResult.hideable`), in stages: between stages, pixels whose
   transmittance reached TRANSMITTANCE_THRESHOLD (where the reference stops) are masked in the depth buffer and
   their tiles read back (``splat_screen.glsl``), so that later Gaussians hidden behind them are rejected per
   fragment or skipped entirely. Same image, far less work in dense scenes.
3. **resolve** (``splat_screen.glsl``): background, depth colour map or alpha view, into the display target
   (an offscreen float texture, or the window).

The per-Gaussian data of a native 4D or skinned model is uploaded once (a skinned model's node poses, a small
texture, when t changes: `splatreel.viewer.skinning`); a keyframed model is re-sliced and re-uploaded when t
changes. The order is recomputed whenever the camera, t or the splat scale changed.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from splatreel.cameras import Camera
from splatreel.constants import TILE_SIZE
from splatreel.errors import GLError
from splatreel.gl import EGLCurrent, create_headless_context, load_program, with_context

from . import splats as splatlib
from .draw_plan import (MIN_HIDEABLE, OCCLUSION_TILE, POINT_MODES, draw_stages, hidden_in_tiles, rescaled_boxes,
                        saturated_table, splat_runs)
from .gpu_buffers import SPLAT_BYTES, SPLAT_FIELDS, RenderTargets, SplatBuffers, set_uniforms, sh_texture_size
from .pick import PixelStack, composite_pixel
from .render_settings import COMPOSITE_ORDERS, RENDER_MODES, VALUE_MODES, FrameStats, RenderSettings
from .skinning import NODE_TEXELS, POSE_SETS
from .sorting import Footprint, SortKey, SortResult, depth_order, footprint_caps

# the settings' names come with the renderer's: callers import its whole API from here
__all__ = ["COMPOSITE_ORDERS", "RENDER_MODES", "VALUE_MODES", "FrameStats", "RenderSettings", "SplatRenderer",
           "headless_context", "render_image"]

class SplatRenderer:
    """Draws a splatreel model with a moderngl context (standalone EGL or a window's).

    Typical use::

        r = SplatRenderer(ctx, model)
        stats = r.render(camera, t, RenderSettings(background=(1, 1, 1)))
        rgba = r.read_display()            # [H, W, 4] float32, top row first

    `render` sorts synchronously when the view changed (offline rendering); an interactive caller can instead
    pass its own (possibly slightly stale) `SortResult` via ``order=``.
    """

    def __init__(self, ctx, model=None) -> None:
        if ctx.version_code < 330:
            raise GLError(f"OpenGL 3.3 or newer is required, this context offers {ctx.version_code}")
        self.ctx = ctx
        self._gl_depth = 0
        self._init_programs()
        self._pre_progs: dict[tuple, object] = {}
        self._targets: RenderTargets | None = None
        self._gpu: SplatBuffers | None = None
        self._model = None
        self._typical_speed: float | None = None
        self.splats: splatlib.SplatArrays | None = None
        self._order: SortResult | None = None
        if model is not None:
            self.set_model(model)

    @with_context
    def _init_programs(self) -> None:
        ctx = self.ctx
        # one splat program per kind: "quads" and "points" draw colour, depth and alpha; "overlay" draws the
        # outline and centre modes (as quads). Kept apart because llvmpipe runs uniform branches as masked code,
        # which would cost the overlay modes' shading on every fragment.
        self._splat_progs = {kind: load_program(ctx, "splat_draw", {f"SPLAT_{kind.upper()}": 1})
                             for kind in ("quads", "points", "overlay")}
        # Points are clipped by their centre: draw them through a viewport reaching `_point_margin` pixels past
        # every edge of the image, so that a point reaching into the image always has its centre inside.
        largest = float((ctx.info.get("GL_POINT_SIZE_RANGE") or (1.0, 1.0))[1])
        self._max_point = min(largest, 1024.0)
        self._point_margin = int(math.ceil(self._max_point / 2)) + 1
        self._max_viewport = min(int(v) for v in (ctx.info.get("GL_MAX_VIEWPORT_DIMS") or (16384, 16384)))
        self._resolve_prog, self._mask_prog, self._tiles_prog = (
            load_program(ctx, "splat_screen", {"SCREEN_PASS": k, "OCCLUSION_TILE": OCCLUSION_TILE}) for k in range(3))
        self._resolve_vao = ctx.vertex_array(self._resolve_prog, [])
        self._mask_vao = ctx.vertex_array(self._mask_prog, [])
        self._tiles_vao = ctx.vertex_array(self._tiles_prog, [])

    # --- model ------------------------------------------------------------------------------------------------
    @property
    def model(self):
        return self._model

    @property
    def per_frame_upload(self) -> bool:
        return splatlib.needs_per_frame_upload(self._model)

    @with_context
    def set_model(self, model, t: float | None = None, arrays: splatlib.SplatArrays | None = None) -> None:
        """Use `model` (Gaussians4D, KeyframedGaussians, SkinnedGaussians, Gaussians3D or ready `SplatArrays`);
        `arrays`: its arrays (at `t` for a keyframed model) when at hand, e.g. `SplatArrays.select` of a larger
        model's."""
        if arrays is None:
            arrays = model if isinstance(model, splatlib.SplatArrays) else splatlib.to_arrays(model, t)
        self._model = model
        self._typical_speed = None  # the speed mode's colour map top, made on first use (`typical_speed`)
        self._order = None  # an order of other Gaussians, even when they are as many (another crop box)
        self._upload(arrays)

    def _default_value_range(self, mode: str, order: SortResult, splats) -> tuple[float, float]:
        """The colour map's ends when the settings give none: the order's depth range, 0 to the model's typical
        speed, 0 to its time span (`RenderSettings.value_range`)."""
        if mode == "speed":
            return 0.0, self.typical_speed()
        if mode == "lifespan":
            return 0.0, splats.duration
        if mode == "fade":
            return 0.0, 1.0
        return order.depth_range

    def typical_speed(self) -> float:
        """The model's `splats.typical_speed` (the speed mode's default colour map top), computed once per model
        and only when the speed mode asks (a keyframed model's runs over every key segment)."""
        if self._typical_speed is None:
            self._typical_speed = splatlib.typical_speed(self._model, self.splats)
        return self._typical_speed

    def _upload(self, arrays: splatlib.SplatArrays) -> None:
        n, texels = len(arrays), arrays.sh_texels
        attrs = arrays.attributes()
        max_size = int(self.ctx.info.get("GL_MAX_TEXTURE_SIZE", 16384))
        width, rows = sh_texture_size(n, texels, arrays.num_coeffs, max_size)
        sh = np.zeros((rows * width, 4), np.float32)
        sh[: n * texels] = arrays.sh.reshape(-1, 4)
        old, gpu = self.splats, self._gpu
        skinned = arrays.skin is not None
        if (gpu is not None and gpu.count == n and old.sh_texels == texels and gpu.sh.size == (width, rows)
                and (old.sh_degree, old.sh_degree_t) == (arrays.sh_degree, arrays.sh_degree_t)
                and not skinned and old.skin is None):
            gpu.write(attrs, sh)  # keyframed re-slice: rewrite in place
        else:
            self._release_model()
            prog = self._pre_program(arrays.sh_degree, arrays.sh_degree_t, texels, width, skinned)
            node_size = (POSE_SETS * NODE_TEXELS, arrays.skin.keys.count) if skinned else None
            self._gpu = SplatBuffers.create(self.ctx, attrs, sh, (width, rows), prog, self._splat_progs, node_size)
        self.splats = arrays

    def _release_model(self) -> None:
        if self._gpu is not None:
            self._gpu.release()
            self._gpu = None

    def _pre_program(self, degree: int, degree_t: int, texels: int, width: int, skinned: bool = False):
        key = (degree, degree_t, texels, width, skinned)
        if key not in self._pre_progs:
            self._pre_progs[key] = load_program(
                self.ctx, "splat_preprocess",
                {"SH_DEGREE": degree, "SH_DEGREE_T": degree_t, "SH_TEXELS": texels, "SH_TEX_WIDTH": width,
                 "TILE_SIZE": TILE_SIZE, "SKINNED": int(skinned)},
                varyings=["o_geom", "o_axes", "o_color", "o_rect"], varyings_capture_mode="interleaved")
        return self._pre_progs[key]

    @with_context
    def splats_at(self, t: float) -> splatlib.SplatArrays:
        """The GPU arrays valid at time `t` (re-slices and re-uploads a keyframed model when t changed; a skinned
        model's node poses alone, `SplatBuffers.pose_nodes`)."""
        if self.splats is None:
            raise GLError("no model loaded")
        if self.per_frame_upload and self.splats.time != float(t):
            self._upload(splatlib.to_arrays(self._model, float(t)))
        if self.splats.skin is not None:
            self._gpu.pose_nodes(self.splats.skin.keys, float(t))
        return self.splats

    # --- sorting ----------------------------------------------------------------------------------------------
    def sort(self, camera: Camera, t: float, footprint: Footprint = Footprint()) -> SortResult:
        """Synchronous back-to-front order at (camera, t); reused while the view does not change."""
        key = SortKey.of(camera, t, footprint)
        splats = self.splats_at(t)
        if self._order is None or self._order.key != key:
            self._order = depth_order(splats, camera, t, footprint, parallel=True)  # nothing else runs meanwhile
        return self._order

    # --- targets ----------------------------------------------------------------------------------------------
    def _ensure_targets(self, size: tuple[int, int]) -> RenderTargets:
        if self._targets is None or self._targets.size != size:
            if self._targets is not None:
                self._targets.release()
            self._targets = RenderTargets.create(self.ctx, size)
        return self._targets

    # --- drawing ----------------------------------------------------------------------------------------------
    @with_context
    def render(self, camera: Camera, t: float, settings: RenderSettings | None = None,
               order: SortResult | None = None, target=None, viewport=None, sync: bool = True) -> FrameStats:
        """Draw the model seen by `camera` at time `t`.

        Args:
            order: a back-to-front order to draw with (e.g. the newest one of an `AsyncSorter`); None sorts now
                (or reuses the order of the same view).
            target: framebuffer for the resolved image (e.g. ``ctx.screen``); None = the offscreen display
                texture read by `read_display`.
            viewport: (x, y, w, h) in `target`; default the whole camera image. A viewport of another size than
                the camera's image stretches the image over it (linear filtering): the desktop app draws at a lower
                resolution while the view moves.
            sync: wait for the GPU so that ``draw_ms`` is the real cost.
        """
        settings = settings or RenderSettings()
        stats = FrameStats(total=self._gpu.count if self._gpu is not None else 0)
        start = time.perf_counter()
        splats = self.splats_at(t)
        stats.upload_ms = (time.perf_counter() - start) * 1e3
        footprint = settings.footprint  # (validated anew on every access: once per frame)
        if order is None or order.needs_sort(camera, footprint):
            before = self._order
            order = self.sort(camera, t, footprint)
            stats.resorted = order is not before
            stats.sort_ms = order.ms if stats.resorted else 0.0
        stats.visible = order.visible
        stats.value_range = settings.value_range or self._default_value_range(settings.mode, order, splats)

        start = time.perf_counter()
        tg = self._ensure_targets((camera.width, camera.height))
        tg.accum_fbo.use()
        tg.accum_fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        if order.visible:
            stats.drawn = self._draw_splats(camera, t, settings, footprint, splats, order)
        self._resolve(settings, stats.value_range, target, viewport or (0, 0, camera.width, camera.height))
        if sync:
            self.ctx.finish()
        stats.draw_ms = (time.perf_counter() - start) * 1e3
        return stats

    def _draw_splats(self, camera: Camera, t: float, settings: RenderSettings, footprint: Footprint, splats,
                     order: SortResult) -> int:
        """Pre-pass + splats (points and/or quads, `_splat_runs`). Front to back, when `SortResult.hideable` says
        it pays, the order is drawn in stages (`draw_stages`); after each stage
        the saturated pixels (alpha >= 1 - TRANSMITTANCE_THRESHOLD, where the reference rasterizer stops) are
        marked in the depth buffer, so later fragments there are rejected before shading, and their tiles are
        read back, so later Gaussians whose screen box lies entirely in saturated tiles are not drawn at all.
        Neither changes the image: such Gaussians could only add to pixels that no longer change."""
        ctx = self.ctx
        front_to_back = settings.composite == "front-to-back"
        # an order sorted for another view (the app draws with the newest finished sort): its boxes may be too small
        stale = order.key != SortKey.of(camera, t, footprint)
        boxes = rescaled_boxes(order, camera) if stale else order.boxes
        indices = order.order[::-1] if front_to_back else order.order
        boxes = boxes[::-1] if front_to_back else boxes
        self._set_pre_uniforms(camera, t, settings, splats, footprint)
        for prog in self._splat_progs.values():
            set_uniforms(prog, u_size=(camera.width, camera.height), u_height=camera.height,
                          u_mode=RENDER_MODES.index(settings.mode), u_margin=self._point_margin,
                          u_max_point=self._max_point)
        set_uniforms(self._mask_prog, u_accum=0)
        set_uniforms(self._tiles_prog, u_accum=0)
        staged = front_to_back and settings.mode in POINT_MODES and \
            order.hideable >= MIN_HIDEABLE
        stages = draw_stages(len(indices)) if staged else [(0, len(indices))]
        ctx.blend_equation = ctx.FUNC_ADD
        ctx.depth_func = "<"
        saturated, drawn = None, 0
        covered = np.array([np.inf, np.inf, -np.inf, -np.inf])  # pixel box (x0, y0, x1, y1) drawn so far
        for k, (first, end) in enumerate(stages):
            idx, stage_boxes = indices[first:end], boxes[first:end]
            if saturated is not None:
                keep = ~hidden_in_tiles(stage_boxes, saturated, camera.height)
                idx, stage_boxes = idx[keep], stage_boxes[keep]
            self._draw_stage(np.ascontiguousarray(idx, dtype=np.uint32), front_to_back, len(stages) > 1,
                             self._splat_runs(settings, stage_boxes, stale))
            drawn += len(idx)
            if k + 1 < len(stages):
                if len(idx):
                    u, v, hx, hy = stage_boxes[:, 0], stage_boxes[:, 1], stage_boxes[:, 2], stage_boxes[:, 3]
                    covered = np.minimum(covered, [(u - hx).min(), (v - hy).min(), np.inf, np.inf])
                    covered = np.maximum(covered, [-np.inf, -np.inf, (u + hx).max(), (v + hy).max()])
                saturated = self._mark_saturated(covered)
        ctx.disable(ctx.DEPTH_TEST)
        return drawn

    def _mark_saturated(self, covered: np.ndarray) -> np.ndarray:
        """Depth 0 on the saturated pixels (alpha >= 1 - TRANSMITTANCE_THRESHOLD); returns the summed-area table
        of the saturated tiles (`saturated_table`). Both passes only visit `covered` (x0, y0, x1, y1: the pixels
        drawn so far, top-down), outside of which nothing can be saturated."""
        ctx, tg = self.ctx, self._targets
        w, h = tg.size
        tile = OCCLUSION_TILE
        x0, x1 = int(np.clip(np.floor(covered[0]), 0, w)), int(np.clip(np.ceil(covered[2]), 0, w))
        y0, y1 = int(np.clip(np.floor(h - covered[3]), 0, h)), int(np.clip(np.ceil(h - covered[1]), 0, h))  # GL
        ctx.disable(ctx.BLEND)
        tg.accum_tex.use(0)
        tg.tiles_fbo.scissor = None
        tg.tiles_fbo.use()
        tg.tiles_fbo.clear(0.0)
        if x1 > x0 and y1 > y0:
            tg.mask_fbo.scissor = (x0, y0, x1 - x0, y1 - y0)
            tg.mask_fbo.use()
            ctx.enable(ctx.DEPTH_TEST)
            self._mask_vao.render(ctx.TRIANGLES, vertices=3)
            ctx.disable(ctx.DEPTH_TEST)
            tg.mask_fbo.scissor = None
            tx0, ty0 = x0 // tile, y0 // tile
            tg.tiles_fbo.scissor = (tx0, ty0, -(-x1 // tile) - tx0, -(-y1 // tile) - ty0)
            tg.tiles_fbo.use()
            self._tiles_vao.render(ctx.TRIANGLES, vertices=3)
            tg.tiles_fbo.scissor = None
        tw, th = tg.tiles_tex.size
        flags = np.frombuffer(tg.tiles_fbo.read(components=1, dtype="f1"), np.uint8).reshape(th, tw)
        return saturated_table(flags[::-1] > 127)

    def _splat_runs(self, settings: RenderSettings, boxes: np.ndarray, stale: bool = False) -> list[tuple]:
        """`draw_plan.splat_runs` of a batch at this context's point limits and the current image size."""
        return splat_runs(boxes, settings.mode, settings.primitive, image_size=self._targets.size,
                          max_point=self._max_point, point_margin=self._point_margin,
                          max_viewport=self._max_viewport, stale=stale)

    def _draw_stage(self, idx: np.ndarray, front_to_back: bool, depth_test: bool, runs: list[tuple]) -> None:
        """Pre-process the Gaussians `idx` (in draw order) and draw them in `runs` (`_splat_runs`)."""
        if not idx.shape[0]:
            return
        ctx, tg = self.ctx, self._targets
        self._preprocess(idx, self._gpu.splats)
        ctx.enable(ctx.BLEND | ctx.DEPTH_TEST) if depth_test else ctx.enable(ctx.BLEND)
        ctx.blend_func = ((ctx.ONE_MINUS_DST_ALPHA, ctx.ONE) if front_to_back
                          else (ctx.ONE, ctx.ONE_MINUS_SRC_ALPHA))
        tg.accum_fbo.depth_mask = False
        w, h = tg.size
        m = self._point_margin
        try:
            for first, end, kind in runs:
                if kind == "points":
                    ctx.viewport = (-m, -m, w + 2 * m, h + 2 * m)  # splat_draw.glsl: points clip by their centre
                    ctx.enable(ctx.PROGRAM_POINT_SIZE)
                    self._gpu.splat_vaos["points"].render(ctx.POINTS, vertices=end - first, first=first)
                else:
                    ctx.disable(ctx.PROGRAM_POINT_SIZE)
                    ctx.viewport = (0, 0, w, h)
                    self._bind_instances(kind, first)
                    self._gpu.splat_vaos[kind].render(ctx.TRIANGLE_STRIP, vertices=4, instances=end - first)
        finally:
            ctx.disable(ctx.PROGRAM_POINT_SIZE)
            ctx.viewport = (0, 0, w, h)
            tg.accum_fbo.depth_mask = True

    def _preprocess(self, idx: np.ndarray, out) -> None:
        """Run the pre-pass (uniforms already set) on the Gaussians `idx` (uint32, in this order) into buffer `out`:
        one `SPLAT_BYTES` record each, in the same order."""
        ctx = self.ctx
        self._gpu.indices.write(idx.tobytes())
        self._gpu.sh.use(0)
        if self._gpu.nodes is not None:
            self._gpu.nodes.use(1)
        ctx.disable(ctx.BLEND | ctx.DEPTH_TEST)
        # a draw needs a complete framebuffer even with rasterizer discard (an EGL context has none of its own)
        self._targets.accum_fbo.use()
        self._gpu.pre_vao.transform(out, ctx.POINTS, vertices=idx.shape[0])

    def _bind_instances(self, kind: str, first: int) -> None:
        """Point the per-instance attributes of quad VAO `kind` at splat `first` of the splat buffer (GL 3.3 has
        no base instance)."""
        prog, vao = self._splat_progs[kind], self._gpu.splat_vaos[kind]
        for k, name in enumerate(SPLAT_FIELDS):
            if name in prog:
                vao.bind(prog[name].location, "f", self._gpu.splats, "4f", offset=first * SPLAT_BYTES + 16 * k,
                         stride=SPLAT_BYTES, divisor=1)

    def _set_pre_uniforms(self, camera: Camera, t: float, settings: RenderSettings,
                          splats: splatlib.SplatArrays, footprint: Footprint) -> None:
        w2c = camera.w2c
        degree = splats.sh_degree if settings.sh_degree is None else max(0, min(int(settings.sh_degree),
                                                                                 splats.sh_degree))
        set_uniforms(self._gpu.pre_prog, u_rot=np.ascontiguousarray(w2c[:3, :3].T, np.float32),  # column-major
                      u_trans=w2c[:3, 3], u_campos=camera.position,
                      u_intrinsics=(camera.fx, camera.fy, camera.cx, camera.cy),
                      u_size=(camera.width, camera.height), u_time=t, u_duration=splats.duration,
                      u_scale=footprint.scale, u_max_radius=footprint_caps(footprint, camera.height),
                      u_near=footprint.near_plane, u_smooth_fade=settings.temporal_fade == "smooth",
                      u_sh_degree=degree, u_sh=0, u_nodes=1,
                      u_skin_step=2.0 * splats.skin.keys.step if splats.skin is not None else 1.0,
                      u_value=VALUE_MODES.index(settings.mode) + 1 if settings.mode in VALUE_MODES else 0)

    def _resolve(self, settings: RenderSettings, value_range, target, viewport) -> None:
        tg = self._targets
        fbo = tg.display_fbo if target is None else target
        fbo.use()
        fbo.viewport = viewport
        self.ctx.disable(self.ctx.BLEND)
        tg.accum_tex.use(0)
        # nearest 1:1 (the exact image), linear when stretched over a larger or smaller viewport (splat_screen.glsl)
        tg.accum_tex.filter = (0x2600, 0x2600) if tuple(viewport[2:]) == tg.size else (0x2601, 0x2601)
        bg_alpha = 0.0 if settings.transparent else 1.0
        set_uniforms(self._resolve_prog, u_accum=0, u_viewport=viewport, u_mode=RENDER_MODES.index(settings.mode),
                      u_background=tuple(float(c) * bg_alpha for c in settings.background) + (bg_alpha,),
                      u_value_range=value_range)
        self._resolve_vao.render(self.ctx.TRIANGLES, vertices=3)

    # --- picking ----------------------------------------------------------------------------------------------
    @with_context
    def pick(self, camera: Camera, t: float, x: int, y: int, settings: RenderSettings | None = None) -> PixelStack:
        """The Gaussians that make pixel (x, y) (column, row from the top left) of `camera`'s image at time `t`,
        nearest first with their weights (`splatreel.viewer.pick`). Runs the pre-pass on the Gaussians whose screen
        box holds the pixel, so colours and footprints are exactly those drawn (with `settings`' splat scale and
        SH degree; in the colour mode whatever `settings.mode` is)."""
        settings = replace(settings or RenderSettings(), mode="color")
        if not (0 <= x < camera.width and 0 <= y < camera.height):
            raise GLError(f"pixel ({x}, {y}) is outside the {camera.width}x{camera.height} image")
        splats = self.splats_at(t)
        footprint = settings.footprint
        order = self.sort(camera, t, footprint)
        px, py = x + 0.5, y + 0.5
        b = order.boxes[::-1]  # nearest first
        near = (np.abs(px - b[:, 0]) <= b[:, 2]) & (np.abs(py - b[:, 1]) <= b[:, 3])
        idx = np.ascontiguousarray(order.order[::-1][near], dtype=np.uint32)
        if not idx.shape[0]:
            return composite_pixel(np.zeros((0, 16), np.float32), idx, (x, y))
        self._set_pre_uniforms(camera, t, settings, splats, footprint)
        if self._targets is None:  # the pre-pass needs a framebuffer; any size will do, the last image is kept
            self._ensure_targets((camera.width, camera.height))
        out = self.ctx.buffer(reserve=SPLAT_BYTES * idx.shape[0])
        try:
            self._preprocess(idx, out)
            records = np.frombuffer(out.read(), np.float32).reshape(-1, 16)
        finally:
            out.release()
        return composite_pixel(records, idx, (x, y))

    # --- read-back --------------------------------------------------------------------------------------------
    @with_context
    def read_display(self) -> np.ndarray:
        """The last resolved offscreen image, ``[H, W, 4]`` float32 RGBA (premultiplied), top row first."""
        return self._read(self._targets.display_tex)

    @with_context
    def read_accumulation(self) -> np.ndarray:
        """The raw accumulation ``[H, W, 4]``: rgb = sum c a T (or expected depth in depth mode), alpha = 1 - T."""
        return self._read(self._targets.accum_tex)

    def _read(self, tex) -> np.ndarray:
        if self._targets is None:
            raise GLError("nothing has been rendered yet")
        w, h = tex.size
        data = np.frombuffer(tex.read(), np.float32).reshape(h, w, 4)
        return np.ascontiguousarray(data[::-1])

    @with_context
    def release(self) -> None:
        self._release_model()
        if self._targets is not None:
            self._targets.release()
            self._targets = None



_HEADLESS: dict[str, object] = {}


def headless_context():
    """The viewer's process-wide EGL context (created on first use, leaving whatever context was current so)."""
    if "ctx" not in _HEADLESS:
        previous = EGLCurrent()
        _HEADLESS["ctx"] = create_headless_context(330)
        previous.restore()
    return _HEADLESS["ctx"]


def render_image(model, camera: Camera, t: float, settings: RenderSettings | None = None,
                 renderer: SplatRenderer | None = None) -> np.ndarray:
    """Render one image offscreen (EGL): ``[H, W, 4]`` float32, top row first.

    With an opaque background the rgb is the composited image and alpha is 1; with ``settings.transparent`` the rgb
    is premultiplied by the alpha channel.
    """
    r = renderer or SplatRenderer(headless_context(), model)
    r.render(camera, t, settings)
    img = r.read_display()
    if renderer is None:
        r.release()
    return img
