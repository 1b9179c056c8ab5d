"""Keyframed camera paths: the JSON file shared by the desktop app (record / save / load) and `splatreel render`.

File format (``.json``; README.md, "Camera path files")::

    {
      "format": "splatreel-camera-path", "version": 1,
      "up": "z",                       # world up for look-at keys: "x", "y", "z", "-x", "-y", "-z" or [x, y, z]
      "loop": false,                   # true: the path closes back to its first key (periodic)
      "keyframes": [
        {"time": 0.0, "position": [3, 0, 1], "look_at": [0, 0, 0], "fov": 40.0, "scene_time": 0.0},
        {"time": 2.5, "position": [0, 3, 1], "quaternion": [w, x, y, z], "fov": 35.0}
      ]
    }

* ``time``: seconds along the path (strictly increasing).
* ``position``: camera centre in world units.
* orientation: either ``look_at`` (a world point; the camera's up is the path's ``up``) or ``quaternion``, the
  camera-to-world rotation in **OpenCV camera axes** (x right, y down, z forward), w first (as `splatreel.cameras`).
* ``fov``: vertical field of view in degrees (optional, default 40).
* ``scene_time``: optional model time shown at this key (used when rendering with ``--time-mode path``); it is
  interpolated linearly and only used when every key has one.

Interpolation: position by a cubic Hermite spline with Catmull-Rom tangents scaled for the key spacing (it passes
through every key), orientation by slerp (`splatreel.quaternion.slerp`) between consecutive keys, fov and scene time
linearly. A looping path adds a closing segment from the last key back to the first, lasting the mean key spacing.

Optional top-level ``"image_size": [width, height]``, ``"fps"`` and ``"projection"`` (``"perspective"``, the
default, or ``"equirect"`` for 360° panoramas) say how the path is meant to be rendered (`splatreel render` uses
them when ``--size`` / ``--fps`` / ``--projection`` are not given).

`CameraPath.load` also reads **nerfstudio camera paths** (``ns-render --camera-path-filename``; written by the
nerfstudio viewer's "Export path" and by the nerfstudio Blender add-on): `from_nerfstudio`.

`path_from_dataset` turns the cameras of a training dataset (D-NeRF / Blender ``transforms_*.json``) into a path.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from splatreel import quaternion
from splatreel.checkpoint_file import LEGACY_NAME
from splatreel.cameras import Camera, DatasetView, as_up, look_at_c2w, opengl_to_opencv
from splatreel.datasets.dnerf import read_transforms, transforms_files
from splatreel.errors import CameraError, DatasetError
from splatreel.fileio import atomic_write_json

from .panorama import PROJECTIONS

FORMAT_NAME = "splatreel-camera-path"
#: the name paths written before the rename carry; still read
_LEGACY_FORMAT_NAME = f"{LEGACY_NAME}-camera-path"
FORMAT_VERSION = 1
#: nerfstudio's camera_type -> ours (`panorama.PROJECTIONS`), and back
_NERFSTUDIO_PROJECTIONS = {"perspective": "perspective", "equirectangular": "equirect"}
_NERFSTUDIO_CAMERA_TYPES = {ours: theirs for theirs, ours in _NERFSTUDIO_PROJECTIONS.items()}
DEFAULT_FOV = 40.0


def rotation_to_quaternion(rot: np.ndarray) -> np.ndarray:
    """``[3, 3]`` rotation -> ``[4]`` unit quaternion (w first, w >= 0)."""
    return quaternion.from_rotmat(torch.tensor(np.asarray(rot, np.float64))).numpy()


def quaternion_to_rotation(q: Sequence[float]) -> np.ndarray:
    """``[4]`` quaternion (w first, normalised here) -> ``[3, 3]`` rotation."""
    return quaternion.to_rotmat(torch.tensor(np.asarray(q, np.float64))).numpy()


@dataclass(frozen=True)
class CameraKey:
    """One keyframe of a `CameraPath`.

    Attributes:
        time: seconds along the path.
        position: ``[3]`` camera centre.
        quaternion: ``[4]`` camera-to-world rotation (OpenCV axes), w first, unit.
        fov: vertical field of view in degrees.
        scene_time: model time at this key, or None.
        look_at: ``[3]`` the point the key was defined to look at (kept for saving), or None.
    """

    time: float
    position: np.ndarray
    quaternion: np.ndarray
    fov: float = DEFAULT_FOV
    scene_time: float | None = None
    look_at: np.ndarray | None = None

    @classmethod
    def from_camera(cls, time: float, camera: Camera, scene_time: float | None = None) -> "CameraKey":
        """A key reproducing `camera`'s pose and vertical field of view."""
        return cls(float(time), camera.position, rotation_to_quaternion(camera.c2w[:3, :3]),
                   math.degrees(camera.fov_y), None if scene_time is None else float(scene_time))

    def c2w(self) -> np.ndarray:
        out = np.eye(4)
        out[:3, :3] = quaternion_to_rotation(self.quaternion)
        out[:3, 3] = self.position
        return out

    def to_json(self) -> dict:
        d: dict = {"time": self.time, "position": [float(x) for x in self.position]}
        if self.look_at is not None:
            d["look_at"] = [float(x) for x in self.look_at]
        else:
            d["quaternion"] = [float(x) for x in self.quaternion]
        d["fov"] = self.fov
        if self.scene_time is not None:
            d["scene_time"] = self.scene_time
        return d


