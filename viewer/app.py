"""The desktop viewer: a glfw window with a Dear ImGui panel over the moderngl `SplatRenderer`.

Controls: left drag orbits (looks around in fly mode), right or middle drag pans, the wheel zooms, W/A/S/D and
Q/E fly, Space plays/pauses, R resets the view, F toggles fly mode, P takes a screenshot, Ctrl+click inspects the
Gaussians under the cursor, Alt+click measures, Shift+drag selects Gaussians (Shift+Alt+drag unselects), Delete
deletes the selection, Ctrl+Z undoes a deletion, Esc quits. Drop a model file on the window (or type its path in the
panel) to open it.

The app is three layers:

* `state.AppState`: the model and its edits, selection, inspect and measure, the camera path being made, the report
  (no window, no imgui: the tests drive it on a headless renderer), over the plain data of ``app_data.py``
  (`AppOptions`, what the panels edit); `frames.FramePlanner` plans each frame from it (time, camera, resolution,
  sorting in a worker thread, overlays, screenshots);
* `window.AppWindow`: glfw + imgui set-up, the frame loop and input, calling the state;
* `panels`: one function per tab of the panel, drawing the state.
"""

from __future__ import annotations

from .state import AppOptions, AppState

__all__ = ["AppOptions", "run_app"]


def run_app(source, options: AppOptions | None = None) -> dict:
    """Open the viewer on `source` (a model path or `Checkpoint`) and block until it closes; returns the report."""
    from .window import AppWindow  # glfw and imgui load only when a window opens

    return AppWindow(AppState(source, options)).run()
