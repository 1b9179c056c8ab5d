"""Gaussians4D slicing against a brute-force float64 numpy conditional, and KeyframedGaussians interpolation."""

import math

import numpy as np
import pytest
import torch

from splatreel import covariance, quaternion
from splatreel.constants import TEMPORAL_CULL
from splatreel.errors import ModelError
from splatreel.model import Gaussians4D, KeyframedGaussians, model_bounds, static_gaussians4d, take_rows


def hamilton(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def rotation_4d_bruteforce(ql, qr, convention):
    """R4 by applying v -> ql ⊗ v ⊗ conj(qr) to the basis vectors (no matrix formulas)."""
    ql, qr = ql / np.linalg.norm(ql), qr / np.linalg.norm(qr)
    conj = qr * np.array([1, -1, -1, -1])
    a = np.stack([hamilton(hamilton(ql, e), conj) for e in np.eye(4)], 1)
    if convention == "current":  # time is the quaternion's scalar part: reverse (x,y,z,t) <-> (t,z,y,x)
        p = np.eye(4)[::-1]
        a = p @ a @ p
    return a


def random_model(n, convention, dtype=torch.float64, sh_degree=1, sh_degree_t=1, seed=0):
    g = torch.Generator().manual_seed(seed)
    m = (sh_degree + 1) ** 2 * (sh_degree_t + 1)
    r = lambda *s: torch.randn(*s, generator=g, dtype=dtype)  # noqa: E731
    return Gaussians4D(
        means=r(n, 3), t_means=torch.rand(n, generator=g, dtype=dtype), log_scales=r(n, 3) * 0.5 - 1.0,
        log_t_scales=r(n) * 0.3 - 1.0, quats_l=r(n, 4), quats_r=r(n, 4), opacity_logits=r(n),
        sh_dc=r(n, 1, 3), sh_rest=r(n, m - 1, 3) * 0.1, sh_degree=sh_degree, sh_degree_t=sh_degree_t,
        time_range=(0.0, 1.0), rotation_convention=convention)


@pytest.mark.parametrize("convention", ["current", "legacy"])
def test_slice_matches_bruteforce_conditional(convention):
    model = random_model(64, convention)
    for t in (0.0, 0.37, 1.3):
        g = model.slice(t)
        for i in range(len(model)):
            r4 = rotation_4d_bruteforce(model.quats_l[i].numpy(), model.quats_r[i].numpy(), convention)
            s = np.exp(np.concatenate([model.log_scales[i].numpy(), [model.log_t_scales[i].item()]]))
            sigma = r4 @ np.diag(s ** 2) @ r4.T
            mu = np.concatenate([model.means[i].numpy(), [model.t_means[i].item()]])
            # Gaussian conditioning on the last coordinate
            s11, s12, s22 = sigma[:3, :3], sigma[:3, 3:], sigma[3:, 3:]
            mean_t = mu[:3] + (s12 @ np.linalg.solve(s22, [[t - mu[3]]]))[:, 0]
            cov_t = s11 - s12 @ np.linalg.solve(s22, s12.T)
            marginal = math.exp(-0.5 * (t - mu[3]) ** 2 / s22[0, 0])
            opacity = 1 / (1 + math.exp(-model.opacity_logits[i].item())) * marginal
            np.testing.assert_allclose(g.means[i].numpy(), mean_t, rtol=1e-9, atol=1e-10)
            np.testing.assert_allclose(g.covariances[i].numpy(), cov_t, rtol=1e-9, atol=1e-12)
            assert g.opacities[i].item() == pytest.approx(opacity, rel=1e-9, abs=1e-300)
            assert bool(g.visible[i]) == (marginal > TEMPORAL_CULL)


def test_equal_quaternions_are_static_under_current_convention():
    model = random_model(32, "current")
    model.quats_r = model.quats_l.clone()
    a, b = model.slice(0.0), model.slice(0.9)
    torch.testing.assert_close(a.means, model.means, rtol=0, atol=1e-12)
    torch.testing.assert_close(b.means, model.means, rtol=0, atol=1e-12)
    torch.testing.assert_close(a.covariances, b.covariances)
    assert float(a.velocities.abs().max()) < 1e-12
    # ... but not under legacy, where q_l == q_r fixes the x axis instead
    legacy = random_model(32, "legacy")
    legacy.quats_r = legacy.quats_l.clone()
    r4 = covariance.rotation_4d(legacy.quats_l, legacy.quats_r, "legacy")
    torch.testing.assert_close(r4[:, :, 0], torch.tensor([1.0, 0, 0, 0], dtype=r4.dtype).expand(32, 4))
    assert float(legacy.slice(0.9).velocities.abs().max()) > 1e-3


def test_temporal_factor_is_unnormalized_gaussian_of_sigma_tt():
    model = random_model(16, "current")
    var_t = model.covariance_4d()[:, 3, 3]
    for t in (0.1, 0.5, 0.8):
        g = model.slice(t)
        expected = torch.sigmoid(model.opacity_logits) * torch.exp(-0.5 * (t - model.t_means) ** 2 / var_t)
        torch.testing.assert_close(g.opacities, expected)
    # far from mu_t everything is culled by the 0.05 threshold
    assert not model.slice(1e3).visible.any()


def test_drawn_in_clip_is_whether_some_slice_of_the_time_range_draws_the_gaussian():
    model = random_model(400, "current", dtype=torch.float32)
    model.t_means.data = torch.linspace(-1.0, 2.0, 400)  # before, inside and after the clip (0, 1)
    drawn = model.drawn_in_clip()
    assert 0 < int(drawn.sum()) < 400
    seen = torch.zeros(400, dtype=torch.bool)
    for t in torch.linspace(0.0, 1.0, 2001).tolist():
        seen |= model.slice(t).visible
    # the rule holds at the clip's ends exactly; between samples a Gaussian drawn for less than 1/2000 may slip
    assert not (seen & ~drawn).any()
    assert int((drawn & ~seen).sum()) <= 2


def test_rotation_4d_inverse_and_decomposition_roundtrip():
    for conv in ("current", "legacy"):
        m = random_model(50, conv)
        r4 = covariance.rotation_4d(m.quats_l, m.quats_r, conv)
        ql, qr = covariance.quaternions_from_rotation_4d(r4, conv)
        torch.testing.assert_close(covariance.rotation_4d(ql, qr, conv), r4)
        cov = m.covariance_4d()
        s, st, ql, qr = covariance.decompose_covariance_4d(cov, conv)
        torch.testing.assert_close(covariance.covariance_4d(s, st, ql, qr, conv), cov)
        cov3, vel, var_t = covariance.condition_on_time(cov)
        torch.testing.assert_close(covariance.covariance_4d_from_motion(cov3, vel, var_t), cov)


def test_slice_is_differentiable_wrt_every_parameter():
    model = random_model(8, "current")
    for k, v in model.tensors().items():
        v.requires_grad_(True)
    g = model.slice(0.4)
    loss = g.means.sum() + g.covariances.sum() + g.opacities.sum() + g.colors(torch.zeros(3)).sum()
    loss.backward()
    for k, v in model.tensors().items():
        assert v.grad is not None and torch.isfinite(v.grad).all() and v.grad.abs().sum() > 0, k


def test_static_gaussians_keep_their_3d_covariance():
    n = 20
    q = quaternion.normalize(torch.randn(n, 4, dtype=torch.float64))
    s = torch.rand(n, 3, dtype=torch.float64) + 0.05
    g = static_gaussians4d(torch.randn(n, 3, dtype=torch.float64), s, q, torch.full((n,), 0.7, dtype=torch.float64),
                           torch.rand(n, 3, dtype=torch.float64))
    sl = g.slice(0.25)
    torch.testing.assert_close(sl.covariances, covariance.covariance_3d(s, q))
    torch.testing.assert_close(sl.opacities, torch.full((n,), 0.7, dtype=torch.float64), atol=1e-6, rtol=0)


def test_model_validation_names_the_bad_tensor():
    m = random_model(4, "current")
    with pytest.raises(ModelError, match="sh_rest"):
        Gaussians4D(**{**m.tensors(), "sh_rest": torch.zeros(4, 2, 3, dtype=torch.float64)}, sh_degree=1,
                    sh_degree_t=1)
    with pytest.raises(ModelError, match="time_range"):
        Gaussians4D(**m.tensors(), sh_degree=1, sh_degree_t=1, time_range=(1.0, 1.0))
    with pytest.raises(ValueError, match="convention"):
        Gaussians4D(**m.tensors(), sh_degree=1, sh_degree_t=1, rotation_convention="sideways")


def keyframed(f=3, n=5):
    g = torch.Generator().manual_seed(1)
    times = torch.tensor([0.0, 0.5, 2.0])[:f]
    return KeyframedGaussians(
        times=times, means=torch.randn(f, n, 3, generator=g), quats=quaternion.normalize(torch.randn(f, n, 4, generator=g)),
        scales=torch.rand(f, n, 3, generator=g) + 0.1, opacities=torch.rand(f, n, generator=g),
        sh=torch.randn(f, n, 4, 3, generator=g), sh_degree=1)


def test_keyframed_slice_hits_keys_and_interpolates():
    k = keyframed()
    for i, t in enumerate(k.times.tolist()):
        g = k.slice(t)
        torch.testing.assert_close(g.means, k.means[i])
        torch.testing.assert_close(g.opacities, k.opacities[i])
        torch.testing.assert_close(g.covariances, covariance.covariance_3d(k.scales[i], k.quats[i]))
    g = k.slice(0.25)  # halfway between keys 0 and 1
    torch.testing.assert_close(g.means, 0.5 * (k.means[0] + k.means[1]))
    torch.testing.assert_close(g.sh, 0.5 * (k.sh[0] + k.sh[1]))
    q = quaternion.slerp(k.quats[0], k.quats[1], 0.5)
    torch.testing.assert_close(g.quats, q)
    # slerp halfway: equal angle to both keys
    d0 = (g.quats * k.quats[0]).sum(-1).abs()
    d1 = (g.quats * k.quats[1]).sum(-1).abs()
    torch.testing.assert_close(d0, d1, atol=1e-5, rtol=0)
    torch.testing.assert_close(g.velocities, (k.means[1] - k.means[0]) / 0.5)
    # outside the range the end keys hold
    torch.testing.assert_close(k.slice(-5.0).means, k.means[0])
    torch.testing.assert_close(k.slice(9.0).means, k.means[2])
    lo, hi = model_bounds(k)
    assert (lo <= k.means.min(0).values.min(0).values + 1e-6).all()


def test_keyframed_rejects_unsorted_times():
    k = keyframed()
    with pytest.raises(ModelError, match="increasing"):
        KeyframedGaussians(**{**k.tensors(), "times": torch.tensor([0.0, 2.0, 1.0])}, sh_degree=1)


def test_centres_are_the_slices_means_and_visibility():
    """`centres` (what bounds and framing use) skips covariances and colours but must agree with `slice` exactly,
    for native 4D (including Gaussians culled by the temporal marginal) and keyframed models."""
    model = random_model(200, "current")
    times = [-0.5, 0.0, 0.37, 1.0, 2.5]
    for (means, visible), t in zip(model.centres(times), times):
        g = model.slice(t)
        torch.testing.assert_close(means, g.means, rtol=0, atol=0)
        assert torch.equal(visible, g.visible)
    assert not model.centres([40.0])[0][1].all()  # far outside: some are culled, so visibility is really tested
    k = keyframed()
    k_times = [-1.0, 0.25, 0.5, 0.8, 3.0]
    for (means, visible), t in zip(k.centres(k_times), k_times):
        g = k.slice(t)
        torch.testing.assert_close(means, g.means, rtol=0, atol=0)
        assert torch.equal(visible, g.visible)


def test_crop_keeps_the_gaussians_anchored_in_the_box_and_slices_like_the_whole():
    """A native model's anchor is its spatial mean (the position at mu_t); a keyframed one's is its mean at the
    key where it is most opaque. The cropped model is the same Gaussians, so every slice is the whole model's
    slice restricted to them, at every time."""
    from splatreel.model import CropBox, crop

    model = random_model(300, "current")
    box = CropBox((-0.5, -1.0, -0.8), (1.0, 0.6, 0.9))
    inside = ((model.means >= torch.tensor(box.lo, dtype=torch.float64))
              & (model.means <= torch.tensor(box.hi, dtype=torch.float64))).all(-1)
    assert 0 < int(inside.sum()) < 300
    cropped = crop(model, box)
    assert len(cropped) == int(inside.sum()) and cropped.time_range == model.time_range
    for t in (0.0, 0.4, 1.3):
        whole, part = model.slice(t), cropped.slice(t)
        torch.testing.assert_close(part.means, whole.means[inside], rtol=0, atol=0)
        torch.testing.assert_close(part.opacities, whole.opacities[inside], rtol=0, atol=0)
        torch.testing.assert_close(part.sh, whole.sh[inside], rtol=0, atol=0)
    k = keyframed(n=40)  # 3 keys of 40 Gaussians with random opacities
    peak = k.opacities.argmax(0)
    torch.testing.assert_close(k.anchors(), torch.stack([k.means[peak[i], i] for i in range(len(k))]))
    kbox = CropBox.of([-1, -1, -1, 1, 1, 1])
    kin = kbox.contains(k.anchors())
    kc = crop(k, kbox)
    assert 0 < len(kc) == int(kin.sum()) < len(k) and torch.equal(kc.times, k.times)
    torch.testing.assert_close(kc.slice(0.25).means, k.slice(0.25).means[kin], rtol=0, atol=0)
    assert len(crop(model, CropBox((9, 9, 9), (9, 9, 9)))) == 0  # an empty crop is a valid (empty) model
    with pytest.raises(ModelError, match="holds none of the 300 Gaussians"):
        crop(model, CropBox((9, 9, 9), (9, 9, 9)), require_any=True)


@pytest.mark.parametrize("values, message", [
    ([0, 0, 0, 1, 1], "6 numbers"),
    ([0, 0, 0, -1, 1, 1], "min <= max on every axis"),
    ([0, 0, 0, float("nan"), 1, 1], "finite"),
])
def test_crop_box_errors(values, message):
    from splatreel.model import CropBox

    with pytest.raises(ModelError, match=message):
        CropBox.of(values)


def accelerated(model: Gaussians4D, scale: float = 1.0, seed: int = 5) -> Gaussians4D:
    """`model` with random accelerations."""
    from dataclasses import replace

    g = torch.Generator().manual_seed(seed)
    return replace(model, accelerations=scale * torch.randn(len(model), 3, generator=g, dtype=model.means.dtype))


def test_accelerations_bend_the_path_and_nothing_else():
    linear = random_model(64, "current")
    model = accelerated(linear)
    a = model.accelerations
    for t in (0.0, 0.37, 1.3):
        tau = (t - model.t_means)[:, None]
        g, lin = model.slice(t), linear.slice(t)
        torch.testing.assert_close(g.means, lin.means + 0.5 * a * tau ** 2)
        torch.testing.assert_close(g.velocities, lin.velocities + a * tau)
        for name in ("covariances", "opacities", "sh", "visible"):
            torch.testing.assert_close(getattr(g, name), getattr(lin, name), msg=name)
        # the fused float32 kernel, a few rows, and the centres agree with the float64 composition
        rows = torch.arange(0, 64, 3)
        g32 = model.to(dtype=torch.float32).slice(t, rows=rows)
        torch.testing.assert_close(g32.means.double(), g.means[rows], rtol=1e-4, atol=1e-4)
        means, visible = model.centres([t])[0]
        torch.testing.assert_close(means, g.means)
    # at its own temporal mean a Gaussian sits where the linear model has it
    i = 7
    torch.testing.assert_close(model.slice(float(model.t_means[i])).means[i],
                               linear.slice(float(model.t_means[i])).means[i])


def test_accelerations_are_validated_selected_and_differentiable():
    model = accelerated(random_model(16, "current"))
    assert set(model.tensors()) == set(Gaussians4D.TENSORS) | {"accelerations"}
    assert "accelerations" not in random_model(4, "current").tensors()
    assert model.select(torch.arange(5)).accelerations.shape == (5, 3)
    from dataclasses import replace

    with pytest.raises(ModelError, match="accelerations has shape"):
        replace(model, accelerations=torch.zeros(3, 3, dtype=torch.float64))
    a = model.accelerations.float().clone().requires_grad_(True)
    replace(model.to(dtype=torch.float32), accelerations=a).slice(0.9).means.sum().backward()
    assert a.grad is not None and a.grad.abs().sum() > 0


def test_take_rows_gathers_like_indexing_with_the_same_gradient():
    x = torch.randn(10, 3, dtype=torch.float64, requires_grad=True)
    rows = torch.tensor([7, 2, 2, 9])  # a repeated row gets both gradients
    weights = torch.randn(4, 3, dtype=torch.float64)
    grads = []
    for gather in (take_rows, lambda v, r: v[r]):
        x.grad = None
        out = gather(x, rows)
        (out * weights).sum().backward()
        grads.append((out.detach(), x.grad.clone()))
    assert torch.equal(grads[0][0], grads[1][0]) and torch.allclose(grads[0][1], grads[1][1])
    mask = torch.zeros(10, dtype=torch.bool)
    mask[[1, 4]] = True
    assert torch.equal(take_rows(x, mask), x[mask])
