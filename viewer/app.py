"""The desktop viewer: a glfw window with a Dear ImGui panel (imgui-bundle's native glfw/OpenGL3 backends) over
the moderngl `SplatRenderer`.

Controls: left drag orbits (looks around in fly mode), right or middle drag pans, the wheel zooms, W/A/S/D and
Q/E fly, Space plays/pauses, R resets the view, F toggles fly mode, P takes a screenshot, Ctrl+click inspects the
Gaussians under the cursor, Alt+click measures, Shift+drag selects Gaussians (Shift+Alt+drag unselects), Delete
deletes the selection, Ctrl+Z undoes a deletion, Esc quits. Drop a model file on the window (or type its path in the
panel) to open it.

Sorting runs in a worker thread (`AsyncSorter`): every frame is drawn with the newest finished back-to-front order
and a new sort is requested whenever the camera, the time or the splat scale changed, so the UI never waits for a
sort. Screenshots are the exception: they wait for the order of their exact view.

While the view moves or the animation plays, frames are drawn at a lower resolution when the full one would not fit
the frame budget (`Resolution`) and stretched to the window; at rest they are sharp again. Screenshots are always
full resolution.

Editing (the Edit tab): the crop box (`splatreel.model.crop`: the Gaussians whose centre lies in the box when they
show most; the panel copies the box as the ``--crop`` option of convert, render and export) and deleted Gaussians
(`selection`: a rectangle selects the Gaussians whose centre shows in it at the displayed time). The window shows
exactly what "Save edited" writes. Unsaved deletions are not dropped silently: opening another file or closing the
window asks a second time.

Inspect (Ctrl+click, `SplatRenderer.pick`): the Gaussians that make the clicked pixel, ranked by their share of its
colour, with the chosen one's attributes (`splatreel.viewer.pick.describe`) and its 2-sigma ellipsoid drawn over the
model as it moves; the panel can jump to the time it shows most. Measure (Alt+click twice): the distance between the
surfaces seen at two pixels (`PixelStack.surface_depth`, unprojected).
"""

from __future__ import annotations

import ctypes
import math
import os
import re
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from splatreel.constants import NEAR_PLANE
from splatreel.errors import GLError, SplatreelError
from splatreel.fileio import atomic_path, atomic_write_json
from splatreel.model import CropBox, crop_mask

from .camera_path import CameraKey, CameraPath, dataset_views
from .controls import CameraController, Playback, Resolution, scaled_size
from .output import write_png
from .overlay import (CROP_COLOR, DATASET_COLOR, KEY_COLOR, MEASURE_COLOR, PATH_COLOR, PICK_COLOR, SELECTED_COLOR,
                      SELECTION_COLOR, Frustums, LineRenderer, box_segments, ellipsoid_segments, path_segments)
from .pick import PixelHit, PixelStack, inspect_gaussian, peak_time, vector_text
from .renderer import COMPOSITE_ORDERS, RENDER_MODES, VALUE_MODES, FrameStats, RenderSettings, SplatRenderer
from .selection import Edits, centres_at, in_rect, marker_segments, normalise_rect
from .sorting import AsyncSorter, SortKey, SortResult, view_key
from .splats import needs_per_frame_upload, to_arrays
from .trajectory import frame_model, framing_of, model_extent, path_as_nerfstudio


@dataclass
class AppOptions:
    """Start-up settings of the desktop app (the ``splatreel view`` options)."""

    size: tuple[int, int] = (1280, 720)
    up: str = "z"
    fov: float = 40.0
    #: render mode, splat scale, SH degree, blending and background at start-up ...
    settings: RenderSettings = field(default_factory=RenderSettings)
    #: ... except that the background is the checkpoint's unless this is False
    checkpoint_background: bool = True
    play: bool = True
    time: float | None = None
    loop_seconds: float = 2.0
    cameras: str | None = None
    split: str | None = "train"
    camera_path: str | None = None
    #: start playing `camera_path` at once (a presentation, a scripted capture)
    play_path: bool = False
    screenshot_dir: str = "."
    vsync: bool = True
    #: share of the window's pixels drawn per axis at rest (`Resolution.scale`) ...
    render_scale: float = 1.0
    #: ... and whether to draw fewer while the view moves, to keep frames within `frame_budget_ms` ...
    adaptive_resolution: bool = True
    frame_budget_ms: float = 40.0
    #: ... and while the animation plays under a still camera (`Resolution.while_playing`)
    lower_while_playing: bool = True
    #: automation (tests, scripted captures): stop after this many frames ...
    exit_after: int | None = None
    #: ... and save a screenshot of the last frame here, and a JSON report here
    screenshot: str | None = None
    report: str | None = None
    force: bool = False
    #: start with the crop box on, at these 6 numbers (min corner, max corner), as ``--crop``
    crop: tuple[float, ...] | None = None
    #: start with this window pixel (x, y from the top left) inspected, as a Ctrl+click there
    inspect: tuple[int, int] | None = None
    #: start with the Gaussians in this window rectangle (x0, y0, x1, y1 from the top left) selected, as a Shift+drag
    select: tuple[float, float, float, float] | None = None


@dataclass
class _Stats:
    """The live numbers of the panel: the last frame's `FrameStats`, its wall time, the last sort, sort count."""

    frame: FrameStats = field(default_factory=FrameStats)
    frame_ms: float = 0.0
    scale: float = 1.0
    moving: bool = False
    playing: bool = False
    sort_ms: float = 0.0
    sorts: int = 0


@dataclass
class _PathEditor:
    path: CameraPath | None = None
    file: str = "camera_path.json"
    key_interval: float = 1.0
    playing: bool = False
    time: float = 0.0
    overwrite: bool = False
    show: bool = True
    #: what Save writes: a splatreel path (keyframes) or a nerfstudio one (frames at 30 FPS, for ns-render)
    nerfstudio: bool = False


#: Save's formats in the Path tab, in `_PathEditor.nerfstudio` order
PATH_FORMATS = ("splatreel keys", "nerfstudio frames")


@dataclass
class _CropEditor:
    """The crop box being edited, and what the renderer shows (`shown`: the box it was cropped to, or None)."""

    enabled: bool = False
    lo: list = field(default_factory=lambda: [-1.0, -1.0, -1.0])
    hi: list = field(default_factory=lambda: [1.0, 1.0, 1.0])
    show: bool = True
    shown: CropBox | None = None
    #: how long the last crop took to apply: above LIVE_CROP_MS, a drag applies when it is released
    apply_ms: float = 0.0
    #: a min/max field is being dragged
    dragging: bool = False

    def edited(self) -> CropBox:
        """The box as edited; a max below the min on some axis counts as the min (an empty slab), so that
        dragging one corner past the other never fails."""
        return CropBox(tuple(self.lo), tuple(max(a, b) for a, b in zip(self.lo, self.hi)))

    def box(self) -> CropBox | None:
        """The box to show: `edited`, or None while cropping is off."""
        return self.edited() if self.enabled else None


@dataclass
class _Editor:
    """The Edit tab besides the crop box: deleted and selected Gaussians, the selection rectangle being dragged, and
    where "Save edited" writes."""

    edits: Edits = field(default_factory=lambda: Edits.of(0))
    #: indices of the loaded model's Gaussians that the renderer shows, ascending (crop box and deletions applied)
    shown_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    #: (crop box, its ``[N]`` bool mask over the loaded model): a deletion does not recompute the crop
    crop_cache: tuple | None = None
    #: the loaded model's `SplatArrays` once converted (each edit uploads a `SplatArrays.select` of them)
    full_arrays: object = None
    #: the rectangle being dragged (x0, y0, x1, y1 in window coordinates, as the mouse gives them), and whether it
    #: unselects (Shift+Alt)
    drag: list | None = None
    drag_removes: bool = False
    #: ((shown set, `Edits.revision`), the selected Gaussians shown (indices into it), (time, their centres then)):
    #: the indices are remade when the selection or the shown set changes, the centres when the time does too
    markers: tuple | None = None
    #: where Save edited writes: `edited_name` of the model's file unless the user typed another (kept for the next
    #: model)
    file: str = "edited.safetensors"
    overwrite: bool = False
    #: deletions made since the model was opened or last saved ...
    unsaved: bool = False
    #: ... and the actions ("open the file", "close the window") the user was already told would drop them
    warned: set = field(default_factory=set)


