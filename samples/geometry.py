"""Triangle meshes with per-vertex colours: the data form of every procedural sample, and small array helpers.

A `Mesh` is ``vertices (V, 3) float64``, ``faces (F, 3) int32`` (counter-clockwise seen from outside, so the
face normal ``cross(v1 - v0, v2 - v0)`` points out) and ``colors (V, 3) float64`` albedo in [0, 1].
Samples keep their topology fixed over time, so a point given by (face id, barycentric coordinates) has a known
trajectory: `points_on_surface` evaluates it on the mesh at any time.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from splatreel import quaternion
from splatreel.meshes import face_cross, vertex_normals  # noqa: F401  (part of this module's API)
from splatreel.pointsets import farthest_point_subset  # noqa: F401  (part of this module's API)


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh at one time.

    Attributes:
        vertices: ``(V, 3)`` float64 world positions (Blender world: +z up).
        faces: ``(F, 3)`` int32 vertex indices, counter-clockwise seen from outside.
        colors: ``(V, 3)`` float64 albedo in [0, 1] (unlit).
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray

    @property
    def normals(self) -> np.ndarray:
        """``(V, 3)`` unit vertex normals (area-weighted face normals: smooth shading)."""
        return vertex_normals(self.vertices, self.faces)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min ``(3,)``, max ``(3,)``) of the vertices."""
        return self.vertices.min(0), self.vertices.max(0)


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F,)`` triangle areas."""
    return 0.5 * np.linalg.norm(face_cross(vertices, faces), axis=-1)


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Volume enclosed by a closed mesh; positive when the faces wind counter-clockwise seen from outside."""
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", v0, np.cross(v1, v2)).sum() / 6.0)


def grid_faces(rows: int, cols: int, wrap_cols: bool = False, offset: int = 0) -> np.ndarray:
    """Triangles of a ``rows x cols`` vertex grid (vertex ``(i, j)`` has index ``offset + i * cols + j``).

    With u along rows (i) and v along columns (j), the triangles wind so that their normal is ``cross(u, v)``.
    `wrap_cols` joins column ``cols - 1`` back to column 0 (a ring).
    """
    jn = cols if wrap_cols else cols - 1
    i, j = np.meshgrid(np.arange(rows - 1), np.arange(jn), indexing="ij")
    i, j = i.ravel(), j.ravel()
    j1 = (j + 1) % cols
    a, b = i * cols + j, (i + 1) * cols + j
    c, d = i * cols + j1, (i + 1) * cols + j1
    faces = np.stack([np.stack([a, b, c], -1), np.stack([b, d, c], -1)], 1).reshape(-1, 3)
    return (faces + offset).astype(np.int32)


def sphere_topology(rings: int, segments: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A closed surface of sphere topology parametrised by (theta, phi), with one vertex at each pole.

    Returns:
        theta: ``(V,)`` polar angle in [0, pi] (0 at the first pole).
        phi: ``(V,)`` azimuth in [0, 2 pi).
        faces: ``(F, 3)`` int32; outward-wound when a vertex is placed at r(theta, phi) * (sin theta cos phi,
            sin theta sin phi, cos theta) with r > 0 (theta then runs along rows, phi along columns).
    V = 2 + (rings - 1) * segments.
    """
    ring_theta = np.pi * np.arange(1, rings) / rings
    ring_phi = 2.0 * np.pi * np.arange(segments) / segments
    th, ph = np.meshgrid(ring_theta, ring_phi, indexing="ij")
    theta = np.concatenate([[0.0], th.ravel(), [np.pi]])
    phi = np.concatenate([[0.0], ph.ravel(), [0.0]])
    last = 1 + (rings - 1) * segments
    s = np.arange(segments)
    s1 = (s + 1) % segments
    top = np.stack([np.zeros_like(s), 1 + s, 1 + s1], -1)
    base = 1 + (rings - 2) * segments
    bottom = np.stack([np.full_like(s, last), base + s1, base + s], -1)
    body = grid_faces(rings - 1, segments, wrap_cols=True, offset=1)
    return theta, phi, np.concatenate([top, body, bottom]).astype(np.int32)


def points_on_surface(mesh: Mesh, face_ids: np.ndarray, bary: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Evaluate surface points given by face and barycentric coordinates.

    Args:
        face_ids: ``(P,)`` face indices.
        bary: ``(P, 3)`` barycentric weights (rows sum to 1).
    Returns:
        positions ``(P, 3)``, unit normals ``(P, 3)`` (interpolated vertex normals), albedo ``(P, 3)``.
    """
    corners = mesh.faces[face_ids]  # (P, 3)

    def interp(values: np.ndarray) -> np.ndarray:
        return np.einsum("pk,pkc->pc", bary, values[corners])

    normals = interp(mesh.normals)
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    return interp(mesh.vertices), normals, interp(mesh.colors)


def sample_surface(areas: np.ndarray, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """`count` random surface points, uniform by area: (face ids ``(count,)``, barycentrics ``(count, 3)``)."""
    face_ids = rng.choice(len(areas), size=count, p=areas / areas.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)  # uniform on the triangle (Osada et al. 2002)
    bary = np.stack([1.0 - s, s * (1.0 - r2), s * r2], -1)
    return face_ids, bary


def smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    """GLSL smoothstep: 0 below edge0, 1 above edge1, cubic Hermite in between."""
    u = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``(...)`` hue in turns (any real, wrapped), saturation and value in [0, 1] -> ``(..., 3)`` RGB in [0, 1]."""
    h, s, v = np.broadcast_arrays(np.asarray(h, np.float64), np.asarray(s, np.float64), np.asarray(v, np.float64))
    hsv = np.stack([np.mod(h, 1.0) * 360.0, s, v], -1).astype(np.float32).reshape(1, -1, 3)
    rgb = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)  # float input: H in degrees, S and V in [0, 1]
    return rgb.reshape(h.shape + (3,)).astype(np.float64)


def axis_angle_matrix(axis, angle: float) -> np.ndarray:
    """``(3, 3)`` rotation by `angle` radians about `axis` (right-handed)."""
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    q = np.concatenate([[np.cos(0.5 * angle)], np.sin(0.5 * angle) * axis])
    return quaternion.to_rotmat(torch.from_numpy(q)).numpy()


def mix(a: np.ndarray, b, w: np.ndarray) -> np.ndarray:
    """Per-row linear blend ``a + (b - a) * w`` with ``w`` of shape ``(V,)`` and colours ``(V, 3)`` or ``(3,)``."""
    return a + (np.asarray(b, np.float64) - a) * np.asarray(w)[..., None]
