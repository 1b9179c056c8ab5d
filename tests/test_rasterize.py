"""Tests of the differentiable rasterizer (`splatreel.rasterize`) against the dense pure-torch oracle."""

from __future__ import annotations

import importlib
import math
import os
import subprocess
import sys
import types

import numpy as np
import pytest
import torch

sys.path.insert(0, os.path.dirname(__file__))
from dense_rasterizer import camera, dense_render, gaussians3d, model4d, scene3d  # noqa: E402

from splatreel.cameras import Camera  # noqa: E402
from splatreel.errors import CameraError, ModelError, SplatreelError  # noqa: E402
from splatreel.model import Gaussians3D  # noqa: E402
from splatreel.rasterize import RenderOutput, rasterize  # noqa: E402

R = importlib.import_module("splatreel.rasterize")  # the module, even if the package re-exports `rasterize`

BG = (0.2, 0.3, 0.4)


# --- images ------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("size,n,seed", [((5, 3), 60, 0), ((16, 16), 150, 1), ((37, 29), 300, 2),
                                         ((64, 48), 400, 3), ((130, 70), 500, 4)])
def test_images_match_dense_reference(size, n, seed):
    leaves = scene3d(n, seed)
    g, cam = gaussians3d(leaves), camera(*size)
    out = rasterize(g, cam, BG)
    ref = dense_render(g, cam, BG)
    assert isinstance(out, RenderOutput)
    assert out.rgb.shape == (size[1], size[0], 3) and out.rgb.dtype == torch.float32
    assert out.alpha.shape == out.depth.shape == (size[1], size[0])
    assert (out.rgb.double() - ref["rgb"]).abs().max() < 1e-5
    assert (out.alpha.double() - ref["alpha"]).abs().max() < 1e-5
    # expected depth: the accumulated sum z a T to 1e-5 of the depth scale, the ratio where alpha is not tiny
    zmax = float(ref["depth"].max())
    assert ((out.depth * out.alpha).double() - ref["depth"] * ref["alpha"]).abs().max() < 1e-5 * zmax
    solid = ref["alpha"] > 0.05
    assert ((out.depth.double() - ref["depth"]).abs()[solid]).max() < 1e-4 * zmax
    assert torch.equal(out.radii.long(), ref["radii"]) and out.radii.dtype == torch.int32
    assert torch.equal(out.visible, ref["radii"] > 0)
    assert (out.means2d - ref["means2d"]).abs().max() < 1e-9
    # the awkward ones are really there: culled behind / off-screen, some very large visible ones
    assert (~out.visible & leaves["visible"]).any() and out.visible.any()
    if size[0] >= 37:
        assert int(out.radii.max()) > max(size)
        assert 0.05 < float(out.alpha.mean()) < 0.999


def test_float32_input_matches_float64():
    leaves = scene3d(300, 5)
    cam = camera(48, 40)
    a = rasterize(gaussians3d(leaves), cam, BG)
    b = rasterize(gaussians3d({k: (v.float() if v.is_floating_point() else v) for k, v in leaves.items()}), cam, BG)
    assert (a.rgb - b.rgb).abs().max() < 1e-4 and (a.alpha - b.alpha).abs().max() < 1e-4
    assert b.means2d.dtype == torch.float32


# --- gradients ---------------------------------------------------------------------------------------------------
def _loss_weights(h: int, w: int, seed: int):
    gen = torch.Generator().manual_seed(seed)
    return (torch.randn(h, w, 3, generator=gen, dtype=torch.float64), torch.randn(h, w, generator=gen,
            dtype=torch.float64), 0.1 * torch.randn(h, w, generator=gen, dtype=torch.float64))


def _loss(rgb, alpha, depth, weights):
    wr, wa, wd = weights
    return (rgb.double() * wr).sum() + (alpha.double() * wa).sum() + (depth.double() * wd).sum()


