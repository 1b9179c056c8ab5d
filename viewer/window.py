"""The desktop app's window: glfw + Dear ImGui (imgui-bundle's native glfw/OpenGL3 backends) set-up, the frame
loop and input (keys, mouse), over an `AppState`. The panel is drawn by `panels`.

Sorting runs in a worker thread (`AsyncSorter`): every frame is drawn with the newest finished back-to-front order
and a new sort is requested whenever the camera, the time or the splat scale changed, so the UI never waits for a
sort. Screenshots are the exception: they wait for the order of their exact view.

While the view moves or the animation plays, frames are drawn at a lower resolution when the full one would not fit
the frame budget (`Resolution`) and stretched to the window; at rest they are sharp again. Screenshots are always
full resolution.
"""

from __future__ import annotations

import ctypes
import re
import time
from pathlib import Path

from imgui_bundle import imgui  # first: it sets PYGLFW_LIBRARY so that glfw shares imgui's libglfw

import glfw
import moderngl
import numpy as np

from splatreel.errors import GLError
from splatreel.fileio import atomic_path, atomic_write_json

from .camera_path import CameraPath, dataset_views
from .controls import scaled_size
from .output import write_png
from .overlay import (CROP_COLOR, DATASET_COLOR, KEY_COLOR, MEASURE_COLOR, PATH_COLOR, PICK_COLOR, SELECTED_COLOR,
                      SELECTION_COLOR, Frustums, LineRenderer, box_segments, path_segments)
from .panels import draw_panel
from .renderer import SplatRenderer
from .sorting import AsyncSorter, SortKey, view_key
from .state import AppState, camera_to_json


