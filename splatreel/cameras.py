"""Pinhole cameras in one internal convention, converters from the others, and look-at / orbit constructors.

Internal convention (the one gsplat and COLMAP use):

* ``c2w`` is a 4x4 **camera-to-world** matrix whose camera axes are **OpenCV**: +x right, +y down, +z forward
  (the camera looks along its +z). ``w2c = inv(c2w)`` is the "view matrix" a rasterizer takes.
* Intrinsics ``fx, fy, cx, cy`` are in pixels. Pixel (i, j) covers [i, i+1) x [j, j+1), so its centre is at
  (i + 0.5, j + 0.5) and ``cx = W/2, cy = H/2`` is the exact image centre.
* World axes are whatever the data uses; `look_at` and `orbit` take the world's up axis.

OpenGL / Blender / NeRF ``transform_matrix`` poses are camera-to-world with +x right, +y up, looking down -z:
they differ from ours by flipping the camera's y and z axes (`opengl_to_opencv`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from .errors import CameraError

_FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])

UP_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0),
           "-x": (-1.0, 0.0, 0.0), "-y": (0.0, -1.0, 0.0), "-z": (0.0, 0.0, -1.0)}


def opengl_to_opencv(c2w: np.ndarray) -> np.ndarray:
    """OpenGL/Blender camera-to-world (y up, looking down -z) -> OpenCV camera-to-world (y down, looking down +z)."""
    return np.asarray(c2w, dtype=np.float64) @ _FLIP_YZ


#: The conversion is its own inverse.
opencv_to_opengl = opengl_to_opencv


def focal_from_fov(fov_rad: float, size: int) -> float:
    """Focal length in pixels for a full field of view `fov_rad` across `size` pixels."""
    return 0.5 * size / math.tan(0.5 * fov_rad)


def fov_from_focal(focal: float, size: int) -> float:
    """Full field of view in radians across `size` pixels for focal length `focal`."""
    return 2.0 * math.atan(0.5 * size / focal)


def as_up(up: str | Sequence[float]) -> np.ndarray:
    if isinstance(up, str):
        if up not in UP_AXES:
            raise CameraError(f"unknown up axis {up!r}; expected one of {', '.join(UP_AXES)}")
        return np.array(UP_AXES[up])
    v = np.asarray(up, dtype=np.float64)
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) == 0:
        raise CameraError(f"up vector must be 3 finite numbers, not all zero, got {up!r}")
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: OpenCV-axes camera-to-world pose + intrinsics in pixels (see module doc)."""

    c2w: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        c2w = np.asarray(self.c2w, dtype=np.float64)
        if c2w.shape == (3, 4):
            c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
        if c2w.shape != (4, 4):
            raise CameraError(f"camera pose must be 4x4 (or 3x4), got shape {list(c2w.shape)}")
        if not np.isfinite(c2w).all():
            raise CameraError("camera pose contains NaN or infinite values")
        r = c2w[:3, :3]
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-4):
            raise CameraError("camera rotation is not orthonormal (scaled or sheared pose)")
        for name in ("fx", "fy", "cx", "cy"):
            v = float(getattr(self, name))
            if not math.isfinite(v):
                raise CameraError(f"camera intrinsic {name} is not finite")
            object.__setattr__(self, name, v)
        if self.fx <= 0 or self.fy <= 0:
            raise CameraError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CameraError(f"image size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        c2w.flags.writeable = False
        object.__setattr__(self, "c2w", c2w)

    # --- constructors -----------------------------------------------------------------------------------------
    @classmethod
    def from_fov(cls, c2w: np.ndarray, width: int, height: int, fov_x_deg: float | None = None,
                 fov_y_deg: float | None = None) -> "Camera":
        """Camera with square pixels and a centred principal point; give the horizontal or the vertical FOV."""
        if (fov_x_deg is None) == (fov_y_deg is None):
            raise CameraError("give exactly one of fov_x_deg and fov_y_deg")
        fov = fov_x_deg if fov_x_deg is not None else fov_y_deg
        if not 0 < fov < 180:
            raise CameraError(f"field of view must be in (0, 180) degrees, got {fov}")
        f = focal_from_fov(math.radians(fov), width if fov_x_deg is not None else height)
        return cls(c2w, f, f, width / 2.0, height / 2.0, width, height)

    @classmethod
    def from_opengl(cls, c2w_gl: np.ndarray, width: int, height: int, fov_x_deg: float | None = None,
                    fov_y_deg: float | None = None, fx: float | None = None, fy: float | None = None,
                    cx: float | None = None, cy: float | None = None) -> "Camera":
        """From an OpenGL/Blender/NeRF camera-to-world (``transform_matrix``) and either a FOV or pixel intrinsics."""
        c2w = opengl_to_opencv(np.asarray(c2w_gl, dtype=np.float64)[:4])
        if fx is not None:
            fy = fx if fy is None else fy
            return cls(c2w, fx, fy, width / 2.0 if cx is None else cx, height / 2.0 if cy is None else cy,
                       width, height)
        return cls.from_fov(c2w, width, height, fov_x_deg, fov_y_deg)

    @classmethod
    def from_opencv_w2c(cls, w2c: np.ndarray, fx: float, fy: float, cx: float, cy: float,
                        width: int, height: int) -> "Camera":
        """From an OpenCV/COLMAP world-to-camera ``[R | t]`` (3x4 or 4x4)."""
        w2c = np.asarray(w2c, dtype=np.float64)
        if w2c.shape == (3, 4):
            w2c = np.vstack([w2c, [0.0, 0.0, 0.0, 1.0]])
        if w2c.shape != (4, 4) or not np.isfinite(w2c).all():
            raise CameraError(f"world-to-camera must be a finite 3x4 or 4x4 matrix, got shape {list(w2c.shape)}")
        return cls(np.linalg.inv(w2c), fx, fy, cx, cy, width, height)

    # --- derived ----------------------------------------------------------------------------------------------
    @property
    def w2c(self) -> np.ndarray:
        """4x4 world-to-camera (view matrix), OpenCV axes."""
        r, t = self.c2w[:3, :3], self.c2w[:3, 3]
        out = np.eye(4)
        out[:3, :3] = r.T
        out[:3, 3] = -r.T @ t
        return out

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def position(self) -> np.ndarray:
        return self.c2w[:3, 3].copy()

    @property
    def forward(self) -> np.ndarray:
        """Viewing direction in world space (camera +z)."""
        return self.c2w[:3, 2].copy()

    @property
    def fov_x(self) -> float:
        """Horizontal field of view in radians."""
        return fov_from_focal(self.fx, self.width)

    @property
    def fov_y(self) -> float:
        return fov_from_focal(self.fy, self.height)

    def to_opengl_c2w(self) -> np.ndarray:
        """OpenGL/Blender camera-to-world (what a NeRF ``transform_matrix`` stores)."""
        return opencv_to_opengl(self.c2w)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points ``[N, 3]`` -> (pixel coordinates ``[N, 2]``, camera-space depth ``[N]``)."""
        p = np.asarray(points, dtype=np.float64) @ self.w2c[:3, :3].T + self.w2c[:3, 3]
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * p[:, 0] / z + self.cx, self.fy * p[:, 1] / z + self.cy], -1)
        return uv, z

    def unproject(self, pixels: np.ndarray, depths: np.ndarray) -> np.ndarray:
        """Pixel coordinates ``[N, 2]`` (x, y; pixel i spans [i, i + 1)) at camera-space depths ``[N]`` -> world points
        ``[N, 3]``; the inverse of `project`."""
        uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(depths, dtype=np.float64).reshape(-1)
        p = np.stack([(uv[:, 0] - self.cx) / self.fx * z, (uv[:, 1] - self.cy) / self.fy * z, z], -1)
        return p @ self.c2w[:3, :3].T + self.c2w[:3, 3]

    def ray_limits(self, slack: float = 0.0) -> tuple[float, float, float, float]:
        """(x lo, x hi, y lo, y hi): the range of x/z and y/z (camera space) the image covers, each side widened by
        `slack` times half the image's width (height) in those units; the EWA Jacobian's clamp uses slack 0.3."""
        sx, sy = slack * 0.5 * self.width / self.fx, slack * 0.5 * self.height / self.fy
        return (-(self.cx / self.fx + sx), (self.width - self.cx) / self.fx + sx,
                -(self.cy / self.fy + sy), (self.height - self.cy) / self.fy + sy)

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera rendering `width` x `height` pixels (intrinsics scaled per axis)."""
        sx, sy = width / self.width, height / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy,
                       width=width, height=height)

    def opengl_projection(self, near: float = 0.01, far: float = 1000.0) -> np.ndarray:
        """4x4 OpenGL clip-space projection for this camera (to be used with the OpenGL-axes view matrix
        ``inv(to_opengl_c2w())``), honouring an off-centre principal point. Row-major."""
        w, h = self.width, self.height
        return np.array([
            [2.0 * self.fx / w, 0.0, 1.0 - 2.0 * self.cx / w, 0.0],
            [0.0, 2.0 * self.fy / h, 2.0 * self.cy / h - 1.0, 0.0],
            [0.0, 0.0, -(far + near) / (far - near), -2.0 * far * near / (far - near)],
            [0.0, 0.0, -1.0, 0.0],
        ])


