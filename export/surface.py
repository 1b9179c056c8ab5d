"""One frame's surface on a grid: marching cubes of the opacity-weighted Gaussian density field.

At each frame the density is ``d(x) = sum_i o_i exp(-1/2 (x - mu_i)ᵀ Σ_i⁻¹ (x - mu_i))`` (opacity o_i with the
temporal factor applied, 0 for Gaussians the slice hides), truncated outside each Gaussian's 3-sigma ellipsoid and
sampled on **one grid for all frames** (the box of every visible Gaussian's 3-sigma support over the exported
frames, plus `MARGIN_VOXELS` empty voxels on each side, with cubic voxels: ``resolution`` along its longest side),
so that surfaces do not jitter from re-quantisation.

* Sampling: every covariance is widened by ``(DILATION_VOXELS * voxel)^2 I`` without changing the peak (the 3D
  analogue of the rasterizer's EPS2D dilation), so that Gaussians thinner than a voxel, such as the flat discs of a
  surface, still form a continuous sheet on the grid.
* Filling: with ``fill`` (default), empty cavities enclosed by the surface (the inside of a closed shell of surface
  Gaussians) count as inside, so a closed object gives one outward surface around a solid, not a thin double wall.
* The surface is the ``iso`` level set (default 0.5: inside a lone opaque Gaussian out to ~1.18 sigma) from
  ``skimage.measure.marching_cubes`` with ``gradient_direction='ascent'`` (outward, counter-clockwise winding for a
  field that is high inside), area-weighted vertex normals pointing out, and vertex colours from the
  ``color_neighbors`` nearest Gaussians, weighted by their density at the vertex, of their DC colour
  ``clip(0.5 + SH_C0 dc, 0, 1)``.

The grid, marching cubes, pieces and normals here are shared with the surface fused from rendered depth
(`splatreel.export.fused`); `splatreel.export.mesh.frame_mesh` picks one of the two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from splatreel.colorspace import srgb_to_linear
from splatreel.covariance import covariance_3d
from splatreel.meshes import vertex_normals

from .base import ExportError, SplatFrame

#: Gaussians are truncated outside this Mahalanobis distance (their 3-sigma ellipsoid).
TRUNCATION_SIGMAS = 3.0
#: Every Gaussian's std-dev is widened (in quadrature) by this many voxels before sampling (see module doc).
DILATION_VOXELS = 0.5
#: Empty voxels around the union of the 3-sigma supports (covers the dilation: 3 * 0.5 voxel < 2).
MARGIN_VOXELS = 2



@dataclass(frozen=True)
class Grid:
    """A regular grid of sample points ``origin + voxel * (i, j, k)`` for i < shape[0] etc. (float64 origin)."""

    origin: np.ndarray
    voxel: float
    shape: tuple[int, int, int]

    def points(self) -> np.ndarray:
        """``[X*Y*Z, 3]`` sample positions, C order (i slowest)."""
        axes = [self.origin[a] + self.voxel * np.arange(self.shape[a]) for a in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)

    def side(self) -> float:
        """Longest side of the box the grid covers, without the margin (`grid_for_box`'s resolution voxels)."""
        return self.voxel * (max(self.shape) - 1 - 2 * MARGIN_VOXELS)


def grid_for_box(box: np.ndarray, resolution: int) -> Grid:
    """The grid with `resolution` cubic voxels along the longest side of `box` ``[2, 3]``, `MARGIN_VOXELS` of margin."""
    lo, hi = box[0].astype(np.float64), box[1].astype(np.float64)
    size = float((hi - lo).max())
    if not np.isfinite(size) or size <= 0:
        raise ExportError("the visible Gaussians span an empty box: nothing to mesh")
    voxel = size / resolution
    shape = tuple(int(n) for n in np.ceil((hi - lo) / voxel - 1e-9).astype(int) + 1 + 2 * MARGIN_VOXELS)
    return Grid(origin=lo - MARGIN_VOXELS * voxel, voxel=voxel, shape=shape)


def inverse_covariances(scales: np.ndarray, quats: np.ndarray, dilation: float = 0.0) -> np.ndarray:
    """``[N, 3, 3]`` float64 (Σ + dilation I)⁻¹ = R diag(1 / (s^2 + dilation)) Rᵀ from std-devs ``[N, 3]`` and
    w-first quaternions ``[N, 4]`` (adding an isotropic variance keeps the axes)."""
    inv_s = 1.0 / np.sqrt(np.square(scales.astype(np.float64)) + dilation)
    return covariance_3d(torch.from_numpy(inv_s), torch.from_numpy(quats.astype(np.float64))).numpy()


def _density_kernel():
    """The numba kernel (compiled on first use, cached on disk)."""
    import numba

    @numba.njit(cache=True, fastmath=False)
    def splat_density(field, origin, voxel, means, inv_covs, opacities, radii, cut2):  # pragma: no cover - numba
        nx, ny, nz = field.shape
        for i in range(means.shape[0]):
            o = opacities[i]
            if o <= 0.0:
                continue
            lo = np.empty(3, np.int64)
            hi = np.empty(3, np.int64)
            dims = (nx, ny, nz)
            for a in range(3):
                lo[a] = max(0, int(np.ceil((means[i, a] - radii[i, a] - origin[a]) / voxel)))
                hi[a] = min(dims[a] - 1, int(np.floor((means[i, a] + radii[i, a] - origin[a]) / voxel)))
            a00, a01, a02 = inv_covs[i, 0, 0], inv_covs[i, 0, 1], inv_covs[i, 0, 2]
            a11, a12, a22 = inv_covs[i, 1, 1], inv_covs[i, 1, 2], inv_covs[i, 2, 2]
            for ix in range(lo[0], hi[0] + 1):
                dx = origin[0] + ix * voxel - means[i, 0]
                for iy in range(lo[1], hi[1] + 1):
                    dy = origin[1] + iy * voxel - means[i, 1]
                    qxy = a00 * dx * dx + 2.0 * a01 * dx * dy + a11 * dy * dy
                    bx = 2.0 * (a02 * dx + a12 * dy)
                    for iz in range(lo[2], hi[2] + 1):
                        dz = origin[2] + iz * voxel - means[i, 2]
                        q = qxy + bx * dz + a22 * dz * dz
                        if q < cut2:
                            field[ix, iy, iz] += o * np.exp(-0.5 * q)

    return splat_density


_KERNEL = None


def density_field(grid: Grid, means: np.ndarray, inv_covs: np.ndarray, opacities: np.ndarray,
                  radii: np.ndarray) -> np.ndarray:
    """``grid.shape`` float32 opacity-weighted density (see module doc), truncated at `TRUNCATION_SIGMAS`.

    Args:
        means: ``[N, 3]``. inv_covs: ``[N, 3, 3]`` Σ⁻¹. opacities: ``[N]`` (0 skips a Gaussian).
        radii: ``[N, 3]`` half-extents of the truncation ellipsoid along the world axes (bounds the voxel loop).
    """
    global _KERNEL
    if _KERNEL is None:
        _KERNEL = _density_kernel()
    field = np.zeros(grid.shape, np.float64)
    _KERNEL(field, np.asarray(grid.origin, np.float64), float(grid.voxel), np.ascontiguousarray(means, np.float64),
            np.ascontiguousarray(inv_covs, np.float64), np.ascontiguousarray(opacities, np.float64),
            np.ascontiguousarray(radii, np.float64), TRUNCATION_SIGMAS ** 2)
    return field.astype(np.float32)


def _density_at(points: np.ndarray, means: np.ndarray, inv_covs: np.ndarray, opacities: np.ndarray) -> np.ndarray:
    """Dense reference of `density_field` at arbitrary ``[P, 3]`` points (O(P N) memory; tests and small inputs)."""
    d = points[:, None, :] - means[None, :, :]  # [P, N, 3]
    q = np.einsum("pni,nij,pnj->pn", d, inv_covs, d)
    return np.where(q < TRUNCATION_SIGMAS ** 2, opacities[None] * np.exp(-0.5 * q), 0.0).sum(1)


def enclosed(mask: np.ndarray) -> np.ndarray:
    """`mask` (bool, 3D) with every region outside it that does not reach the grid border added: what
    `scipy.ndimage.binary_fill_holes` gives, by one connected-component labelling (6-connected) instead of its
    iterated dilation, which took most of a fused frame's non-render time."""
    from scipy.ndimage import label

    labels, _ = label(~mask)
    border = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                       labels[:, :, [0, -1]].ravel()]))
    reaches_border = np.zeros(labels.max() + 1, bool)
    reaches_border[border] = True
    return mask | ~reaches_border[labels]


