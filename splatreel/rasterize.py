"""Differentiable tile rasterizer for 3D Gaussians (the slice of a 4D model at one time).

``rasterize(gaussians3d, camera, background) -> RenderOutput`` renders RGB, alpha and expected depth, plus the
per-Gaussian screen radius, projected centre and visibility that densification needs. It is differentiable with
PyTorch autograd with respect to every tensor of the `Gaussians3D`, hence (through ``Gaussians4D.slice(t)``) to
every parameter of a native 4D model.

The math is the reference 3DGS one (Kerbl et al. 2023, "3D Gaussian Splatting for Real-Time Radiance Field
Rendering"; graphdeco-inria/diff-gaussian-rasterization ``cuda_rasterizer/forward.cu`` and ``auxiliary.h``, as
vendored by fudan-zvg/4d-gaussian-splatting; gsplat ``gsplat/cuda/_torch_impl.py``), with the constants of
`splatreel.constants`:

1. **Projection** (differentiable; plain torch, or for float32 on the CPU the same math fused in one numba pass,
   `splatreel.projecting`): world -> camera with the OpenCV ``w2c``; cull at
   ``z <= NEAR_PLANE``; EWA ``Σ2D = J W Σ Wᵀ Jᵀ`` with the Jacobian evaluated at x/z, y/z clamped to
   ``[-(cx/fx + 0.3 tan_fovx), (W - cx)/fx + 0.3 tan_fovx]`` (same for y; 1.3 tan_fov when centred), centres
   ``(fx x/z + cx, fy y/z + cy)`` from the unclamped x, y; ``+EPS2D`` on the diagonal (no opacity
   compensation); conic = inverse; radius ``ceil(3 sqrt(λmax))`` with λmax = mid + sqrt(max(0.1, mid² - det)).
2. **Culling** (radius 0): not `visible` (temporal cull), behind the near plane or beyond a far plane, opacity
   < 1/255 (can never reach alpha 1/255), singular 2D covariance, or the square ``mean ± radius`` box entirely off
   the image.
3. **Binning**: 16x16 tiles; a Gaussian goes to the tiles of its ``mean ± radius`` box (gsplat's
   floor/ceil rule), minus the tiles its alpha >= 1/255 ellipse cannot reach (no effect on the image);
   stable depth order, so equal depths keep their index order.
4. **Compositing** (numba CPU kernels in `_kernels`, one `torch.autograd.Function`, float32): front to back,
   ``alpha = min(0.99, o exp(-σ))``, skipped below 1/255, stopping once T would fall to 1e-4 or below, pixel centres
   at +0.5. Gradients are race-free and deterministic (one slot per tile intersection, summed in a fixed order).

On a CUDA device with gsplat installed (``pip install splatreel[cuda]``) step 4 runs gsplat's
``rasterize_to_pixels`` on the GPU with the same projection and tile lists; otherwise CUDA tensors are composited
by the CPU kernels (data moves to the CPU for that step only).
"""

from __future__ import annotations

import functools
import importlib.util
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
from torch import Tensor

from splatreel.cameras import Camera
from splatreel.constants import (ALPHA_THRESHOLD, EIGEN_FLOOR, EPS2D, FAR_PLANE, FRUSTUM_CLAMP, NEAR_PLANE,
                               RADIUS_SIGMAS, TILE_SIZE)
from splatreel.errors import CameraError, ModelError, SplatreelError
from splatreel.model import Gaussians3D
from splatreel.sh import num_sh_bases

__all__ = ["RenderOutput", "rasterize", "project_gaussians", "ProjectedGaussians"]


@dataclass
class RenderOutput:
    """What `rasterize` returns. H, W = camera height, width; N = number of Gaussians given.

    Attributes:
        rgb: ``[H, W, 3]`` float32, ``sum c_i a_i T_i + T_final * background``.
        alpha: ``[H, W]`` float32, ``1 - T_final``.
        depth: ``[H, W]`` float32 expected camera-space depth ``sum z_i a_i T_i / alpha`` where alpha > 0, else 0
            (z_i = depth of Gaussian i's centre along the camera's +z axis, not the distance to the camera).
        radii: ``[N]`` int32 screen radius in pixels, ``ceil(3 sqrt(λmax))``; 0 for culled Gaussians.
        means2d: ``[N, 2]`` projected centres in pixels (dtype of the input; 0 for Gaussians culled before
            projection: not visible, behind the near plane, opacity < 1/255). Upstream of the image, so
            ``means2d.retain_grad()`` before ``backward()`` gives the screen-space gradient densification uses
            (zero for culled Gaussians).
        visible: ``[N]`` bool, ``radii > 0``.
    """

    rgb: Tensor
    alpha: Tensor
    depth: Tensor
    radii: Tensor
    means2d: Tensor
    visible: Tensor


