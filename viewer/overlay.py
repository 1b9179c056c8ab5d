"""Line overlays of the desktop app: the camera path being edited, camera frustums, the crop box and the inspected
Gaussian's ellipsoid, drawn over the splats.

The geometry is pure numpy (``[M, 2, 3]`` world-space segments, one row per line segment); `LineRenderer` draws
segments with per-segment colours through ``shaders/lines.glsl``, which projects them with the splats' own pinhole
convention. Overlays are drawn after a screenshot is read, so screenshots show the model only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from splatreel.cameras import Camera
from splatreel.gl import load_program

from .camera_path import CameraPath

#: Colours (RGB in [0, 1]) of the overlays.
PATH_COLOR = (1.0, 0.85, 0.1)
KEY_COLOR = (1.0, 0.5, 0.1)
DATASET_COLOR = (0.35, 0.75, 1.0)
SELECTED_COLOR = (1.0, 1.0, 1.0)
CROP_COLOR = (0.3, 1.0, 0.4)
PICK_COLOR = (1.0, 0.2, 0.9)
#: Gaussians selected for deletion (crosses at their centres) and the selection rectangle being dragged
SELECTION_COLOR = (1.0, 0.25, 0.2)
#: the measuring tape: its two ends and the segment between them
MEASURE_COLOR = (0.55, 1.0, 1.0)


def frustum_segments(camera: Camera, depth: float) -> np.ndarray:
    """``[9, 2, 3]`` segments drawing `camera` as a pyramid: its centre to the four corners of its image at
    `depth` along the view axis, the rectangle of those corners, and a tick above the top edge (image -y) showing
    which way is up."""
    w, h = camera.width, camera.height
    pixels = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
    rays = np.stack([(pixels[:, 0] - camera.cx) / camera.fx, (pixels[:, 1] - camera.cy) / camera.fy,
                     np.ones(4)], -1)
    c2w = camera.c2w
    corners = (rays * depth) @ c2w[:3, :3].T + c2w[:3, 3]
    centre = c2w[:3, 3]
    top_mid = 0.5 * (corners[0] + corners[1])
    up = -c2w[:3, 1] * (0.25 * depth * h / camera.fy)  # image -y, a quarter of the half-height
    segments = [(centre, c) for c in corners]
    segments += [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    segments.append((top_mid, top_mid + up))
    return np.asarray(segments, np.float64)


def box_segments(lo, hi) -> np.ndarray:
    """``[12, 2, 3]`` segments: the edges of the axis-aligned box with corners `lo` and `hi`."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    corners = np.array([[(hi if (k >> a) & 1 else lo)[a] for a in range(3)] for k in range(8)])
    # corners k and k ^ (1 << a) differ along axis a only: one edge per pair
    return np.array([(corners[k], corners[k | 1 << a]) for a in range(3) for k in range(8) if not (k >> a) & 1])


def ellipsoid_segments(mean, cov, sigmas: float = 2.0, samples: int = 48) -> np.ndarray:
    """``[3 * samples, 2, 3]`` segments: the three principal ellipses of the `sigmas`-sigma ellipsoid of a 3D Gaussian
    (`mean` [3], covariance `cov` [3, 3]), each in the plane of two of its principal axes."""
    evals, evecs = np.linalg.eigh(np.asarray(cov, np.float64))
    axes = evecs * (sigmas * np.sqrt(np.clip(evals, 0.0, None)))  # columns: principal axes, scaled
    angle = np.linspace(0.0, 2.0 * np.pi, samples + 1)
    rings = [np.asarray(mean, np.float64) + np.outer(np.cos(angle), axes[:, i]) + np.outer(np.sin(angle), axes[:, j])
             for i, j in ((0, 1), (1, 2), (2, 0))]
    return np.concatenate([polyline_segments(r) for r in rings])