def fill_cavities(field: np.ndarray, iso: float, value: float | None = None) -> np.ndarray:
    """`field` with every below-`iso` region that is not connected to the grid border raised above `iso` (to
    `value`; default twice `iso`)."""
    inside = field >= iso
    cavities = enclosed(inside) & ~inside
    if not cavities.any():
        return field
    out = field.copy()
    out[cavities] = 2.0 * iso if value is None else value
    return out


def extract_surface(field: np.ndarray, grid: Grid, iso: float) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes of `field` at `iso`: (vertices ``[V, 3]`` float64 world, faces ``[F, 3]`` int64, outward
    counter-clockwise winding); empty arrays when the field never reaches `iso`."""
    from skimage.measure import marching_cubes

    if not field.size or float(field.max()) <= iso:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    verts, faces, _, _ = marching_cubes(field, level=iso, spacing=(grid.voxel,) * 3, gradient_direction="ascent",
                                        allow_degenerate=False)
    return verts.astype(np.float64) + grid.origin, faces.astype(np.int64)


def vertex_colors(vertices: np.ndarray, means: np.ndarray, inv_covs: np.ndarray, opacities: np.ndarray,
                  colors: np.ndarray, k: int = 8) -> np.ndarray:
    """``[V, 3]`` colour per vertex: the `k` nearest Gaussians' `colors` ``[N, 3]`` weighted by their density at the
    vertex (the nearest one's colour where all weights vanish)."""
    from scipy.spatial import cKDTree

    if vertices.shape[0] == 0 or means.shape[0] == 0:
        return np.zeros((vertices.shape[0], 3), np.float32)
    k = min(k, means.shape[0])
    _, idx = cKDTree(means).query(vertices, k=k)
    idx = idx.reshape(vertices.shape[0], k)
    d = vertices[:, None, :] - means[idx]  # [V, k, 3]
    q = np.einsum("vki,vkij,vkj->vk", d, inv_covs[idx], d)
    w = opacities[idx] * np.exp(-0.5 * np.minimum(q, 1e4))
    total = w.sum(1, keepdims=True)
    blended = (w[..., None] * colors[idx]).sum(1) / np.maximum(total, 1e-300)
    return np.where(total > 1e-30, blended, colors[idx[:, 0]]).astype(np.float32)


@dataclass
class FrameMesh:
    """One frame's surface. vertices ``[V, 3]``, faces ``[F, 3]``, normals ``[V, 3]`` (unit, outward),
    colors ``[V, 3]`` sRGB-encoded in [0, 1]."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    colors: np.ndarray

    def trimesh(self, linear_colors: bool = False):
        """As a ``trimesh.Trimesh`` with vertex normals and 8-bit RGBA vertex colours (linear if asked)."""
        import trimesh

        if len(self.faces) == 0:  # trimesh cannot attach (empty) normals or colours to an empty mesh
            return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), process=False)
        rgb = srgb_to_linear(self.colors) if linear_colors else self.colors
        rgba = np.concatenate([np.round(np.clip(rgb, 0, 1) * 255), np.full((len(rgb), 1), 255)], 1).astype(np.uint8)
        return trimesh.Trimesh(self.vertices, self.faces, vertex_normals=self.normals, vertex_colors=rgba,
                               process=False)


def largest_pieces(vertices: np.ndarray, faces: np.ndarray, min_share: float) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) without the connected pieces whose area is below `min_share` of the whole surface's
    (floaters: a trained model's stray Gaussians each make a small blob); `min_share` 0 keeps every piece."""
    import trimesh

    if min_share <= 0 or not len(faces):
        return vertices, faces
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(faces))
    area = np.bincount(labels, weights=mesh.area_faces)
    keep_faces = area[labels] >= min_share * area.sum()
    if keep_faces.all():
        return vertices, faces
    used = np.unique(faces[keep_faces])
    remap = np.full(len(vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[faces[keep_faces]]


def empty_mesh() -> FrameMesh:
    z = np.zeros((0, 3))
    return FrameMesh(z, np.zeros((0, 3), np.int64), z, z.astype(np.float32))


def live_density(frame: SplatFrame, grid: Grid) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(density field on `grid`; means, inverse dilated covariances and opacities of the live Gaussians, float64)
    of one frame (module doc)."""
    live = frame.opacities > 0
    means = frame.means[live].astype(np.float64)
    dilation = (DILATION_VOXELS * grid.voxel) ** 2
    inv = inverse_covariances(frame.scales[live], frame.quats[live], dilation)
    radii = np.sqrt(np.square(frame.radii[live].astype(np.float64)) + TRUNCATION_SIGMAS ** 2 * dilation)
    opacities = frame.opacities[live].astype(np.float64)
    return density_field(grid, means, inv, opacities, radii), means, inv, opacities


def density_mesh(frame: SplatFrame, grid: Grid, iso: float = 0.5, color_neighbors: int = 8, fill: bool = True,
                 min_piece_share: float = 0.0) -> FrameMesh:
    """The density iso-surface of one frame on `grid` (see module doc)."""
    field, means, inv, opacities = live_density(frame, grid)
    if fill:
        field = fill_cavities(field, iso)
    vertices, faces = largest_pieces(*extract_surface(field, grid, iso), min_piece_share)
    if faces.shape[0] == 0:
        return empty_mesh()
    normals = vertex_normals(vertices, faces)
    colors = vertex_colors(vertices, means, inv, opacities, frame.dc_rgb()[frame.opacities > 0], color_neighbors)
    return FrameMesh(vertices, faces, normals, colors)