def test_gradients_of_every_4d_parameter_match_finite_differences():
    """Autograd through slice(t) + rasterize (float32 kernels) vs float64 central differences of the dense oracle."""
    model, t = model4d(10, seed=7, sh_degree=1, sh_degree_t=1, t_focus=0.45), 0.45
    cam = camera(32, 24, fov_deg=40.0)
    weights = _loss_weights(24, 32, 0)
    params = {name: getattr(model, name).clone().requires_grad_() for name in model.TENSORS}
    live = type(model)(**params, sh_degree=1, sh_degree_t=1, time_range=model.time_range)
    out = rasterize(live.slice(t), cam, BG)
    assert int(out.visible.sum()) >= 8
    _loss(out.rgb, out.alpha, out.depth, weights).backward()

    def dense_loss(m) -> float:
        ref = dense_render(m.slice(t), cam, BG)
        return float(_loss(ref["rgb"], ref["alpha"], ref["depth"], weights))

    eps, skipped, checked = 1e-6, 0, 0
    with torch.no_grad():
        base = dense_loss(model)
        for name in model.TENSORS:
            value = getattr(model, name)
            grad = params[name].grad
            fd = torch.zeros_like(value)
            keep = torch.ones_like(value, dtype=torch.bool)
            for i in range(value.numel()):
                v = value.view(-1)
                orig = float(v[i])
                v[i] = orig + eps
                up = dense_loss(model)
                v[i] = orig - eps
                down = dense_loss(model)
                v[i] = orig
                fwd, bwd = (up - base) / eps, (base - down) / eps
                fd.view(-1)[i] = (up - down) / (2 * eps)
                # a threshold (alpha 1/255, T 1e-4, tile edge) crossed inside [-eps, eps]: no derivative there
                if abs(fwd - bwd) > 1e-3 * (abs(fwd) + abs(bwd)) + 1e-6:
                    keep.view(-1)[i] = False
            scale = float(fd.abs().max())
            assert scale > 0, f"{name}: the loss does not depend on it"
            err = (grad - fd).abs()
            bad = keep & (err > 2e-3 * scale + 1e-3 * fd.abs())
            assert not bad.any(), f"{name}: max error {float(err[keep].max()):.3g} (scale {scale:.3g})"
            skipped += int((~keep).sum())
            checked += value.numel()
    assert skipped <= 0.02 * checked


def test_gradients_match_dense_autograd():
    """Analytic float32 gradients of every Gaussians3D tensor and the background vs float64 autograd of the oracle."""
    leaves = scene3d(400, 11, sh_degree=2)
    cam = camera(64, 48)
    weights = _loss_weights(48, 64, 1)
    grads = []
    for render in (rasterize, dense_render):
        g = gaussians3d(leaves, sh_degree=2, requires_grad=True)
        bg = torch.tensor(BG, dtype=torch.float64, requires_grad=True)
        out = render(g, cam, bg)
        rgb, alpha, depth = (out.rgb, out.alpha, out.depth) if isinstance(out, RenderOutput) else (
            out["rgb"], out["alpha"], out["depth"])
        _loss(rgb, alpha, depth, weights).backward()
        grads.append({"means": g.means.grad, "covariances": g.covariances.grad, "opacities": g.opacities.grad,
                      "sh": g.sh.grad, "background": bg.grad})
    for name, ref in grads[1].items():
        err = float((grads[0][name] - ref).abs().max() / ref.abs().max())
        assert err < 1e-4, f"{name}: relative error {err:.3g}"


def test_means2d_retains_screen_gradient():
    leaves = scene3d(300, 13)
    g = gaussians3d(leaves, requires_grad=True)
    out = rasterize(g, camera(40, 30), BG)
    out.means2d.retain_grad()
    out.rgb.sum().backward()
    grad = out.means2d.grad
    assert grad is not None and grad.shape == (300, 2)
    assert (grad[~out.visible] == 0).all()
    assert (grad[out.visible].abs().sum(1) > 0).float().mean() > 0.5


# --- determinism -------------------------------------------------------------------------------------------------
def test_gradients_bit_identical_across_runs_and_thread_counts():
    model, t = model4d(3000, seed=3, sh_degree=2, sh_degree_t=1, dtype=torch.float32), 0.5
    cam = camera(96, 80)
    weights = _loss_weights(80, 96, 2)
    results = []
    for threads in (2, 2, 1):
        params = {name: getattr(model, name).clone().requires_grad_() for name in model.TENSORS}
        live = type(model)(**params, sh_degree=2, sh_degree_t=1, time_range=model.time_range)
        out = rasterize(live.slice(t), cam, BG, num_threads=threads)
        _loss(out.rgb, out.alpha, out.depth, weights).backward()
        results.append([out.rgb, out.alpha, out.depth] + [params[n].grad for n in model.TENSORS])
    assert int(out.visible.sum()) > 1000
    for other in results[1:]:
        for a, b in zip(results[0], other):
            assert torch.equal(a, b)