@dataclass
class _Inspector:
    """The Inspect panel: the pixel last Ctrl+clicked, the Gaussians that make it, which of them is shown."""

    stack: PixelStack | None = None
    #: the Gaussian shown: 0 = the largest share of the pixel's colour, 1 the next, ...
    rank: int = 0
    #: (index, time, splat scale) -> (`describe` rows, ellipsoid segments), remade when one of them changes
    cache: tuple | None = None
    #: the camera the pixel was picked with
    camera: object = None
    #: open the panel's Inspect section on the next frame (a new pick)
    reveal: bool = False
    #: the stack's Gaussians, the largest share first
    ranked: list[PixelHit] = field(init=False)

    def __post_init__(self) -> None:
        self.ranked = sorted(self.stack.hits, key=lambda h: -h.weight) if self.stack is not None else []

    @property
    def hit(self) -> PixelHit | None:
        ranked = self.ranked
        return ranked[min(self.rank, len(ranked) - 1)] if ranked else None


@dataclass
class _Measure:
    """The measuring tape: up to two world points (the surfaces under two Alt+clicks) and the pixels they came from."""

    points: list = field(default_factory=list)
    pixels: list = field(default_factory=list)

    @property
    def distance(self) -> float | None:
        return float(np.linalg.norm(self.points[1] - self.points[0])) if len(self.points) == 2 else None


#: crops that apply faster than this follow the drag live; slower ones (large models) apply on release
LIVE_CROP_MS = 50.0


def edited_name(source: str) -> str:
    """Where "Save edited" writes by default: ``<model file's stem>_edited.safetensors`` in the current folder
    (like screenshots; the model's own folder may be read-only, e.g. the bundled sample's)."""
    stem = Path(source).stem if Path(source).suffix else ""
    return f"{stem}_edited.safetensors" if stem else "edited.safetensors"


def camera_to_json(camera) -> dict:
    """A camera as plain JSON (c2w rows, intrinsics, size)."""
    return {"c2w": np.asarray(camera.c2w).tolist(), "fx": camera.fx, "fy": camera.fy, "cx": camera.cx,
            "cy": camera.cy, "width": camera.width, "height": camera.height}


def camera_from_json(data: dict):
    """The camera `camera_to_json` wrote (e.g. a report's, to render its view headless)."""
    from splatreel.cameras import Camera

    return Camera(np.array(data["c2w"]), data["fx"], data["fy"], data["cx"], data["cy"], data["width"],
                  data["height"])


