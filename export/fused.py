"""Surfaces fused from rendered depth: a truncated signed distance field (TSDF) over many virtual views.

The density iso-surface (`splatreel.export.surface`) is a level of the Gaussians' summed density, so it sits where
the density crosses a chosen value, which is outside the surface the images show by about a Gaussian's width. Here
the surface is where the model's renders put it instead:

1. The frame's slice is rendered (`splatreel.rasterize`, the trainer's rasterizer) from `FUSION_VIEWS` cameras
   spread evenly over a sphere around the grid (a Fibonacci lattice), each framing the whole grid.
2. Each voxel centre is projected into every view (nearest pixel). Where the pixel is opaque (alpha >= 0.5) the
   voxel's signed distance along the ray is ``depth - z`` (the render's expected depth): positive in front of the
   surface, negative behind it; it is averaged over the views in which it lies no deeper than the truncation band
   (Curless and Levoy 1996, "A Volumetric Method for Building Complex Models from Range Images"; KinectFusion's
   truncated average). Where the pixel is transparent the voxel lies in empty space seen by that view (+1).
   Voxels no view sees in front of a surface or through empty space are inside (space carving: a closed
   object's interior).
3. The field is smoothed (`SMOOTHING_SHARE`); pockets of empty space the inside encloses are filled (where a soft,
   semi-transparent part's expected depth lies behind its front surface, its interior can look empty from some
   views, which left a closed shell inside the wave sample's body); the surface is the field's zero level
   (marching cubes), and its colour the average of the renders' colours over the voxels in the band, sampled at
   each vertex.
"""

from __future__ import annotations

import math

import numpy as np

#: Virtual views per frame, on a Fibonacci lattice over the sphere (measured on the samples at resolutions 64 and
#: 128: 24 views give the same surfaces as 32 and 48, within 0.01 % of the object's size, in half the time of 48).
FUSION_VIEWS = 24
#: Width and height of each virtual view in pixels (a multiple of the grid's resolution is wasted: each voxel reads
#: one pixel per view).
FUSION_SIZE = 256
#: Field of view of the virtual cameras, in degrees.
FUSION_FOV = 40.0
#: Truncation band of the signed distance, as a share of the grid's longest side (3 voxels at resolution 64).
TRUNCATION_SHARE = 3.0 / 64.0
#: Std-dev of the Gaussian filter over the signed distance before marching cubes, as a share of the grid's longest
#: side (1 voxel at resolution 64): each voxel reads the nearest pixel of each view, and the filter removes that
#: quantisation's ripples and the Gaussians' bumps. Measured on the samples: at resolution 64, no filter gives
#: Chamfer 0.8-1.1 % and normal consistency 0.90-0.96, 1 voxel 0.7-0.8 % and 0.96-0.97; at resolution 128, the same
#: 1 voxel (and a 3-voxel band) gives 0.6-1.1 % and 0.79-0.98, this share 0.6-0.7 % and 0.97-0.98.
SMOOTHING_SHARE = 1.0 / 64.0
#: Voxels where the Gaussians' density is below this everywhere within the band are empty space, not fused.
SUPPORT_DENSITY = 1e-3
#: A pixel with at least this alpha shows a surface; below it, the ray passes through empty space.
OPAQUE_ALPHA = 0.5
#: `surface_coverage` below which the fused surface is not used by default: it has lost parts of the model. Measured
#: at resolution 128 on three frames each: the bounded samples and the bundled model 0.75-0.99; the floor sample
#: (an open floor, a sheet seen from both sides, which a signed distance cannot hold) 0.004-0.06.
MIN_COVERAGE = 0.5

def sphere_directions(count: int) -> np.ndarray:
    """``[count, 3]`` unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def fusion_cameras(grid, count: int = FUSION_VIEWS, size: int = FUSION_SIZE, fov: float = FUSION_FOV):
    """Cameras around `grid`'s box, each looking at its centre from far enough to see all of it."""
    from splatreel.cameras import look_at

    lo = grid.origin
    hi = grid.origin + grid.voxel * (np.asarray(grid.shape) - 1)
    centre, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    distance = radius / math.sin(math.radians(0.5 * fov)) * 1.05
    cams = []
    for d in sphere_directions(count):
        up = (0.0, 1.0, 0.0) if abs(d[2]) > 0.9 else (0.0, 0.0, 1.0)
        cams.append(look_at(centre + distance * d, centre, up, fov, size, size))
    return cams


