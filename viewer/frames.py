"""The desktop app's frames, planned without a window: `FramePlanner.next` advances time (and a playing camera path),
picks the camera and the resolution and has the Gaussians sorted; the window draws the `Frame` it returns, then
hands back what it cost (`drawn`), its pixels when a screenshot was asked for (`save_screenshot`), and draws the
`overlay_lines` over it.

Sorting runs in a worker thread (`AsyncSorter`): every frame is drawn with the newest finished back-to-front order
and a new sort is requested whenever the camera, the time or the splat scale changed, so the UI never waits for a
sort. Screenshots are the exception: they wait for the order of their exact view.

While the view moves or the animation plays, frames are drawn at a lower resolution when the full one would not fit
the frame budget (`Resolution`) and stretched to the window; at rest they are sharp again. Screenshots are always
full resolution.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from splatreel.cameras import Camera
from splatreel.fileio import atomic_path

from .app_data import camera_to_json
from .controls import scaled_size
from .output import write_png
from .overlay import (CROP_COLOR, DATASET_COLOR, KEY_COLOR, MEASURE_COLOR, PATH_COLOR, PICK_COLOR, SELECTED_COLOR,
                      SELECTION_COLOR, Frustums, box_segments, path_segments)
from .render_settings import FrameStats
from .sorting import AsyncSorter, SortKey, SortResult, view_key
from .state import AppState

#: the longest step of time between two frames: a stall (file load, first frame) must not make time jump
MAX_FRAME_STEP = 0.1


@dataclass
class Frame:
    """What to draw this frame: the window's camera `view` at model time `t`, drawn as `camera` (the view at
    `scale` of the window's pixels per axis, stretched to the window) in sort `order`."""

    view: Camera
    camera: Camera
    t: float
    scale: float
    order: SortResult
    #: whether the camera moved / the model time changed since the frame before
    moving: bool
    playing: bool
    #: save this frame's pixels here (`FramePlanner.save_screenshot`)
    screenshot: str | None = None