class ViewerApp:
    """Interactive viewer of one model at a time (see module doc). ``run()`` blocks until the window closes."""

    def __init__(self, source, options: AppOptions | None = None) -> None:
        """`source`: a model file path, or a `Checkpoint`."""
        self.options = options or AppOptions()
        self.status = ""
        self.report: dict = {"frames": 0}
        self._source = source
        self._window = None
        self._pending_open: str | None = None
        self._screenshot_request: str | None = None
        self._fly = False
        self._stats = _Stats()
        self._path = _PathEditor()
        self._crop = _CropEditor()
        self._editor = _Editor()
        self._inspect = _Inspector()
        self._measure = _Measure()
        self._edit_tab_first = self.options.crop is not None  # --crop: show the Edit tab at start-up
        self._views = []
        self._view_index = 0
        self._show_cameras = True
        self._overlay_cache: tuple | None = None
        self._generation = 0
        self._order: SortResult | None = None
        self._requested: tuple | None = None
        o = self.options
        self.resolution = Resolution(scale=o.render_scale, adaptive=o.adaptive_resolution, budget_ms=o.frame_budget_ms,
                                     while_playing=o.lower_while_playing)
        self._last_pose: tuple | None = None
        self._last_time: float | None = None

    # --- set-up -------------------------------------------------------------------------------------------------
    def _init_window(self) -> None:
        from imgui_bundle import imgui  # sets PYGLFW_LIBRARY so that glfw shares imgui's libglfw

        import glfw
        import moderngl

        glfw.ERROR_REPORTING = "exception"  # set-up failures become one-line errors, not warnings
        try:
            if not glfw.init():
                raise GLError("could not initialise glfw")
            glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
            glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
            glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
            glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
            w, h = self.options.size
            window = glfw.create_window(w, h, "splatreel", None, None)
            if not window:
                raise GLError("could not open an OpenGL 3.3 core window")
        except glfw.GLFWError as exc:
            glfw.terminate()
            msg = re.sub(r"^\(\d+\)\s*", "", str(exc).replace("b'", "").rstrip("'")).strip()
            raise GLError(f"cannot open a window: {msg} (run under a desktop or Xvfb, or use `splatreel render`)") \
                from None
        glfw.ERROR_REPORTING = "warn"
        self._window = window
        glfw.make_context_current(window)
        glfw.swap_interval(1 if self.options.vsync else 0)
        glfw.set_drop_callback(window, self._on_drop)
        self.ctx = moderngl.create_context(require=330)
        imgui.create_context()
        io = imgui.get_io()
        io.set_ini_filename(None)  # no imgui.ini in the user's folder
        addr = ctypes.cast(window, ctypes.c_void_p).value
        if not (imgui.backends.glfw_init_for_opengl(addr, True) and imgui.backends.opengl3_init("#version 330")):
            raise GLError("could not initialise the Dear ImGui glfw/OpenGL3 backends")
        self.renderer = SplatRenderer(self.ctx)
        self.overlay = LineRenderer(self.ctx)
        self.sorter = AsyncSorter()

    def _on_drop(self, _window, paths) -> None:
        if paths:
            self._pending_open = str(paths[0])

    def load(self, source) -> None:
        """Show a model file (or `Checkpoint`); on failure keep the current model and report the error."""
        from splatreel.formats import load_model

        ckpt = load_model(source) if isinstance(source, (str, os.PathLike)) else source
        model = ckpt.model
        first_load = self.renderer.model is None
        t0, t1 = model.time_range
        start = self.options.time if (first_load and self.options.time is not None) else 0.5 * (t0 + t1)
        extent = model_extent(model)  # once: over a second for 1M Gaussians
        name = str(source if isinstance(source, (str, os.PathLike)) else getattr(ckpt, "path", "model"))
        old = self._editor
        # Save edited writes <name>_edited.safetensors unless the user typed a file; overwriting is asked anew
        file = old.file if old.file != edited_name(getattr(self, "source_name", "")) else edited_name(name)
        state = ("_crop", "_editor", "_measure", "model", "checkpoint", "_extent", "source_name")
        before = {k: getattr(self, k, None) for k in state}
        self._crop = self._initial_crop(extent, self.options.crop if first_load else None)
        self._editor = _Editor(edits=Edits.of(len(model)), file=file)
        self.model, self.checkpoint, self._extent, self.source_name = model, ckpt, extent, name
        self._measure = _Measure()  # points on the previous model
        try:
            shown = self._apply_edits(start)
        except SplatreelError:  # e.g. too large for this GPU: back to the model shown before, edits and all
            if first_load:
                raise
            for k, v in before.items():
                setattr(self, k, v)
            self._apply_edits(self.playback.time)
            raise
        self.framing = framing_of(*extent) if shown is model else frame_model(shown)
        if first_load:
            o = self.options
            self.settings = replace(o.settings, background=ckpt.background) if o.checkpoint_background \
                else replace(o.settings)
            self.playback = Playback(time_range=(t0, t1), time=start, playing=o.play, loop_seconds=o.loop_seconds)
            self.controller = CameraController(fov=o.fov, up=o.up)
        else:
            self.playback.set_range((t0, t1))
            self.playback.time = start
        self.controller.reset(self.framing)
        self.status = f"opened {self.source_name}: {len(model):,} Gaussians"
        if not self.options.cameras:
            self._views = self._training_views(ckpt)
        self._update_frame_times()

    @staticmethod
    def _initial_crop(extent: tuple[np.ndarray, np.ndarray], values) -> _CropEditor:
        """A new model's crop editor: off, with the box at the model's extent (`model_extent`); on at `values`
        (``--crop``) when given."""
        if values is not None:
            box = CropBox.of(values)
            return _CropEditor(enabled=True, lo=list(box.lo), hi=list(box.hi))
        return _CropEditor(lo=extent[0].tolist(), hi=extent[1].tolist())

    def _in_box(self, box: CropBox | None) -> np.ndarray:
        """``[N]`` bool: the loaded model's Gaussians that crop box `box` keeps (all of them without a box)."""
        ed = self._editor
        if box is None:
            return np.ones(len(self.model), bool)
        if ed.crop_cache is None or ed.crop_cache[0] != box:
            ed.crop_cache = (box, crop_mask(self.model, box).numpy())
        return ed.crop_cache[1]

    def _kept(self, box: CropBox | None) -> np.ndarray:
        """``[N]`` bool: the loaded model's Gaussians inside `box` and not deleted."""
        return self._in_box(box) & ~self._editor.edits.deleted

    def _apply_edits(self, t: float):
        """Show the model cropped to the editor's box (or whole) without its deleted Gaussians; returns the model
        now shown."""
        ce, ed = self._crop, self._editor
        start = time.perf_counter()
        box = ce.box()
        keep = self._kept(box)
        whole = bool(keep.all())
        shown = self.model if whole else self.model.select(torch.from_numpy(keep))
        ed.shown_index = np.flatnonzero(keep)
        full = ed.full_arrays  # the whole model's arrays: a subset of them is a gather, not a new conversion
        if full is None and not whole and not needs_per_frame_upload(self.model):  # e.g. opened with --crop
            full = ed.full_arrays = to_arrays(self.model)
        usable = full is not None and (full.time is None or full.time == float(t))  # a keyframed slice: at t only
        self.renderer.set_model(shown, t, arrays=(full if whole else full.select(keep)) if usable else None)
        if whole:
            ed.full_arrays = self.renderer.splats
        self._generation += 1  # sorts of the previous set of Gaussians no longer apply
        self._order, self._requested = None, None
        ce.shown, ce.apply_ms = box, (time.perf_counter() - start) * 1e3
        self.report.update(shown_gaussians=len(shown), deleted=ed.edits.num_deleted)
        self._inspect = _Inspector()  # its indices were into the previous set of Gaussians
        return shown

    # --- selection and deletion ---------------------------------------------------------------------------------
    def select_rect(self, camera, t: float, rect, mode: str = "add") -> int:
        """Select (mode "add" / "replace") or unselect ("remove") the shown Gaussians whose centre at `t` lies in
        `rect` (x0, y0, x1, y1: pixels of `camera`'s image; `selection.in_rect`); returns how many it caught."""
        ed = self._editor
        footprint = self.settings.footprint
        order = self._order  # the frame's own sort when it is of this view, else one now (kept for a pick)
        if order is None or order.key != SortKey.of(camera, t, footprint):
            order = self.renderer.sort(camera, t, footprint)
        caught = ed.shown_index[in_rect(order, rect)]
        selected = self.report["selected"] = ed.edits.select(caught, mode)
        self.report["selection"] = {"rect": [float(x) for x in rect], "time": t, "mode": mode,
                                    "camera": camera_to_json(camera), "caught": len(caught)}
        verb = "unselected" if mode == "remove" else "selected"
        self.status = f"{verb} {len(caught):,} Gaussian(s); {selected:,} selected"
        return len(caught)

    def _inspected_gaussian(self) -> int:
        """The loaded model's index of the Gaussian shown in the Inspect tab."""
        hit = self._inspect.hit
        if hit is None:
            raise SplatreelError("Ctrl+click the model first: nothing is inspected")
        return int(self._editor.shown_index[hit.index])

    def select_inspected(self) -> None:
        """Add the Gaussian shown in the Inspect tab to the selection."""
        selected = self.report["selected"] = self._editor.edits.select([self._inspected_gaussian()], "add")
        self.status = f"{selected:,} selected"

    def delete_selected(self) -> int:
        """Delete the selected Gaussians (Undo brings them back); returns how many."""
        count = self._editor.edits.delete_selected()
        if not count:
            raise SplatreelError("nothing is selected: Shift+drag over the model, or Select in the Inspect tab")
        self._edited(f"deleted {count:,} Gaussian(s)")
        return count

    def _edited(self, what: str) -> None:
        """After a change of the deleted set: show the rest, and mark the edits unsaved."""
        ed = self._editor
        ed.unsaved = True
        ed.warned.clear()
        self._apply_edits(self.playback.time)
        self.report["selected"] = ed.edits.num_selected
        self.status = f"{what}; {ed.edits.num_deleted:,} deleted, {len(self.renderer.model):,} shown"

    def _undo(self) -> None:
        if not self._editor.edits.undo():
            raise SplatreelError("nothing to undo")
        self._edited("undid the last deletion")

    def _restore_all(self) -> None:
        count = self._editor.edits.restore_all()
        if not count:
            raise SplatreelError("nothing is deleted")
        self._edited(f"restored {count:,} Gaussian(s) (Undo deletes them again)")

    def _delete_inspected(self) -> None:
        """Delete the Gaussian shown in the Inspect tab, then inspect the same pixel again: the next Gaussian there
        comes up, so a floater made of several can be removed click by click."""
        index = self._inspected_gaussian()
        pixel, camera = self._inspect.stack.pixel, self._inspect.camera
        self._editor.edits.delete([index])  # the rest of the selection stays
        self._edited("deleted 1 Gaussian")
        if camera is not None:
            status = self.status
            self.inspect(camera, self.playback.time, *pixel)
            self.status = status

    def _drops_unsaved_edits(self, action: str) -> bool:
        """True when `action` (opening, closing) would drop deletions not yet saved and the user has not yet been
        told: the status line tells them and the next attempt goes ahead."""
        ed = self._editor
        if not ed.unsaved or action in ed.warned:
            return False
        ed.warned.add(action)
        self.status = (f"{ed.edits.num_deleted:,} deleted Gaussian(s) are not saved: Save edited in the Edit tab, "
                       f"or {action} again to drop them")
        return True

    def inspect(self, camera, t: float, x: int, y: int) -> PixelStack:
        """Pick pixel (x, y) of `camera`'s image at time `t` (`SplatRenderer.pick`) and show its Gaussians in the
        Inspect panel, the largest share first."""
        stack = self.renderer.pick(camera, t, x, y, self.settings)
        self._inspect = _Inspector(stack, camera=camera, reveal=True)
        top = stack.top
        self.status = (f"pixel ({x}, {y}): {len(stack.hits)} Gaussian(s), alpha {stack.alpha:.3f}" if top else
                       f"pixel ({x}, {y}): background, no Gaussian there")
        self.report["inspected"] = {
            "pixel": [x, y], "time": t, "camera": camera_to_json(camera), "alpha": stack.alpha,
            "color": list(stack.color), "gaussians": len(stack.hits),
            "hits": [{"index": h.index, "weight": h.weight, "alpha": h.alpha, "depth": h.depth} for h in stack.hits],
            "top": None if top is None else {"index": top.index, "weight": top.weight,
                                             "attributes": dict(self._inspected(t)[0])}}  # rank 0 = top
        return stack

    def measure(self, camera, t: float, x: int, y: int) -> np.ndarray:
        """Put an end of the measuring tape on the surface seen at pixel (x, y) of `camera`'s image at time `t` (the
        pick's `surface_depth`, unprojected through the pixel centre); a third point starts a new measurement.
        Returns the world point."""
        stack = self.renderer.pick(camera, t, x, y, self.settings)
        depth = stack.surface_depth
        if depth is None:
            raise SplatreelError(f"pixel ({x}, {y}) shows no surface to measure from (background)")
        point = camera.unproject([[x + 0.5, y + 0.5]], [depth])[0]
        m = self._measure
        if len(m.points) == 2:
            m.points, m.pixels = [], []
        m.points.append(point)
        m.pixels.append((x, y))
        self.status = f"measure: point {len(m.points)} at {vector_text(point)}" + \
            (f"; distance {m.distance:.4g}" if m.distance is not None else "; Alt+click the second point")
        self.report["measured"] = {"points": [p.tolist() for p in m.points], "pixels": [list(p) for p in m.pixels],
                                   "distance": m.distance, "time": t, "camera": camera_to_json(camera)}
        return point

    def _measure_lines(self, camera) -> np.ndarray:
        """The tape's ends (crosses) and the segment between them."""
        pts = self._measure.points
        if not pts:
            return np.zeros((0, 2, 3))
        ends = marker_segments(np.array(pts), camera, pixels=10.0)
        return np.concatenate([ends, np.array(pts)[None]]) if len(pts) == 2 else ends

    def _inspected(self, t: float) -> tuple[list, np.ndarray] | None:
        """(`describe` rows, 2-sigma ellipsoid segments at the splat scale) of the inspected Gaussian at `t`."""
        ins = self._inspect
        hit = ins.hit
        if hit is None:
            return None
        key = (hit.index, t, self.settings.splat_scale, self.settings.temporal_fade)
        if ins.cache is None or ins.cache[0] != key:
            rows, g = inspect_gaussian(self.renderer.model, hit.index, t, self.settings.temporal_fade)
            cov = g.covariances[0].double().numpy() * self.settings.splat_scale ** 2
            ins.cache = (key, rows, ellipsoid_segments(g.means[0].double().numpy(), cov))
        return ins.cache[1], ins.cache[2]

    def _save_edited(self) -> None:
        """Write what the window shows: the model cropped to the box (when on) without its deleted Gaussians, with
        both edits in the provenance ("crop": the box; "deleted": Gaussians deleted by hand inside it)."""
        from splatreel.checkpoint import save_checkpoint

        ed, ckpt, n = self._editor, self.checkpoint, len(self.model)
        box = self._crop.shown
        in_box = self._in_box(box)
        model = self.renderer.model  # `_apply_edits` made it: the box's Gaussians less the deleted ones
        deleted = int(np.count_nonzero(in_box & ed.edits.deleted))
        if box is None and not deleted:
            raise SplatreelError("nothing to save: turn on 'crop to box' or delete Gaussians first")
        if not len(model):
            raise SplatreelError("the edits leave no Gaussians to save")
        provenance = dict(ckpt.provenance or {})
        if box is not None:
            provenance["crop"] = box.provenance(int(in_box.sum()), n)
        if deleted:
            provenance["deleted"] = {"count": deleted, "kept": len(model), "of": n}
        save_checkpoint(ed.file, model, background=ckpt.background, provenance=provenance,
                        training=ckpt.training, force=ed.overwrite, views=getattr(ckpt, "views", None))
        ed.unsaved = False
        self.status = f"saved {len(model):,} of {n:,} Gaussians to {ed.file}"

    def _update_frame_times(self) -> None:
        """The times that frame stepping visits: a keyframed model's keys, else its dataset's frame times."""
        keys = getattr(self.model, "times", None)
        times = keys.tolist() if keys is not None else sorted({v.time for v in self._views})
        self.playback.frame_times = tuple(float(t) for t in times)

    @staticmethod
    def _training_views(ckpt) -> list:
        """The cameras of the dataset a checkpoint was trained on: those it records, else those of its dataset
        folder when that is still readable."""
        if getattr(ckpt, "views", None):
            return list(ckpt.views)
        root = (getattr(ckpt, "training", None) or {}).get("dataset")
        if not root or not Path(root).is_dir():
            return []
        try:
            return dataset_views(root, "train")
        except SplatreelError:
            return []

    # --- main loop ----------------------------------------------------------------------------------------------
    def run(self) -> dict:
        """Open the window and loop until it is closed (or `exit_after` frames); returns the report dict."""
        import glfw
        from imgui_bundle import imgui

        self._init_window()
        try:
            if self.options.cameras:  # before the model: `load` steps frames through these views' times
                self._views = dataset_views(self.options.cameras, self.options.split)
            self.load(self._source)
            if self.options.camera_path:
                self._path.path = CameraPath.load(self.options.camera_path, self.model.time_range)
                self._path.file = self.options.camera_path
                if self.options.play_path:
                    self._path.playing, self._path.time = True, self._path.path.start
            self.report.update(time_start=self.playback.time, started=time.time())
            width, height = glfw.get_framebuffer_size(self._window)
            if self.options.inspect is not None:
                self.inspect(*self._current_view(width, height), *self.options.inspect)
            if self.options.select is not None:
                self.select_rect(*self._current_view(width, height), self.options.select)
                self._edit_tab_first = True
            last = time.perf_counter()
            frames = 0
            while True:
                if glfw.window_should_close(self._window):
                    if not self._drops_unsaved_edits("close the window"):
                        break
                    glfw.set_window_should_close(self._window, False)
                glfw.poll_events()
                now = time.perf_counter()
                dt, last = now - last, now
                imgui.backends.opengl3_new_frame()
                imgui.backends.glfw_new_frame()
                imgui.new_frame()
                if self._pending_open:
                    path, self._pending_open = self._pending_open, None
                    self._open(path)
                final = self.options.exit_after is not None and frames + 1 >= self.options.exit_after
                if final and self.options.screenshot:
                    self._screenshot_request = self.options.screenshot
                self._handle_input(dt)
                self._draw_frame(dt)
                self._draw_ui()
                imgui.render()
                imgui.backends.opengl3_render_draw_data(imgui.get_draw_data())
                glfw.swap_buffers(self._window)
                frames += 1
                if final:
                    break
            self.report.update(frames=frames, time_end=self.playback.time, sorts=self._stats.sorts,
                               seconds=time.time() - self.report["started"],
                               resolutions=sorted(self.report.get("resolutions", ())))
        finally:
            self._shutdown()
        if self.options.report:
            atomic_write_json(self.options.report, self.report, force=True)
        return self.report

    def _shutdown(self) -> None:
        import glfw
        from imgui_bundle import imgui

        if getattr(self, "sorter", None) is not None:
            self.sorter.close()
        if self._window is not None:
            if getattr(self, "renderer", None) is not None:
                self.renderer.release()
            if getattr(self, "overlay", None) is not None:
                self.overlay.release()
            imgui.backends.opengl3_shutdown()
            imgui.backends.glfw_shutdown()
            imgui.destroy_context()
            glfw.destroy_window(self._window)
            self._window = None
        glfw.terminate()

    def _open(self, path: str) -> None:
        if not self._drops_unsaved_edits("open the file"):
            self._attempt(lambda: self.load(path))

    def _attempt(self, action, done: str | None = None) -> bool:
        """Run a user action; its one-line error (or `done`) goes to the panel's status line. True on success."""
        try:
            action()
        except SplatreelError as exc:
            self.status = f"error: {exc}"
            return False
        if done:
            self.status = done
        return True

    # --- per frame ----------------------------------------------------------------------------------------------
    def _current_view(self, width: int, height: int):
        """(camera, model time) of this frame: the camera path while it plays, else the interactive rig."""
        t = self.playback.time
        pe = self._path
        if pe.playing and pe.path is not None:
            cam = pe.path.camera(pe.time, width, height)
            st = pe.path.scene_time(pe.time)
            if st is not None:
                t = self.playback.time = st
            return cam, t
        return self.controller.camera(width, height), t

    def _draw_frame(self, dt: float) -> None:
        import glfw

        t_frame = time.perf_counter()
        dt = min(dt, 0.1)  # a stall (file load, first frame) must not make time jump
        self.playback.advance(dt)
        pe = self._path
        if pe.playing and pe.path is not None:
            pe.time += dt
            if pe.time > pe.path.start + pe.path.duration and not pe.path.loop:
                pe.time, pe.playing = pe.path.start + pe.path.duration, False
        width, height = glfw.get_framebuffer_size(self._window)
        if width <= 0 or height <= 0:  # minimised
            return
        window_camera, t = self._current_view(width, height)
        camera = window_camera
        screenshot = self._screenshot_request
        pose = view_key(window_camera)
        moving, self._last_pose = pose != self._last_pose and self._last_pose is not None, pose
        playing, self._last_time = t != self._last_time and self._last_time is not None, t
        changing = self.resolution.changing(moving, playing)
        scale = 1.0 if screenshot else self.resolution.choose(changing, width, height)
        if scale != 1.0:
            camera = window_camera.resized(*scaled_size(width, height, scale))
        s = self.settings
        footprint = s.footprint
        splats = self.renderer.splats_at(t)
        key = SortKey.of(camera, t, footprint)
        if self._requested != (self._generation, key):
            self.sorter.request(splats, camera, t, footprint, tag=self._generation)
            self._requested = (self._generation, key)
        self._take_sort_result(self.sorter.poll())
        # the first frame of a model, a screenshot, or the first frame after a cap or the near plane changed (an
        # order of another footprint bounds nothing here): wait for the sort just requested
        if self._order is None or screenshot or self._order.needs_sort(camera, footprint):
            self._take_sort_result(self.sorter.wait())
        if self._order is None:
            return
        stats = self.renderer.render(camera, t, s, order=self._order, target=self.ctx.screen,
                                     viewport=(0, 0, width, height), sync=True)
        glfw.make_context_current(self._window)  # the panel draws next, with the window's context
        self.resolution.observe(stats.draw_ms + stats.upload_ms, scale)
        st = self._stats
        st.frame, st.scale, st.moving, st.playing = stats, scale, moving, playing
        self.report.setdefault("resolutions", set()).add(scale)
        self.report["moving_frames"] = self.report.get("moving_frames", 0) + moving
        if screenshot:
            self._screenshot_request = None
            self._save_screenshot(screenshot, camera, t, width, height)
        self._draw_overlays(window_camera)  # after the screenshot: screenshots show the model only
        st.frame_ms = (time.perf_counter() - t_frame) * 1e3

    def _draw_overlays(self, camera) -> None:
        """The camera path (its curve and key frustums), the dataset cameras and the crop box, as lines over the
        splats; a frustum at the viewing camera's own position (snapped to it, or flying the path) is left out."""
        depth = 0.15 * self.framing.radius  # frustum size
        path_lines, frustums = self._overlay_geometry(camera.width, camera.height, depth)
        segs, colors = frustums.lines(camera.position, 1e-3 * depth)
        ce = self._crop
        box = ce.box() if ce.show else None
        box_lines = box_segments(box.lo, box.hi) if box is not None else np.zeros((0, 2, 3))
        inspected = self._inspected(self.playback.time)
        pick_lines = inspected[1] if inspected is not None else np.zeros((0, 2, 3))
        marks = self._selection_markers(camera)
        self.report["markers"] = len(marks) // 3
        layers = ((self._measure_lines(camera), MEASURE_COLOR), (marks, SELECTION_COLOR), (pick_lines, PICK_COLOR),
                  (box_lines, CROP_COLOR), (path_lines, PATH_COLOR))  # drawn in this order, then the frustums
        segs = np.concatenate([lines for lines, _ in layers] + [segs])
        colors = np.concatenate([np.broadcast_to(np.asarray(color, np.float32), (len(lines), 3))
                                 for lines, color in layers] + [colors])
        self.report["overlay_lines"] = len(segs)
        if len(segs):
            self.ctx.screen.use()
            self.ctx.viewport = (0, 0, camera.width, camera.height)
            self.overlay.draw(camera, segs, colors)

    def _selection_markers(self, camera) -> np.ndarray:
        """Crosses (`selection.marker_segments`) at the centres of the selected Gaussians that are shown, at the
        displayed time."""
        ed, t = self._editor, self.playback.time
        selection = (self._generation, ed.edits.revision)
        if ed.markers is None or ed.markers[0] != selection:  # a scan of the whole selection mask: on a change only
            ed.markers = (selection, np.flatnonzero(ed.edits.selected[ed.shown_index]), None)
        _, shown, centres = ed.markers
        if not len(shown):
            return np.zeros((0, 2, 3))
        if centres is None or centres[0] != t:  # the centres move with time
            centres = (t, centres_at(self.renderer.splats_at(t), t, shown))
            ed.markers = (selection, shown, centres)
        return marker_segments(centres[1], camera)

    def _overlay_geometry(self, width: int, height: int, depth: float):
        """(path polyline, `Frustums` of the path keys and dataset cameras), remade only when what they show
        changed: sampling a path evaluates a spline and a slerp per point, too slow for every frame."""
        pe = self._path
        path = pe.path if pe.show else None
        views = self._views if self._show_cameras else ()  # () is one object: a stable cache key
        # the path and the view list are replaced, never changed in place; the cache holds them, so while it
        # lives their ids cannot be reused by new objects
        key = (id(path), id(views), self._view_index, depth, width, height)
        if self._overlay_cache is None or self._overlay_cache[0] != key:
            cameras, colors = [], []
            if path is not None:
                cameras += [path.camera(k.time, width, height) for k in path.keys]
                colors += [KEY_COLOR] * len(path.keys)
            cameras += [v.camera for v in views]
            colors += [SELECTED_COLOR if i == self._view_index else DATASET_COLOR for i in range(len(views))]
            lines = path_segments(path) if path is not None else np.zeros((0, 2, 3))
            self._overlay_cache = (key, lines, Frustums.of(cameras, colors, depth), (path, views))
        return self._overlay_cache[1], self._overlay_cache[2]

    def _take_sort_result(self, res: SortResult | None) -> None:
        if res is not None and res.tag == self._generation:
            self._order = res
            self._stats.sort_ms = res.ms
            self._stats.sorts += 1

    def _save_screenshot(self, path: str, camera, t: float, width: int, height: int) -> None:
        """Save what the window shows (without the panel) as a PNG."""
        data = self.ctx.screen.read(viewport=(0, 0, width, height), components=3)
        rgb = np.frombuffer(data, np.uint8).reshape(height, width, 3)[::-1].astype(np.float32) / 255.0
        rgba = np.concatenate([rgb, np.ones_like(rgb[..., :1])], -1)
        explicit = path is self.options.screenshot
        target = Path(path)

        def save() -> None:
            with atomic_path(target, force=self.options.force if explicit else False) as tmp:
                write_png(tmp, rgba, alpha=False)

        if not self._attempt(save, f"saved {target}"):
            return
        self.report["screenshot"] = {"path": str(target), "camera": camera_to_json(camera), "time": t,
                                     "background": list(self.settings.background), "mode": self.settings.mode,
                                     "splat_scale": self.settings.splat_scale, "sh_degree": self.settings.sh_degree,
                                     "max_std_dev": self.settings.max_std_dev,
                                     "max_screen_radius": self.settings.max_screen_radius,
                                     "near_plane": self.settings.near_plane,
                                     "temporal_fade": self.settings.temporal_fade}

    def _next_screenshot_name(self) -> str:
        folder = Path(self.options.screenshot_dir)
        for i in range(1, 100000):
            p = folder / f"splatreel_{i:04d}.png"
            if not p.exists():
                return str(p)
        raise GLError(f"{folder}: too many screenshots")

    # --- input --------------------------------------------------------------------------------------------------
    def _handle_input(self, dt: float) -> None:
        import glfw
        from imgui_bundle import imgui

        io = imgui.get_io()
        c = self.controller
        width, height = glfw.get_framebuffer_size(self._window)
        win_w, win_h = glfw.get_window_size(self._window)
        # window coordinates -> framebuffer pixels (they differ on high-DPI screens)
        kx, ky = width / max(win_w, 1), height / max(win_h, 1)
        cursor = (io.mouse_pos.x, io.mouse_pos.y)
        clicked = imgui.is_mouse_clicked(imgui.MouseButton_.left)
        ed = self._editor
        if ed.drag is not None:  # a selection rectangle: follows the cursor until the button is released
            ed.drag[2:] = cursor
            if not imgui.is_mouse_down(imgui.MouseButton_.left):
                x0, y0, x1, y1 = ed.drag
                rect, ed.drag = (x0 * kx, y0 * ky, x1 * kx, y1 * ky), None
                camera, t = self._current_view(width, height)
                self._attempt(lambda: self.select_rect(camera, t, rect, "remove" if ed.drag_removes else "add"))
        elif not io.want_capture_mouse:
            d = io.mouse_delta
            tool = self.inspect if io.key_ctrl else self.measure if io.key_alt and not io.key_shift else None
            x, y = int(cursor[0] * kx), int(cursor[1] * ky)
            if clicked and tool is not None:  # Ctrl+click inspects, Alt+click measures the pixel under the cursor
                if 0 <= x < width and 0 <= y < height:
                    camera, t = self._current_view(width, height)
                    self._attempt(lambda: tool(camera, t, x, y))
            elif clicked and io.key_shift:
                ed.drag, ed.drag_removes = [*cursor, *cursor], io.key_alt
            elif imgui.is_mouse_down(imgui.MouseButton_.left) and not (io.key_ctrl or io.key_alt) and (d.x or d.y):
                c.look(d.x, d.y) if self._fly else c.orbit(d.x, d.y)
                self._path.playing = False
            if (imgui.is_mouse_down(imgui.MouseButton_.right) or imgui.is_mouse_down(imgui.MouseButton_.middle)) \
                    and (d.x or d.y):
                c.pan(d.x, d.y, height)
                self._path.playing = False
            if io.mouse_wheel:
                c.zoom(io.mouse_wheel)
        if io.want_capture_keyboard:
            return
        key = imgui.Key
        down = imgui.is_key_down
        fwd = float(down(key.w)) - float(down(key.s))
        right = float(down(key.d)) - float(down(key.a))
        upward = float(down(key.e)) - float(down(key.q))
        if fwd or right or upward:
            speed = self.framing.radius * (4.0 if down(key.left_shift) else 1.0)
            c.fly(fwd, right, upward, dt, speed)
            self._path.playing = False
        if imgui.is_key_pressed(key.space, False):
            self.playback.playing = not self.playback.playing
        for k, frames in ((key.left_arrow, -1), (key.right_arrow, 1), (key.comma, -1), (key.period, 1)):
            if imgui.is_key_pressed(k, True):
                self.playback.step(frames)
        if imgui.is_key_pressed(key.r, False):
            c.reset(self.framing)
        if imgui.is_key_pressed(key.f, False):
            self._fly = not self._fly
        if imgui.is_key_pressed(key.p, False):
            self._screenshot_request = self._next_screenshot_name()
        if imgui.is_key_pressed(key.delete, False) or imgui.is_key_pressed(key.backspace, False):
            self._attempt(self.delete_selected)
        if io.key_ctrl and imgui.is_key_pressed(key.z, False):
            self._attempt(self._undo)
        if imgui.is_key_pressed(key.escape, False):
            glfw.set_window_should_close(self._window, True)

    # --- panel --------------------------------------------------------------------------------------------------
    def _draw_ui(self) -> None:
        from imgui_bundle import imgui

        imgui.set_next_window_pos((10, 10), imgui.Cond_.first_use_ever)
        imgui.set_next_window_size((370, 0), imgui.Cond_.first_use_ever)
        imgui.begin("splatreel")
        st, pb = self._stats, self.playback
        imgui.text(f"{imgui.get_io().framerate:5.1f} FPS  frame {st.frame_ms:5.1f} ms")
        imgui.text(f"sort {st.sort_ms:5.1f} ms  draw {st.frame.draw_ms + st.frame.upload_ms:5.1f} ms")
        imgui.text(f"visible {st.frame.visible:,} / {st.frame.total:,} Gaussians")
        why = "moving" if st.moving else "animating" if st.playing else None
        imgui.text(f"resolution {100 * st.scale:3.0f}%" + (f"  ({why})" if why and st.scale < 1 else ""))

        imgui.separator_text("Time")
        t0, t1 = pb.time_range
        if imgui.arrow_button("##back", imgui.Dir.left):
            pb.step(-1)
        imgui.same_line()
        if imgui.button("Pause" if pb.playing else "Play"):
            pb.playing = not pb.playing
        imgui.same_line()
        if imgui.arrow_button("##on", imgui.Dir.right):
            pb.step(1)
        if imgui.is_item_hovered():
            imgui.set_tooltip("one frame on (right arrow; left arrow: back)")
        imgui.same_line()
        _, pb.loop = imgui.checkbox("loop", pb.loop)
        changed, value = imgui.slider_float("time", pb.time, t0, t1, "%.3f")
        if changed:
            pb.time, pb.playing = value, False
        _, pb.speed = imgui.slider_float("speed", pb.speed, 0.0, 4.0, "%.2fx")

        # the rest in tabs: as sections they outgrew a 720-pixel window
        if imgui.begin_tab_bar("##sections"):
            for name, draw, selected in (("View", self._draw_view_ui, False),
                                         ("Path", self._draw_path_ui, False),
                                         ("Edit", self._draw_edit_ui, self._edit_tab_first),
                                         ("Inspect", self._draw_inspect_ui, self._inspect.reveal)):
                flags = imgui.TabItemFlags_.set_selected if selected else 0
                if imgui.begin_tab_item(name, None, flags)[0]:
                    draw()
                    imgui.end_tab_item()
            self._edit_tab_first = self._inspect.reveal = False
            imgui.end_tab_bar()
        self._apply_crop_edits()
        ed = self._editor
        if ed.drag is not None:  # the selection rectangle (window coordinates, as imgui draws)
            x0, y0, x1, y1 = normalise_rect(*ed.drag)
            r, g, b = SELECTION_COLOR
            imgui.get_foreground_draw_list().add_rect((x0, y0), (x1, y1),
                                                      imgui.IM_COL32(int(255 * r), int(255 * g), int(255 * b), 255),
                                                      0.0, 1.5)

        imgui.separator_text("File")
        changed, self._open_text = imgui.input_text("##open", getattr(self, "_open_text", ""))
        imgui.same_line()
        if imgui.button("Open"):
            self._pending_open = self._open_text
        imgui.text_wrapped(self.status or "drop a model file on the window to open it")
        imgui.end()

    def _draw_view_ui(self) -> None:
        from imgui_bundle import imgui

        st, pb, s, c = self._stats, self.playback, self.settings, self.controller
        imgui.separator_text("Camera")
        if imgui.button("Reset (R)"):
            c.reset(self.framing)
        imgui.same_line()
        _, self._fly = imgui.checkbox("fly mode (F)", self._fly)
        _, c.fov = imgui.slider_float("fov", c.fov, 10.0, 120.0, "%.0f deg")
        if self._views:
            _, self._view_index = imgui.slider_int("dataset view", self._view_index, 0, len(self._views) - 1)
            if imgui.button("Snap to dataset camera"):
                v = self._views[self._view_index]
                c.snap(v.camera)
                pb.time, pb.playing = v.time, False
                self._path.playing = False
            imgui.same_line()
            imgui.text(Path(self._views[self._view_index].name).name)
            _, self._show_cameras = imgui.checkbox("show dataset cameras", self._show_cameras)

        imgui.separator_text("Look")
        _, mode = imgui.combo("mode", RENDER_MODES.index(s.mode), list(RENDER_MODES))
        s.mode = RENDER_MODES[mode]
        if s.mode in VALUE_MODES:  # the colour map's legend
            lo, hi = st.frame.value_range
            imgui.text_wrapped({
                "depth": f"red = near ({lo:.3g}), blue = far ({hi:.3g})",
                "speed": f"blue = still ({lo:.3g}), red = fast ({hi:.3g} units per unit of model time)",
                "lifespan": f"time each Gaussian is drawn: blue = brief, red = the whole time range ({hi:.3g})",
                "fade": "temporal opacity factor: red = at its peak (1), blue = fading in or out",
            }[s.mode])
        changed, scale = imgui.slider_float("splat scale", s.splat_scale, 0.05, 3.0, "%.2f",
                                            imgui.SliderFlags_.always_clamp)
        if changed:  # only then: the slider's float32 round trip would change a value given on the command line
            s.splat_scale = scale
        self._draw_footprint_ui(s)
        max_deg = self.renderer.splats.sh_degree if self.renderer.splats is not None else 0
        deg = max_deg if s.sh_degree is None else min(s.sh_degree, max_deg)
        changed, deg = imgui.slider_int("SH degree", deg, 0, max_deg)
        if changed:
            s.sh_degree = deg
        _, bg = imgui.color_edit3("background", list(s.background))
        s.background = tuple(float(x) for x in bg)
        _, comp = imgui.combo("blending", COMPOSITE_ORDERS.index(s.composite), list(COMPOSITE_ORDERS))
        s.composite = COMPOSITE_ORDERS[comp]
        res = self.resolution
        changed, eighths = imgui.slider_int("resolution", round(8 * res.step_of(res.scale)), 2, 8, "%d/8")
        if changed:
            res.scale = eighths / 8
        _, res.adaptive = imgui.checkbox("lower while moving", res.adaptive)
        if imgui.is_item_hovered():
            imgui.set_tooltip(f"draw fewer pixels while the view moves, to keep frames under {res.budget_ms:.0f} ms")
        if res.adaptive:
            imgui.same_line()
            _, res.while_playing = imgui.checkbox("and playing", res.while_playing)
            if imgui.is_item_hovered():
                imgui.set_tooltip("also while the animation plays under a still camera (sharp again when paused)")
        if imgui.button("Screenshot (P)"):
            self._screenshot_request = self._next_screenshot_name()

    @staticmethod
    def _draw_footprint_ui(s: RenderSettings) -> None:
        """The footprint caps (`sorting.Footprint`; checkbox and slider each, off by default), near plane and
        temporal fade."""
        from imgui_bundle import imgui

        s.max_std_dev = _optional_slider(
            s.max_std_dev, "limit reach", "std-devs##reach", 1.0, 3.3, math.sqrt(8.0),
            "draw each splat out to at most this many std-devs: fewer pixels, harder edges\n"
            "(off: out to alpha 1/255 as the trainer, ~3.3; web viewers 2.83; fast 2.24)")
        s.max_screen_radius = _optional_slider(
            s.max_screen_radius, "limit screen size", "of height##radius", 0.01, 1.0, 0.25,
            "cap each splat's radius at a share of the window height,\n"
            "against huge splats close to the camera filling the screen")
        changed, near = imgui.slider_float("near plane", s.near_plane, 0.001, 1.0, "%.3f",
                                           imgui.SliderFlags_.logarithmic | imgui.SliderFlags_.always_clamp)
        if changed:
            s.near_plane = near
        if imgui.is_item_hovered():
            imgui.set_tooltip(f"Gaussians closer than this are not drawn ({NEAR_PLANE:g} as the trainer);\n"
                              "lower it to fly close to or into a model (with limit screen size)")
        changed, smooth = imgui.checkbox("smooth temporal fade", s.temporal_fade == "smooth")
        if changed:
            s.temporal_fade = "smooth" if smooth else "cut"
        if imgui.is_item_hovered():
            imgui.set_tooltip("fade Gaussians out at the end of their time window instead of dropping them\n"
                              "at 0.05 of their opacity (the trainer's cut, a small pop as time plays)")

    def _draw_path_ui(self) -> None:
        from imgui_bundle import imgui

        pe = self._path
        n = len(pe.path.keys) if pe.path else 0
        imgui.text(f"{n} keyframe(s)" + (f", {pe.path.duration:.1f} s" if n else ""))
        _, pe.key_interval = imgui.slider_float("key spacing", pe.key_interval, 0.1, 5.0, "%.1f s")
        if imgui.button("Add key"):
            import glfw

            width, height = glfw.get_framebuffer_size(self._window)  # the window as it is now, maybe resized
            cam = self.controller.camera(width, height)
            time_at = pe.path.keys[-1].time + pe.key_interval if pe.path else 0.0
            key = CameraKey.from_camera(time_at, cam, self.playback.time)
            pe.path = pe.path.with_key(key) if pe.path else CameraPath([key], self.controller.up)
        imgui.same_line()
        if imgui.button("Clear"):
            pe.path, pe.playing = None, False
        imgui.same_line()
        if imgui.button("Stop" if pe.playing else "Play path"):
            self._attempt(self._toggle_path)
        _, pe.file = imgui.input_text("path file", pe.file)
        if imgui.button("Save"):
            self._attempt(self._save_path, f"saved camera path {pe.file} ({PATH_FORMATS[pe.nerfstudio]})")
        imgui.same_line()
        if imgui.button("Load"):
            self._attempt(lambda: setattr(pe, "path", CameraPath.load(pe.file, self.model.time_range)),
                          f"loaded camera path {pe.file}")
        imgui.same_line()
        _, pe.overwrite = imgui.checkbox("overwrite", pe.overwrite)
        _, pe.show = imgui.checkbox("show path", pe.show)
        _, fmt = imgui.combo("save as", int(pe.nerfstudio), list(PATH_FORMATS))
        pe.nerfstudio = bool(fmt)
        if imgui.is_item_hovered():
            imgui.set_tooltip("nerfstudio: the path sampled at 30 FPS with each frame's scene time, for ns-render "
                              "camera-path (e.g. a dynamic NeRF of the same data); splatreel reads both")

    def _path_or_error(self) -> CameraPath:
        if self._path.path is None:
            raise SplatreelError("no camera path: Add key, or Load a path file")
        return self._path.path

    def _toggle_path(self) -> None:
        """Play the camera path from its start, or stop it."""
        pe = self._path
        if pe.playing:
            pe.playing = False
            return
        pe.time, pe.playing = self._path_or_error().start, True

    def _save_path(self) -> None:
        """Write the edited path to the path file: its keys (splatreel), or its frames at the window's size (nerfstudio,
        `path_as_nerfstudio`)."""
        pe = self._path
        self._path_or_error()
        if not pe.nerfstudio:
            pe.path.save(pe.file, force=pe.overwrite)
            return
        width, height = self.options.size
        if self._window is not None:
            import glfw

            width, height = glfw.get_framebuffer_size(self._window)
        atomic_write_json(pe.file, path_as_nerfstudio(pe.path, width, height, time_range=self.model.time_range),
                          force=pe.overwrite)

    def _draw_edit_ui(self) -> None:
        from imgui_bundle import imgui

        ce, ed = self._crop, self._editor
        edits = ed.edits
        imgui.separator_text("Crop box")
        _, ce.enabled = imgui.checkbox("crop to box", ce.enabled)
        imgui.same_line()
        _, ce.show = imgui.checkbox("show box", ce.show)
        step = max(self.framing.radius, 1e-3) / 200.0
        _, ce.lo = imgui.drag_float3("min", ce.lo, step, 0.0, 0.0, "%.3f")
        ce.dragging = imgui.is_item_active()
        _, ce.hi = imgui.drag_float3("max", ce.hi, step, 0.0, 0.0, "%.3f")
        ce.dragging = ce.dragging or imgui.is_item_active()
        if imgui.button("Fit to model"):
            ce.lo, ce.hi = self._extent[0].tolist(), self._extent[1].tolist()
        imgui.same_line()
        edited = ce.edited()
        option = "--crop " + " ".join(f"{x:.6g}" for x in (*edited.lo, *edited.hi))
        if imgui.button("Copy option"):
            imgui.set_clipboard_text(option)
        if imgui.is_item_hovered():
            imgui.set_tooltip(f"{option}\n(for splatreel convert / render / view)")

        imgui.separator_text("Delete Gaussians")
        imgui.text_wrapped("Shift+drag: select what shows in a rectangle now (Shift+Alt+drag: unselect); "
                           "Ctrl+click, then Select or Delete in the Inspect tab")
        imgui.text(f"{edits.num_selected:,} selected, {edits.num_deleted:,} deleted")
        if imgui.button("Delete (Del)"):
            self._attempt(self.delete_selected)
        imgui.same_line()
        if imgui.button("Invert"):  # among the Gaussians in the box (`invert_selection` leaves deleted ones out)
            edits.invert_selection(among=self._in_box(self._crop.shown))
        if imgui.is_item_hovered():
            imgui.set_tooltip("select every Gaussian not selected (e.g. select the object, invert, delete)")
        imgui.same_line()
        if imgui.button("Unselect"):
            edits.clear_selection()
        if imgui.button("Undo (Ctrl+Z)"):
            self._attempt(self._undo)
        imgui.same_line()
        if imgui.button("Restore all"):
            self._attempt(self._restore_all)

        imgui.separator_text("Save")
        imgui.text(f"{len(self.renderer.model):,} of {len(self.model):,} Gaussians shown")
        _, ed.file = imgui.input_text("file##edit", ed.file)
        if imgui.button("Save edited"):
            self._attempt(self._save_edited)
        if imgui.is_item_hovered():
            imgui.set_tooltip("write what the window shows: the cropped model without its deleted Gaussians")
        imgui.same_line()
        _, ed.overwrite = imgui.checkbox("overwrite##edit", ed.overwrite)

    def _apply_crop_edits(self) -> None:
        """Show the edited box: at once when cropping is quick, else when the drag is released."""
        ce = self._crop
        if ce.box() != ce.shown and (not ce.dragging or ce.apply_ms < LIVE_CROP_MS):
            self._apply_edits(self.playback.time)
            if not len(self.renderer.model):  # as `--crop` says of such a box, instead of an empty window
                self.status = f"the crop box holds none of the {len(self.model):,} Gaussians"

    def _draw_inspect_ui(self) -> None:
        from imgui_bundle import imgui

        self._draw_pick_ui()
        imgui.separator_text("Measure")
        m = self._measure
        if not m.points:
            imgui.text_wrapped("Alt+click two points of the model: the distance between the surfaces there")
            return
        for i, p in enumerate(m.points):
            imgui.text(f"point {i + 1}: {vector_text(p)}")
        imgui.text(f"distance {m.distance:.4g}" if m.distance is not None else "Alt+click the second point")
        if imgui.button("Clear##measure"):
            self._measure = _Measure()

    def _draw_pick_ui(self) -> None:
        from imgui_bundle import imgui

        ins = self._inspect
        if ins.stack is None:
            imgui.text_wrapped("Ctrl+click the model: the Gaussians that make that pixel, largest share first")
            return
        x, y = ins.stack.pixel
        ranked = ins.ranked
        imgui.text(f"pixel ({x}, {y}): alpha {ins.stack.alpha:.3f}, {len(ranked)} Gaussian(s)")
        if not ranked:
            return
        if len(ranked) > 1:
            changed, rank = imgui.slider_int("by share", ins.rank + 1, 1, len(ranked), f"%d of {len(ranked)}")
            if changed:
                ins.rank = rank - 1
        hit = ins.hit
        imgui.text(f"share of the pixel {hit.weight:.3f}  alpha there {hit.alpha:.3f}")
        imgui.color_button("##colour", (*[min(max(c, 0.0), 1.0) for c in hit.color], 1.0))
        imgui.same_line()
        imgui.text("colour (" + ", ".join(f"{c:.3f}" for c in hit.color) + f")  depth {hit.depth:.4g}")
        inspected = self._inspected(self.playback.time)
        if inspected is not None and imgui.begin_table("##gaussian", 2):
            imgui.table_setup_column("attribute", imgui.TableColumnFlags_.width_fixed)
            imgui.table_setup_column("value", imgui.TableColumnFlags_.width_stretch)
            for label, value in inspected[0]:
                imgui.table_next_row()
                imgui.table_next_column()
                imgui.text(label)
                imgui.table_next_column()
                imgui.text(value)
            imgui.end_table()
        if imgui.button("Go to peak time"):
            self.playback.time, self.playback.playing = peak_time(self.renderer.model, hit.index), False
        if imgui.is_item_hovered():
            imgui.set_tooltip("pause at the time this Gaussian shows most")
        imgui.same_line()
        if imgui.button("Select"):
            self._attempt(self.select_inspected)
        if imgui.is_item_hovered():
            imgui.set_tooltip("add this Gaussian to the selection (Edit tab)")
        imgui.same_line()
        if imgui.button("Delete"):
            self._attempt(self._delete_inspected)
        if imgui.is_item_hovered():
            imgui.set_tooltip("delete this Gaussian and inspect the pixel again (Ctrl+Z undoes)")
        imgui.same_line()
        if imgui.button("Clear##inspect"):
            self._inspect = _Inspector()


def run_app(source, options: AppOptions | None = None) -> dict:
    """Open the viewer on `source` (a model path or `Checkpoint`) and block until it closes."""
    return ViewerApp(source, options).run()


def _optional_slider(value: float | None, label: str, slider: str, lo: float, hi: float, default: float,
                     tooltip: str) -> float | None:
    """A checkbox `label` (None when unticked; ticking starts at `default`) with a slider from `lo` to `hi` beside
    it while ticked; returns the new value."""
    from imgui_bundle import imgui

    changed, on = imgui.checkbox(label, value is not None)
    if changed:
        value = default if on else None
    if imgui.is_item_hovered():
        imgui.set_tooltip(tooltip)
    if value is not None:
        imgui.same_line()
        # (clamped: a value typed with Ctrl+click stays in range, so the settings stay valid)
        changed, moved = imgui.slider_float(slider, value, lo, hi, "%.2f", imgui.SliderFlags_.always_clamp)
        if changed:  # only then: the slider's float32 round trip would change a value given on the command line
            value = moved
    return value
