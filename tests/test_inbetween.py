"""Frames interpolated by optical flow half-way between a camera's consecutive frames (`splatreel.train.flow`), and
the trainer drawing them."""

import dataclasses
import math

import cv2
import numpy as np
import pytest

from splatreel.datasets import DatasetImage
from splatreel.train.config import preset
from splatreel.train.data import load_dataset
from splatreel.train.flow import inbetween_views, interpolate_midway, midway_view, optical_flow
from splatreel.train.trainer import Trainer

from conftest import sample_dataset


@pytest.fixture(scope="module")
def spinner(tmp_path_factory):
    """The spinning box as an image matrix: 4 views x 5 frames at 64 px."""
    return sample_dataset(tmp_path_factory, "spinner", views=4, frames=5, size=64, test_views=2)


def psnr(a, b) -> float:
    return -10 * math.log10(float(((a - b) ** 2).mean()))


def textured_square(shift: float) -> np.ndarray:
    """``[96, 96, 3]`` float: a smoothly textured square on grey, `shift` pixels to the right."""
    y, x = np.mgrid[0:96, 0:96].astype(np.float32)
    inside = ((x - shift >= 24) & (x - shift < 64) & (y >= 28) & (y < 68)).astype(np.float32)[..., None]
    pattern = np.stack([0.5 + 0.4 * np.sin((x - shift) / 3.0), 0.5 + 0.4 * np.cos(y / 4.0),
                        0.5 + 0.3 * np.sin((x - shift + y) / 5.0)], -1)
    return inside * pattern + (1 - inside) * 0.5


def test_a_translation_is_interpolated_half_way():
    a, b, truth = textured_square(0.0), textured_square(8.0), textured_square(4.0)
    as_bytes = lambda im: (im * 255 + 0.5).astype(np.uint8)  # noqa: E731
    mid, trust = interpolate_midway(a, b, as_bytes(a), as_bytes(b))
    assert psnr(mid, truth) > psnr(0.5 * (a + b), truth) + 10  # a cross-fade shows two half copies
    assert psnr(mid, truth) > 30
    assert trust.shape == (96, 96) and trust.dtype == np.float32 and trust.mean() > 0.95


def test_the_fine_flow_follows_a_small_turning_object_further():
    """A 70 px textured square on black turning 30 degrees about its centre: the preset's smoothing pulls its flow
    towards the still background (short of the turn); the fine flow, which node tracking uses, follows it."""
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(0, 1, (70, 70, 3)).astype(np.float32), (0, 0), 3)
    a = np.zeros((256, 256, 3), np.uint8)
    a[93:163, 93:163] = (40 + 160 * (texture - texture.min()) / np.ptp(texture)).astype(np.uint8)
    turn = cv2.getRotationMatrix2D((127.5, 127.5), 30.0, 1.0)
    b = cv2.warpAffine(a, turn, (256, 256), flags=cv2.INTER_LINEAR)
    ys, xs = np.mgrid[99:157, 99:157]
    at = np.stack([xs, ys], -1).astype(np.float64)
    truth = at @ turn[:, :2].T + turn[:, 2] - at

    def error(fine):  # median error as a share of the motion
        flow = optical_flow(a, b, fine)[ys, xs]
        return float(np.median(np.linalg.norm(flow - truth, axis=-1) / np.linalg.norm(truth, axis=-1).clip(1e-6)))

    assert error(True) < 0.75 * error(False)


def test_the_spinners_in_between_frames_beat_the_nearest_frame_and_a_cross_fade():
    from splatreel.samples.catalog import get_sample
    from splatreel.samples.dataset import DatasetConfig, SampleView, _camera, render_views
    from splatreel.samples.render import MeshRenderer

    cfg = DatasetConfig(views=8, frames=16, size=128)
    renderer, box = MeshRenderer(), get_sample("spinner")
    on_white = lambda v: v.image / 255 * (v.alpha[..., None] / 255) + 1 - v.alpha[..., None] / 255  # noqa: E731
    scores = {"flow": [], "cross-fade": [], "nearest": [], "trusted": []}
    left_out = []
    for azimuth in (0.0, 135.0):
        camera = _camera(cfg, cfg.elevation, azimuth)
        for f in (2, 9):
            times = [f / 15, (f + 0.5) / 15, (f + 1) / 15]
            views = [SampleView("x", k, t, azimuth, cfg.elevation, camera) for k, t in enumerate(times)]
            a, truth, b = (DatasetImage(im[..., :3].copy(), im[..., 3].copy(), camera, t, 0, k, "x")
                           for k, ((_, im), t) in enumerate(zip(render_views(box, views, renderer), times)))
            frame = midway_view(a, b, (1.0, 1.0, 1.0))
            mid, trusted = frame.view, frame.trust > 0.5
            assert mid.time == pytest.approx(truth.time) and mid.camera is camera
            scores["flow"].append(psnr(on_white(mid), on_white(truth)))
            scores["trusted"].append(psnr(on_white(mid)[trusted], on_white(truth)[trusted]))
            left_out.append(1 - trusted.mean())
            scores["cross-fade"].append(psnr(0.5 * (on_white(a) + on_white(b)), on_white(truth)))
            scores["nearest"].append(psnr(on_white(a), on_white(truth)))
    mean = {k: np.mean(v) for k, v in scores.items()}
    # measured 28.6 / 24.0 / 21.4 dB at 256 px, 16 views
    assert mean["flow"] > mean["cross-fade"] + 2 and mean["flow"] > mean["nearest"] + 4, mean
    # the trust leaves out few pixels, and they carry much of the error
    assert np.mean(left_out) < 0.1 and mean["trusted"] > mean["flow"] + 1, (mean, left_out)


def test_one_in_between_frame_per_pair_of_consecutive_frames(spinner, small_floor):
    ds = load_dataset(spinner)
    frames = [f.view for f in inbetween_views(ds)]
    assert len(frames) == 4 * 4
    mids = sorted({v.time for v in frames})
    times = ds.frame_times
    np.testing.assert_allclose(mids, [(s + t) / 2 for s, t in zip(times[:-1], times[1:])])
    assert all(v.alpha is not None and v.image.dtype == np.uint8 and v.image.shape == (64, 64, 3) for v in frames)
    assert inbetween_views(load_dataset(small_floor)) == []  # one camera per time films no consecutive frames


@pytest.mark.parametrize("share", [0.0, 0.5, 1.0])
def test_the_trainer_draws_in_between_frames_at_their_share(spinner, tmp_path, share):
    ds = load_dataset(spinner)
    cfg = dataclasses.replace(preset("efficient4d"), iters=2, batch_size=1, num_gaussians=500, confidence=False,
                              inbetween_share=share)
    trainer = Trainer(ds, cfg, tmp_path / "m.safetensors", progress=False)
    assert len(trainer.inbetween) == (16 if share else 0)
    drawn = [trainer._pick() >= len(ds.train) for _ in range(400)]
    assert abs(np.mean(drawn) - share) < 0.08
    assert trainer.train_step()[0] > 0
    if share:  # an in-between frame's loss is weighted by its trust, at every resolution of the ramp
        first = len(ds.train)
        for factor in (1, 2):
            weights = trainer._loss_weights(first, factor)
            trust = trainer.inbetween[0].trust
            expected = trust if factor == 1 else cv2.resize(trust, (32, 32), interpolation=cv2.INTER_AREA)
            assert all(np.allclose(w.cpu().numpy(), expected) for w in weights)