class FramePlanner:
    """Plans the frames of an `AppState` (see module doc) and owns its sorting thread; `close` stops it."""

    def __init__(self, app: AppState) -> None:
        self.app = app
        self.sorter = AsyncSorter()
        self._requested: tuple | None = None  # (generation, `SortKey`) of the last sort asked for
        self._last_pose: tuple | None = None
        self._last_time: float | None = None
        self._overlay_cache: tuple | None = None

    def close(self) -> None:
        self.sorter.close()

    def next(self, dt: float, width: int, height: int) -> Frame | None:
        """Advance the time by `dt` seconds and plan the frame of a `width` x `height` window; None when there is
        nothing to draw (a minimised window, no sort yet)."""
        app = self.app
        dt = min(dt, MAX_FRAME_STEP)
        app.playback.advance(dt)
        pe = app._path
        if pe.playing and pe.path is not None:
            pe.time += dt
            if pe.time > pe.path.start + pe.path.duration and not pe.path.loop:
                pe.time, pe.playing = pe.path.start + pe.path.duration, False
        if width <= 0 or height <= 0:  # minimised
            return None
        view, t = app._current_view(width, height)
        screenshot = app._screenshot_request
        pose = view_key(view)
        moving, self._last_pose = pose != self._last_pose and self._last_pose is not None, pose
        playing, self._last_time = t != self._last_time and self._last_time is not None, t
        changing = app.resolution.changing(moving, playing)
        scale = 1.0 if screenshot else app.resolution.choose(changing, width, height)
        camera = view if scale == 1.0 else view.resized(*scaled_size(width, height, scale))
        order = self._sort(camera, t, wait=screenshot is not None)
        if order is None:
            return None
        return Frame(view, camera, t, scale, order, moving, playing, screenshot)

    def _sort(self, camera: Camera, t: float, wait: bool) -> SortResult | None:
        """Ask for the order of (camera, t) unless already asked, and return the newest one of the shown Gaussians;
        wait for the one asked for on the first frame of a model, for a screenshot (`wait`), and on the first frame
        after a cap or the near plane changed (an order of another footprint bounds nothing here)."""
        app = self.app
        footprint = app.settings.footprint
        splats = app.renderer.splats_at(t)  # (re-slices a keyframed model when t changed)
        key = SortKey.of(camera, t, footprint)
        if self._requested != (app._generation, key):
            self.sorter.request(splats, camera, t, footprint, tag=app._generation)
            self._requested = (app._generation, key)
        app._take_sort_result(self.sorter.poll())
        if app._order is None or wait or app._order.needs_sort(camera, footprint):
            app._take_sort_result(self.sorter.wait())
        return app._order

    def drawn(self, frame: Frame, stats: FrameStats) -> None:
        """Record what drawing `frame` cost and drew: for the resolution's predictions, the panel and the report."""
        app = self.app
        app.resolution.observe(stats.draw_ms + stats.upload_ms, frame.scale)
        st = app._stats
        st.frame, st.scale, st.moving, st.playing = stats, frame.scale, frame.moving, frame.playing
        app.report.setdefault("resolutions", set()).add(frame.scale)
        app.report["moving_frames"] = app.report.get("moving_frames", 0) + frame.moving

    def save_screenshot(self, frame: Frame, rgb: np.ndarray) -> None:
        """Save `rgb` (``[H, W, 3]`` uint8, top row first: what the window shows of `frame`, without the panel) to
        `frame.screenshot` as a PNG, with its view and look in the report."""
        app = self.app
        app._screenshot_request = None
        explicit = frame.screenshot is app.options.screenshot  # ``--screenshot``: overwritten with ``--force``
        target = Path(frame.screenshot)
        rgba = np.concatenate([rgb.astype(np.float32) / 255.0, np.ones((*rgb.shape[:2], 1), np.float32)], -1)

        def save() -> None:
            with atomic_path(target, force=app.options.force if explicit else False) as tmp:
                write_png(tmp, rgba, alpha=False)

        if not app._attempt(save, f"saved {target}"):
            return
        s = app.settings
        app.report["screenshot"] = {"path": str(target), "camera": camera_to_json(frame.camera), "time": frame.t,
                                    "background": list(s.background), "mode": s.mode, "splat_scale": s.splat_scale,
                                    "sh_degree": s.sh_degree, "max_std_dev": s.max_std_dev,
                                    "max_screen_radius": s.max_screen_radius, "near_plane": s.near_plane,
                                    "temporal_fade": s.temporal_fade}

    def overlay_lines(self, view: Camera) -> tuple[np.ndarray, np.ndarray]:
        """(``[M, 2, 3]`` segments, ``[M, 3]`` colours) to draw over the splats seen by `view`: the measuring tape,
        the selection's crosses, the inspected Gaussian's ellipsoid, the crop box, the camera path and the key and
        dataset camera frustums (one at the viewing camera's own position, snapped to it or flying the path, is
        left out)."""
        app = self.app
        depth = 0.15 * app.framing.radius  # frustum size
        path_lines, frustums = self._overlay_geometry(view.width, view.height, depth)
        segs, colors = frustums.lines(view.position, 1e-3 * depth)
        ce = app._crop
        box = ce.edited() if ce.show else None  # shown while placed, before it crops
        box_lines = box_segments(box.lo, box.hi) if box is not None else np.zeros((0, 2, 3))
        inspected = app._inspected(app.playback.time)
        pick_lines = inspected[1] if inspected is not None else np.zeros((0, 2, 3))
        marks = app._selection_markers(view)
        app.report["markers"] = len(marks) // 3
        layers = ((app._measure_lines(view), MEASURE_COLOR), (marks, SELECTION_COLOR), (pick_lines, PICK_COLOR),
                  (box_lines, CROP_COLOR), (path_lines, PATH_COLOR))  # drawn in this order, then the frustums
        segs = np.concatenate([lines for lines, _ in layers] + [segs])
        colors = np.concatenate([np.broadcast_to(np.asarray(color, np.float32), (len(lines), 3))
                                 for lines, color in layers] + [colors])
        app.report["overlay_lines"] = len(segs)
        return segs, colors

    def _overlay_geometry(self, width: int, height: int, depth: float) -> tuple[np.ndarray, Frustums]:
        """(path polyline, `Frustums` of the path keys and dataset cameras), remade only when what they show
        changed: sampling a path evaluates a spline and a slerp per point, too slow for every frame."""
        app = self.app
        pe = app._path
        path = pe.path if pe.show else None
        views = app._views if app._show_cameras else ()  # () is one object: a stable cache key
        # the path and the view list are replaced, never changed in place; the cache holds them, so while it
        # lives their ids cannot be reused by new objects
        key = (id(path), id(views), app._view_index, depth, width, height)
        if self._overlay_cache is None or self._overlay_cache[0] != key:
            cameras, colors = [], []
            if path is not None:
                cameras += [path.camera(k.time, width, height) for k in path.keys]
                colors += [KEY_COLOR] * len(path.keys)
            cameras += [v.camera for v in views]
            colors += [SELECTED_COLOR if i == app._view_index else DATASET_COLOR for i in range(len(views))]
            lines = path_segments(path) if path is not None else np.zeros((0, 2, 3))
            self._overlay_cache = (key, lines, Frustums.of(cameras, colors, depth), (path, views))
        return self._overlay_cache[1], self._overlay_cache[2]