# --- bad and degenerate input ------------------------------------------------------------------------------------
def test_bad_input_gives_clear_errors():
    leaves = scene3d(50, 17)
    cam = camera(20, 20)
    nan = dict(leaves, means=leaves["means"].clone())
    first_visible = int(leaves["visible"].nonzero()[0, 0])
    nan["means"][first_visible, 1] = math.nan
    with pytest.raises(ModelError, match="NaN"):
        rasterize(gaussians3d(nan), cam)
    hidden = dict(leaves, visible=leaves["visible"].clone(), opacities=leaves["opacities"].clone())
    hidden["visible"][first_visible] = False
    hidden["opacities"][first_visible] = math.inf
    hidden["means"] = nan["means"]
    assert torch.isfinite(rasterize(gaussians3d(hidden), cam).rgb).all()  # NaN only where culled: fine
    with pytest.raises(ModelError, match="covariances"):
        rasterize(gaussians3d(dict(leaves, covariances=leaves["covariances"][:, :2])), cam)
    with pytest.raises(ModelError):
        rasterize("not gaussians", cam)  # type: ignore[arg-type]
    with pytest.raises(CameraError):
        rasterize(gaussians3d(leaves), "not a camera")  # type: ignore[arg-type]
    with pytest.raises(CameraError):
        Camera(cam.c2w, cam.fx, cam.fy, cam.cx, cam.cy, 0, 20)  # zero-size images cannot be asked for
    with pytest.raises(SplatreelError, match="background"):
        rasterize(gaussians3d(leaves), cam, (0.0, math.nan, 0.0))
    with pytest.raises(ModelError, match="SH degree"):
        rasterize(gaussians3d(leaves, sh_degree=3), cam)


def test_empty_and_fully_culled_scenes_render_background():
    cam = camera(24, 17)
    empty = Gaussians3D(means=torch.zeros(0, 3), covariances=torch.zeros(0, 3, 3), opacities=torch.zeros(0),
                        sh=torch.zeros(0, 1, 3), visible=torch.zeros(0, dtype=torch.bool), sh_degree=0)
    out = rasterize(empty, cam, BG)
    assert torch.equal(out.rgb, torch.tensor(BG).expand(17, 24, 3)) and (out.alpha == 0).all()
    assert (out.depth == 0).all() and out.radii.shape == (0,)
    leaves = scene3d(40, 19)
    g = gaussians3d(dict(leaves, visible=torch.zeros(40, dtype=torch.bool)), requires_grad=True)
    out = rasterize(g, cam, BG)
    assert (out.alpha == 0).all() and (out.radii == 0).all()
    out.rgb.sum().backward()
    assert (g.means.grad == 0).all() and (g.sh.grad == 0).all()


def test_camera_inside_the_gaussians_is_well_defined():
    """Huge Gaussians around the camera, some centred on it or behind it: a finite image and finite gradients."""
    gen = torch.Generator().manual_seed(23)
    n = 200
    eye = torch.tensor([0.0, -4.0, 1.0])
    means = eye + torch.randn(n, 3, generator=gen) * 1.5
    means[0] = eye  # exactly at the camera centre
    means[1] = eye + torch.tensor([0.0, 0.2, 0.0])  # on the near plane
    scales = torch.exp(torch.randn(n, 3, generator=gen) * 0.5 + 0.5)
    quats = torch.randn(n, 4, generator=gen)
    from splatreel.covariance import covariance_3d
    leaves = {"means": means, "covariances": covariance_3d(scales, quats), "opacities": torch.full((n,), 0.5),
              "sh": torch.randn(n, 1, 3, generator=gen) * 0.3, "visible": torch.ones(n, dtype=torch.bool)}
    g = gaussians3d(leaves, sh_degree=0, requires_grad=True)
    out = rasterize(g, camera(32, 32), BG)
    assert torch.isfinite(out.rgb).all() and torch.isfinite(out.depth).all()
    assert float(out.alpha.detach().min()) > 0.9 and float(out.alpha.detach().max()) <= 1.0
    assert out.radii[0] == 0 and out.radii[1] == 0
    (out.rgb.sum() + out.depth.sum()).backward()
    for t in (g.means.grad, g.covariances.grad, g.opacities.grad, g.sh.grad):
        assert torch.isfinite(t).all()
    ref = dense_render(gaussians3d(leaves, sh_degree=0), camera(32, 32), BG)
    assert (out.rgb.double() - ref["rgb"].double()).abs().max() < 1e-5


