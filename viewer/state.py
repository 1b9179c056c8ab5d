"""The desktop app's state: the model shown and its edits (load, crop, delete, undo, save), selection, inspect and
measure, the camera path being made, the newest sort of the shown Gaussians, the report and screenshots' file names.
No window and no imgui: `AppWindow` (``window.py``) drives it from glfw input, `FramePlanner` (``frames.py``) plans
each frame from it, `panels` draws it, and the tests drive it directly on a headless renderer
(``state.renderer = SplatRenderer(headless_context())``, then `load`).

Editing: the crop box (`splatreel.model.crop`: the Gaussians whose centre lies in the box when they show most; the
Edit tab copies the box as the ``--crop`` option of convert, render and export) and deleted Gaussians (`selection`:
a rectangle selects the Gaussians whose centre shows in it at the displayed time). The window shows exactly what
"Save edited" writes. Unsaved deletions are not dropped silently: opening another file or closing the window asks a
second time.

Inspect (`SplatRenderer.pick`): the Gaussians that make a pixel, ranked by their share of its colour, with the chosen
one's attributes (`splatreel.viewer.pick.describe`) and its 2-sigma ellipsoid drawn over the model as it moves.
Measure: the distance between the surfaces seen at two pixels (`PixelStack.surface_depth`, unprojected).
"""

from __future__ import annotations

import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from splatreel.errors import GLError, SplatreelError
from splatreel.fileio import atomic_write_json
from splatreel.model import CropBox, crop_mask

from .app_data import (LIVE_CROP_MS, AppOptions, CropEditor, DeletionEditor, Inspector, LiveStats, MeasureTape,
                       PathEditor, camera_to_json, edited_name)
from .camera_path import CameraKey, CameraPath, dataset_views
from .controls import CameraController, Playback, Resolution
from .overlay import ellipsoid_segments
from .pick import PixelStack, inspect_gaussian, vector_text
from .render_settings import RenderSettings
from .renderer import SplatRenderer
from .selection import Edits, centres_at, in_rect, marker_segments
from .sorting import SortKey, SortResult
from .splats import needs_per_frame_upload, to_arrays
from .trajectory import frame_model, framing_of, model_extent, path_as_nerfstudio


