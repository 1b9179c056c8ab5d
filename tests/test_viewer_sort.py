"""Depth sorting at time t: two Gaussians that swap places, the numba kernel against the trainer's projection of
the model's slice, and the worker-thread sorter of the desktop app."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from splatreel.cameras import look_at, orbit
from splatreel.covariance import covariance_4d_from_motion, decompose_covariance_4d
from splatreel.model import Gaussians4D
from splatreel.sh import rgb_to_sh
from splatreel.viewer.renderer import RenderSettings, render_image
from splatreel.viewer.sorting import AsyncSorter, depth_order
from splatreel.viewer.splats import to_arrays
from splatreel.viewer.synthetic import synthetic_model

RED, BLUE = 0, 1


def gaussians_from_motion(means, cov3, velocity, var_t, opacity_logits, rgb, **model_fields) -> Gaussians4D:
    """Native 4D Gaussians (temporal mean t = 0, SH degree 0) with these 3D covariances ``[N, 3, 3]``, velocities of
    the mean and temporal variances (`covariance_4d_from_motion`); `model_fields` e.g. ``time_range``."""
    f64 = lambda x: torch.as_tensor(x, dtype=torch.float64)  # noqa: E731
    means, cov3, var_t = f64(means), f64(cov3), f64(var_t)
    n = means.shape[0]
    scales, scale_t, q_l, q_r = decompose_covariance_4d(
        covariance_4d_from_motion(cov3.expand(n, 3, 3), f64(velocity).expand(n, 3), var_t.expand(n)))
    return Gaussians4D(means=means, t_means=torch.zeros(n, dtype=torch.float64), log_scales=scales.log(),
                       log_t_scales=scale_t.log(), quats_l=q_l, quats_r=q_r,
                       opacity_logits=f64(opacity_logits).expand(n).clone(),
                       sh_dc=rgb_to_sh(f64(rgb).expand(n, 3))[:, None],
                       sh_rest=torch.zeros(n, 0, 3, dtype=torch.float64), **model_fields)


def swapping_pair() -> Gaussians4D:
    """Gaussian 0 (red) moves from x=-1 to x=+1 over t in [0, 1], Gaussian 1 (blue) from +1 to -1.

    Both are stored with their temporal mean at t = 0, so their *stored* means are -1 and +1 whatever t is:
    a viewer sorting static positions gets the order wrong at t = 1.
    """
    return gaussians_from_motion(
        [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]], torch.eye(3) * 0.15 ** 2, [[2.0, 0.0, 0.0], [-2.0, 0.0, 0.0]],
        100.0,  # sigma_t = 10: no fading over [0, 1]
        5.0, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def test_sort_at_time_t_swaps_two_crossing_gaussians():
    model = swapping_pair()
    # the camera looks along +x from x = -4: smaller x is nearer
    cam = look_at((-4.0, 0.0, 0.0), (0.0, 0.0, 0.0), "z", fov_deg=30, width=32, height=32)
    splats = to_arrays(model)
    start = depth_order(splats, cam, 0.0)
    end = depth_order(splats, cam, 1.0)
    assert start.order.tolist() == [BLUE, RED]  # back to front: blue (x=+1) is behind at t=0
    assert end.order.tolist() == [RED, BLUE]  # ... and in front at t=1
    for t, front in ((0.0, RED), (1.0, BLUE)):
        for composite in ("front-to-back", "back-to-front"):
            img = render_image(model, cam, t, RenderSettings(composite=composite))
            centre = img[16, 16, :3]
            assert centre[front * 2] > 0.9 and centre[2 - front * 2] < 0.05, (t, composite, centre)


def reference_order(model, camera, t: float) -> tuple[np.ndarray, np.ndarray]:
    """What `depth_order` must give, from the model's own slice and the trainer's EWA projection (the math's one
    place): the back-to-front indices and their (u, v, hx, hy, quad area, optical mass) boxes."""
    from scipy.special import spence  # Li2(x) = spence(1 - x)

    from splatreel.constants import ALPHA_THRESHOLD, MAX_ALPHA, NEAR_PLANE
    from splatreel.rasterize import project_gaussians

    g = model.slice(t)
    means, covs, o = g.means.double(), g.covariances.double(), g.opacities.double().numpy()
    p = project_gaussians(means, covs, camera)
    z, (u, v) = p.depths.numpy(), p.means2d.numpy().T
    xx, xy, yy = p.cov2d.numpy().T
    det = xx * yy - xy * xy
    with np.errstate(divide="ignore", invalid="ignore"):
        rr = 2.0 * np.log(o / ALPHA_THRESHOLD)
        hx, hy = np.sqrt(rr * xx) + 1.0, np.sqrt(rr * yy) + 1.0
        keep = (g.visible.numpy() & (o >= ALPHA_THRESHOLD) & (z > NEAR_PLANE) & (det > 0) & (u + hx >= 0)
                & (u - hx <= camera.width) & (v + hy >= 0) & (v - hy <= camera.height))
    order = np.flatnonzero(keep)[np.argsort(-z[keep], kind="stable")]
    mass = 2.0 * np.pi * np.sqrt(det) * spence(1.0 - np.minimum(o, MAX_ALPHA))
    boxes = np.stack([u, v, hx, hy, 4.0 * rr * np.sqrt(det), mass], -1)[order]
    return order, boxes


@pytest.mark.parametrize("accelerated", [False, True])
def test_numba_sort_matches_the_trainers_projection(accelerated):
    model = synthetic_model(3000, seed=3, speed=0.5)
    if accelerated:  # the keys follow the accelerations as the model's slice does
        g = torch.Generator().manual_seed(1)
        model = replace(model, accelerations=3.0 * torch.randn(len(model), 3, generator=g, dtype=model.means.dtype))
    splats = to_arrays(model)
    for t in (0.0, 0.37, 1.0):
        cam = orbit(15, 40 + 100 * t, 1.2, fov_deg=60, width=120, height=90)
        fast = depth_order(splats, cam, t)
        order, boxes = reference_order(model, cam, t)
        assert fast.visible > 100
        np.testing.assert_array_equal(np.sort(fast.order), np.sort(order))
        same = fast.order == order  # float32 vs float64 depths may swap near-ties only
        assert same.mean() > 0.99
        np.testing.assert_allclose(fast.boxes[same, :4], boxes[same, :4], rtol=1e-4, atol=5e-3)  # pixels
        # areas and masses go with sqrt(det): float32 packing of near-flat covariances costs a few 1e-4
        np.testing.assert_allclose(fast.boxes[same, 4:], boxes[same, 4:], rtol=2e-3)
        # the all-cores kernel (synchronous sorts) gives the serial one's result bit for bit
        par = depth_order(splats, cam, t, parallel=True)
        np.testing.assert_array_equal(par.order, fast.order)
        np.testing.assert_array_equal(par.boxes, fast.boxes)
        assert par.hideable == fast.hideable


def test_culling_drops_only_invisible_gaussians():
    model = synthetic_model(2000, seed=4, speed=0.3, lifetime=0.1)
    splats = to_arrays(model)
    cam = orbit(10, 30, 1.2, fov_deg=45, width=80, height=80)
    res = depth_order(splats, cam, 0.5)
    g = model.slice(0.5)
    dropped = np.setdiff1d(np.arange(len(model)), res.order)
    # every temporally culled Gaussian is dropped ...
    assert set(np.flatnonzero(~g.visible.numpy())) <= set(dropped.tolist())
    assert res.visible < len(model)
    # ... and each dropped one leaves the image unchanged: rendering only the kept ones gives the same picture
    full = render_image(model, cam, 0.5, RenderSettings(transparent=True))
    kept = render_image(g.select(torch.as_tensor(res.order.astype(np.int64))), cam, 0.5,
                        RenderSettings(transparent=True))
    # float32 slices vs float64 conditioning (Mesa versions differ by a few 1e-5); a wrongly dropped Gaussian would
    # change its pixels by at least its cut-off alpha, 1/255
    np.testing.assert_allclose(kept, full, atol=1e-4)
    # the screen boxes hold every pixel a Gaussian touches: render each of a few alone and look outside its box
    for i in range(0, res.visible, max(1, res.visible // 8)):
        alone = render_image(g.select(torch.tensor([int(res.order[i])])), cam, 0.5, RenderSettings(transparent=True))
        ys, xs = np.nonzero(alone[..., 3] > 0)
        u, v, hx, hy = res.boxes[i, :4]
        assert np.all(np.abs(xs + 0.5 - u) <= hx) and np.all(np.abs(ys + 0.5 - v) <= hy)
        # ... and it is tight: the drawn pixels reach to within ~2 px of it on some side
        assert np.abs(xs + 0.5 - u).max() >= hx - 2.5 or np.abs(ys + 0.5 - v).max() >= hy - 2.5


def test_async_sorter_delivers_the_latest_request():
    splats = to_arrays(synthetic_model(5000, seed=5))
    sorter = AsyncSorter()
    try:
        cams = [orbit(10, a, 1.5, width=64, height=64) for a in (0, 90, 180)]
        for cam in cams:
            sorter.request(splats, cam, 0.5, tag="gen1")
        res = sorter.wait()
        assert res is not None and res.tag == "gen1"
        np.testing.assert_array_equal(res.order, depth_order(splats, cams[-1], 0.5).order)
        assert sorter.poll() is None  # a result is handed out once
    finally:
        sorter.close()


def test_dilogarithm_of_the_optical_mass():
    from scipy.special import spence

    from splatreel.viewer.sorting import _dilog

    for x in (0.0, 1e-3, 0.3, 0.5, 0.5001, 0.8, 0.99):
        assert _dilog(x) == pytest.approx(spence(1.0 - x), abs=2e-6), x



def test_radix_order_is_a_stable_argsort_of_the_finite_keys():
    from splatreel.viewer.sorting import _radix_order

    rng = np.random.default_rng(5)
    keys = np.concatenate([rng.normal(0, 3, 5000), rng.choice([-2.5, 0.0, -0.0, 1.0], 3000),  # many ties
                           [np.inf, -np.inf, np.nan, 1e-40, -1e-40, 3e38, -3e38]]).astype(np.float32)
    rng.shuffle(keys)
    boxes = rng.normal(size=(keys.shape[0], 6)).astype(np.float32)
    order, gathered = _radix_order(keys.view(np.uint32), boxes)
    finite = np.flatnonzero(np.isfinite(keys))
    expected = finite[np.argsort(keys[finite], kind="stable")]
    # -0.0 and 0.0 compare equal in numpy but not as bits: they may only trade places with each other
    zero = keys[expected] == 0
    np.testing.assert_array_equal(order[~zero], expected[~zero])
    np.testing.assert_array_equal(np.sort(order[zero]), np.sort(expected[zero]))
    np.testing.assert_array_equal(gathered, boxes[order])