def test_tile_bins_hold_every_tile_once_with_near_equal_work():
    """The kernels' load balance: each bin is one thread's share; longest-processing-time dealing keeps the
    heaviest bin within one tile's work of the lightest."""
    from splatreel import _kernels as K

    rng = np.random.default_rng(3)
    work = np.zeros(256, np.int64)
    work[:60] = rng.integers(0, 5000, 60)  # an object in the top rows of the image, as a static split sees it
    for bins in (1, 2, 3, 8):
        offsets, tiles = K.balance_tiles(work, bins)
        assert offsets[0] == 0 and offsets[-1] == 256 and np.array_equal(np.sort(tiles), np.arange(256))
        loads = [int((work[tiles[a:b]] + K._TILE_OVERHEAD).sum()) for a, b in zip(offsets[:-1], offsets[1:])]
        assert max(loads) - min(loads) <= work.max() + K._TILE_OVERHEAD
    last = np.full((40, 40), -1, np.int32)
    last[3, 20], last[35, 2] = 7, 2  # tiles (0, 1) and (2, 0) of a 3 x 3 grid
    assert K.backward_work(last, 3, 3).tolist() == [0, 8, 0, 0, 0, 0, 3, 0, 0]


def test_rows_touched_keep_every_row_with_a_passing_pixel_and_skip_the_rest():
    """The kernels evaluate only the rows `_rows_touched` lists: it must list every row where a pixel passes the
    alpha test (the kernels' own `_pixel_alpha`), for sizes from sub-pixel to needles, and skip the bounding-box
    rows the ellipse misses (at most 20 % extra rows; the box alone gave half as many again)."""
    from numba import njit

    from splatreel import _kernels as K
    from splatreel.rasterize import alpha_extent

    rng = np.random.default_rng(7)
    n = 20000
    major = np.exp(rng.uniform(math.log(0.2), math.log(30.0), n))
    minor = major / np.exp(rng.uniform(0.0, math.log(200.0), n))
    cos, sin = (f(rng.uniform(0.0, math.pi, n)) for f in (np.cos, np.sin))
    xx = cos * cos * major ** 2 + sin * sin * minor ** 2 + 0.3
    yy = sin * sin * major ** 2 + cos * cos * minor ** 2 + 0.3
    xy = cos * sin * (major ** 2 - minor ** 2)
    opacity = torch.tensor(np.exp(rng.uniform(math.log(1 / 255), 0.0, n)), dtype=torch.float32)
    s_max, _, ext_y = alpha_extent(torch.tensor(np.stack([xx, xy, yy], -1), dtype=torch.float32), opacity)
    det = xx * yy - xy * xy
    conics = np.stack([yy / det, -xy / det, xx / det], -1).astype(np.float32)
    means = rng.uniform(-8.0, 24.0, (n, 2)).astype(np.float32)
    gauss = K.pack_gaussians(means, conics, np.zeros((n, 4), np.float32), opacity.numpy(), s_max.numpy(),
                             ext_y.numpy())

    @njit
    def count(gauss):
        rows = np.empty(16, np.int64)
        dropped, needed, listed = 0, 0, 0
        for g in range(gauss.shape[0]):
            num = K._rows_touched(gauss, g, 0, 0, 16, 16, rows)
            listed += num
            u, v, a, b, c, o = gauss[g, 0], gauss[g, 1], gauss[g, 2], gauss[g, 3], gauss[g, 4], gauss[g, 5]
            for py in range(16):
                hit = False
                for px in range(16):
                    sigma, _, _, alpha = K._pixel_alpha(a, b, c, o, u - (np.float32(px) + np.float32(0.5)),
                                                        v - (np.float32(py) + np.float32(0.5)))
                    hit |= (sigma >= 0) & (alpha >= K._ALPHA_MIN)
                needed += hit
                dropped += hit and py not in rows[:num]
        return dropped, needed, listed

    dropped, needed, listed = count(gauss)
    assert needed > 50000 and dropped == 0
    assert listed < 1.2 * needed


# --- GPU path glue (gsplat), checked on the CPU ------------------------------------------------------------------
def test_torch_binning_matches_kernel_binning():
    from splatreel import _kernels as K

    gen = torch.Generator().manual_seed(29)
    cam = camera(70, 45)
    tiles_x, tiles_y = R.tile_grid(cam)
    m = 300
    x0 = torch.randint(0, tiles_x, (m,), generator=gen)
    y0 = torch.randint(0, tiles_y, (m,), generator=gen)
    rects = torch.stack([x0, (x0 + torch.randint(0, 4, (m,), generator=gen)).clamp_max(tiles_x),
                         y0, (y0 + torch.randint(0, 3, (m,), generator=gen)).clamp_max(tiles_y)], 1).int()
    order = torch.randperm(m, generator=gen)
    offsets, flat = R.bin_tiles_torch(rects, order, cam)
    k_offsets, k_flat, _, _ = K.bin_tiles(rects[order].numpy(), tiles_x * tiles_y, tiles_x)
    assert np.array_equal(offsets.reshape(-1).numpy(), k_offsets[:-1])
    assert np.array_equal(flat.numpy(), order.numpy()[k_flat])  # kernel lists hold depth ranks


