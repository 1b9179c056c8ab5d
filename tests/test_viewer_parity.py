"""The offscreen GL image agrees with the trainer's rasterizer (PSNR >= 40 dB) for the same checkpoint, camera and
time: native 4D models in both rotation conventions and with SH time terms, the bundled sample, keyframed models,
an off-centre principal point, and both blending orders."""

from __future__ import annotations


import numpy as np
import pytest
import torch

from splatreel.cameras import Camera, look_at_c2w, orbit
from splatreel.checkpoint import load_checkpoint, save_checkpoint
from splatreel.errors import GLError
from splatreel.model import KeyframedGaussians
from splatreel.samples import trained_checkpoint
from splatreel.train import losses
from splatreel.rasterize import rasterize
from splatreel.viewer.renderer import RenderSettings, SplatRenderer, headless_context
from splatreel.viewer.synthetic import synthetic_model

MIN_PSNR = 40.0


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """`splatreel.train.losses.psnr` (the project's one PSNR) on numpy images."""
    return losses.psnr(torch.from_numpy(np.asarray(a, np.float64)), torch.from_numpy(np.asarray(b, np.float64)))


def keyframed(source, times) -> KeyframedGaussians:
    """`source` (a native model) baked into keyframes at `times`, as the deformation importers do."""
    times = torch.tensor(times)
    slices = [source.slice(float(t)) for t in times]
    sq = [g.scales_quats() for g in slices]
    return KeyframedGaussians(
        times=times, means=torch.stack([g.means for g in slices]), quats=torch.stack([q for _, q in sq]),
        scales=torch.stack([s for s, _ in sq]), opacities=torch.stack([g.opacities for g in slices]),
        sh=torch.stack([g.sh for g in slices]), sh_degree=source.sh_degree)


def value_images(model, camera, t, mode: str, values: torch.Tensor):
    """A value mode against the rasterizer: (the GL accumulation ``[H, W, 4]``, the frame's `FrameStats`, the
    rasterizer's red channel of ``model.slice(t)`` with every Gaussian's colour set to its entry of `values`)."""
    from dataclasses import replace

    from splatreel.sh import SH_C0

    r = SplatRenderer(headless_context(), model)
    try:
        stats = r.render(camera, t, RenderSettings(mode=mode))
        acc = r.read_accumulation()
    finally:
        r.release()
    g = model.slice(t)
    as_colour = replace(g, sh=((values.to(g.sh.dtype) - 0.5) / SH_C0)[:, None, None].expand(-1, 1, 3).clone(),
                        sh_degree=0)
    with torch.no_grad():
        ref = rasterize(as_colour, camera, (0.0, 0.0, 0.0)).rgb[..., 0].numpy()
    return acc, stats, ref


def compare(model, camera, t, background=(0.1, 0.2, 0.3), composite="front-to-back", primitive="auto"):
    """(PSNR of rgb, max alpha error) between the GL renderer and the trainer's rasterizer."""
    r = SplatRenderer(headless_context(), model)
    try:
        r.render(camera, t, RenderSettings(background=background, composite=composite, primitive=primitive))
        gl = r.read_display()[..., :3]
        gl_alpha = r.read_accumulation()[..., 3]
    finally:
        r.release()
    with torch.no_grad():
        ref = rasterize(model.slice(t), camera, background)
    return psnr(gl, ref.rgb.numpy()), float(np.abs(gl_alpha - ref.alpha.numpy()).max())


@pytest.mark.parametrize("convention, degree, degree_t", [("current", 3, 2), ("legacy", 1, 1), ("current", 0, 0)])
def test_gl_matches_rasterizer_for_a_checkpoint(tmp_path, convention, degree, degree_t):
    model = synthetic_model(6000, seed=7, sh_degree=degree, sh_degree_t=degree_t, convention=convention,
                            radius=0.45, scale=0.015, speed=0.4)
    path = save_checkpoint(tmp_path / "m.safetensors", model)
    loaded = load_checkpoint(path).model
    # off-centre principal point and non-square pixels
    camera = Camera(look_at_c2w((1.3, 1.0, 0.6), (0.0, 0.0, 0.0), "z"), 150.0, 140.0, 70.0, 66.0, 160, 120)
    for t in (0.15, 0.6):
        value, alpha_err = compare(loaded, camera, t)
        assert value >= MIN_PSNR, (t, value)
        assert alpha_err < 0.02


