"""Real-time OpenGL viewer and headless renderer for splatreel models.

* `SplatRenderer` / `render_image`: the moderngl renderer (EGL offscreen or a window's context).
* `render_frames` / `render_to_file`: headless video and image output.
* `CameraPath`, `CameraKey`, `path_from_dataset`, `dataset_views`, `nerfstudio_camera_path`: keyframed camera
  paths (JSON; nerfstudio's in and out).
* `orbit_cameras`, `path_cameras`, `scene_times`, `frame_model`: trajectories and scene-time schedules.
* `RenderRequest` / `plan_render` -> `RenderJob`: what ``splatreel render`` draws, decided without argparse.
* `PixelStack` / `PixelHit` (from `SplatRenderer.pick`), `describe`: which Gaussians make a pixel, and what one is.
* `run_app` / `AppOptions`: the glfw + Dear ImGui desktop app (needs a display).

Names are imported on first use, so that ``splatreel --help`` and light submodules stay fast (numba, moderngl, glfw
and imgui load only when needed). The viewer never imports the trainer.
"""

import importlib

_EXPORTS = {
    "camera_path": ("CameraKey", "CameraPath", "DatasetView", "dataset_views", "nerfstudio_camera_path",
                    "path_from_dataset"),
    "headless": ("render_frames", "render_to_file"),
    "render_job": ("RenderJob", "RenderRequest", "plan_render"),
    "pick": ("PixelHit", "PixelStack", "describe"),
    "renderer": ("COMPOSITE_ORDERS", "RENDER_MODES", "FrameStats", "RenderSettings", "SplatRenderer",
                 "headless_context", "render_image"),
    "sorting": ("AsyncSorter", "SortResult", "depth_order"),
    "trajectory": ("TIME_MODES", "TRAJECTORIES", "Framing", "frame_model", "orbit_cameras", "path_cameras",
                   "scene_times"),
    "app": ("AppOptions", "run_app"),
    "state": ("AppState",),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name):
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