def frame_gaussians(frame):
    """The `Gaussians3D` of an exported frame (`splatreel.export.SplatFrame`), to render it."""
    import torch

    from splatreel.covariance import covariance_3d
    from splatreel.model import Gaussians3D

    shown = np.nonzero(frame.visible & (frame.opacities > 0))[0]  # the rest are culled in every view: skip them once
    scales, quats = torch.from_numpy(frame.scales[shown]).double(), torch.from_numpy(frame.quats[shown]).double()
    return Gaussians3D(means=torch.from_numpy(frame.means[shown]).float(),
                       covariances=covariance_3d(scales, quats).float(),
                       opacities=torch.from_numpy(frame.opacities[shown]).float(),
                       sh=torch.from_numpy(frame.sh[shown]).float(),
                       visible=torch.ones(len(shown), dtype=torch.bool), sh_degree=frame.sh_degree)


def fused_mesh(frame, grid, fill: bool = True, min_piece_share: float = 0.0):
    """The fused surface (`splatreel.export.surface.FrameMesh`) of one exported frame on `grid` (module doc)."""
    return mesh_of_fields(fuse_frame(frame, grid, fill), grid, min_piece_share)


def mesh_of_fields(fields: tuple[np.ndarray, np.ndarray, np.ndarray], grid, min_piece_share: float = 0.0):
    """The `FrameMesh` of `fuse`'s (signed distance, colours, held) on `grid`: the zero level, its largest pieces,
    vertex normals and the fused colours."""
    from splatreel.meshes import vertex_normals

    from .surface import FrameMesh, empty_mesh, extract_surface, largest_pieces

    sdf, colors, held = fields
    vertices, faces = largest_pieces(*extract_surface(-sdf, grid, 0.0), min_piece_share)
    if faces.shape[0] == 0:
        return empty_mesh()
    return FrameMesh(vertices, faces, vertex_normals(vertices, faces), sample_colors(colors, held, grid, vertices))


def surface_coverage(frame, grid, sdf: np.ndarray, iso: float = 0.5) -> float:
    """Share of the voxels inside the frame's density iso-surface (`iso`) that lie inside its fused surface (`sdf`
    from `fuse`) or within two voxels of it: near 1 where the fused surface holds the model's solid parts, near 0
    where it lost them (thin open sheets such as a floor)."""
    from scipy.ndimage import binary_dilation

    from .surface import live_density

    solid = live_density(frame, grid)[0] >= iso
    near = binary_dilation(sdf < 0, iterations=2)
    return float((solid & near).sum() / max(int(solid.sum()), 1))


