"""Inspect: which Gaussians make a pixel (`SplatRenderer.pick`), what one Gaussian is (`pick.describe`), and the
app's Inspect state (Ctrl+click) on a headless renderer."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from splatreel.cameras import look_at, orbit
from splatreel.checkpoint import save_checkpoint
from splatreel.covariance import condition_on_time, visible_span
from splatreel.model import CropBox
from splatreel.viewer.overlay import ellipsoid_segments
from splatreel.viewer.pick import composite_pixel, describe, peak_time
from splatreel.viewer.renderer import RenderSettings, SplatRenderer, headless_context
from splatreel.viewer.synthetic import synthetic_model
from test_model import keyframed
from test_viewer_sort import BLUE, RED, swapping_pair


@pytest.fixture(scope="module")
def ctx():
    return headless_context()


def test_pick_decomposes_the_drawn_pixel(ctx):
    """The picked Gaussians' weights sum to the pixel's alpha in the GL accumulation, and their weighted colours to
    its colour: the pick is what the renderer drew there, Gaussian by Gaussian (native and keyframed models)."""
    cam = orbit(20, 30, 2.0, fov_deg=40, width=96, height=80)
    native = synthetic_model(3000, seed=3, sh_degree=1, radius=0.4, scale=0.03, speed=0.3)
    keyed = keyframed(3, 400)
    keyed_cam = orbit(20, 30, 9.0, fov_deg=40, width=96, height=80)
    for model, camera, t in ((native, cam, 0.4), (keyed, keyed_cam, 0.3)):
        r = SplatRenderer(ctx, model)
        r.render(camera, t, RenderSettings(background=(0.0, 0.0, 0.0)))
        acc = r.read_accumulation()
        covered = 0
        for x, y in ((48, 40), (30, 20), (60, 50), (70, 33), (5, 75), (40, 60)):
            stack = r.pick(camera, t, x, y)
            weights = [h.weight for h in stack.hits]
            assert math.isclose(sum(weights), stack.alpha, abs_tol=1e-9)
            # the reference stops a saturated pixel 1e-4 early; the GL pass drew this view in one stage
            assert abs(stack.alpha - acc[y, x, 3]) < 2e-4, (x, y)
            np.testing.assert_allclose(stack.color, acc[y, x, :3], atol=2e-4)
            if stack.hits:
                covered += 1
                assert stack.top.weight == max(weights)
                assert all(a.depth <= b.depth for a, b in zip(stack.hits, stack.hits[1:]))  # nearest first
        assert covered >= 3  # the pixels were not all background
        r.release()


def test_pick_follows_the_order_at_time_t(ctx):
    """Two Gaussians that swap places over time: the centre pixel's front Gaussian (and largest share) is red at
    t = 0 and blue at t = 1, as drawn."""
    model = swapping_pair()
    cam = look_at((-4.0, 0.0, 0.0), (0.0, 0.0, 0.0), "z", fov_deg=30, width=32, height=32)
    r = SplatRenderer(ctx, model)
    for t, front in ((0.0, RED), (1.0, BLUE)):
        stack = r.pick(cam, t, 16, 16)
        assert [h.index for h in stack.hits][:1] == [front] and stack.top.index == front
        assert stack.top.color[2 * front] > 0.9  # red (0) or blue (2) channel
    # a translucent front Gaussian gives the pixel less than the opaque one behind it
    faint = swapping_pair()
    faint.opacity_logits = torch.tensor([-2.0, 5.0], dtype=torch.float64)  # red: opacity 0.12
    r.set_model(faint)
    stack = r.pick(cam, 0.0, 16, 16)
    assert [h.index for h in stack.hits] == [RED, BLUE] and stack.top.index == BLUE
    assert stack.hits[0].weight < 0.2 < stack.hits[1].weight
    assert not r.pick(cam, 0.0, 0, 0).hits and r.pick(cam, 0.0, 0, 0).top is None  # background
    with pytest.raises(Exception, match="outside"):
        r.pick(cam, 0.0, 32, 5)
    r.release()


def test_composite_stops_where_the_reference_does():
    """Front to back, the Gaussian that would take T below 1e-4 is left out (and all behind it)."""
    rec = np.zeros((4, 16), np.float32)
    rec[:, 0:2] = 10.0  # centres at (10, 10): pixel (10, 10)'s centre (10.5, 10.5) is 0.7 px away
    rec[:, 2] = 3.0
    rec[:, 3] = [1.0, 2.0, 3.0, 4.0]
    rec[:, 4:8] = [100.0, 0.0, 0.0, 100.0]  # huge std-devs: alpha = opacity at the centre
    rec[:, 8:11] = 1.0
    rec[:, 11] = 0.99
    rec[:, 12:16] = [0.0, 0.0, 32.0, 32.0]
    stack = composite_pixel(rec, np.arange(4), (10, 10))
    assert [h.index for h in stack.hits] == [0, 1]  # T: 1 -> 0.01 -> 1e-4 (kept, not below) -> 1e-6 (stopped)
    rec[1, 12:16] = [16.0, 16.0, 32.0, 32.0]  # Gaussian 1's tile rectangle misses the pixel
    assert [h.index for h in composite_pixel(rec, np.arange(4), (10, 10)).hits] == [0, 2]


def test_describe_and_peak_time_read_the_model():
    model = synthetic_model(50, seed=5, sh_degree=1, radius=0.4, scale=0.03, speed=0.3)
    i, t = 7, 0.3
    rows = dict(describe(model, i, t))
    g = model.slice(t)
    pos = [float(v) for v in rows["position"].strip("()").split(",")]
    np.testing.assert_allclose(pos, g.means[i].detach().numpy(), rtol=1e-3, atol=1e-4)
    _, _, var_t = condition_on_time(model.covariance_4d())
    assert rows["drawn for"].startswith(f"{float(visible_span(var_t)[i]):.4g}")
    assert f"at t = {float(model.t_means[i]):.4g}" in rows["peak opacity"]
    assert rows["index"] == "7 of 50"
    t0, t1 = model.time_range
    assert peak_time(model, i) == min(max(float(model.t_means[i]), t0), t1)
    keyed = keyframed(3, 5)
    assert peak_time(keyed, 2) == float(keyed.times[int(keyed.opacities[:, 2].argmax())])
    assert dict(describe(keyed, 2, 0.25))["keyframes"] == "3"


def test_ellipsoid_rings_lie_at_two_sigma():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 3))
    cov = a @ a.T + 0.1 * np.eye(3)
    mean = np.array([1.0, -2.0, 0.5])
    segs = ellipsoid_segments(mean, cov, sigmas=2.0, samples=24)
    assert segs.shape == (72, 2, 3)
    d = segs.reshape(-1, 3) - mean
    mahalanobis = np.sqrt(np.einsum("ij,jk,ik->i", d, np.linalg.inv(cov), d))
    np.testing.assert_allclose(mahalanobis, 2.0, rtol=1e-9)


def test_app_inspects_a_pixel_and_forgets_it_on_crop(tmp_path):
    """The app's Ctrl+click handler: `inspect` fills the panel and the report; the inspected Gaussian's ellipsoid
    and rows follow the time; a crop (new indices) clears it."""
    from splatreel.viewer.state import AppOptions, AppState

    model = synthetic_model(2000, seed=11, sh_degree=1, radius=0.4, scale=0.02, speed=0.3)
    ckpt = save_checkpoint(tmp_path / "m.safetensors", model)
    app = AppState(ckpt, AppOptions(play=False))
    app.renderer = SplatRenderer(headless_context())
    app.load(ckpt)
    cam = orbit(20, 30, 2.0, fov_deg=40, width=64, height=64)
    stack = app.inspect(cam, 0.5, 32, 32)
    top = stack.top
    assert top is not None and app.report["inspected"]["top"]["index"] == top.index
    assert app.report["inspected"]["gaussians"] == len(stack.hits) > 1
    app.playback.time = 0.5
    rows, segs = app._inspected(0.5)
    assert dict(rows)["index"].startswith(f"{top.index:,} of")
    mean = model.slice(0.5).means[top.index].detach().numpy()
    np.testing.assert_allclose(segs.reshape(-1, 3).mean(0), mean, atol=1e-6)  # rings centred on it at t
    later = app._inspected(0.9)[1].reshape(-1, 3).mean(0)
    np.testing.assert_allclose(later, model.slice(0.9).means[top.index].detach().numpy(), atol=1e-6)
    app._inspect.rank = 1  # the next largest share
    assert app._inspect.hit.weight <= top.weight and app._inspect.hit.index != top.index
    app._crop.enabled = True
    app._crop.lo, app._crop.hi = [-0.2] * 3, [0.2] * 3
    app._apply_edits(0.5)
    assert app._inspect.stack is None and app._inspected(0.5) is None
    assert CropBox((-0.2,) * 3, (0.2,) * 3) == app._crop.shown
    app.renderer.release()


def test_surface_depth_is_where_half_the_pixel_is_accumulated():
    from splatreel.viewer.pick import PixelHit, PixelStack

    hits = tuple(PixelHit(i, 0.5, w, d, (1.0, 1.0, 1.0)) for i, (w, d) in enumerate([(0.1, 1.0), (0.3, 2.0),
                                                                                      (0.5, 3.0)]))
    assert PixelStack((0, 0), hits, 0.9, (0.9, 0.9, 0.9)).surface_depth == 3.0  # 0.1 + 0.3 < 0.45 <= 0.9
    assert PixelStack((0, 0), hits[:2], 0.4, (0.4,) * 3).surface_depth == 2.0  # translucent: half of its 0.4
    assert PixelStack((0, 0), (), 0.0, (0.0,) * 3).surface_depth is None


def test_app_measures_the_distance_between_two_surfaces(tmp_path):
    """Alt+click twice (`AppState.measure`): two small opaque blobs at known places, clicked at the pixels their
    centres project to, are measured at their true distance (to the half-pixel the click is rounded to); a third
    click starts again; the background is a one-line error."""
    from splatreel.model import static_gaussians4d
    from splatreel.viewer.state import AppOptions, AppState

    ends = np.array([[-0.5, 0.0, 0.1], [0.6, 0.8, -0.3]])
    model = static_gaussians4d(torch.tensor(ends), torch.full((2, 3), 0.04, dtype=torch.float64),
                               torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=torch.float64),
                               torch.full((2,), 0.99, dtype=torch.float64), torch.ones(2, 3, dtype=torch.float64))
    ckpt = save_checkpoint(tmp_path / "two.safetensors", model)
    app = AppState(ckpt, AppOptions(play=False))
    app.renderer = SplatRenderer(headless_context())
    app.load(str(ckpt))
    cam = look_at((0.0, -4.0, 0.0), (0.0, 0.0, 0.0), "z", fov_deg=40, width=128, height=128)
    uv, z = cam.project(ends)
    pixel = z[0] / cam.fx  # world size of a pixel at that depth
    first = app.measure(cam, 0.5, int(uv[0, 0]), int(uv[0, 1]))
    assert np.linalg.norm(first - ends[0]) < pixel and app._measure.distance is None
    second = app.measure(cam, 0.5, int(uv[1, 0]), int(uv[1, 1]))
    assert np.linalg.norm(second - ends[1]) < pixel
    true = float(np.linalg.norm(ends[1] - ends[0]))
    assert abs(app._measure.distance - true) < 2 * pixel
    # exactly: each end is the pick's surface depth unprojected through its pixel's centre
    for (x, y), point in zip(uv.astype(int), (first, second)):
        depth = app.renderer.pick(cam, 0.5, int(x), int(y), app.settings).surface_depth
        np.testing.assert_allclose(point, cam.unproject([[x + 0.5, y + 0.5]], [depth])[0], atol=1e-9)
    assert app._measure.distance == pytest.approx(float(np.linalg.norm(second - first)), abs=1e-12)
    assert app.report["measured"]["distance"] == app._measure.distance
    assert app._measure_lines(cam).shape == (3 * 2 + 1, 2, 3)  # two crosses and the tape
    app.measure(cam, 0.5, int(uv[0, 0]), int(uv[0, 1]))
    assert len(app._measure.points) == 1
    assert not app._attempt(lambda: app.measure(cam, 0.5, 0, 0)) and "no surface" in app.status
    app.renderer.release()