def look_at_c2w(eye: Sequence[float], target: Sequence[float], up: str | Sequence[float] = "z") -> np.ndarray:
    """OpenCV-axes camera-to-world placing the camera at `eye`, looking at `target`, with `up` pointing up
    on screen (image -y)."""
    eye = np.asarray(eye, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    up_v = as_up(up)
    fwd = target - eye
    if not np.isfinite(fwd).all() or np.linalg.norm(fwd) < 1e-12:
        raise CameraError("look-at needs distinct, finite eye and target points")
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up_v)
    if np.linalg.norm(right) < 1e-9:  # looking straight along up: pick any perpendicular
        right = np.cross(fwd, np.roll(up_v, 1))
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, fwd, eye
    return c2w


def look_at(eye: Sequence[float], target: Sequence[float] = (0.0, 0.0, 0.0), up: str | Sequence[float] = "z",
            fov_deg: float = 50.0, width: int = 512, height: int = 512) -> Camera:
    """Camera at `eye` looking at `target`; `fov_deg` is the vertical field of view."""
    return Camera.from_fov(look_at_c2w(eye, target, up), width, height, fov_y_deg=fov_deg)


def orbit_position(elevation_deg: float, azimuth_deg: float, radius: float, up: str = "z",
                   target: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Point on a sphere around `target`. Positive elevation is above the target.

    * ``up='z'`` (Blender, D-NeRF, SyncDreamer, threestudio): azimuth 0 is +x, increasing towards +y:
      ``r (cos e cos a, cos e sin a, sin e)``.
    * ``up='y'`` (DreamGaussian/kiui, Efficient4D, 4DGen, with the elevation sign made positive-up):
      azimuth 0 is +z, 90 is +x: ``r (cos e sin a, sin e, cos e cos a)``.
    """
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    if up == "z":
        p = (math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e))
    elif up == "y":
        p = (math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a))
    else:
        raise CameraError(f"orbit up axis must be 'y' or 'z', got {up!r}")
    return np.asarray(target, dtype=np.float64) + radius * np.array(p)


def orbit(elevation_deg: float, azimuth_deg: float, radius: float, fov_deg: float = 49.1343,
          width: int = 256, height: int = 256, up: str = "z",
          target: Sequence[float] = (0.0, 0.0, 0.0)) -> Camera:
    """Camera on an orbit around `target`, looking at it (see `orbit_position` for the angle conventions).

    The default FOV is Efficient4D's / SyncDreamer's (fx = 280 px at 256 px, 49.13 degrees).
    """
    if not radius > 0:
        raise CameraError(f"orbit radius must be positive, got {radius}")
    eye = orbit_position(elevation_deg, azimuth_deg, radius, up, target)
    return look_at(eye, target, up, fov_deg, width, height)


def nerf_frame_camera(frame: dict, meta: dict, width: int, height: int) -> Camera:
    """Camera of one frame of a NeRF / D-NeRF / Blender ``transforms_*.json``.

    ``transform_matrix`` is an OpenGL camera-to-world; intrinsics are ``fl_x, fl_y, cx, cy`` (per frame, else top
    level; ``fl_y`` defaults to ``fl_x``, the principal point to the image centre) and otherwise
    ``camera_angle_x`` (horizontal FOV in radians, square pixels). Raises CameraError naming what is missing.
    """
    try:
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)[:4]
    except KeyError:
        raise CameraError("no transform_matrix") from None
    except (TypeError, ValueError) as exc:
        raise CameraError(f"transform_matrix is not a 4x4 matrix ({exc})") from None
    get = lambda key, default=None: frame.get(key, meta.get(key, default))  # noqa: E731
    try:
        fx = get("fl_x")
        if fx is None:
            angle = get("camera_angle_x")
            if angle is None:
                raise CameraError("no intrinsics (camera_angle_x or fl_x)")
            fx = focal_from_fov(float(angle), width)
        fx = float(fx)
        return Camera(opengl_to_opencv(c2w), fx, float(get("fl_y", fx)), float(get("cx", width / 2.0)),
                      float(get("cy", height / 2.0)), width, height)
    except (TypeError, ValueError) as exc:
        raise CameraError(f"invalid intrinsics ({exc})") from None


# --- the cameras of a training dataset -------------------------------------------------------------------------
@dataclass(frozen=True)
class DatasetView:
    """One camera of a training dataset: its name (image path), the camera and the frame's scene time."""

    name: str
    camera: Camera
    time: float


def views_to_json(views: Sequence[DatasetView]) -> dict:
    """A compact JSON form of dataset views (what a checkpoint records of the data it was trained on): each
    distinct camera once (``cameras``: OpenCV camera-to-world rows 0-2, fx, fy, cx, cy, width, height) and each
    view as ``[camera index, time, name]`` (``views``), since a multi-view video repeats every camera per frame."""
    cameras: list[dict] = []
    index: dict[tuple, int] = {}
    rows = []
    for v in views:
        c = v.camera
        key = (np.asarray(c.c2w, np.float64)[:3].tobytes(), c.fx, c.fy, c.cx, c.cy, c.width, c.height)
        if key not in index:
            index[key] = len(cameras)
            cameras.append({"c2w": [float(x) for x in np.asarray(c.c2w, np.float64)[:3].reshape(-1)],
                            "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy, "width": int(c.width),
                            "height": int(c.height)})
        rows.append([index[key], float(v.time), str(v.name)])
    return {"cameras": cameras, "views": rows}


def views_from_json(obj: dict) -> list[DatasetView]:
    """The dataset views of `views_to_json`'s form; raises CameraError (one line) on a malformed one."""
    try:
        cameras = [Camera(np.asarray(c["c2w"], np.float64).reshape(3, 4), c["fx"], c["fy"], c["cx"], c["cy"],
                          int(c["width"]), int(c["height"])) for c in obj["cameras"]]
        views = []
        for i, t, name in obj["views"]:
            if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < len(cameras):
                raise IndexError(f"camera index {i!r} of {len(cameras)} cameras")
            views.append(DatasetView(str(name), cameras[i], float(t)))
        return views
    except (KeyError, TypeError, ValueError, IndexError, ArithmeticError, CameraError) as exc:
        raise CameraError(f"malformed recorded cameras ({type(exc).__name__}: {exc})") from None
