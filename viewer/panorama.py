"""360° equirectangular images from six cube-face renders.

Splats are projected with a pinhole camera (the EWA projection of the reference rasterizer), which cannot see
more than a hemisphere, so a panorama is assembled the way SuperSplat's 360° export does: six square 90° views
from the camera's position (front, right, back, left, up, down), each drawn by the ordinary renderer with its own
depth sort, then resampled into longitude x latitude.

Conventions (OpenCV camera axes, x right, y down, z forward): the image centre is the camera's forward direction,
longitude grows to the right (x), the top row looks up (-y) and the bottom row down (+y); pixel (u, v) of a W x H
panorama looks at longitude 2 pi ((u + 0.5) / W - 1/2) and latitude pi (1/2 - (v + 0.5) / H). Each face is drawn
`FACE_MARGIN` pixels wider than its 90° on every side, so that bilinear sampling next to a face edge reads drawn
pixels, not clamped ones. The faces are sampled as premultiplied RGBA, for which linear interpolation is exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from splatreel.cameras import Camera
from splatreel.errors import CameraError

#: How frames are formed: a pinhole camera, or a 360° equirectangular panorama from the camera's position.
PROJECTIONS = ("perspective", "equirect")
#: Extra pixels drawn on each side of a face beyond its 90° field of view.
FACE_MARGIN = 2

#: The faces' (forward, image-down) axes in the panorama camera's frame; a face's right axis is down x forward.
_FACES = (((0, 0, 1), (0, 1, 0)),    # front
          ((1, 0, 0), (0, 1, 0)),    # right
          ((0, 0, -1), (0, 1, 0)),   # back
          ((-1, 0, 0), (0, 1, 0)),   # left
          ((0, -1, 0), (0, 0, 1)),   # up
          ((0, 1, 0), (0, 0, -1)))   # down


def face_rotations() -> np.ndarray:
    """``[6, 3, 3]`` rotations whose columns are each face camera's right, down and forward axes, in the frame of
    the panorama's camera."""
    out = []
    for forward, down in _FACES:
        z, y = np.asarray(forward, np.float64), np.asarray(down, np.float64)
        out.append(np.stack([np.cross(y, z), y, z], 1))
    return np.asarray(out)


@dataclass(frozen=True)
class Equirect:
    """A W x H equirectangular panorama (W = 2 H) and how it is made from cube faces (see module doc)."""

    width: int
    height: int

    def __post_init__(self) -> None:
        if self.width != 2 * self.height or self.height < 2:
            raise CameraError(f"a 360° equirectangular image is twice as wide as high (e.g. 2048x1024), got "
                              f"{self.width}x{self.height}")

    @property
    def face_size(self) -> int:
        """Pixels across a face's 90°: at least the panorama's W / (2 pi) pixels per radian at every face's centre
        (where a face samples most coarsely), rounded up to an even number."""
        return 2 * math.ceil(self.width / math.pi / 2)

    def face_cameras(self, camera: Camera) -> list[Camera]:
        """The six square face cameras at `camera`'s position, turned with it (its intrinsics are not used)."""
        s, m = self.face_size, FACE_MARGIN
        size = s + 2 * m
        cameras = []
        for rot in face_rotations():
            c2w = np.array(camera.c2w, np.float64)
            c2w[:3, :3] = camera.c2w[:3, :3] @ rot
            cameras.append(Camera(c2w, s / 2, s / 2, size / 2, size / 2, size, size))
        return cameras

    def maps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(face ``[H, W]`` int8, x ``[H, W]``, y ``[H, W]`` float32): the face each panorama pixel looks through and
        where, in that face's pixel coordinates (cv2.remap's: pixel centres at integers). Made once per size."""
        return self._maps

    @cached_property
    def _maps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w, h = self.width, self.height
        lon = 2.0 * np.pi * ((np.arange(w) + 0.5) / w - 0.5)
        lat = np.pi * (0.5 - (np.arange(h) + 0.5) / h)
        lon, lat = np.meshgrid(lon, lat)
        d = np.stack([np.cos(lat) * np.sin(lon), -np.sin(lat), np.cos(lat) * np.cos(lon)], -1)  # camera frame
        local = np.einsum("hwi,fij->fhwj", d, face_rotations())  # each face's (right, down, forward) components
        face = np.argmax(local[..., 2], axis=0)
        x, y, z = np.take_along_axis(local, face[None, ..., None], axis=0)[0].transpose(2, 0, 1)
        half = self.face_size / 2
        centre = half + FACE_MARGIN - 0.5
        return (face.astype(np.int8), (half * x / z + centre).astype(np.float32),
                (half * y / z + centre).astype(np.float32))

    @cached_property
    def _face_lookups(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per face: (the flat indices of the panorama pixels it gives, and their x and y maps). The maps are laid
        out in rows of W (padded with the face's first sample): cv2.remap takes maps under 32767 rows or columns,
        and a face's pixels of a large panorama outnumber that."""
        face, x, y = self._maps
        w = self.width
        out = []
        for k in range(len(_FACES)):
            idx = np.flatnonzero(face.reshape(-1) == k)
            pad = -len(idx) % w
            rows = [np.pad(m.reshape(-1)[idx], (0, pad), mode="edge").reshape(-1, w) for m in (x, y)]
            out.append((idx, rows[0], rows[1]))
        return out

    def assemble(self, faces: list[np.ndarray]) -> np.ndarray:
        """The panorama ``[H, W, C]`` float32 from the six face images (top row first, in `face_cameras` order):
        each face resampled (bilinearly) at its own panorama pixels only."""
        import cv2

        channels = faces[0].shape[-1]
        out = np.zeros((self.height * self.width, channels), np.float32)
        for (idx, x, y), img in zip(self._face_lookups, faces):
            sampled = cv2.remap(np.ascontiguousarray(img, np.float32), x, y, cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE)
            out[idx] = sampled.reshape(-1, channels)[:len(idx)]
        return out.reshape(self.height, self.width, channels)
