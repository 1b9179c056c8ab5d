"""Triangle-mesh array helpers shared by the procedural samples and the mesh exporter.

Faces wind counter-clockwise seen from outside, so ``cross(v1 - v0, v2 - v0)`` points out; its length is twice the
triangle's area.
"""

from __future__ import annotations

import numpy as np


def face_cross(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F, 3)`` un-normalised face normals ``cross(v1 - v0, v2 - v0)`` (length: twice the area)."""
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    return np.cross(v1 - v0, v2 - v0)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V, 3)`` float64 area-weighted unit vertex normals: the sum of the adjacent faces' `face_cross`. A vertex
    without a face (or with only degenerate ones) gets (0, 0, 0)."""
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    cross = face_cross(vertices, faces)
    corners = faces.reshape(-1)
    summed = np.stack([np.bincount(corners, np.repeat(cross[:, a], 3), len(vertices)) for a in range(3)], -1)
    length = np.linalg.norm(summed, axis=1, keepdims=True)
    return np.divide(summed, length, out=np.zeros_like(summed), where=length > 0)
