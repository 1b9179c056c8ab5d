"""What ``splatreel render`` draws, decided without argparse: a `RenderRequest` (what the user asked, None where the
model, the camera path or the output decides) becomes a `RenderJob` (one camera and one model time per frame, image
size, fps, projection and look) through the pure `plan_render`.

Defaults, in order: an option given; what a camera path file records (size, fps, projection, scene times); else
1280x720 (2048x1024 for an equirect panorama), 30 fps, ``--seconds`` of orbit, and the loop time mode.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from .options import OptionError

if TYPE_CHECKING:
    from splatreel.cameras import Camera

    from .camera_path import CameraPath
    from .panorama import Equirect
    from .render_settings import RenderSettings

DEFAULT_SIZE = (1280, 720)
DEFAULT_PANORAMA_SIZE = (2048, 1024)
DEFAULT_FPS = 30.0


@dataclass(frozen=True)
class RenderRequest:
    """What the user asked for (`splatreel render`'s options). None: decided by `plan_render`.

    Attributes:
        out: output file or folder; a .png/.exr image is one frame.
        trajectory: "orbit", "spiral" or "path" (None: path when `path_file` or `cameras` is given, else orbit).
        path_file: keyframed camera path JSON (`CameraPath.load`).
        cameras: training dataset (or checkpoint recording its cameras) whose views make the path.
        split, seconds_per_key: which views of `cameras`, and the seconds between them.
        size: (width, height) in pixels.
        fps: frames per second.
        frame_count: frames to render (None: 1 for an image, else seconds x fps, or the whole path).
        seconds: video length of an orbit or spiral.
        elevation, azimuth, amplitude, turns: orbit/spiral angles in degrees, and full turns.
        distance, target: camera distance and orbit centre (None: frame the model).
        fov: vertical field of view in degrees.
        projection: "perspective" or "equirect" (None: the path file's, else perspective).
        up: world up axis of the orbit and the dataset cameras.
        time_mode: "loop", "timelapse", "hold" or "path" (None: path when the path has scene times, hold with
            `time`, else loop).
        time: the held model time.
        loop_seconds: video seconds per pass through the time range in loop mode.
    """

    out: str
    trajectory: str | None = None
    path_file: str | None = None
    cameras: str | None = None
    split: str = "train"
    seconds_per_key: float = 0.5
    size: tuple[int, int] | None = None
    fps: float | None = None
    frame_count: int | None = None
    seconds: float = 4.0
    elevation: float = 20.0
    azimuth: float = 0.0
    amplitude: float = 25.0
    turns: float = 1.0
    distance: float | None = None
    target: tuple[float, float, float] | None = None
    fov: float = 40.0
    projection: str | None = None
    up: str = "z"
    time_mode: str | None = None
    time: float | None = None
    loop_seconds: float = 2.0

    @property
    def trajectory_name(self) -> str:
        """The trajectory asked for, or the one the other options imply."""
        return self.trajectory or ("path" if (self.path_file or self.cameras) else "orbit")


@dataclass
class RenderJob:
    """What to draw: ``cameras[i]`` at model time ``times[i]`` for every frame."""

    cameras: list[Camera]
    times: np.ndarray  # [frames]
    size: tuple[int, int]
    fps: float
    projection: str
    equirect: Equirect | None
    settings: RenderSettings

    @property
    def frame_count(self) -> int:
        return len(self.cameras)


def check_request(request: RenderRequest) -> RenderRequest:
    """OptionError (one line) for values that cannot be rendered, before any model is read; an image output gets
    ``frame_count = 1``."""
    from .output import output_kind

    if request.fps is not None and not request.fps > 0:
        raise OptionError(f"--fps must be positive, got {request.fps}")
    if request.frame_count is not None and request.frame_count < 1:
        raise OptionError(f"--frame-count must be at least 1, got {request.frame_count}")
    if request.path_file and request.cameras:
        raise OptionError("give either --path or --cameras, not both")
    if not 0 < request.fov < 180:
        raise OptionError(f"--fov must be in (0, 180) degrees, got {request.fov}")
    if output_kind(request.out) == "image":  # a still is one frame
        if request.frame_count is not None and request.frame_count > 1:
            raise OptionError(f"{request.out} holds one image, not {request.frame_count} frames; give a folder name "
                              "for numbered frames, or a video")
        return replace(request, frame_count=1)
    return request


def load_camera_path(request: RenderRequest, time_range: tuple[float, float]) -> CameraPath | None:
    """The camera path a ``path`` trajectory follows (from `path_file` or the `cameras` dataset); None for an orbit
    or a spiral."""
    from .camera_path import CameraPath, path_from_dataset

    if request.trajectory_name != "path":
        return None
    if request.path_file:
        return CameraPath.load(request.path_file, time_range=time_range)
    if request.cameras:
        return path_from_dataset(request.cameras, request.split, request.seconds_per_key, request.up)
    raise OptionError("--trajectory path needs --path FILE or --cameras DATASET")


def plan_render(request: RenderRequest, model, path: CameraPath | None, settings: RenderSettings) -> RenderJob:
    """The cameras, model times, size, fps and projection of `request` for `model` (from `load_camera_path`'s `path`
    when the trajectory is a path), drawn with `settings`. Raises OptionError / CameraError (one line)."""
    from splatreel.errors import CameraError

    from .panorama import Equirect
    from .trajectory import frame_model, orbit_cameras, path_cameras, path_frame_count, scene_times

    # a path file may say how it is meant to be rendered (a nerfstudio path always does)
    projection = request.projection or (path.projection if path is not None else "perspective")
    default_size = DEFAULT_PANORAMA_SIZE if projection == "equirect" else DEFAULT_SIZE
    width, height = request.size or (path is not None and path.projection == projection and path.image_size) \
        or default_size
    equirect = Equirect(width, height) if projection == "equirect" else None
    fps = request.fps or (path is not None and path.fps) or DEFAULT_FPS
    if path is not None:
        frames = request.frame_count or path_frame_count(path, fps)
        cameras = path_cameras(path, frames, fps, width, height)
    else:
        frames = request.frame_count or max(1, int(round(request.seconds * fps)))
        framing = frame_model(model)
        target = framing.center if request.target is None else request.target
        distance = request.distance or framing.distance(request.fov)
        amplitude = request.amplitude if request.trajectory_name == "spiral" else 0.0
        cameras = orbit_cameras(frames, width, height, target, distance, request.elevation, request.fov, request.up,
                                request.turns, request.azimuth, amplitude)

    mode = request.time_mode
    if mode is None:
        mode = ("path" if path is not None and path.has_scene_time else "hold" if request.time is not None
                else "loop")
    if request.time is not None and mode != "hold":
        raise OptionError(f"--time sets the held time; it does not apply to --time-mode {mode}")
    if request.time is not None:
        from splatreel.argtypes import warn_outside_time_range

        warn_outside_time_range(request.time, model.time_range, "--time")
    times = scene_times(mode, frames, fps, model.time_range, request.loop_seconds, request.time, path)
    if mode == "path" and path is None:
        raise CameraError("--time-mode path needs --path or --cameras")
    return RenderJob(cameras, times, (width, height), fps, projection, equirect, settings)