def test_gl_matches_rasterizer_for_the_bundled_sample():
    model = load_checkpoint(trained_checkpoint("spinner")).model  # 50k trained Gaussians
    for t, az in ((0.3, 40.0), (0.85, 200.0)):
        camera = orbit(25, az, 2.6, fov_deg=40, width=128, height=128)
        for composite, primitive in (("front-to-back", "auto"), ("back-to-front", "points"),
                                     ("front-to-back", "quads")):
            value, _ = compare(model, camera, t, background=(1.0, 1.0, 1.0), composite=composite,
                               primitive=primitive)
            assert value >= MIN_PSNR, (t, composite, primitive, value)


def test_gl_matches_rasterizer_for_a_keyframed_model():
    model = keyframed(synthetic_model(3000, seed=8, sh_degree=1, radius=0.4, scale=0.02), (0.0, 0.4, 1.0))
    camera = orbit(15, 75, 1.7, fov_deg=45, width=96, height=96)
    for t in (0.2, 0.7):
        value, _ = compare(model, camera, t)
        assert value >= MIN_PSNR, (t, value)


def test_speed_mode_accumulates_each_gaussians_speed_like_the_rasterizer_composites_colour():
    """The speed mode composites |d mean / dt| in place of colour: the GL accumulation equals the rasterizer's image
    of the same slice with every Gaussian's colour set to its speed (`Gaussians3D.velocities`), for a native model
    (conditional-mean velocity, with the accelerations' term at t when it has them) and a keyframed one (its key
    segment's velocity)."""
    from dataclasses import replace

    from splatreel.viewer.splats import to_arrays, typical_speed

    native = synthetic_model(3000, seed=5, sh_degree=1, radius=0.4, scale=0.02, speed=0.5)
    keyed = keyframed(native, (0.0, 0.5, 1.0))
    g = torch.Generator().manual_seed(3)
    accelerated = replace(native, accelerations=4.0 * torch.randn(len(native), 3, generator=g,
                                                                  dtype=native.means.dtype))
    camera = orbit(20, 60, 1.6, fov_deg=45, width=96, height=96)
    for model, t in ((native, 0.3), (keyed, 0.7), (accelerated, 0.8)):
        speed = torch.linalg.vector_norm(model.slice(t).velocities, dim=-1)
        assert float(speed.max()) > 0.1 and float(speed.min()) < float(speed.max()) / 2
        acc, stats, ref = value_images(model, camera, t, "speed", speed)
        top = float(speed.max())
        assert ref.max() > 0.2 * top  # the image is not empty
        assert psnr(acc[..., 0] / top, ref / top) >= MIN_PSNR
        # the colour map runs from 0 to the model-wide typical speed (the same at every time)
        assert stats.value_range == (0.0, typical_speed(model, to_arrays(model, t)))