def _vector(value, n: int, what: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CameraError(f"{what} must be {n} numbers, got {value!r}") from None
    if v.shape != (n,) or not np.isfinite(v).all():
        raise CameraError(f"{what} must be {n} finite numbers, got {value!r}")
    return v


def _number(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CameraError(f"{what} must be a finite number, got {value!r}")
    return float(value)


def _key_from_json(d, i: int, up) -> CameraKey:
    where = f"keyframe {i}"
    if not isinstance(d, dict):
        raise CameraError(f"{where} must be an object, got {type(d).__name__}")
    unknown = set(d) - {"time", "position", "look_at", "quaternion", "fov", "scene_time"}
    if unknown:
        raise CameraError(f"{where}: unknown field(s) {', '.join(sorted(unknown))}")
    for name in ("time", "position"):
        if name not in d:
            raise CameraError(f"{where}: missing '{name}'")
    position = _vector(d["position"], 3, f"{where} position")
    if ("look_at" in d) == ("quaternion" in d):
        raise CameraError(f"{where}: give exactly one of 'look_at' and 'quaternion'")
    look = None
    if "look_at" in d:
        look = _vector(d["look_at"], 3, f"{where} look_at")
        q = rotation_to_quaternion(look_at_c2w(position, look, up)[:3, :3])
    else:
        q = _vector(d["quaternion"], 4, f"{where} quaternion")
        if np.linalg.norm(q) < 1e-9:
            raise CameraError(f"{where}: quaternion is zero")
        q = q / np.linalg.norm(q)
    fov = _number(d.get("fov", DEFAULT_FOV), f"{where} fov")
    if not 0 < fov < 180:
        raise CameraError(f"{where}: fov must be in (0, 180) degrees, got {fov}")
    scene_time = None if d.get("scene_time") is None else _number(d["scene_time"], f"{where} scene_time")
    return CameraKey(_number(d["time"], f"{where} time"), position, q, fov, scene_time, look)


def _hermite(p0, p1, m0, m1, h: float, s: float):
    """Cubic Hermite between p0 and p1 (tangents m0, m1 per unit time, segment length h) at s in [0, 1]."""
    s2, s3 = s * s, s * s * s
    return ((2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * m0 + (-2 * s3 + 3 * s2) * p1
            + (s3 - s2) * h * m1)


@dataclass
class CameraPath:
    """An interpolated sequence of `CameraKey` (see module doc for the file format and interpolation)."""

    keys: list[CameraKey]
    up: str | tuple[float, float, float] = "z"
    loop: bool = False
    #: how the path is meant to be rendered, when its file says: (width, height) and frames per second
    image_size: tuple[int, int] | None = None
    fps: float | None = None
    #: "perspective", or "equirect" for a path of 360° panoramas (`splatreel.viewer.panorama`)
    projection: str = "perspective"
    _times: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.keys:
            raise CameraError("a camera path needs at least one keyframe")
        if self.projection not in PROJECTIONS:
            raise CameraError(f"unknown projection {self.projection!r}; expected one of {', '.join(PROJECTIONS)}")
        times = np.array([k.time for k in self.keys], np.float64)
        if np.any(np.diff(times) <= 0):
            raise CameraError("camera path keyframe times must be strictly increasing")
        as_up(self.up)
        self._times = times

    # --- timing ---------------------------------------------------------------------------------------------
    @property
    def start(self) -> float:
        return float(self._times[0])

    @property
    def closing_time(self) -> float:
        """Duration of the closing segment of a looping path (the mean key spacing)."""
        if len(self.keys) < 2:
            return 1.0
        return float(np.mean(np.diff(self._times)))

    @property
    def duration(self) -> float:
        """Seconds from the first key to the last (to the first again when looping)."""
        span = float(self._times[-1] - self._times[0])
        return span + self.closing_time if self.loop and len(self.keys) > 1 else span

    @property
    def has_scene_time(self) -> bool:
        return all(k.scene_time is not None for k in self.keys)

    def _segment(self, time: float) -> tuple[int, int, float, float]:
        """(key a, key b, local parameter s in [0, 1], segment length h) for path time `time`."""
        n = len(self.keys)
        times = self._times
        if n == 1:
            return 0, 0, 0.0, 1.0
        if self.loop:
            u = (time - times[0]) % self.duration + times[0]
            if u >= times[-1]:
                h = self.closing_time
                return n - 1, 0, (u - times[-1]) / h, h
            time = u
        if time <= times[0]:
            return 0, 1, 0.0, float(times[1] - times[0])
        if time >= times[-1]:
            return n - 2, n - 1, 1.0, float(times[-1] - times[-2])
        i = int(np.searchsorted(times, time, side="right")) - 1
        h = float(times[i + 1] - times[i])
        return i, i + 1, (time - times[i]) / h, h

    def _tangent(self, i: int) -> np.ndarray:
        """Catmull-Rom tangent at key i (per unit time), one-sided at the ends of an open path."""
        n, p, t = len(self.keys), [k.position for k in self.keys], self._times
        if n == 1:
            return np.zeros(3)
        if self.loop:
            period = self.duration
            prev_t = t[i - 1] if i > 0 else t[-1] - period
            next_t = t[i + 1] if i < n - 1 else t[0] + period
            return (p[(i + 1) % n] - p[i - 1]) / (next_t - prev_t)
        if i == 0:
            return (p[1] - p[0]) / (t[1] - t[0])
        if i == n - 1:
            return (p[-1] - p[-2]) / (t[-1] - t[-2])
        return (p[i + 1] - p[i - 1]) / (t[i + 1] - t[i - 1])

    # --- evaluation -----------------------------------------------------------------------------------------
    def pose(self, time: float) -> tuple[np.ndarray, float]:
        """(camera-to-world ``[4, 4]`` (OpenCV axes), vertical fov in degrees) at path time `time`."""
        a, b, s, h = self._segment(float(time))
        ka, kb = self.keys[a], self.keys[b]
        pos = _hermite(ka.position, kb.position, self._tangent(a), self._tangent(b), h, s)
        q = quaternion.slerp(torch.as_tensor(ka.quaternion), torch.as_tensor(kb.quaternion), float(s)).numpy()
        c2w = np.eye(4)
        c2w[:3, :3] = quaternion_to_rotation(q)
        c2w[:3, 3] = pos
        return c2w, ka.fov + (kb.fov - ka.fov) * s

    def camera(self, time: float, width: int, height: int) -> Camera:
        """The camera at path time `time` rendering `width` x `height` pixels."""
        c2w, fov = self.pose(time)
        return Camera.from_fov(c2w, width, height, fov_y_deg=fov)

    def scene_time(self, time: float) -> float | None:
        """Model time at path time `time` (linear between keys), or None if some key has no scene time."""
        if not self.has_scene_time:
            return None
        a, b, s, _ = self._segment(float(time))
        ta, tb = self.keys[a].scene_time, self.keys[b].scene_time
        return ta + (tb - ta) * s

    # --- editing --------------------------------------------------------------------------------------------
    def with_key(self, key: CameraKey) -> "CameraPath":
        """A copy with `key` added (keys are kept sorted by time; a key at an existing time replaces it)."""
        keys = [k for k in self.keys if k.time != key.time] + [key]
        return CameraPath(sorted(keys, key=lambda k: k.time), self.up, self.loop, self.image_size, self.fps,
                          self.projection)

    # --- files ----------------------------------------------------------------------------------------------
    def to_json(self) -> dict:
        up = self.up if isinstance(self.up, str) else [float(x) for x in self.up]
        out = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "up": up, "loop": self.loop}
        if self.image_size is not None:
            out["image_size"] = list(self.image_size)
        if self.fps is not None:
            out["fps"] = self.fps
        if self.projection != "perspective":
            out["projection"] = self.projection
        return {**out, "keyframes": [k.to_json() for k in self.keys]}

    @classmethod
    def from_json(cls, data, source: str = "camera path",
                  time_range: tuple[float, float] | None = None) -> "CameraPath":
        """A path from its JSON: splatreel's format, or nerfstudio's (`from_nerfstudio`; `time_range` maps its
        normalised times)."""
        if not isinstance(data, dict):
            raise CameraError(f"{source}: expected a JSON object")
        if "format" not in data and "camera_path" in data:
            return cls.from_nerfstudio(data, source, time_range)
        if data.get("format", FORMAT_NAME) not in (FORMAT_NAME, _LEGACY_FORMAT_NAME):
            raise CameraError(f"{source}: not a splatreel camera path (format {data.get('format')!r})")
        version = data.get("version", FORMAT_VERSION)
        if not isinstance(version, int) or version > FORMAT_VERSION:
            raise CameraError(f"{source}: camera path version {version!r} is newer than this splatreel reads")
        keys = data.get("keyframes")
        if not isinstance(keys, list) or not keys:
            raise CameraError(f"{source}: 'keyframes' must be a non-empty list")
        up = data.get("up", "z")
        try:
            as_up(up)
        except CameraError as exc:
            raise CameraError(f"{source}: {exc}") from None
        up = up if isinstance(up, str) else tuple(float(x) for x in up)
        try:
            parsed = [_key_from_json(k, i, up) for i, k in enumerate(keys)]
            size = data.get("image_size")
            if size is not None:
                size = tuple(int(x) for x in _vector(size, 2, "image_size"))
                if min(size) < 1:
                    raise CameraError(f"image_size must be positive, got {list(size)}")
            fps = None if data.get("fps") is None else _number(data["fps"], "fps")
            if fps is not None and not fps > 0:
                raise CameraError(f"fps must be positive, got {fps}")
            return cls(parsed, up, bool(data.get("loop", False)), size, fps, data.get("projection", "perspective"))
        except CameraError as exc:
            raise CameraError(f"{source}: {exc}") from None

    @classmethod
    def from_nerfstudio(cls, data: dict, source: str = "camera path",
                        time_range: tuple[float, float] | None = None) -> "CameraPath":
        """nerfstudio's camera path JSON: ``render_width``/``render_height``, ``seconds`` (or ``fps``) and
        ``camera_path``, a list of already interpolated frames, each with ``camera_to_world`` (16 numbers, row-major
        4x4, OpenGL camera axes), ``fov`` (vertical, degrees) and, for dynamic scenes, ``render_time`` in [0, 1].

        Every frame becomes a key; frame i sits at i / fps seconds (fps = frames / seconds, as ns-render plays it),
        so rendering at the file's fps gives exactly its frames. ``render_time`` r becomes the scene time
        t0 + r (t1 - t0) of `time_range` (r itself without one). Rotations are re-orthonormalised (a Blender camera
        with a scale has a scaled matrix). The perspective and equirectangular camera types are read (the
        latter as a path of 360° panoramas, `projection` "equirect"); fisheye is not."""
        def fail(message: str):
            raise CameraError(f"{source}: nerfstudio camera path: {message}")

        kind = data.get("camera_type", "perspective")
        if kind not in _NERFSTUDIO_PROJECTIONS:
            fail(f"camera_type {kind!r} is not supported (only perspective and equirectangular)")
        try:
            size = (int(_number(data["render_width"], "render_width")),
                    int(_number(data["render_height"], "render_height")))
        except KeyError as exc:
            fail(f"missing {exc}")
        except CameraError as exc:
            fail(str(exc))
        frames = data["camera_path"]
        if not isinstance(frames, list) or not frames or min(size) < 1:
            fail("'camera_path' must be a non-empty list of frames and the render size positive")
        try:
            if data.get("seconds") is not None:
                fps = len(frames) / _number(data["seconds"], "seconds")
            else:
                fps = _number(data.get("fps", 30.0), "fps")
        except (CameraError, ZeroDivisionError) as exc:
            fail(f"bad seconds or fps ({exc})")
        if not (math.isfinite(fps) and fps > 0):
            fail("seconds and fps must be positive")
        timed = all(isinstance(f, dict) and f.get("render_time") is not None for f in frames)
        keys = []
        for i, f in enumerate(frames):
            try:
                if not isinstance(f, dict):
                    raise CameraError(f"must be an object, got {type(f).__name__}")
                c2w = opengl_to_opencv(_vector(np.ravel(np.asarray(f.get("camera_to_world"), dtype=object)), 16,
                                               "camera_to_world").reshape(4, 4))
                u, sv, vt = np.linalg.svd(c2w[:3, :3])
                if sv.min() < 1e-9 or np.linalg.det(u @ vt) < 0:
                    raise CameraError("camera_to_world has no proper rotation (singular or mirrored)")
                fov = _number(f.get("fov"), "fov")
                if not 0 < fov < 180:
                    raise CameraError(f"fov must be in (0, 180) degrees, got {fov}")
                scene_time = None
                if timed:
                    r = _number(f["render_time"], "render_time")
                    scene_time = r if time_range is None else time_range[0] + r * (time_range[1] - time_range[0])
            except CameraError as exc:
                fail(f"frame {i}: {exc}")
            keys.append(CameraKey(i / fps, c2w[:3, 3].copy(), rotation_to_quaternion(u @ vt), fov, scene_time))
        return cls(keys, "z", False, size, fps, _NERFSTUDIO_PROJECTIONS[kind])

    def save(self, path: str | os.PathLike, force: bool = False) -> Path:
        return atomic_write_json(path, self.to_json(), force)

    @classmethod
    def load(cls, path: str | os.PathLike, time_range: tuple[float, float] | None = None) -> "CameraPath":
        """Read a path file (splatreel's or nerfstudio's; `time_range`: the model's, for nerfstudio's normalised
        times)."""
        path = Path(path)
        if not path.is_file():
            raise CameraError(f"{path}: no such camera path file")
        try:
            data = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise CameraError(f"{path}: not a readable JSON camera path ({exc})") from None
        return cls.from_json(data, str(path), time_range)


def nerfstudio_camera_path(cameras: Sequence[Camera], fps: float, times: Sequence[float] | None = None,
                           time_range: tuple[float, float] | None = None, projection: str = "perspective",
                           size: tuple[int, int] | None = None) -> dict:
    """The nerfstudio camera-path JSON of rendered frames (what ``ns-render camera-path`` plays, and what
    `CameraPath.from_nerfstudio` reads back frame for frame): one entry per camera with its OpenGL
    ``camera_to_world`` (row-major), vertical ``fov`` in degrees and ``aspect``, and with `times` a ``render_time``
    normalised to [0, 1] over `time_range`. nerfstudio's cameras have their principal point at the image centre,
    so an off-centre one is not kept. `projection` "equirect": the frames are 360° panoramas of `size` seen from
    the cameras' poses (camera_type "equirectangular")."""
    if not cameras:
        raise CameraError("a camera path needs at least one camera")
    width, height = size or (cameras[0].width, cameras[0].height)
    kind = _NERFSTUDIO_CAMERA_TYPES[projection]
    t0, t1 = time_range or (0.0, 1.0)
    span = (t1 - t0) or 1.0
    frames = []
    for i, cam in enumerate(cameras):
        frame = {"camera_to_world": cam.to_opengl_c2w().ravel().tolist(), "fov": math.degrees(cam.fov_y),
                 "aspect": cam.width / cam.height}
        if times is not None:
            frame["render_time"] = (float(times[i]) - t0) / span
        frames.append(frame)
    return {"camera_type": kind, "render_width": width, "render_height": height,
            "seconds": len(cameras) / fps, "fps": fps, "camera_path": frames}


# --- training dataset cameras ----------------------------------------------------------------------------------
def dataset_views(path: str | os.PathLike, split: str | None = "train") -> list[DatasetView]:
    """Cameras of a D-NeRF / Blender layout dataset (``transforms_<split>.json``; ``split=None``: all splits), read
    by the trainer's reader (`splatreel.datasets.dnerf.read_transforms`: the same poses, intrinsics, image sizes
    and times), or the training cameras a splatreel checkpoint (``.safetensors``) records (`recorded_views`; any
    layout it was trained on, `split` aside). A bad dataset is a CameraError here, like any other camera source.
    """
    if Path(path).suffix.lower() == ".safetensors":
        if split not in ("train", None):
            raise CameraError(f"{path}: a checkpoint records its training cameras only, not a {split!r} split")
        return recorded_views(path)
    try:
        frames = [fr for f in transforms_files(Path(path), split) for fr in read_transforms(f)[0]]
    except DatasetError as exc:
        raise CameraError(str(exc)) from None
    return [DatasetView(fr.file_path, fr.camera, fr.time) for fr in frames]


def recorded_views(path: str | os.PathLike) -> list[DatasetView]:
    """The training cameras recorded in the splatreel checkpoint `path` (`splatreel.checkpoint`), read from its
    metadata alone; CameraError (one line) when it records none."""
    from splatreel.checkpoint_file import read_metadata, views_in_metadata
    from splatreel.errors import CheckpointError

    try:
        views = views_in_metadata(read_metadata(path), path)
    except CheckpointError as exc:
        raise CameraError(str(exc)) from None
    if not views:
        raise CameraError(f"{path}: records no training cameras (written by an importer, or by splatreel train "
                          "before it recorded them); give the dataset folder instead")
    return views


def path_from_dataset(path: str | os.PathLike, split: str | None = "train", seconds_per_key: float = 0.5,
                      up: str | Sequence[float] = "z") -> CameraPath:
    """A camera path through the cameras of a training dataset, ordered by frame time (then file order).

    Each view becomes one key, `seconds_per_key` apart, carrying its frame time as ``scene_time``.
    """
    if not seconds_per_key > 0:
        raise CameraError(f"seconds per key must be positive, got {seconds_per_key}")
    views = sorted(enumerate(dataset_views(path, split)), key=lambda iv: (iv[1].time, iv[0]))
    keys = [CameraKey.from_camera(i * seconds_per_key, v.camera, v.time) for i, (_, v) in enumerate(views)]
    return CameraPath(keys, up if isinstance(up, str) else tuple(up))

