"""Slow, dense pure-PyTorch oracle of `splatreel.rasterize`: every Gaussian against every pixel.

Written independently of `splatreel/rasterize.py` (full-matrix EWA projection, a matrix inverse for the conic, the
whole compositing as a cumulative product over a ``[pixels, N]`` tensor) and differentiable by plain autograd, in
float64 or float32. Only the reference rules are shared, restated here from the reference rasterizer
(graphdeco-inria/diff-gaussian-rasterization ``cuda_rasterizer/forward.cu`` and ``auxiliary.h``, as vendored by
fudan-zvg/4d-gaussian-splatting):

* cull: not visible, z <= 0.2, opacity < 1/255, det(Σ2D + 0.3 I) <= 0, the square ``mean ± r`` box off-image;
  r = ceil(3 sqrt(mid + sqrt(max(0.1, mid² - det))));
* a Gaussian is seen only by the pixels of the tiles (16x16) of its ``mean ± r`` box;
* alpha = min(0.99, o exp(-sigma)), kept if sigma >= 0 and alpha >= 1/255; front to back in stable depth order;
  the first Gaussian that would bring T to <= 1e-4 and all after it are dropped.

Also random test scenes (`scene3d`, `model4d`) seen by `camera(w, h)` (at (0, -4, 1) looking at the origin, z up),
which mix ordinary Gaussians with the awkward ones: behind the camera or the near plane, off-screen, very large
(covering the image, reaching behind the camera), very thin (needles and discs) and not visible at this time.

`tests/` helper module (no conftest): ``from dense_rasterizer import dense_render`` with ``tests/`` on sys.path.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from splatreel.cameras import Camera, look_at
from splatreel.covariance import covariance_3d
from splatreel.model import Gaussians3D, Gaussians4D
from splatreel.sh import num_sh_coeffs

TILE = 16


def dense_render(g: Gaussians3D, camera: Camera, background=(0.0, 0.0, 0.0), sh_degree: int | None = None,
                 rows: tuple[int, int] | None = None) -> dict[str, Tensor]:
    """Render image rows ``[rows[0], rows[1])`` (default: all) in the dtype of ``g.means``.

    Returns a dict: ``rgb [h, W, 3]``, ``alpha [h, W]``, ``depth [h, W]`` (sum z a T / alpha, 0 where alpha = 0),
    ``radii [N]`` (int64, 0 = culled), ``means2d [N, 2]``.
    """
    dtype, dev = g.means.dtype, g.means.device
    w2c = torch.as_tensor(camera.w2c, dtype=dtype, device=dev)
    rot, trans = w2c[:3, :3], w2c[:3, 3]
    pc = torch.einsum("ij,nj->ni", rot, g.means) + trans
    z = pc[:, 2]
    front = g.visible.bool() & (z > 0.2) & (g.opacities >= 1.0 / 255.0)
    zs = torch.where(front, z, torch.ones_like(z))  # keeps the culled ones finite (and their gradients zero)
    xs, ys = pc[:, 0], pc[:, 1]
    fx, fy, cx, cy, w, h = camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height
    tan_x, tan_y = 0.5 * w / fx, 0.5 * h / fy
    txc = zs * torch.clamp(xs / zs, -(cx / fx + 0.3 * tan_x), (w - cx) / fx + 0.3 * tan_x)
    tyc = zs * torch.clamp(ys / zs, -(cy / fy + 0.3 * tan_y), (h - cy) / fy + 0.3 * tan_y)
    zero = torch.zeros_like(zs)
    jac = torch.stack([
        torch.stack([fx / zs, zero, -fx * txc / zs ** 2], -1),
        torch.stack([zero, fy / zs, -fy * tyc / zs ** 2], -1),
    ], -2)  # [N, 2, 3]
    cov = 0.5 * (g.covariances + g.covariances.transpose(-1, -2))  # symmetric gradient, as the rasterizer
    cov2 = jac @ (rot @ cov @ rot.T) @ jac.transpose(-1, -2)
    cov2 = cov2 + 0.3 * torch.eye(2, dtype=dtype, device=dev)
    det = torch.linalg.det(cov2)
    ok = front & (det > 0) & (cov2[:, 0, 0] > 0)
    conic = torch.linalg.inv(torch.where(ok[:, None, None], cov2, torch.eye(2, dtype=dtype, device=dev)))
    uv = torch.stack([fx * xs / zs + cx, fy * ys / zs + cy], -1)
    with torch.no_grad():
        mid = 0.5 * (cov2[:, 0, 0] + cov2[:, 1, 1])
        lam = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.1))
        r = torch.ceil(3.0 * torch.sqrt(lam))
        u, v = uv[:, 0].detach(), uv[:, 1].detach()
        ok = ok & (u + r > 0) & (u - r < w) & (v + r > 0) & (v - r < h)
        r = torch.where(ok, r, torch.zeros_like(r))
        tiles_x, tiles_y = math.ceil(w / TILE), math.ceil(h / TILE)
        tx0 = torch.floor((u - r) / TILE).clamp(0, tiles_x)
        tx1 = torch.ceil((u + r) / TILE).clamp(0, tiles_x)
        ty0 = torch.floor((v - r) / TILE).clamp(0, tiles_y)
        ty1 = torch.ceil((v + r) / TILE).clamp(0, tiles_y)
        order = torch.argsort(torch.where(ok, z.detach(), torch.full_like(z, math.inf)), stable=True)

    r0, r1 = rows if rows is not None else (0, h)
    jj, ii = torch.meshgrid(torch.arange(r0, r1, device=dev), torch.arange(w, device=dev), indexing="ij")
    jj, ii = jj.reshape(-1), ii.reshape(-1)  # [P]
    px, py = ii.to(dtype)[:, None] + 0.5, jj.to(dtype)[:, None] + 0.5  # [P, 1]
    tile_x, tile_y = (ii // TILE).to(dtype)[:, None], (jj // TILE).to(dtype)[:, None]

    o = order  # everything below is front to back, [P, N]
    in_tile = (ok[o] & (tile_x >= tx0[o]) & (tile_x < tx1[o]) & (tile_y >= ty0[o]) & (tile_y < ty1[o]))
    dx, dy = uv[o, 0] - px, uv[o, 1] - py
    a, b, c = conic[o, 0, 0], conic[o, 0, 1], conic[o, 1, 1]
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    alpha = torch.clamp(g.opacities[o] * torch.exp(-sigma), max=0.99)
    alpha = torch.where(in_tile & (sigma >= 0) & (alpha >= 1.0 / 255.0), alpha, torch.zeros_like(alpha))
    t_incl = torch.cumprod(1.0 - alpha, 1)
    t_excl = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], 1)
    weight = alpha * t_excl * (t_incl > 1e-4)
    campos = torch.as_tensor(camera.position, dtype=dtype, device=dev)
    feats = torch.cat([g.colors(campos, degree=sh_degree), z[:, None]], -1)[o]  # [N, 4]
    acc = weight @ feats  # [P, 4]
    alpha_img = weight.sum(1)
    bg = torch.as_tensor(background, dtype=dtype, device=dev)
    rgb = acc[:, :3] + (1.0 - alpha_img)[:, None] * bg
    depth = torch.where(alpha_img > 0, acc[:, 3] / alpha_img.clamp_min(1e-30), torch.zeros_like(alpha_img))
    shape = (r1 - r0, w)
    means2d = torch.where(front[:, None], uv, torch.zeros_like(uv))
    return {"rgb": rgb.reshape(shape + (3,)), "alpha": alpha_img.reshape(shape), "depth": depth.reshape(shape),
            "radii": r.long(), "means2d": means2d}


# --- scenes ---------------------------------------------------------------------------------------------------------
EYE = (0.0, -4.0, 1.0)


def camera(width: int, height: int, fov_deg: float = 60.0) -> Camera:
    return look_at(EYE, (0.0, 0.0, 0.0), "z", fov_deg, width, height)


def scene3d(n: int, seed: int, dtype=torch.float64, sh_degree: int = 1) -> dict[str, torch.Tensor]:
    """Leaf tensors of a Gaussians3D (means, covariances, opacities, sh) plus `visible`, with the awkward cases."""
    gen = torch.Generator().manual_seed(seed)

    def rand(*shape):
        return torch.rand(*shape, generator=gen, dtype=torch.float64)

    means = (rand(n, 3) * 2 - 1) * torch.tensor([2.0, 2.0, 1.5], dtype=torch.float64)
    log_scales = rand(n, 3) * 2.0 - 3.5
    opacities = rand(n) * 0.9 + 0.05
    opacities[-max(1, n // 8):] = 0.999  # alpha clamped to 0.99 near their centres; opaque stacks saturate (T stop)
    k = max(1, n // 12)
    log_scales[:k] = rand(k, 3) * 0.7 + math.log(1.5)  # very large: cover the image, reach behind the camera
    opacities[:k] *= 0.2
    log_scales[k:2 * k, :2] = math.log(2e-4)  # very thin: needles along one axis
    log_scales[2 * k:3 * k, 0] = math.log(2e-4)  # discs
    eye = torch.tensor(EYE, dtype=torch.float64)
    means[3 * k:4 * k] = eye + (rand(k, 3) - 0.5) * 0.6 + torch.tensor([0.0, -0.5, 0.0], dtype=torch.float64)  # behind
    means[4 * k:5 * k, 0] = (rand(k) + 1.2) * 6.0 * torch.sign(rand(k) - 0.5)  # far off-screen left/right
    means[5 * k] = eye + torch.tensor([0.0, 0.15, 0.0], dtype=torch.float64)  # just in front of the camera, < near
    quats = rand(n, 4) * 2 - 1
    covariances = covariance_3d(torch.exp(log_scales), quats)
    sh = (rand(n, (sh_degree + 1) ** 2, 3) - 0.5) * 0.8
    visible = rand(n) > 0.1
    return {"means": means.to(dtype), "covariances": covariances.to(dtype), "opacities": opacities.to(dtype),
            "sh": sh.to(dtype), "visible": visible}


def gaussians3d(leaves: dict[str, torch.Tensor], sh_degree: int = 1, requires_grad: bool = False) -> Gaussians3D:
    t = {k: (v.detach().clone().requires_grad_(requires_grad) if k != "visible" else v) for k, v in leaves.items()}
    return Gaussians3D(**t, sh_degree=sh_degree)


def model4d(n: int, seed: int, sh_degree: int = 1, sh_degree_t: int = 1, dtype=torch.float64,
            t_focus: float = 0.5) -> Gaussians4D:
    """A small moving, fading native 4D model around the origin (time range [0, 1], to be sliced near t = 0.5);
    a few Gaussians are nearly opaque and centred in time at `t_focus`, so that alpha clamps at 0.99 there."""
    gen = torch.Generator().manual_seed(seed)

    def rand(*shape):
        return torch.rand(*shape, generator=gen, dtype=torch.float64)

    m = num_sh_coeffs(sh_degree, sh_degree_t)
    t_means, logits = 0.5 + (rand(n) - 0.5) * 0.4, (rand(n) - 0.5) * 3.0
    k = max(1, n // 5)
    t_means[:k], logits[:k] = t_focus, 7.0
    return Gaussians4D(
        means=(rand(n, 3) * 2 - 1) * 0.9, t_means=t_means,
        log_scales=rand(n, 3) * 1.2 - 2.6, log_t_scales=rand(n) * 0.6 - 1.6,
        quats_l=rand(n, 4) * 2 - 1, quats_r=rand(n, 4) * 2 - 1,
        opacity_logits=logits, sh_dc=(rand(n, 1, 3) - 0.5) * 2.0,
        sh_rest=(rand(n, m - 1, 3) - 0.5) * 0.6, sh_degree=sh_degree, sh_degree_t=sh_degree_t,
        time_range=(0.0, 1.0)).to(dtype=dtype)
