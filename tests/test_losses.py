"""The training loss over the box where a render or its target differs from the background equals the whole image's."""

import torch

from splatreel.train.losses import SSIM_REACH, dssim, image_loss, l1, loss_window


def _object_image(h, w, box, seed, background=1.0):
    """(rgb ``[h, w, 3]`` on `background`, alpha ``[h, w]``): random colour and alpha inside `box`, nothing outside."""
    g = torch.Generator().manual_seed(seed)
    alpha = torch.zeros(h, w)
    r0, r1, c0, c1 = box
    alpha[r0:r1, c0:c1] = torch.rand(r1 - r0, c1 - c0, generator=g) * 0.9 + 0.1
    colour = torch.rand(h, w, 3, generator=g)
    return colour * alpha[..., None] + background * (1 - alpha[..., None]), alpha


def _full_loss(rgb, alpha, target, mask, weights):
    """What the trainer computed before the window: every term over the whole image."""
    return (0.8 * l1(rgb, target, weights[0]) + 0.2 * dssim(rgb, target, weights[1])
            + 0.1 * l1(alpha, mask, weights[2]))


def test_window_covers_both_alphas_grown_by_the_ssim_reach():
    a, b = torch.zeros(64, 80), torch.zeros(64, 80)
    a[20:25, 30:40] = 0.5
    b[22:30, 3:8] = 1.0  # near the left border: the box is clipped there
    rows, cols = loss_window(a, b)
    assert (rows.start, rows.stop) == (20 - SSIM_REACH, 30 + SSIM_REACH)
    assert (cols.start, cols.stop) == (0, 40 + SSIM_REACH)
    assert loss_window(torch.zeros(5, 6), torch.zeros(5, 6)) == (slice(0, 5), slice(0, 6))


def test_loss_and_gradients_over_the_window_equal_the_whole_image():
    h, w = 96, 112
    target, mask = _object_image(h, w, (30, 60, 40, 75), seed=0)
    # the render overlaps the target and has a stray blob elsewhere, which the window must include
    base, alpha0 = _object_image(h, w, (33, 64, 36, 70), seed=1)
    stray, stray_alpha = _object_image(h, w, (80, 84, 5, 9), seed=2)
    g = torch.Generator().manual_seed(3)
    weights = tuple(torch.rand(h, w, generator=g) + 0.5 for _ in range(3))
    for pixel_weights in ((None, None, None), weights):
        grads = []
        for windowed in (True, False):
            rgb = torch.where((stray_alpha > 0)[..., None], stray, base).clone().requires_grad_(True)
            alpha = torch.maximum(alpha0, stray_alpha).clone().requires_grad_(True)
            if windowed:
                loss = image_loss(rgb, alpha, target, mask, 0.8, 0.2, 0.1, pixel_weights)
            else:
                loss = _full_loss(rgb, alpha, target, mask, pixel_weights)
            loss.backward()
            grads.append((float(loss.detach()), rgb.grad, alpha.grad))
        (lw, gw, aw), (lf, gf, af) = grads
        assert abs(lw - lf) <= 1e-6 * lf
        for windowed_grad, full_grad in ((gw, gf), (aw, af)):  # equal up to float rounding
            assert (windowed_grad - full_grad).abs().max() <= 1e-4 * full_grad.abs().max()
        assert gf[82, 7].abs().sum() > 0  # the stray blob gets its gradient


def test_window_is_smaller_than_the_image_for_an_object():
    target, mask = _object_image(128, 128, (50, 70, 50, 70), seed=0)
    rows, cols = loss_window(mask, mask)
    assert (rows.stop - rows.start) * (cols.stop - cols.start) < 0.2 * 128 * 128


def test_off_the_cpu_the_loss_takes_the_whole_image():
    # on a GPU a window of a new size every image makes cuDNN choose its algorithms again each time; the 'meta'
    # device stands in for one here: finding the window reads values, which meta tensors do not have
    target, mask = _object_image(64, 64, (20, 30, 20, 30), seed=0)
    rgb, alpha = _object_image(64, 64, (22, 34, 18, 28), seed=1)
    meta = [x.to("meta") for x in (rgb, alpha, target, mask)]
    loss = image_loss(*meta, 0.8, 0.2, 0.1)
    assert loss.device.type == "meta" and loss.shape == ()
    try:
        loss_window(meta[1], meta[3])
    except (NotImplementedError, RuntimeError):
        pass  # what the CPU's window would have hit
    else:
        raise AssertionError("loss_window worked on meta tensors: this test no longer tells the paths apart")
