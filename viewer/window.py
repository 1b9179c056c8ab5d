"""The desktop app's window: glfw + Dear ImGui set-up (imgui-bundle's native glfw/OpenGL3 backends), the frame loop
and input (keys, mouse) over an `AppState`. Each frame, `FramePlanner` decides what to draw, the `SplatRenderer`
draws it into the window, the overlay lines go over it and `panels.draw_panel` over all.
"""

from __future__ import annotations

import ctypes
import re
import time

from imgui_bundle import imgui  # first: it sets PYGLFW_LIBRARY so that glfw shares imgui's libglfw

import glfw
import moderngl
import numpy as np

from splatreel.errors import GLError

from .frames import FramePlanner
from .overlay import LineRenderer
from .panels import draw_panel
from .renderer import SplatRenderer
from .state import AppState


class AppWindow:
    """The window around an `AppState`; ``run()`` blocks until the window closes."""

    def __init__(self, app: AppState) -> None:
        self.app = app
        self._window = None
        self.ctx = None
        self.overlay: LineRenderer | None = None
        self.frames: FramePlanner | None = None

    def run(self) -> dict:
        """Open the window and loop until it is closed (or ``exit_after`` frames); returns the report dict."""
        app, o = self.app, self.app.options
        self._open_window()
        try:
            app.size = glfw.get_framebuffer_size(self._window)
            app.start()
            last = time.perf_counter()
            frames, title = 0, "splatreel"
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
                if app.title != title:
                    title = app.title
                    glfw.set_window_title(self._window, title)
                final = o.exit_after is not None and frames + 1 >= o.exit_after
                if final and o.screenshot:
                    app._screenshot_request = o.screenshot
                self._handle_input(dt)
                self._draw_frame(dt)
                draw_panel(app)
                imgui.render()
                imgui.backends.opengl3_render_draw_data(imgui.get_draw_data())
                glfw.swap_buffers(self._window)
                frames += 1
                if final:
                    break
            return app.finish(frames)
        finally:
            self._close_window()

    def _open_window(self) -> None:
        """An OpenGL 3.3 core window with its moderngl context, imgui on it, and the app's renderer."""
        glfw.ERROR_REPORTING = "exception"  # set-up failures become one-line errors, not warnings
        try:
            if not glfw.init():
                raise GLError("could not initialise glfw")
            glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
            glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
            glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
            glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
            w, h = self.app.options.size
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
        glfw.swap_interval(1 if self.app.options.vsync else 0)
        glfw.set_drop_callback(window, self._on_drop)
        self.ctx = moderngl.create_context(require=330)
        imgui.create_context()
        io = imgui.get_io()
        io.set_ini_filename(None)  # no imgui.ini in the user's folder
        addr = ctypes.cast(window, ctypes.c_void_p).value
        if not (imgui.backends.glfw_init_for_opengl(addr, True) and imgui.backends.opengl3_init("#version 330")):
            raise GLError("could not initialise the Dear ImGui glfw/OpenGL3 backends")
        self.app.renderer = SplatRenderer(self.ctx)
        self.overlay = LineRenderer(self.ctx)
        self.frames = FramePlanner(self.app)

    def _close_window(self) -> None:
        self.frames.close()
        self.app.renderer.release()
        self.overlay.release()
        imgui.backends.opengl3_shutdown()
        imgui.backends.glfw_shutdown()
        imgui.destroy_context()
        glfw.destroy_window(self._window)
        self._window = None
        glfw.terminate()

    def _on_drop(self, _window, paths) -> None:
        if paths:
            self.app._pending_open = str(paths[0])

    def _draw_frame(self, dt: float) -> None:
        """The model as `FramePlanner` plans it, a screenshot when one is due, then the overlays."""
        start = time.perf_counter()
        app, ctx = self.app, self.ctx
        width, height = app.size
        frame = self.frames.next(dt, width, height)
        if frame is None:
            return
        stats = app.renderer.render(frame.camera, frame.t, app.settings, order=frame.order, target=ctx.screen,
                                    viewport=(0, 0, width, height), sync=True)
        glfw.make_context_current(self._window)  # the panel draws next, with the window's context
        self.frames.drawn(frame, stats)
        if frame.screenshot:
            data = ctx.screen.read(viewport=(0, 0, width, height), components=3)
            self.frames.save_screenshot(frame, np.frombuffer(data, np.uint8).reshape(height, width, 3)[::-1])
        segs, colors = self.frames.overlay_lines(frame.view)  # after the screenshot: screenshots show the model only
        if len(segs):
            ctx.screen.use()
            ctx.viewport = (0, 0, width, height)
            self.overlay.draw(frame.view, segs, colors)
        app._stats.frame_ms = (time.perf_counter() - start) * 1e3

    def _handle_input(self, dt: float) -> None:
        """Mouse and keys (see `splatreel.viewer.app`), unless the panel has them."""
        io = imgui.get_io()
        self._handle_mouse(io)
        if not io.want_capture_keyboard:
            self._handle_keys(io, dt)

    def _handle_mouse(self, io) -> None:
        app = self.app
        c = app.controller
        width, height = app.size
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

    def _handle_keys(self, io, dt: float) -> None:
        app = self.app
        c = app.controller
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

