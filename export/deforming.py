"""One mesh that deforms over time (``export mesh --deforming``): one topology for every frame, so DCC tools see one
object whose vertices move (motion blur, UVs and simulation on top) instead of a new object each frame.

The surface is extracted once (`splatreel.export.mesh.frame_mesh`) at the reference frame, by default the frame
whose Gaussians show the most opacity. Each vertex is then carried by the Gaussians around it, one frame step at a
time away from the reference (both ways): its `CARRIERS` nearest live Gaussians at the frame the step starts from,
weighted by their opacity-weighted density at the vertex (as the vertex colours are), move it by the weighted mean
of their own displacements over the step (for native 4D Gaussians the conditional means, which move linearly; for
keyframed models the interpolated keys; for skinned models the means their control nodes carry). Stepping matters:
native 4D Gaussians (skinned ones too) live briefly, so the Gaussians that carry a vertex change along the way. Each
step's displacement field is smoothed over the mesh (`SMOOTHING_STEPS` of Laplacian averaging) so that neighbouring
vertices carried by different Gaussians do not crumple the surface.

Drift: at up to `DRIFT_FRAMES` frames the deformed surface is compared with the surface extracted at that frame
(mean two-way nearest-vertex distance, as a share of the grid's diagonal). Above `DRIFT_WARNING`, or where the
extracted surface has a different number of pieces (a split or a merge), the export says so and suggests per-frame
meshes for that span; the manifest records every measured frame.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from splatreel.constants import TEMPORAL_CULL
from splatreel.meshes import vertex_normals
from splatreel.pointsets import rigid_fit

from .base import iter_frames

#: Gaussians that carry each vertex
CARRIERS = 16
#: sub-steps of one frame step at most (see `substeps`)
MAX_SUBSTEPS = 16
#: Laplacian averaging steps of a displacement field (each mixes a vertex half-way to its neighbours' mean)
SMOOTHING_STEPS = 40
#: tangential relaxation steps after each frame's vertices are drawn onto its surface
RELAX_STEPS = 3
#: frames at which the drift from the per-frame surface is measured
DRIFT_FRAMES = 8
#: drift (share of the grid's diagonal) above which the export warns
DRIFT_WARNING = 0.02


def reference_frame(frames: Sequence) -> int:
    """Index of the `SplatFrame` whose Gaussians show the most opacity in total (the most surface to extract)."""
    return int(np.argmax([float(f.opacities.sum()) for f in frames]))


def carriers(vertices: np.ndarray, frame, dilation: float, k: int = CARRIERS) -> tuple[np.ndarray, np.ndarray]:
    """(``[V, k]`` Gaussian indices, ``[V, k]`` weights summing to 1) of the Gaussians of `frame` that carry each
    vertex: their opacity-weighted density at the vertex (the nearest alone where every weight vanishes)."""
    from scipy.spatial import cKDTree

    from .surface import inverse_covariances

    live = np.flatnonzero(frame.opacities > 0)
    k = min(k, len(live))
    means = frame.means[live].astype(np.float64)
    _, near = cKDTree(means).query(vertices, k=k)
    near = near.reshape(len(vertices), k)
    inv = inverse_covariances(frame.scales[live], frame.quats[live], dilation)
    d = vertices[:, None, :] - means[near]
    q = np.einsum("vki,vkij,vkj->vk", d, inv[near], d)
    w = frame.opacities[live][near].astype(np.float64) * np.exp(-0.5 * np.minimum(q, 1e4))
    total = w.sum(1, keepdims=True)
    nearest_only = np.zeros_like(w)
    nearest_only[:, 0] = 1.0
    w = np.where(total > 1e-30, w / np.maximum(total, 1e-300), nearest_only)
    return live[near], w


@dataclass(frozen=True)
class MotionState:
    """What carrying needs of a frame, at any time: means, opacities (temporal factor applied), scales and w-first
    quaternions ``[N, ...]`` and the time. A light stand-in for `SplatFrame` between frames."""

    time: float
    means: np.ndarray
    opacities: np.ndarray
    scales: np.ndarray
    quats: np.ndarray


def motion_states(model, times: Sequence[float]) -> list:
    """States of `model` at `times`: for a native 4D model from its motion (linear, plus the accelerations' term),
    conditioned once (the conditional covariance does not change with time); otherwise the model's slices."""
    from .base import linear_motion

    if model.kind != "gaussians4d":
        return list(iter_frames(model, times))
    g = linear_motion(model, "a deforming mesh")
    out = []
    for t in times:
        dt = float(t) - g.t_means
        marginal = np.exp(-0.5 * dt * dt / g.var_t)
        opacity = np.where(marginal > TEMPORAL_CULL, g.opacity * marginal, 0.0)
        dt = dt[:, None]
        out.append(MotionState(float(t), g.means + (g.velocity + 0.5 * g.acceleration * dt) * dt, opacity, g.scales,
                               g.quats))
    return out


def substeps(model, start, t_end: float, end) -> tuple[list, list]:
    """(starts, ends): the frame step from `start` to `end` (at `t_end`) cut into sub-steps no longer than half the
    median temporal std-dev of the Gaussians alive at `start`, so that each sub-step is carried by Gaussians that
    are still alive at its end (native 4D Gaussians are short-lived; their linear motion means nothing past their
    life; a skinned model's Gaussians fade as native ones do, wherever their nodes carry them). Keyframed and static
    models: one step."""
    t_scales = getattr(model.gaussians if model.kind == "skinned" else model, "t_scales", None)
    live = start.opacities > 0
    if t_scales is None or not live.any():
        return [start], [end]
    sigma = float(np.median(t_scales.detach().double().numpy()[live]))
    count = int(min(MAX_SUBSTEPS, max(1, math.ceil(abs(t_end - start.time) / (0.5 * max(sigma, 1e-9))))))
    if count == 1:
        return [start], [end]
    chain = [start, *motion_states(model, np.linspace(start.time, t_end, count + 1)[1:-1]), end]
    return chain[:-1], chain[1:]


def rigid_carry(points: np.ndarray, before: np.ndarray, after: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Each of `points` ``[V, 3]`` moved by the weighted rigid motion (rotation and translation, Kabsch/Procrustes)
    that best takes its carriers from `before` to `after` (``[V, k, 3]``, `weights` ``[V, k]`` summing to 1): a
    turning surface turns its vertices with it, where the mean displacement would shear them. Where the carriers
    cannot fix a rotation (fewer than three spread out), the mean displacement."""
    rot, c0, c1, spread = rigid_fit(before, after, weights)
    moved = np.einsum("vij,vj->vi", rot, points - c0) + c1
    return np.where(spread[:, None], moved, points + (c1 - c0))


def vertex_neighbours(faces: np.ndarray, count: int):
    """Row-normalised ``[V, V]`` sparse adjacency of the mesh's vertices (each row averages its neighbours)."""
    from scipy import sparse

    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges = np.concatenate([edges, edges[:, ::-1]])
    adjacency = sparse.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(count, count)).tocsr()
    adjacency.data[:] = 1.0  # an edge shared by two faces counts once
    degree = np.asarray(adjacency.sum(1)).ravel()
    return sparse.diags(1.0 / np.maximum(degree, 1.0)) @ adjacency


def smooth(displacement: np.ndarray, neighbours, steps: int = SMOOTHING_STEPS) -> np.ndarray:
    """`steps` of Laplacian averaging of a per-vertex field ``[V, 3]`` (each step half-way to the neighbours' mean)."""
    for _ in range(steps):
        displacement = 0.5 * displacement + 0.5 * (neighbours @ displacement)
    return displacement


def relax(vertices: np.ndarray, faces: np.ndarray, neighbours, steps: int = RELAX_STEPS) -> np.ndarray:
    """Even out the vertex spacing without changing the shape: Laplacian steps with their normal part removed."""
    for _ in range(steps):
        normals = vertex_normals(vertices, faces)
        pull = neighbours @ vertices - vertices
        vertices = vertices + 0.5 * (pull - (pull * normals).sum(1, keepdims=True) * normals)
    return vertices


def onto_surface(points: np.ndarray, surface) -> np.ndarray:
    """The nearest vertex of `surface` (a `FrameMesh` from marching cubes, whose vertices lie about a voxel apart) to
    each of `points` (`points` itself where the surface is empty)."""
    from scipy.spatial import cKDTree

    if not len(surface.vertices):
        return points
    return surface.vertices[cKDTree(surface.vertices).query(points)[1]].astype(np.float64)


def mean_surface_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Mean two-way nearest-vertex distance between two vertex sets (inf when one is empty)."""
    from scipy.spatial import cKDTree

    if not len(a) or not len(b):
        return float("inf")
    return 0.5 * (float(cKDTree(b).query(a)[0].mean()) + float(cKDTree(a).query(b)[0].mean()))


def deforming_meshes(model, times: Sequence[float], grid, surface_of: Callable, reference: int | None = None,
                     progress: bool = False) -> tuple[list, dict]:
    """(one `FrameMesh` per time, all with the reference frame's faces; the drift report) of `model` on `grid`;
    `surface_of(frame)` extracts a `SplatFrame`'s own surface (`splatreel.export.mesh.frame_mesh`)."""
    from .surface import DILATION_VOXELS

    times = [float(t) for t in times]
    frames = list(iter_frames(model, times, progress, desc="mesh frames"))
    ref = reference_frame(frames) if reference is None else int(reference)
    base = surface_of(frames[ref])
    if not len(base.faces):
        return [base for _ in times], {"reference_frame": ref, "reference_time": times[ref], "frames": []}
    dilation = (DILATION_VOXELS * grid.voxel) ** 2
    neighbours = vertex_neighbours(base.faces, len(base.vertices))
    vertices = {ref: base.vertices}
    surfaces = {}
    # frame by frame away from the reference, both ways: native 4D Gaussians live briefly, so each step is carried
    # by the Gaussians alive at the frame it starts from; then the vertices are drawn onto that frame's own surface
    for step in (1, -1):
        for i in range(ref + step, len(frames) if step > 0 else -1, step):
            carried = vertices[i - step]
            for start, end in zip(*substeps(model, frames[i - step], times[i], frames[i])):
                idx, w = carriers(carried, start, dilation)
                moved = rigid_carry(carried, start.means.astype(np.float64)[idx], end.means.astype(np.float64)[idx], w)
                carried = carried + smooth(moved - carried, neighbours)
            surfaces[i] = surface_of(frames[i])
            offset = onto_surface(carried, surfaces[i]) - carried  # smoothed below: no vertex jumps alone
            vertices[i] = relax(carried + smooth(offset, neighbours), base.faces, neighbours)
    meshes = [replace(base, vertices=vertices[i], normals=vertex_normals(vertices[i], base.faces))
              for i in range(len(frames))]
    return meshes, drift_report(meshes, frames, grid, surface_of, ref, times, {**surfaces, ref: base})


def drift_report(meshes, frames, grid, surface_of: Callable, ref: int, times: Sequence[float],
                 surfaces: dict | None = None) -> dict:
    """How far the deformed surface is from the surface (`surface_of(frame)`) extracted at up to `DRIFT_FRAMES`
    frames (see module doc); warns (one line) where it drifts past `DRIFT_WARNING` or the pieces change. `surfaces`
    holds frames' surfaces already extracted (by frame index), which are not extracted again."""
    import trimesh

    diagonal = float(np.linalg.norm(np.asarray(grid.shape) * grid.voxel))
    pieces = lambda m: len(trimesh.Trimesh(m.vertices, m.faces, process=False).split(only_watertight=False))  # noqa
    base_pieces = pieces(meshes[ref])
    measured = []
    for i in sorted(set(np.linspace(0, len(frames) - 1, min(DRIFT_FRAMES, len(frames))).round().astype(int))):
        truth = (surfaces or {}).get(i) or surface_of(frames[i])
        measured.append({"frame": int(i), "time": float(times[i]),
                         "drift": mean_surface_distance(meshes[i].vertices, truth.vertices) / diagonal,
                         "pieces": pieces(truth) if len(truth.faces) else 0})
    bad = [m for m in measured if m["drift"] > DRIFT_WARNING or m["pieces"] != base_pieces]
    if bad:
        span = f"t = {bad[0]['time']:g} .. {bad[-1]['time']:g}"
        worst = max(m["drift"] for m in bad)
        warnings.warn(f"the deforming mesh drifts from the model's surface by up to {worst:.1%} of its size, or the "
                      f"surface splits or merges, at {span}: export per-frame meshes (without --deforming) for that "
                      "span", stacklevel=2)
    return {"reference_frame": ref, "reference_time": float(times[ref]), "pieces": base_pieces,
            "max_drift": max(m["drift"] for m in measured), "frames": measured}


def morph_animation_glb(meshes, fps: float, up_axis: str = "Y") -> bytes:
    """One glTF binary of a deforming mesh (same faces at every frame): the reference frame's mesh with one morph
    target per frame (the displacement of its points and normals) and an animation of the morph weights, one-hot
    per frame and linear in between, at `fps` (glTF 2.0 §3.7.2.2 morph targets, §3.11 animations). Blender,
    three.js and game engines play it; glTF is +Y up, so a +Z-up model is turned (`to_y_up`)."""
    import pygltflib as gl

    from splatreel.colorspace import srgb_to_linear

    from .base import to_y_up

    base = meshes[0]
    positions = [to_y_up(m.vertices, up_axis).astype(np.float32) for m in meshes]
    normals = [to_y_up(m.normals, up_axis).astype(np.float32) for m in meshes]
    frames = len(meshes)
    blob, views, accessors = bytearray(), [], []

    def add(data: np.ndarray, kind: str, target: int | None, bounds: bool = False) -> int:
        data = np.ascontiguousarray(data)
        views.append(gl.BufferView(buffer=0, byteOffset=len(blob), byteLength=data.nbytes, target=target))
        blob.extend(data.tobytes())
        blob.extend(b"\0" * (-len(blob) % 4))
        component = {np.dtype(np.float32): gl.FLOAT, np.dtype(np.uint32): gl.UNSIGNED_INT}[data.dtype]
        count = data.shape[0] if kind != "SCALAR" or data.ndim == 1 else data.size
        accessor = gl.Accessor(bufferView=len(views) - 1, componentType=component, count=count, type=kind)
        if bounds:
            flat = data.reshape(count, -1)
            accessor.min, accessor.max = flat.min(0).tolist(), flat.max(0).tolist()
        accessors.append(accessor)
        return len(accessors) - 1

    array_buffer, element_buffer = 34962, 34963
    rgba = np.concatenate([srgb_to_linear(base.colors), np.ones((len(base.colors), 1))], 1).astype(np.float32)
    attributes = {"POSITION": add(positions[0], "VEC3", array_buffer, bounds=True),
                  "NORMAL": add(normals[0], "VEC3", array_buffer), "COLOR_0": add(rgba, "VEC4", array_buffer)}
    indices = add(base.faces.astype(np.uint32).reshape(-1), "SCALAR", element_buffer)
    targets = [{"POSITION": add(p - positions[0], "VEC3", array_buffer, bounds=True),
                "NORMAL": add(n - normals[0], "VEC3", array_buffer)} for p, n in zip(positions, normals)]
    times = add((np.arange(frames) / fps).astype(np.float32), "SCALAR", None, bounds=True)
    weights = add(np.eye(frames, dtype=np.float32).reshape(-1), "SCALAR", None)
    primitive = gl.Primitive(attributes=gl.Attributes(), indices=indices, mode=4, targets=targets)
    primitive.attributes = attributes
    doc = gl.GLTF2(
        asset=gl.Asset(version="2.0", generator="splatreel"), scene=0, scenes=[gl.Scene(nodes=[0])],
        nodes=[gl.Node(mesh=0, name="deforming")],
        meshes=[gl.Mesh(primitives=[primitive], weights=[1.0] + [0.0] * (frames - 1), name="deforming")],
        animations=[gl.Animation(name="deform", samplers=[gl.AnimationSampler(input=times, output=weights,
                                                                                interpolation="LINEAR")],
                                 channels=[gl.AnimationChannel(sampler=0, target=gl.AnimationChannelTarget(
                                     node=0, path="weights"))])],
        accessors=accessors, bufferViews=views, buffers=[gl.Buffer(byteLength=len(blob))])
    doc.set_binary_blob(bytes(blob))
    return b"".join(doc.save_to_bytes())
