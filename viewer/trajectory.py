"""Camera trajectories and scene-time schedules for rendering a model to video.

Trajectories (one `Camera` per output frame, u = frame / frames so an orbit loops seamlessly):

* ``orbit``: constant elevation and distance, azimuth sweeping `turns` full turns.
* ``spiral``: the same azimuth sweep while the elevation swings from ``elevation - amplitude`` up to
  ``elevation + amplitude`` and back (a closed helix around the object).
* ``path``: a keyframed `CameraPath`, sampled at ``path.start + frame / fps`` seconds.

Scene time against the camera (`TIME_MODES`):

* ``loop``: the animation plays at its own pace, one pass through the time range every `loop_seconds` of video,
  repeating.
* ``timelapse``: exactly one pass through the time range over the whole video (slow or fast).
* ``hold``: a fixed model time (default the middle of the range).
* ``path``: the ``scene_time`` of the camera path's keys.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from splatreel.cameras import Camera, look_at, orbit_position
from splatreel.errors import CameraError
from splatreel.model import model_bounds

from .camera_path import CameraPath, nerfstudio_camera_path

TRAJECTORIES: tuple[str, ...] = ("orbit", "spiral", "path")
TIME_MODES: tuple[str, ...] = ("loop", "timelapse", "hold", "path")


@dataclass(frozen=True)
class Framing:
    """Where a model is: the centre and radius of a sphere around its means over its time range."""

    center: np.ndarray
    radius: float

    def distance(self, fov_deg: float, margin: float = 1.1) -> float:
        """Camera distance at which the sphere fits a (vertical) field of view `fov_deg`."""
        return margin * self.radius / math.sin(math.radians(0.5 * fov_deg))


#: Share of the means left out at each end of every axis when framing a model (floaters far from the object).
FRAMING_QUANTILE = 0.005


def model_extent(model) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) corners of a model's bounds over time (`splatreel.model.model_bounds`), leaving out the outermost
    FRAMING_QUANTILE of its means per axis: a handful of floaters does not stretch them."""
    with torch.no_grad():
        lo, hi = model_bounds(model, quantile=FRAMING_QUANTILE)
    return lo.double().cpu().numpy(), hi.double().cpu().numpy()


def framing_of(lo: np.ndarray, hi: np.ndarray) -> Framing:
    """The `Framing` of the box (lo, hi): its centre and half its diagonal."""
    return Framing(0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3))


def frame_model(model) -> Framing:
    """`Framing` of a model's `model_extent`: a handful of floaters no longer shrinks the object on screen."""
    return framing_of(*model_extent(model))


def orbit_cameras(frames: int, width: int, height: int, center: Sequence[float], distance: float,
                  elevation: float = 20.0, fov: float = 40.0, up: str = "z", turns: float = 1.0,
                  start_azimuth: float = 0.0, amplitude: float = 0.0) -> list[Camera]:
    """Cameras on an orbit (``amplitude = 0``) or a spiral around `center` (angles in degrees).

    With ``amplitude > 0`` the elevation is ``elevation - amplitude cos(2 pi u)``, u = frame / frames.
    """
    if frames < 1:
        raise CameraError(f"need at least one frame, got {frames}")
    if not distance > 0:
        raise CameraError(f"camera distance must be positive, got {distance}")
    out = []
    for i in range(frames):
        u = i / frames
        elev = elevation - amplitude * math.cos(2.0 * math.pi * u)
        if abs(elev) >= 89.9:
            raise CameraError(f"elevation {elev:.1f} degrees is at a pole; keep |elevation| + amplitude < 90")
        eye = orbit_position(elev, start_azimuth + 360.0 * turns * u, distance, up, center)
        out.append(look_at(eye, center, up, fov, width, height))
    return out


def path_cameras(path: CameraPath, frames: int, fps: float, width: int, height: int) -> list[Camera]:
    """Cameras along a keyframed path, one every 1/fps seconds from its first key."""
    return [path.camera(path.start + i / fps, width, height) for i in range(frames)]


def path_frame_count(path: CameraPath, fps: float) -> int:
    """Frames that cover a path at `fps`: its last key included when open, a whole period when looping."""
    n = int(round(path.duration * fps))
    return max(1, n if path.loop else n + 1)


def path_as_nerfstudio(path: CameraPath, width: int, height: int, fps: float = 30.0,
                       time_range: tuple[float, float] | None = None) -> dict:
    """A keyframed path sampled into nerfstudio's camera-path JSON (`nerfstudio_camera_path`): one frame every
    1/fps seconds over the path (`path_frame_count`), at the path's own image size and fps when it records them,
    with each frame's scene time as ``render_time`` when every key has one (normalised over `time_range`)."""
    fps = path.fps or fps
    if path.projection == "equirect":  # a panorama path: its frames are 360° images, not the window's view
        width, height = (2 * height, height)
    width, height = path.image_size or (width, height)
    frames = path_frame_count(path, fps)
    cameras = path_cameras(path, frames, fps, width, height)
    times = scene_times("path", frames, fps, time_range or (0.0, 1.0), path=path) if path.has_scene_time else None
    return nerfstudio_camera_path(cameras, fps, times, time_range, path.projection)


def scene_times(mode: str, frames: int, fps: float, time_range: tuple[float, float], loop_seconds: float = 2.0,
                hold: float | None = None, path: CameraPath | None = None) -> np.ndarray:
    """``[frames]`` model times for each output frame (see module doc for the modes)."""
    t0, t1 = float(time_range[0]), float(time_range[1])
    span = t1 - t0
    i = np.arange(frames, dtype=np.float64)
    if mode == "loop":
        if not loop_seconds > 0:
            raise CameraError(f"loop seconds must be positive, got {loop_seconds}")
        return t0 + np.mod(i / fps / loop_seconds, 1.0) * span
    if mode == "timelapse":
        return t0 + span * i / max(frames - 1, 1)
    if mode == "hold":
        t = 0.5 * (t0 + t1) if hold is None else float(hold)
        return np.full(frames, t)
    if mode == "path":
        if path is None or not path.has_scene_time:
            raise CameraError("time mode 'path' needs a camera path whose keyframes all have a scene_time")
        return np.array([path.scene_time(path.start + k / fps) for k in range(frames)], np.float64)
    raise CameraError(f"unknown time mode {mode!r}; expected one of {', '.join(TIME_MODES)}")