# --- projection --------------------------------------------------------------------------------------------------
@dataclass
class ProjectedGaussians:
    """EWA projection of M Gaussians (differentiable tensors, dtype of the input).

    Attributes:
        means2d: ``[M, 2]`` pixel coordinates of the centres.
        depths: ``[M]`` camera-space z.
        cov2d: ``[M, 3]`` (xx, xy, yy) of the 2D covariance, EPS2D already added to the diagonal.
    """

    means2d: Tensor
    depths: Tensor
    cov2d: Tensor


def view_matrix(camera: Camera, like: Tensor) -> tuple[Tensor, Tensor]:
    """(rotation ``[3, 3]``, translation ``[3]``) of the camera's OpenCV world-to-camera, as tensors like `like`."""
    w2c = torch.as_tensor(camera.w2c, dtype=like.dtype, device=like.device)
    return w2c[:3, :3], w2c[:3, 3]


def camera_depths(means: Tensor, camera: Camera) -> Tensor:
    """``[N, 3]`` world points -> ``[N]`` camera-space z."""
    rot, trans = view_matrix(camera, means)
    return means @ rot[2] + trans[2]


def project_gaussians(means: Tensor, covariances: Tensor, camera: Camera) -> ProjectedGaussians:
    """EWA-project ``[M, 3]`` means and ``[M, 3, 3]`` covariances (all assumed in front of the near plane)."""
    rot, trans = view_matrix(camera, means)
    p = means @ rot.T + trans
    x, y, z = p.unbind(-1)
    s = rot @ covariances @ rot.T  # camera-space covariances
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    # Jacobian clamp: bounded footprints for Gaussians far outside the frustum (1.3 tan_fov when centred)
    x_lo, x_hi, y_lo, y_hi = camera.ray_limits(FRUSTUM_CLAMP - 1.0)
    tx = z * (x / z).clamp(x_lo, x_hi)
    ty = z * (y / z).clamp(y_lo, y_hi)
    # J = [[j00, 0, j02], [0, j11, j12]]; Σ2D = J S Jᵀ written out (J is sparse)
    j00, j11 = fx / z, fy / z
    j02, j12 = -fx * tx / (z * z), -fy * ty / (z * z)
    # symmetric parts only, so that the gradient w.r.t. the covariances is a symmetric matrix
    s00, s11, s22 = s[:, 0, 0], s[:, 1, 1], s[:, 2, 2]
    s01 = 0.5 * (s[:, 0, 1] + s[:, 1, 0])
    s02 = 0.5 * (s[:, 0, 2] + s[:, 2, 0])
    s12 = 0.5 * (s[:, 1, 2] + s[:, 2, 1])
    xx = j00 * j00 * s00 + 2.0 * j00 * j02 * s02 + j02 * j02 * s22
    xy = j00 * j11 * s01 + j00 * j12 * s02 + j02 * j11 * s12 + j02 * j12 * s22
    yy = j11 * j11 * s11 + 2.0 * j11 * j12 * s12 + j12 * j12 * s22
    cov2d = torch.stack([xx + EPS2D, xy, yy + EPS2D], -1)
    means2d = torch.stack([fx * x / z + cx, fy * y / z + cy], -1)
    return ProjectedGaussians(means2d=means2d, depths=z, cov2d=cov2d)


def conics_from_cov2d(cov2d: Tensor) -> Tensor:
    """``[M, 3]`` (xx, xy, yy) -> ``[M, 3]`` conic (a, b, c) = upper triangle of the inverse."""
    xx, xy, yy = cov2d.unbind(-1)
    inv_det = 1.0 / (xx * yy - xy * xy)
    return torch.stack([yy * inv_det, -xy * inv_det, xx * inv_det], -1)


def screen_radii(cov2d: Tensor) -> Tensor:
    """``[M]`` float radius ``ceil(3 sqrt(λmax))`` of ``[M, 3]`` 2D covariances (Inria's 0.1 eigen floor)."""
    xx, xy, yy = cov2d.unbind(-1)
    mid = 0.5 * (xx + yy)
    lam = mid + torch.sqrt((mid * mid - (xx * yy - xy * xy)).clamp_min(EIGEN_FLOOR))
    return torch.ceil(RADIUS_SIGMAS * torch.sqrt(lam))