def test_point_and_quad_splats_agree_at_the_image_edges_and_large_splats_fall_back_to_quads():
    """Points are clipped by their centre and limited in size: splats centred off-screen must still reach in, and
    splats larger than the largest point must come out right with "auto" (drawn as quads)."""
    model = synthetic_model(1500, seed=12, radius=0.5, scale=0.03, speed=0.2, sh_degree=0)
    # the cloud's centre sits near the image's top-left corner: many centres are outside the image
    edge = Camera(look_at_c2w((1.6, 0.4, 0.5), (0.0, 0.0, 0.0), "z"), 110.0, 110.0, 6.0, 4.0, 120, 90)
    images = {}
    for primitive in ("points", "quads"):
        value, _ = compare(model, edge, 0.4, primitive=primitive)
        assert value >= MIN_PSNR, (primitive, value)
        r = SplatRenderer(headless_context(), model)
        r.render(edge, 0.4, RenderSettings(primitive=primitive, transparent=True))
        images[primitive] = r.read_display()
        r.release()
    assert images["points"][..., 3].max() > 0.5
    np.testing.assert_allclose(images["points"], images["quads"], atol=2e-3)

    # with a small point limit, the larger splats of a batch are drawn as quads in runs between point runs
    mixed = synthetic_model(800, seed=14, radius=0.4, scale=0.01, speed=0.1, sh_degree=0)
    with torch.no_grad():
        mixed.log_scales[:4] += 2.0  # four large Gaussians among small ones
    cam = orbit(20, 30, 1.6, fov_deg=50, width=128, height=128)
    r = SplatRenderer(headless_context(), mixed)
    r._max_point = 32.0  # stands in for a context whose points are small (real limits: 255 llvmpipe, ~2k GPUs)
    runs = []
    splat_runs = r._splat_runs
    r._splat_runs = lambda *a: runs.append(splat_runs(*a)) or runs[-1]
    try:
        r.render(cam, 0.5, RenderSettings(transparent=True))
        got = r.read_display()
        kinds = {kind for batch in runs for _, _, kind in batch}
        assert kinds == {"points", "quads"}, runs
        r.render(cam, 0.5, RenderSettings(transparent=True, primitive="quads"))
        np.testing.assert_allclose(got, r.read_display(), atol=2e-3)
        with pytest.raises(GLError, match="do not fit"):
            r.render(cam, 0.5, RenderSettings(primitive="points"))
    finally:
        r.release()
    value, _ = compare(mixed, cam, 0.5)
    assert value >= MIN_PSNR


def test_splat_runs_follow_the_cost_model():
    r = SplatRenderer(headless_context(), synthetic_model(10, seed=1))
    r.render(orbit(20, 30, 1.6, width=64, height=64), 0.5)  # sets the targets
    auto = RenderSettings()
    try:
        def boxes(half_w, half_h, area):
            b = np.zeros((len(half_w), 6), np.float32)
            b[:, 2], b[:, 3], b[:, 4] = half_w, half_h, area
            return b

        small_round = boxes([3.0] * 4, [3.0] * 4, [20.0] * 4)  # 5 px squares: points
        assert r._splat_runs(auto, small_round) == [(0, 4, "points")]
        long_thin = boxes([40.0] * 4, [3.0] * 4, [60.0] * 4)  # 79 px squares for 60 px of quad: quads
        assert r._splat_runs(auto, long_thin) == [(0, 4, "quads")]
        one_huge = boxes([3.0, 3.0, 500.0, 3.0], [3.0] * 4, [20.0, 20.0, 9e5, 20.0])  # beyond the point limit
        assert r._splat_runs(auto, one_huge) == [(0, 2, "points"), (2, 3, "quads"), (3, 4, "points")]
        near_limit = boxes([100.0], [100.0], [39500.0])  # 199 px: fits, but not with a stale order's headroom
        assert r._splat_runs(auto, near_limit)[0][2] == "points"
        assert r._splat_runs(auto, near_limit, stale=True)[0][2] == "quads"
        assert r._splat_runs(RenderSettings(mode="outlines"), small_round) == [(0, 4, "overlay")]
        assert r._splat_runs(RenderSettings(primitive="quads"), small_round) == [(0, 4, "quads")]
    finally:
        r.release()