class AppWindow:
    """The window around an `AppState`; ``run()`` blocks until the window closes."""

    def __init__(self, app: AppState) -> None:
        self.app = app
        self._window = None
        self._overlay_cache: tuple | None = None

    def _init_window(self) -> None:
        app = self.app
        glfw.ERROR_REPORTING = "exception"  # set-up failures become one-line errors, not warnings
        try:
            if not glfw.init():
                raise GLError("could not initialise glfw")
            glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
            glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
            glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
            glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
            w, h = app.options.size
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
        glfw.swap_interval(1 if app.options.vsync else 0)
        glfw.set_drop_callback(window, self._on_drop)
        self.ctx = moderngl.create_context(require=330)
        imgui.create_context()
        io = imgui.get_io()
        io.set_ini_filename(None)  # no imgui.ini in the user's folder
        addr = ctypes.cast(window, ctypes.c_void_p).value
        if not (imgui.backends.glfw_init_for_opengl(addr, True) and imgui.backends.opengl3_init("#version 330")):
            raise GLError("could not initialise the Dear ImGui glfw/OpenGL3 backends")
        app.renderer = SplatRenderer(self.ctx)
        self.overlay = LineRenderer(self.ctx)
        self.sorter = AsyncSorter()

    def _on_drop(self, _window, paths) -> None:
        app = self.app
        if paths:
            app._pending_open = str(paths[0])

    def run(self) -> dict:
        """Open the window and loop until it is closed (or `exit_after` frames); returns the report dict."""
        app = self.app
        self._init_window()
        try:
            if app.options.cameras:  # before the model: `load` steps frames through these views' times
                app._views = dataset_views(app.options.cameras, app.options.split)
            app.load(app._source)
            if app.options.camera_path:
                app._path.path = CameraPath.load(app.options.camera_path, app.model.time_range)
                app._path.file = app.options.camera_path
                if app.options.play_path:
                    app._path.playing, app._path.time = True, app._path.path.start
            app.report.update(time_start=app.playback.time, started=time.time())
            width, height = glfw.get_framebuffer_size(self._window)
            if app.options.inspect is not None:
                app.inspect(*app._current_view(width, height), *app.options.inspect)
            if app.options.select is not None:
                app.select_rect(*app._current_view(width, height), app.options.select)
                app._edit_tab_first = True
            last = time.perf_counter()
            frames = 0
            while True:
                if glfw.window_should_close(self._window):
                    if not app._drops_unsaved_edits("close the window"):
                        break
                    glfw.set_window_should_close(self._window, False)
                glfw.poll_events()
                app.size = glfw.get_framebuffer_size(self._window)
                now = time.perf_counter()
                dt, last = now - last, now
                imgui.backends.opengl3_new_frame()
                imgui.backends.glfw_new_frame()
                imgui.new_frame()
                if app._pending_open:
                    path, app._pending_open = app._pending_open, None
                    app._open(path)
                final = app.options.exit_after is not None and frames + 1 >= app.options.exit_after
                if final and app.options.screenshot:
                    app._screenshot_request = app.options.screenshot
                self._handle_input(dt)
                self._draw_frame(dt)
                draw_panel(app)
                imgui.render()
                imgui.backends.opengl3_render_draw_data(imgui.get_draw_data())
                glfw.swap_buffers(self._window)
                frames += 1
                if final:
                    break
            app.report.update(frames=frames, time_end=app.playback.time, sorts=app._stats.sorts,
                               seconds=time.time() - app.report["started"],
                               resolutions=sorted(app.report.get("resolutions", ())))
        finally:
            self._shutdown()
        if app.options.report:
            atomic_write_json(app.options.report, app.report, force=True)
        return app.report

    def _shutdown(self) -> None:
        app = self.app
        if getattr(self, "sorter", None) is not None:
            self.sorter.close()
        if self._window is not None:
            if getattr(app, "renderer", None) is not None:
                app.renderer.release()
            if getattr(self, "overlay", None) is not None:
                self.overlay.release()
            imgui.backends.opengl3_shutdown()
            imgui.backends.glfw_shutdown()
            imgui.destroy_context()
            glfw.destroy_window(self._window)
            self._window = None
        glfw.terminate()

    def _draw_frame(self, dt: float) -> None:
        app = self.app
        t_frame = time.perf_counter()
        dt = min(dt, 0.1)  # a stall (file load, first frame) must not make time jump
        app.playback.advance(dt)
        pe = app._path
        if pe.playing and pe.path is not None:
            pe.time += dt
            if pe.time > pe.path.start + pe.path.duration and not pe.path.loop:
                pe.time, pe.playing = pe.path.start + pe.path.duration, False
        width, height = glfw.get_framebuffer_size(self._window)
        if width <= 0 or height <= 0:  # minimised
            return
        window_camera, t = app._current_view(width, height)
        camera = window_camera
        screenshot = app._screenshot_request
        pose = view_key(window_camera)
        moving, app._last_pose = pose != app._last_pose and app._last_pose is not None, pose
        playing, app._last_time = t != app._last_time and app._last_time is not None, t
        changing = app.resolution.changing(moving, playing)
        scale = 1.0 if screenshot else app.resolution.choose(changing, width, height)
        if scale != 1.0:
            camera = window_camera.resized(*scaled_size(width, height, scale))
        s = app.settings
        footprint = s.footprint
        splats = app.renderer.splats_at(t)
        key = SortKey.of(camera, t, footprint)
        if app._requested != (app._generation, key):
            self.sorter.request(splats, camera, t, footprint, tag=app._generation)
            app._requested = (app._generation, key)
        app._take_sort_result(self.sorter.poll())
        # the first frame of a model, a screenshot, or the first frame after a cap or the near plane changed (an
        # order of another footprint bounds nothing here): wait for the sort just requested
        if app._order is None or screenshot or app._order.needs_sort(camera, footprint):
            app._take_sort_result(self.sorter.wait())
        if app._order is None:
            return
        stats = app.renderer.render(camera, t, s, order=app._order, target=self.ctx.screen,
                                     viewport=(0, 0, width, height), sync=True)
        glfw.make_context_current(self._window)  # the panel draws next, with the window's context
        app.resolution.observe(stats.draw_ms + stats.upload_ms, scale)
        st = app._stats
        st.frame, st.scale, st.moving, st.playing = stats, scale, moving, playing
        app.report.setdefault("resolutions", set()).add(scale)
        app.report["moving_frames"] = app.report.get("moving_frames", 0) + moving
        if screenshot:
            app._screenshot_request = None
            self._save_screenshot(screenshot, camera, t, width, height)
        self._draw_overlays(window_camera)  # after the screenshot: screenshots show the model only
        st.frame_ms = (time.perf_counter() - t_frame) * 1e3

    def _draw_overlays(self, camera) -> None:
        """The camera path (its curve and key frustums), the dataset cameras and the crop box, as lines over the
        splats; a frustum at the viewing camera's own position (snapped to it, or flying the path) is left out."""
        app = self.app
        depth = 0.15 * app.framing.radius  # frustum size
        path_lines, frustums = self._overlay_geometry(camera.width, camera.height, depth)
        segs, colors = frustums.lines(camera.position, 1e-3 * depth)
        ce = app._crop
        box = ce.box() if ce.show else None
        box_lines = box_segments(box.lo, box.hi) if box is not None else np.zeros((0, 2, 3))
        inspected = app._inspected(app.playback.time)
        pick_lines = inspected[1] if inspected is not None else np.zeros((0, 2, 3))
        marks = app._selection_markers(camera)
        app.report["markers"] = len(marks) // 3
        layers = ((app._measure_lines(camera), MEASURE_COLOR), (marks, SELECTION_COLOR), (pick_lines, PICK_COLOR),
                  (box_lines, CROP_COLOR), (path_lines, PATH_COLOR))  # drawn in this order, then the frustums
        segs = np.concatenate([lines for lines, _ in layers] + [segs])
        colors = np.concatenate([np.broadcast_to(np.asarray(color, np.float32), (len(lines), 3))
                                 for lines, color in layers] + [colors])
        app.report["overlay_lines"] = len(segs)
        if len(segs):
            self.ctx.screen.use()
            self.ctx.viewport = (0, 0, camera.width, camera.height)
            self.overlay.draw(camera, segs, colors)

    def _overlay_geometry(self, width: int, height: int, depth: float):
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

    def _save_screenshot(self, path: str, camera, t: float, width: int, height: int) -> None:
        """Save what the window shows (without the panel) as a PNG."""
        app = self.app
        data = self.ctx.screen.read(viewport=(0, 0, width, height), components=3)
        rgb = np.frombuffer(data, np.uint8).reshape(height, width, 3)[::-1].astype(np.float32) / 255.0
        rgba = np.concatenate([rgb, np.ones_like(rgb[..., :1])], -1)
        explicit = path is app.options.screenshot
        target = Path(path)

        def save() -> None:
            with atomic_path(target, force=app.options.force if explicit else False) as tmp:
                write_png(tmp, rgba, alpha=False)

        if not app._attempt(save, f"saved {target}"):
            return
        app.report["screenshot"] = {"path": str(target), "camera": camera_to_json(camera), "time": t,
                                     "background": list(app.settings.background), "mode": app.settings.mode,
                                     "splat_scale": app.settings.splat_scale, "sh_degree": app.settings.sh_degree,
                                     "max_std_dev": app.settings.max_std_dev,
                                     "max_screen_radius": app.settings.max_screen_radius,
                                     "near_plane": app.settings.near_plane,
                                     "temporal_fade": app.settings.temporal_fade}

    def _handle_input(self, dt: float) -> None:
        app = self.app
        io = imgui.get_io()
        c = app.controller
        width, height = glfw.get_framebuffer_size(self._window)
        win_w, win_h = glfw.get_window_size(self._window)
        # window coordinates -> framebuffer pixels (they differ on high-DPI screens)
        kx, ky = width / max(win_w, 1), height / max(win_h, 1)
        cursor = (io.mouse_pos.x, io.mouse_pos.y)
        clicked = imgui.is_mouse_clicked(imgui.MouseButton_.left)
        ed = app._editor
        if ed.drag is not None:  # a selection rectangle: follows the cursor until the button is released
            ed.drag[2:] = cursor
            if not imgui.is_mouse_down(imgui.MouseButton_.left):
                x0, y0, x1, y1 = ed.drag
                rect, ed.drag = (x0 * kx, y0 * ky, x1 * kx, y1 * ky), None
                camera, t = app._current_view(width, height)
                app._attempt(lambda: app.select_rect(camera, t, rect, "remove" if ed.drag_removes else "add"))
        elif not io.want_capture_mouse:
            d = io.mouse_delta
            tool = app.inspect if io.key_ctrl else app.measure if io.key_alt and not io.key_shift else None
            x, y = int(cursor[0] * kx), int(cursor[1] * ky)
            if clicked and tool is not None:  # Ctrl+click inspects, Alt+click measures the pixel under the cursor
                if 0 <= x < width and 0 <= y < height:
                    camera, t = app._current_view(width, height)
                    app._attempt(lambda: tool(camera, t, x, y))
            elif clicked and io.key_shift:
                ed.drag, ed.drag_removes = [*cursor, *cursor], io.key_alt
            elif imgui.is_mouse_down(imgui.MouseButton_.left) and not (io.key_ctrl or io.key_alt) and (d.x or d.y):
                c.look(d.x, d.y) if app._fly else c.orbit(d.x, d.y)
                app._path.playing = False
            if (imgui.is_mouse_down(imgui.MouseButton_.right) or imgui.is_mouse_down(imgui.MouseButton_.middle)) \
                    and (d.x or d.y):
                c.pan(d.x, d.y, height)
                app._path.playing = False
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
            speed = app.framing.radius * (4.0 if down(key.left_shift) else 1.0)
            c.fly(fwd, right, upward, dt, speed)
            app._path.playing = False
        if imgui.is_key_pressed(key.space, False):
            app.playback.playing = not app.playback.playing
        for k, frames in ((key.left_arrow, -1), (key.right_arrow, 1), (key.comma, -1), (key.period, 1)):
            if imgui.is_key_pressed(k, True):
                app.playback.step(frames)
        if imgui.is_key_pressed(key.r, False):
            c.reset(app.framing)
        if imgui.is_key_pressed(key.f, False):
            app._fly = not app._fly
        if imgui.is_key_pressed(key.p, False):
            app._screenshot_request = app._next_screenshot_name()
        if imgui.is_key_pressed(key.delete, False) or imgui.is_key_pressed(key.backspace, False):
            app._attempt(app.delete_selected)
        if io.key_ctrl and imgui.is_key_pressed(key.z, False):
            app._attempt(app._undo)
        if imgui.is_key_pressed(key.escape, False):
            glfw.set_window_should_close(self._window, True)