def _fake_gsplat() -> types.ModuleType:
    """gsplat's documented `rasterize_to_pixels` contract, implemented slowly in torch (one pixel at a time)."""

    def rasterize_to_pixels(means2d, conics, colors, opacities, image_width, image_height, tile_size,
                            isect_offsets, flatten_ids, backgrounds=None, **_):
        assert means2d.dim() == 3 and isect_offsets.shape[1:] == (math.ceil(image_height / tile_size),
                                                                   math.ceil(image_width / tile_size))
        assert flatten_ids.dtype == torch.int32 and isect_offsets.dtype == torch.int32
        offsets = torch.cat([isect_offsets.reshape(-1), torch.tensor([flatten_ids.shape[0]], dtype=torch.int32)])
        channels = colors.shape[-1]
        rows = []
        for py in range(image_height):
            row = []
            for px in range(image_width):
                tile = (py // tile_size) * isect_offsets.shape[2] + px // tile_size
                t = torch.ones((), dtype=colors.dtype)
                acc = torch.zeros(channels, dtype=colors.dtype)
                for gid in flatten_ids[offsets[tile]:offsets[tile + 1]].tolist():
                    d = means2d[0, gid] - torch.tensor([px + 0.5, py + 0.5])
                    a, b, c = conics[0, gid]
                    sigma = 0.5 * (a * d[0] ** 2 + c * d[1] ** 2) + b * d[0] * d[1]
                    alpha = torch.clamp(opacities[0, gid] * torch.exp(-sigma), max=0.99)
                    if sigma < 0 or alpha < 1.0 / 255.0:
                        continue
                    if t * (1 - alpha) <= 1e-4:
                        break
                    acc = acc + colors[0, gid] * alpha * t
                    t = t * (1 - alpha)
                row.append(torch.cat([acc + t * backgrounds[0], (1 - t)[None]]))
            rows.append(torch.stack(row))
        out = torch.stack(rows)[None]
        return out[..., :channels], out[..., channels:]

    return types.SimpleNamespace(rasterize_to_pixels=rasterize_to_pixels)


def test_gsplat_path_matches_cpu_path(monkeypatch):
    """The CUDA branch's glue (tile lists, shapes, channels) with gsplat replaced by a slow torch stand-in."""
    leaves = scene3d(80, 31)
    g = gaussians3d(leaves, requires_grad=True)
    cam = camera(36, 20)
    cpu = rasterize(g, cam, BG)
    assert not R.uses_gsplat(torch.device("cpu"))
    monkeypatch.setitem(sys.modules, "gsplat", _fake_gsplat())
    monkeypatch.setattr(R, "uses_gsplat", lambda device: True)
    gpu = rasterize(g, cam, BG)
    assert (gpu.rgb - cpu.rgb).abs().max() < 1e-5 and (gpu.alpha - cpu.alpha).abs().max() < 1e-5
    assert (gpu.depth - cpu.depth).abs().max() < 1e-4 and torch.equal(gpu.radii, cpu.radii)
    gpu.rgb.sum().backward()  # differentiable through the stand-in as through gsplat
    assert torch.isfinite(g.means.grad).all() and g.means.grad.abs().sum() > 0


# --- numba cache location ----------------------------------------------------------------------------------------
def _cache_dir_in_subprocess(env: dict) -> str:
    code = "import os, splatreel._kernels as K; print(os.environ['NUMBA_CACHE_DIR'], K.CACHE_ENABLED)"
    full_env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    full_env.update(env)
    res = subprocess.run([sys.executable, "-c", code], env=full_env, capture_output=True, text=True, check=True)
    return res.stdout.strip()


def test_numba_cache_goes_to_a_writable_user_directory(tmp_path):
    out = _cache_dir_in_subprocess({"XDG_CACHE_HOME": str(tmp_path / "xdg")})
    assert out == f"{tmp_path / 'xdg' / 'splatreel' / 'numba'} True"
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    out = _cache_dir_in_subprocess({"XDG_CACHE_HOME": str(blocker / "sub")})  # cannot be created
    assert out.endswith(" True") and "splatreel-numba-" in out
    assert _cache_dir_in_subprocess({"NUMBA_CACHE_DIR": str(tmp_path / "mine")}) == f"{tmp_path / 'mine'} True"