class AppState:
    """The app's state around one model at a time (see module doc). The window sets `renderer` and `size` (its
    framebuffer's), then calls `start`; the tests set a headless renderer and call `load`."""

    def __init__(self, source, options: AppOptions | None = None) -> None:
        """`source`: a model file path, or a `Checkpoint`."""
        self.options = o = options or AppOptions()
        self.status = ""
        self.report: dict = {"frames": 0}
        #: set by the window (or a test) before `start` / `load`
        self.renderer: SplatRenderer | None = None
        #: what `load` opened: the model, its checkpoint and file name; the look, playback and camera rig are made
        #: at the first load (from the options) and kept for the next models
        self.model = self.checkpoint = self.framing = self._extent = None
        self.source_name = ""
        self.settings: RenderSettings | None = None
        self.playback: Playback | None = None
        self.controller: CameraController | None = None
        #: the window's framebuffer size (`AppWindow` keeps it current; the view, Add key and Save path use it)
        self.size: tuple[int, int] = tuple(o.size)
        self.resolution = Resolution(scale=o.render_scale, adaptive=o.adaptive_resolution, budget_ms=o.frame_budget_ms,
                                     sharp_playback=o.sharp_playback)
        self._source = source
        self._pending_open: str | None = None  # a file dropped on the window or typed in the panel, opened next
        self._open_text = ""
        self._screenshot_request: str | None = None  # taken at the next frame
        self._fly = False
        self._stats = LiveStats()
        self._path = PathEditor()
        self._crop = CropEditor()
        self._editor = DeletionEditor()
        self._inspect = Inspector()
        self._measure = MeasureTape()
        self._edit_tab_first = o.crop is not None  # --crop: show the Edit tab at start-up
        self._views = []
        self._view_index = 0
        self._show_cameras = True
        #: the newest sort of the shown Gaussians (`FramePlanner` requests them) and which set they are: each edit
        #: makes a new generation, and sorts of an older one no longer apply
        self._order: SortResult | None = None
        self._generation = 0

    # --- start and end ------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Open what the options name as the window opens: the dataset cameras (before the model: `load` steps
        frames through their times), the model, the camera path, then the ``--inspect`` pixel and the ``--select``
        rectangle of the window's view."""
        o = self.options
        if o.cameras:
            self._views = dataset_views(o.cameras, o.split)
        self.load(self._source)
        if o.camera_path:
            pe = self._path
            pe.path, pe.file = CameraPath.load(o.camera_path, self.model.time_range), o.camera_path
            if o.play_path:
                pe.playing, pe.time = True, pe.path.start
        self.report.update(time_start=self.playback.time, started=time.time())
        if o.inspect is not None:
            self.inspect(*self._current_view(*self.size), *o.inspect)
        if o.select is not None:
            self.select_rect(*self._current_view(*self.size), o.select)
            self._edit_tab_first = True

    @property
    def title(self) -> str:
        """The window's title: the open file's name, then the tool's."""
        return f"{os.path.basename(self.source_name)} - splatreel" if self.source_name else "splatreel"

    def finish(self, frames: int) -> dict:
        """The report's totals after `frames` frames, written to the options' report file when one is named."""
        self.report.update(frames=frames, time_end=self.playback.time, sorts=self._stats.sorts,
                           seconds=time.time() - self.report["started"],
                           resolutions=sorted(self.report.get("resolutions", ())))
        if self.options.report:
            atomic_write_json(self.options.report, self.report, force=True)
        return self.report

    # --- the model ----------------------------------------------------------------------------------------------
    def load(self, source) -> None:
        """Show a model file (or `Checkpoint`); on failure keep the current model and report the error."""
        from splatreel.formats import read_checkpoint

        ckpt = read_checkpoint(source) if isinstance(source, (str, os.PathLike)) else source
        model = ckpt.model
        first_load = self.renderer.model is None
        t0, t1 = model.time_range
        start = self.options.time if (first_load and self.options.time is not None) else 0.5 * (t0 + t1)
        extent = model_extent(model)  # once: over a second for 1M Gaussians
        name = str(source if isinstance(source, (str, os.PathLike)) else getattr(ckpt, "path", "model"))
        old = self._editor
        # Save edited writes <name>_edited.safetensors unless the user typed a file; overwriting is asked anew
        file = old.file if old.file != edited_name(self.source_name) else edited_name(name)
        state = ("_crop", "_editor", "_measure", "model", "checkpoint", "_extent", "source_name")
        before = {k: getattr(self, k) for k in state}
        self._crop = self._initial_crop(extent, self.options.crop if first_load else None)
        self._editor = DeletionEditor(edits=Edits.of(len(model)), file=file)
        self.model, self.checkpoint, self._extent, self.source_name = model, ckpt, extent, name
        self._measure = MeasureTape()  # points on the previous model
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
        self.report["title"] = self.title
        if not self.options.cameras:
            self._views = self._training_views(ckpt)
        self._update_frame_times()

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

    def _update_frame_times(self) -> None:
        """The times that frame stepping visits: a keyframed model's keys, else its dataset's frame times."""
        keys = getattr(self.model, "times", None)
        times = keys.tolist() if keys is not None else sorted({v.time for v in self._views})
        self.playback.frame_times = tuple(float(t) for t in times)

    def _open(self, path: str) -> None:
        if not self._drops_unsaved_edits("open the file"):
            self._attempt(lambda: self.load(path))

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

    # --- crop box and deletions --------------------------------------------------------------------------------
    @staticmethod
    def _initial_crop(extent: tuple[np.ndarray, np.ndarray], values) -> CropEditor:
        """A new model's crop editor: off, with the box at the model's extent (`model_extent`); on at `values`
        (``--crop``) when given."""
        if values is not None:
            box = CropBox.of(values)
            return CropEditor(enabled=True, lo=list(box.lo), hi=list(box.hi), show=True)
        return CropEditor(lo=extent[0].tolist(), hi=extent[1].tolist())

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
        self._order = None
        ce.shown, ce.apply_ms = box, (time.perf_counter() - start) * 1e3
        self.report.update(shown_gaussians=len(shown), deleted=ed.edits.num_deleted)
        self._inspect = Inspector()  # its indices were into the previous set of Gaussians
        return shown

    def _apply_crop_edits(self) -> None:
        """Show the edited box: at once when cropping is quick, else when the drag is released."""
        ce = self._crop
        if ce.box() != ce.shown and (not ce.dragging or ce.apply_ms < LIVE_CROP_MS):
            self._apply_edits(self.playback.time)
            if not len(self.renderer.model):  # as `--crop` says of such a box, instead of an empty window
                self.status = f"the crop box holds none of the {len(self.model):,} Gaussians"

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

    # --- inspect and measure -----------------------------------------------------------------------------------
    def inspect(self, camera, t: float, x: int, y: int) -> PixelStack:
        """Pick pixel (x, y) of `camera`'s image at time `t` (`SplatRenderer.pick`) and show its Gaussians in the
        Inspect panel, the largest share first."""
        stack = self.renderer.pick(camera, t, x, y, self.settings)
        self._inspect = Inspector(stack, camera=camera, reveal=True)
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

    def _inspected_gaussian(self) -> int:
        """The loaded model's index of the Gaussian shown in the Inspect tab."""
        hit = self._inspect.hit
        if hit is None:
            raise SplatreelError("Ctrl+click the model first: nothing is inspected")
        return int(self._editor.shown_index[hit.index])

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

    # --- view, camera path, sorting, screenshots ---------------------------------------------------------------
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

    def snap_to_view(self) -> None:
        """Look through the dataset camera chosen in the View tab, paused at its time."""
        v = self._views[self._view_index]
        self.controller.snap(v.camera)
        self.playback.time, self.playback.playing = v.time, False
        self._path.playing = False

    def add_path_key(self) -> None:
        """Add the window's view now as the camera path's next key, `PathEditor.key_interval` after the last."""
        pe = self._path
        camera = self.controller.camera(*self.size)  # the window as it is now, maybe resized
        time_at = pe.path.keys[-1].time + pe.key_interval if pe.path else 0.0
        key = CameraKey.from_camera(time_at, camera, self.playback.time)
        pe.path = pe.path.with_key(key) if pe.path else CameraPath([key], self.controller.up)

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
        width, height = self.size
        atomic_write_json(pe.file, path_as_nerfstudio(pe.path, width, height, time_range=self.model.time_range),
                          force=pe.overwrite)

    def _take_sort_result(self, res: SortResult | None) -> None:
        """Keep a finished sort (`AsyncSorter`) when it is of the Gaussians shown now."""
        if res is not None and res.tag == self._generation:
            self._order = res
            self._stats.sort_ms = res.ms
            self._stats.sorts += 1

    def _next_screenshot_name(self) -> str:
        """Where the next screenshot taken with P goes: the first free ``splatreel_NNNN.png`` of the screenshot
        folder."""
        folder = Path(self.options.screenshot_dir)
        for i in range(1, 100000):
            p = folder / f"splatreel_{i:04d}.png"
            if not p.exists():
                return str(p)
        raise GLError(f"{folder}: too many screenshots")