def test_lifespan_mode_accumulates_each_gaussians_visible_span_capped_at_the_time_range():
    """The lifespan mode composites how long each Gaussian is drawn (`covariance.visible_span`: where its temporal
    marginal exceeds the cull), capped at the model's time span, like the rasterizer composites that value as
    colour; the colour map runs from 0 to the time span. A keyframed model stores no lifespans: all read as the
    whole span."""
    from splatreel.covariance import condition_on_time, visible_span

    model = synthetic_model(4000, seed=6, sh_degree=1, radius=0.4, scale=0.02, speed=0.3, lifetime=0.08)
    camera = orbit(20, 40, 1.6, fov_deg=45, width=96, height=96)
    t0, t1 = model.time_range
    with torch.no_grad():
        _, _, var_t = condition_on_time(model.covariance_4d())
        span = torch.clamp(visible_span(var_t), max=t1 - t0).float()
    assert float(span.min()) < 0.5 * float(span.max())  # the spans differ, so the test sees them
    for t in (0.35, 0.6):
        acc, stats, ref = value_images(model, camera, t, "lifespan", span)
        assert ref.max() > 0.1 * (t1 - t0)
        assert psnr(acc[..., 0] / (t1 - t0), ref / (t1 - t0)) >= MIN_PSNR
        assert stats.value_range == (0.0, t1 - t0)
    keyed = keyframed(model, (0.0, 0.5, 1.0))
    acc, _, _ = value_images(keyed, camera, 0.5, "lifespan", torch.full((len(keyed),), t1 - t0))
    covered = acc[..., 3] > 0.05
    assert covered.any() and np.allclose(acc[..., 0][covered] / acc[..., 3][covered], t1 - t0, rtol=1e-3)


def test_fade_mode_accumulates_each_gaussians_temporal_opacity_factor():
    """The fade mode composites each Gaussian's temporal marginal at t (the factor on its opacity: 1 at its temporal
    peak, down to the 0.05 cull), like the rasterizer composites that value as colour; the map runs from 0 to 1.
    A keyframed model does not fade: all read 1."""
    from splatreel.covariance import condition_on_time, temporal_marginal

    model = synthetic_model(4000, seed=7, sh_degree=1, radius=0.4, scale=0.02, speed=0.3, lifetime=0.15)
    camera = orbit(20, 40, 1.6, fov_deg=45, width=96, height=96)
    with torch.no_grad():
        _, _, var_t = condition_on_time(model.covariance_4d())
    for t in (0.35, 0.6):
        with torch.no_grad():
            factor = temporal_marginal(t, model.t_means, var_t).float()
        acc, stats, ref = value_images(model, camera, t, "fade", factor)
        covered = acc[..., 3] > 0.05
        mean_factor = acc[..., 0][covered] / acc[..., 3][covered]
        assert mean_factor.min() < 0.5 < mean_factor.max()  # fading and peaking Gaussians both in view
        assert psnr(acc[..., 0], ref) >= MIN_PSNR
        assert stats.value_range == (0.0, 1.0)
    keyed = keyframed(model, (0.0, 0.5, 1.0))
    acc, _, _ = value_images(keyed, camera, 0.5, "fade", torch.ones(len(keyed)))
    covered = acc[..., 3] > 0.05
    assert covered.any() and np.allclose(acc[..., 0][covered] / acc[..., 3][covered], 1.0, rtol=1e-3)


def test_gl_moves_gaussians_with_their_accelerations_as_the_rasterizer_does():
    from dataclasses import replace

    linear = synthetic_model(6000, seed=3, radius=0.45, scale=0.015, speed=0.4)
    g = torch.Generator().manual_seed(0)
    model = replace(linear, accelerations=4.0 * torch.randn(len(linear), 3, generator=g, dtype=linear.means.dtype))
    camera = Camera(look_at_c2w((1.3, 1.0, 0.6), (0.0, 0.0, 0.0), "z"), 150.0, 140.0, 70.0, 66.0, 160, 120)
    for t in (0.15, 0.6):
        value, alpha_err = compare(model, camera, t)
        assert value >= MIN_PSNR, (t, value)
        assert alpha_err < 0.02
        with torch.no_grad():  # the accelerations move the image: a renderer ignoring them would fail above
            moved = rasterize(model.slice(t), camera, (0.1, 0.2, 0.3)).rgb.numpy()
            still = rasterize(linear.slice(t), camera, (0.1, 0.2, 0.3)).rgb.numpy()
        assert psnr(moved, still) < MIN_PSNR - 10, t