def polyline_segments(points: np.ndarray) -> np.ndarray:
    """``[K, 3]`` points -> ``[K - 1, 2, 3]`` segments joining consecutive points."""
    p = np.asarray(points, np.float64)
    return np.stack([p[:-1], p[1:]], 1) if len(p) > 1 else np.zeros((0, 2, 3))


def path_segments(path: CameraPath, samples_per_key: int = 24) -> np.ndarray:
    """The interpolated camera centres of `path` over its whole duration (the closing segment of a looping path
    included), as a polyline of `samples_per_key` segments per key interval."""
    count = max(2, samples_per_key * max(len(path.keys) - (0 if path.loop else 1), 1) + 1)
    times = path.start + np.linspace(0.0, path.duration, count)
    return polyline_segments(np.array([path.pose(float(t))[0][:3, 3] for t in times]))


@dataclass
class Frustums:
    """Camera frustums ready to draw: ``centres [F, 3]``, ``segments [F, 9, 2, 3]`` (`frustum_segments`) and
    ``colors [F, 3]``. Built once per set of cameras; `lines` is the cheap per-frame part."""

    centres: np.ndarray
    segments: np.ndarray
    colors: np.ndarray

    @classmethod
    def of(cls, cameras: Sequence[Camera], colors: Sequence, depth: float) -> "Frustums":
        if not cameras:
            return cls(np.zeros((0, 3)), np.zeros((0, 9, 2, 3)), np.zeros((0, 3), np.float32))
        return cls(np.array([c.position for c in cameras]), np.stack([frustum_segments(c, depth) for c in cameras]),
                   np.asarray(colors, np.float32).reshape(len(cameras), 3))

    def lines(self, away_from: np.ndarray, min_distance: float) -> tuple[np.ndarray, np.ndarray]:
        """(``[M, 2, 3]`` segments, ``[M, 3]`` colours) of the frustums whose centre is farther than
        `min_distance` from `away_from` (the viewing camera: its own frustum would frame the screen)."""
        keep = np.linalg.norm(self.centres - np.asarray(away_from, np.float64), axis=1) > min_distance
        return self.segments[keep].reshape(-1, 2, 3), np.repeat(self.colors[keep], 9, axis=0)


class LineRenderer:
    """Draws coloured segments over whatever is in the target, with no depth test (always visible)."""

    def __init__(self, ctx) -> None:
        self.ctx = ctx
        self.program = load_program(ctx, "lines")
        self._vbo = None
        self._vao = None
        self._capacity = 0

    def draw(self, camera: Camera, segments: np.ndarray, colors: np.ndarray) -> None:
        """Draw ``[M, 2, 3]`` `segments` with ``[M, 3]`` `colors` as seen by `camera`, into the current
        framebuffer and viewport (which should have the camera's image size)."""
        m = len(segments)
        if m == 0:
            return
        verts = np.empty((m, 2, 6), np.float32)
        verts[..., :3] = segments
        verts[..., 3:] = np.asarray(colors, np.float32)[:, None, :]
        data = verts.tobytes()
        if self._vbo is None or len(data) > self._capacity:
            self.release()
            self._capacity = max(len(data), 4096)
            self._vbo = self.ctx.buffer(reserve=self._capacity, dynamic=True)
            self._vao = self.ctx.vertex_array(self.program, [(self._vbo, "3f 3f", "in_position", "in_color")])
        self._vbo.write(data)
        prog = self.program
        prog["u_w2c"].write(np.ascontiguousarray(camera.w2c.T, np.float32).tobytes())  # column-major
        prog["u_intrinsics"].value = (camera.fx, camera.fy, camera.cx, camera.cy)
        prog["u_size"].value = (float(camera.width), float(camera.height))
        self.ctx.disable(self.ctx.DEPTH_TEST | self.ctx.BLEND)
        self._vao.render(self.ctx.LINES, vertices=2 * m)

    def release(self) -> None:
        for obj in (self._vao, self._vbo):
            if obj is not None:
                obj.release()
        self._vao = self._vbo = None
        self._capacity = 0
