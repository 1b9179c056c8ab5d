"""How far a mesh of a sample is from the sample's true surface: what the mesh tests and bench/mesh.py measure.

The samples' meshes have one topology at every time (`splatreel.samples.mesh_at`), so a point of the true surface
is a *material* point: a triangle and barycentric coordinates that follow the motion exactly.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np


def true_surface(name: str, t: float):
    """The sample's true surface at `t` as a ``trimesh.Trimesh``, and the object's size (its box diagonal)."""
    import trimesh

    from .catalog import mesh_at

    vertices, faces, _ = mesh_at(name, float(t))
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    return mesh, float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0]))


def chamfer(vertices: np.ndarray, name: str, t: float, samples: int = 5000) -> float:
    """Two-way Chamfer distance between a mesh's `vertices` and the sample's true surface at `t`: the mean of both
    directions' mean nearest distances (the vertices against `samples` points spread evenly over the true surface),
    as a share of the object's size."""
    import trimesh
    from scipy.spatial import cKDTree

    truth, size = true_surface(name, t)
    points, _ = trimesh.sample.sample_surface_even(truth, samples, seed=0)
    there = float(cKDTree(points).query(vertices)[0].mean())
    back = float(cKDTree(vertices).query(points)[0].mean())
    return 0.5 * (there + back) / size


def material_slide(vertices: Sequence[np.ndarray], name: str, times: Sequence[float], reference: int,
                   samples: int = 100000) -> list[float]:
    """Per time, the mean distance (share of the object's size) between each vertex of a deforming mesh and the
    material point of the true surface it lay on at time ``times[reference]`` (its nearest of `samples` points spread
    evenly over the true surface then, followed through the true motion)."""
    import trimesh
    from scipy.spatial import cKDTree

    truth, size = true_surface(name, times[reference])
    points, face_ids = trimesh.sample.sample_surface_even(truth, samples, seed=0)
    near = cKDTree(points).query(vertices[reference])[1]
    faces = face_ids[near]
    bary = trimesh.triangles.points_to_barycentric(truth.triangles[faces], points[near])
    out = []
    for v, t in zip(vertices, times):
        moved, _ = true_surface(name, t)
        material = (bary[:, :, None] * moved.vertices[moved.faces[faces]]).sum(1)
        out.append(float(np.linalg.norm(v - material, axis=1).mean()) / size)
    return out