def fuse_frame(frame, grid, fill: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`fuse` of one exported frame (`splatreel.export.SplatFrame`) from `fusion_cameras` around `grid`, over the
    voxels near the support of its Gaussians (`support`)."""
    return fuse(frame_gaussians(frame), grid, fusion_cameras(grid), support(frame, grid), fill)


def support(frame, grid) -> np.ndarray:
    """``grid.shape`` bool: the voxels within the truncation band (and one voxel more) of where the frame's Gaussians
    have any density (`SUPPORT_DENSITY`), enclosed regions included. The density is evaluated on a grid of twice
    the voxel size (a fifth of the time, measured on the bundled model at resolution 128) and read back at the
    nearest coarse voxel."""
    from scipy.ndimage import binary_dilation

    from .surface import Grid, enclosed, live_density

    coarse = Grid(origin=grid.origin, voxel=2.0 * grid.voxel, shape=tuple((n + 1) // 2 for n in grid.shape))
    band = TRUNCATION_SHARE * grid.side() / coarse.voxel
    field = live_density(frame, coarse)[0]
    held = enclosed(binary_dilation(field > SUPPORT_DENSITY, iterations=int(math.ceil(band)) + 1))
    nearest = [np.minimum((np.arange(n) + 1) // 2, c - 1) for n, c in zip(grid.shape, coarse.shape)]
    return held[np.ix_(*nearest)]


def fuse(gaussians, grid, cameras, candidates: np.ndarray | None = None, fill: bool = True
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(signed distance ``grid.shape`` in units of the truncation band, negative inside; colour ``grid.shape + (3,)``
    sRGB-encoded, averaged over the band; ``grid.shape`` bool, where a colour was seen) of the slice `gaussians`
    rendered from `cameras`. Only the voxels `candidates` (bool ``grid.shape``; default all) are fused; the others
    are empty space (+1). `fill`: pockets of empty space the inside encloses are inside (module doc, step 3)."""
    import torch

    from splatreel.rasterize import rasterize

    chosen = np.ones(int(np.prod(grid.shape)), bool) if candidates is None else candidates.reshape(-1)
    points = grid.origin + grid.voxel * np.stack(np.unravel_index(np.flatnonzero(chosen), grid.shape), -1)
    # every render first, then the voxels: interleaved with the passes over the voxels, a render took 110 ms
    # against 36 ms in a row (measured on the bundled model; whether threads or caches cause it is not pinned down)
    with torch.no_grad():
        renders = [rasterize(gaussians, cam, (0.0, 0.0, 0.0), sh_degree=0) for cam in cameras]
    alpha = np.stack([out.alpha.numpy() for out in renders]).astype(np.float32, copy=False)
    depth = np.stack([out.depth.numpy() for out in renders]).astype(np.float32, copy=False)
    rgb = np.stack([out.rgb.numpy() for out in renders]).astype(np.float32, copy=False)  # premultiplied by alpha
    world_to_camera = np.stack([np.linalg.inv(cam.c2w)[:3] for cam in cameras]).astype(np.float64)
    intrinsics = np.array([[cam.fx, cam.fy, cam.cx, cam.cy] for cam in cameras], np.float64)
    sdf_sum, seen = np.zeros(len(points)), np.zeros(len(points))
    rgb_sum, rgb_weight = np.zeros((len(points), 3)), np.zeros(len(points))
    _fusion_kernel()(points, world_to_camera, intrinsics, alpha, depth, rgb, TRUNCATION_SHARE * grid.side(),
                     OPAQUE_ALPHA, sdf_sum, seen, rgb_sum, rgb_weight)
    from scipy.ndimage import gaussian_filter

    from .surface import fill_cavities

    n = len(chosen)
    sdf, rgb, held = np.ones(n), np.zeros((n, 3)), np.zeros(n, bool)
    sdf[chosen] = np.where(seen > 0, sdf_sum / np.maximum(seen, 1), -1.0)
    rgb[chosen] = np.clip(rgb_sum / np.maximum(rgb_weight, 1)[:, None], 0, 1)
    held[chosen] = rgb_weight > 0
    sdf = gaussian_filter(sdf.reshape(grid.shape), SMOOTHING_SHARE * grid.side() / grid.voxel, mode="nearest")
    if fill:
        sdf = -fill_cavities(-sdf, 0.0, value=1.0)
    return sdf, rgb.reshape(*grid.shape, 3), held.reshape(grid.shape)


_KERNEL = None


def _fusion_kernel():
    """The numba kernel of `fuse` (compiled on first use, cached on disk): for each voxel centre, over every view,
    the nearest pixel's vote (module doc, step 2), summed into sdf_sum/seen and rgb_sum/rgb_weight."""
    global _KERNEL
    if _KERNEL is not None:
        return _KERNEL
    import numba

    @numba.njit(parallel=True, cache=True)
    def fuse_views(points, world_to_camera, intrinsics, alpha, depth, rgb, trunc, opaque_alpha, sdf_sum, seen,
                   rgb_sum, rgb_weight):  # pragma: no cover - numba
        views, height, width = alpha.shape
        for p in numba.prange(points.shape[0]):
            x, y, z = points[p, 0], points[p, 1], points[p, 2]
            for k in range(views):
                m = world_to_camera[k]
                lz = m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3]
                if lz <= 1e-6:
                    continue
                lx = m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3]
                ly = m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3]
                u = int(np.floor(intrinsics[k, 0] * lx / lz + intrinsics[k, 2]))
                v = int(np.floor(intrinsics[k, 1] * ly / lz + intrinsics[k, 3]))
                if u < 0 or u >= width or v < 0 or v >= height:
                    continue
                if alpha[k, v, u] < opaque_alpha:  # the ray passes through this voxel into empty space
                    sdf_sum[p] += 1.0
                    seen[p] += 1.0
                    continue
                dist = (depth[k, v, u] - lz) / trunc
                if dist > -1.0:  # in front of the surface, or behind it within the band
                    sdf_sum[p] += min(dist, 1.0)
                    seen[p] += 1.0
                if abs(dist) < 1.0:
                    for c in range(3):
                        rgb_sum[p, c] += rgb[k, v, u, c] / alpha[k, v, u]
                    rgb_weight[p] += 1.0

    _KERNEL = fuse_views
    return _KERNEL


def sample_colors(colors: np.ndarray, held: np.ndarray, grid, vertices: np.ndarray) -> np.ndarray:
    """``[V, 3]`` colour of the grid `colors` at `vertices` (trilinear, over the voxels `held` that hold one)."""
    from scipy.ndimage import map_coordinates

    coords = ((vertices - grid.origin) / grid.voxel).T
    held = held.astype(np.float64)
    weight = map_coordinates(held, coords, order=1, mode="nearest")
    out = np.stack([map_coordinates(colors[..., c] * held, coords, order=1, mode="nearest") for c in range(3)], -1)
    return (out / np.maximum(weight, 1e-6)[:, None]).astype(np.float32)