def tile_grid(camera: Camera) -> tuple[int, int]:
    """(tiles_x, tiles_y) covering the image."""
    return -(-camera.width // TILE_SIZE), -(-camera.height // TILE_SIZE)


def alpha_extent(cov2d: Tensor, opacities: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Where a Gaussian can reach alpha >= 1/255: sigma <= s_max = ln(255 o), an ellipse of half-extents
    sqrt(2 s_max Σxx) by sqrt(2 s_max Σyy). s_max is enlarged by a relative 1e-5 so that pixels on the boundary
    are kept; the kernels' exact per-pixel test has the last word. Returns (s_max, ext_x, ext_y), each ``[M]``."""
    s_max = torch.log((opacities / ALPHA_THRESHOLD).clamp_min(1.0)) * (1.0 + 1e-5) + 1e-6
    return s_max, torch.sqrt(2.0 * s_max * cov2d[:, 0]), torch.sqrt(2.0 * s_max * cov2d[:, 2])


def tile_rects(means2d: Tensor, radii: Tensor, ext_x: Tensor, ext_y: Tensor, camera: Camera) -> Tensor:
    """``[M, 4]`` int32 tile rectangles (x0, x1, y0, y1), end exclusive, possibly empty.

    The reference rule is the tiles of the square ``mean ± radius`` box: ``floor((mean - r) / 16)`` to
    ``ceil((mean + r) / 16)``, clamped to the grid. Tiles beyond the alpha >= 1/255 ellipse (plus one pixel)
    are dropped: they would composite nothing.
    """
    tiles_x, tiles_y = tile_grid(camera)

    def axis(centre: Tensor, ext: Tensor, n: int) -> tuple[Tensor, Tensor]:
        lo = torch.maximum(centre - radii, centre - ext - 1.0)
        hi = torch.minimum(centre + radii, centre + ext + 1.0)
        t0 = torch.floor(lo / TILE_SIZE).clamp(0, n)
        t1 = torch.ceil(hi / TILE_SIZE).clamp(0, n)
        return t0, torch.maximum(t0, t1)

    x0, x1 = axis(means2d[:, 0], ext_x, tiles_x)
    y0, y1 = axis(means2d[:, 1], ext_y, tiles_y)
    return torch.stack([x0, x1, y0, y1], -1).to(torch.int32)


def bin_tiles_torch(rects: Tensor, order: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
    """Vectorised torch twin of `_kernels.bin_tiles` (used on the GPU path): the same lists in the same order.

    Args:
        rects: ``[M, 4]`` from `tile_rects`.
        order: ``[M]`` Gaussian indices front to back.
    Returns:
        tile_offsets ``[tiles_y, tiles_x]`` int32 (start of each tile's list), flat_ids ``[n]`` int32.
    """
    tiles_x, tiles_y = tile_grid(camera)
    r = rects.long()[order]
    widths = (r[:, 1] - r[:, 0]).clamp_min(0)
    counts = widths * (r[:, 3] - r[:, 2]).clamp_min(0)
    rank = torch.repeat_interleave(torch.arange(r.shape[0], device=r.device), counts)  # depth rank per pair
    local = torch.arange(rank.shape[0], device=r.device) - (torch.cumsum(counts, 0) - counts)[rank]
    tile = (r[rank, 2] + local // widths[rank]) * tiles_x + r[rank, 0] + local % widths[rank]
    tile_sorted, perm = torch.sort(tile, stable=True)
    offsets = torch.searchsorted(tile_sorted, torch.arange(tiles_x * tiles_y, device=r.device))
    return offsets.to(torch.int32).reshape(tiles_y, tiles_x), order[rank[perm]].to(torch.int32)


# --- compositing -------------------------------------------------------------------------------------------------
@dataclass
class _TileLists:
    """Non-differentiable per-render data of the CPU kernels (numpy, see `_kernels.bin_tiles`)."""

    order: np.ndarray  # [R] indices of the rendered Gaussians, front to back (ranks index this)
    s_max: np.ndarray  # [R]
    ext_y: np.ndarray  # [R]
    tile_offsets: np.ndarray
    flat_ids: np.ndarray
    isect_slots: np.ndarray
    gauss_offsets: np.ndarray
    width: int
    height: int
    tiles_x: int
    num_threads: int | None


def _np32(t: Tensor) -> np.ndarray:
    return t.detach().to(device="cpu", dtype=torch.float32).contiguous().numpy()


class _CompositeCPU(torch.autograd.Function):
    """(means2d ``[M,2]``, conics ``[M,3]``, channels ``[M,4]``, opacities ``[M]``, background ``[4]``) ->
    (channels image ``[H,W,4]``, alpha ``[H,W]``) with the numba kernels; works for tensors on any device.
    Only the Gaussians listed in ``lists.order`` are composited; the others get zero gradients."""

    @staticmethod
    def forward(ctx, means2d, conics, channels, opacities, background, lists: _TileLists):
        from . import _kernels as K

        h, w, o = lists.height, lists.width, lists.order
        gauss = K.pack_gaussians(_np32(means2d)[o], _np32(conics)[o], _np32(channels)[o], _np32(opacities)[o],
                                 lists.s_max, lists.ext_y)
        bg = _np32(background)
        out = np.empty((h, w, K.NUM_CHANNELS), np.float32)
        trans = np.empty((h, w), np.float32)
        last = np.empty((h, w), np.int32)
        with K.num_threads(lists.num_threads):
            bins = K.tile_bins(np.diff(lists.tile_offsets))
            K.composite_forward(gauss, bg, lists.tile_offsets, lists.flat_ids, *bins, w, h, lists.tiles_x, out, trans,
                                last)
        ctx.gauss, ctx.bg, ctx.lists, ctx.trans, ctx.last = gauss, bg, lists, trans, last
        ctx.num_gaussians, ctx.device = means2d.shape[0], means2d.device
        return torch.from_numpy(out).to(ctx.device), torch.from_numpy(1.0 - trans).to(ctx.device)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_channels, grad_alpha):
        from . import _kernels as K

        lists = ctx.lists
        slots = np.zeros((lists.flat_ids.shape[0], K.NUM_GRADS), np.float32)
        grads = np.zeros((ctx.num_gaussians, K.NUM_GRADS), np.float32)
        with K.num_threads(lists.num_threads):
            tiles_y = (lists.height + TILE_SIZE - 1) // TILE_SIZE
            bins = K.tile_bins(K.backward_work(ctx.last, lists.tiles_x, tiles_y))
            K.composite_backward(ctx.gauss, ctx.bg, lists.tile_offsets, lists.flat_ids, lists.isect_slots, *bins,
                                 lists.width, lists.height, lists.tiles_x, ctx.trans, ctx.last, _np32(grad_channels),
                                 _np32(grad_alpha), slots)
            K.reduce_slots(slots, lists.gauss_offsets, lists.order, grads)
        g = torch.from_numpy(grads).to(ctx.device)
        grad_bg = None
        if ctx.needs_input_grad[4]:
            t_final = torch.from_numpy(ctx.trans).to(ctx.device)
            grad_bg = (t_final[..., None] * grad_channels).sum((0, 1))
        return g[:, 0:2], g[:, 2:5], g[:, 5:9], g[:, 9], grad_bg, None


def _composite_cpu(means2d, conics, channels, opacities, background, s_max, ext_y, rects, order, camera,
                   num_threads):
    """`order` lists the Gaussians to composite, front to back (the others are skipped)."""
    from . import _kernels as K

    tiles_x, tiles_y = tile_grid(camera)
    order_np = order.cpu().numpy()
    tile_offsets, flat_ids, isect_slots, gauss_offsets = K.bin_tiles(
        np.ascontiguousarray(rects.cpu().numpy()[order_np]), tiles_x * tiles_y, tiles_x)
    lists = _TileLists(order_np, _np32(s_max)[order_np], _np32(ext_y)[order_np], tile_offsets, flat_ids,
                       isect_slots, gauss_offsets, camera.width, camera.height, tiles_x, num_threads)
    return _CompositeCPU.apply(means2d, conics, channels, opacities, background, lists)


@functools.lru_cache(maxsize=1)
def _gsplat():
    """The gsplat module if it is installed and importable, else None."""
    if importlib.util.find_spec("gsplat") is None:
        return None
    try:
        import gsplat
    except Exception:  # a broken CUDA build must not break the CPU path
        return None
    return gsplat


def uses_gsplat(device: torch.device) -> bool:
    """True when tensors on `device` are composited by gsplat (CUDA device and gsplat importable)."""
    return device.type == "cuda" and torch.cuda.is_available() and _gsplat() is not None


def _composite_gsplat(means2d, conics, channels, opacities, background, rects, order, camera):
    """gsplat's CUDA compositing of the same tile lists (`bin_tiles_torch`): same rules, float32."""
    from gsplat import rasterize_to_pixels

    tile_offsets, flat_ids = bin_tiles_torch(rects, order, camera)
    f32 = torch.float32
    colors, alphas = rasterize_to_pixels(
        means2d.to(f32)[None].contiguous(), conics.to(f32)[None].contiguous(), channels.to(f32)[None].contiguous(),
        opacities.to(f32)[None].contiguous(), camera.width, camera.height, TILE_SIZE, tile_offsets[None].contiguous(),
        flat_ids.contiguous(), backgrounds=background.to(f32)[None].contiguous())
    return colors[0], alphas[0, ..., 0]


# --- entry point -------------------------------------------------------------------------------------------------
def _background(background, like: Tensor) -> Tensor:
    bg = torch.as_tensor(background, dtype=torch.float32, device=like.device) if not isinstance(
        background, Tensor) else background.to(device=like.device, dtype=torch.float32)
    if bg.shape != (3,) or not bool(torch.isfinite(bg).all()):
        raise SplatreelError(f"background must be 3 finite numbers (RGB), got {background!r}")
    return bg


def _check_gaussians(g: Gaussians3D, sh_degree: int | None) -> None:
    if not isinstance(g, Gaussians3D):
        raise ModelError(f"rasterize needs a Gaussians3D (e.g. model.slice(t)), got {type(g).__name__}")
    n = g.means.shape[0] if isinstance(g.means, Tensor) and g.means.dim() == 2 else -1
    k = g.sh.shape[1] if isinstance(g.sh, Tensor) and g.sh.dim() == 3 else -1
    expected = {"means": (n, 3), "covariances": (n, 3, 3), "opacities": (n,), "sh": (n, k, 3), "visible": (n,)}
    for name, shape in expected.items():
        v = getattr(g, name)
        if not isinstance(v, Tensor) or tuple(v.shape) != shape or n < 0:
            got = list(v.shape) if isinstance(v, Tensor) else type(v).__name__
            raise ModelError(f"Gaussians3D.{name} has shape {got}, expected {[('N' if s == n else s) for s in shape]}")
        if name != "visible" and v.dtype not in (torch.float32, torch.float64):
            raise ModelError(f"Gaussians3D.{name} has dtype {v.dtype}, expected float32 or float64")
    degree = g.sh_degree if sh_degree is None else min(sh_degree, g.sh_degree)
    if not 0 <= degree <= 3 or k < num_sh_bases(degree):
        raise ModelError(f"Gaussians3D.sh has {k} coefficients per channel, not enough for SH degree {degree}")
    with torch.no_grad():
        # one reduction per tensor: a NaN or inf anywhere in a row makes the row sum non-finite
        finite = torch.isfinite(g.means.sum(1) + g.covariances.sum((1, 2)) + g.opacities + g.sh.sum((1, 2)))
        bad = ~finite & g.visible.bool()
        if bool(bad.any()):
            first = int(bad.nonzero()[0, 0])
            raise ModelError(f"{int(bad.sum())} visible Gaussians have NaN or infinite parameters "
                             f"(first: index {first}); cannot rasterize")


def rasterize(gaussians: Gaussians3D, camera: Camera, background: Sequence[float] | Tensor = (0.0, 0.0, 0.0), *,
              sh_degree: int | None = None, num_threads: int | None = None,
              far_plane: float | None = None) -> RenderOutput:
    """Render `gaussians` seen by `camera` over a constant `background`.

    Args:
        gaussians: N Gaussians (``model.slice(t)``), float32 or float64, any device; `visible == False` are culled.
        camera: pinhole camera, OpenCV axes, pixel centres at +0.5.
        background: RGB ``[3]`` (sequence or tensor; a tensor may require grad).
        sh_degree: evaluate colours at this SH degree at most (default: the model's).
        num_threads: CPU threads for the compositing kernels (default: numba's setting, i.e. all cores).
        far_plane: Gaussians whose centre's camera depth is at or beyond this are culled, as the near plane culls
            (None: no far plane). A capture whose alpha was cut at a far clip is compared at its clip.
    Returns:
        `RenderOutput` (see there); rgb/alpha/depth are differentiable w.r.t. every input tensor.
    Raises:
        ModelError: wrong shapes or dtypes, or NaN/inf in a visible Gaussian. CameraError: not a Camera.
    """
    if not isinstance(camera, Camera):
        raise CameraError(f"rasterize needs a splatreel Camera, got {type(camera).__name__}")
    if camera.width <= 0 or camera.height <= 0:
        raise CameraError(f"image size must be positive, got {camera.width}x{camera.height}")
    _check_gaussians(gaussians, sh_degree)
    g = gaussians
    n, device, dtype = len(g), g.means.device, g.means.dtype
    bg = _background(background, g.means)

    # 1. cheap culling first (time, near plane, opacity); the survivors ("front", M of them) are projected
    with torch.no_grad():
        z_all = camera_depths(g.means.detach(), camera)
        far = FAR_PLANE if far_plane is None else far_plane
        front = g.visible.bool() & (z_all > NEAR_PLANE) & (z_all < far) & (g.opacities >= ALPHA_THRESHOLD)
    fused = all(x.device.type == "cpu" and x.dtype == torch.float32 for x in (g.means, g.covariances))
    if fused:  # every row projected in place by the numba kernel (no gather / scatter); culled rows are inert
        from .projecting import project_fused

        front_idx, sub = None, g
        means2d, depths, cov2d_all, fused_conics = project_fused(g.means, g.covariances, front, camera)
        proj = ProjectedGaussians(means2d=means2d, depths=depths, cov2d=cov2d_all)
    else:
        front_idx = None if bool(front.all()) else front.nonzero()[:, 0]
        sub = g if front_idx is None else g.select(front_idx)
        proj = project_gaussians(sub.means, sub.covariances, camera)
        if front_idx is None:
            means2d = proj.means2d
        else:
            means2d = torch.zeros((n, 2), dtype=dtype, device=device).index_put((front_idx,), proj.means2d)

    # 2. the rest of the culling and the screen radii, on detached values
    with torch.no_grad():
        cov2d = proj.cov2d.detach()
        xx, xy, yy = cov2d.unbind(-1)
        radii_f = screen_radii(cov2d)
        uv = proj.means2d.detach()
        keep = ((xx * yy - xy * xy > 0) & (xx > 0) & (yy > 0) & torch.isfinite(radii_f) & (front if fused else True)
                & (uv[:, 0] + radii_f > 0) & (uv[:, 0] - radii_f < camera.width)
                & (uv[:, 1] + radii_f > 0) & (uv[:, 1] - radii_f < camera.height))
        radii_f = torch.where(keep, radii_f, torch.zeros_like(radii_f))
        radii_sub = radii_f.clamp_max(2 ** 31 - 1).to(torch.int32)
        radii = radii_sub if front_idx is None else torch.zeros(n, dtype=torch.int32, device=device).index_put(
            (front_idx,), radii_sub)
        # rendered Gaussians front to back; ties keep index order
        kept = keep.nonzero()[:, 0]
        order = kept[torch.argsort(proj.depths.detach()[kept], stable=True)]

    # 3. what the compositor needs, per front Gaussian; culled ones are not in `order` and are never read (an
    #    identity covariance keeps their conic, and its zero gradient, finite)
    safe_cov2d = torch.where(keep[:, None], proj.cov2d, cov2d.new_tensor([1.0, 0.0, 1.0]).expand_as(cov2d))
    conics = fused_conics if fused else conics_from_cov2d(safe_cov2d)
    campos = torch.as_tensor(camera.position, dtype=dtype, device=device)
    channels = torch.cat([sub.colors(campos, degree=sh_degree), proj.depths[:, None]], -1)
    opacities = sub.opacities
    with torch.no_grad():
        s_max, ext_x, ext_y = alpha_extent(safe_cov2d.detach(), opacities.detach())
        rects = tile_rects(uv, radii_f, ext_x, ext_y, camera) * keep[:, None]  # culled: empty
    background4 = torch.cat([bg, bg.new_zeros(1)])  # the depth channel composites over 0
    # through `means2d`, for retain_grad
    means2d_sub = proj.means2d if front_idx is None else means2d.index_select(0, front_idx)

    if uses_gsplat(device):
        image, alpha = _composite_gsplat(means2d_sub, conics, channels, opacities, background4, rects, order, camera)
    else:
        image, alpha = _composite_cpu(means2d_sub, conics, channels, opacities, background4, s_max, ext_y, rects,
                                      order, camera, num_threads)
    depth = torch.where(alpha > 0, image[..., 3] / alpha.clamp_min(1e-20), torch.zeros_like(alpha))
    return RenderOutput(rgb=image[..., :3], alpha=alpha, depth=depth, radii=radii, means2d=means2d,
                        visible=radii > 0)
