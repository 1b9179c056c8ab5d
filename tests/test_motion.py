"""Velocities from optical flow (`splatreel.train.motion`): the videos it reads, the motion it recovers on a sample
whose motion is known, and the model it rebuilds."""

import dataclasses

import numpy as np
import pytest
import torch

from splatreel.covariance import condition_on_time
from splatreel.train.config import preset
from splatreel.train.data import camera_videos, load_dataset
from splatreel.train.motion import flow_tracks, flow_velocities, with_velocities
from splatreel.train.trainer import Trainer

from conftest import sample_dataset
from test_model import random_model


@pytest.fixture(scope="module")
def spinner(tmp_path_factory):
    """The spinning box as an image matrix: 8 views x 16 frames at 128 px (it turns 24 degrees per frame)."""
    return sample_dataset(tmp_path_factory, "spinner", views=8, frames=16, size=128, test_views=2)


def test_an_image_matrix_has_one_video_per_camera_and_one_camera_per_time_none(spinner, small_floor):
    ds = load_dataset(spinner)
    videos = camera_videos(ds)
    assert len(videos) == 8 and all(len(v) == 16 for v in videos)
    for video in videos:
        assert len({ds.train[i].view_id for i in video}) == 1
        assert [ds.train[i].time for i in video] == sorted(ds.frame_times)
    assert camera_videos(load_dataset(small_floor)) == []


def test_with_velocities_sets_the_motion_and_keeps_the_rest():
    model = random_model(64, "current")
    times = [0.0, 0.25, 0.5, 0.75, 1.0]
    cov3, _, var_t = condition_on_time(model.covariance_4d().double())
    velocity = torch.randn(64, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    moved = dataclasses.replace(model, **with_velocities(model, velocity, times))
    cov3_new, velocity_new, var_t_new = condition_on_time(moved.covariance_4d().double())
    torch.testing.assert_close(velocity_new, velocity, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(cov3_new, cov3, rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(var_t_new, var_t, rtol=1e-4, atol=1e-7)
    # each Gaussian is where it was at the frame nearest its temporal mean
    frame = torch.tensor(times, dtype=torch.float64)[torch.argmin((model.t_means.double()[:, None]
                                                                   - torch.tensor(times)[None].double()).abs(), 1)]
    at = lambda m, v: m.means.double() + v * (frame - m.t_means.double())[:, None]  # noqa: E731
    torch.testing.assert_close(at(moved, velocity_new), at(model, condition_on_time(model.covariance_4d().double())[1]),
                               rtol=1e-4, atol=1e-5)


def test_flow_recovers_the_known_motion_of_the_sample(spinner):
    from splatreel.samples.catalog import build_model

    ds = load_dataset(spinner)
    model = build_model("spinner", frames=16)
    _, truth, _ = condition_on_time(model.covariance_4d().detach())
    estimate, seen = flow_velocities(model, ds, torch.ones(3))
    assert seen > 0.5 * len(model)
    moving = truth.norm(dim=-1) > 0.2 * truth.norm(dim=-1).median()
    cos = torch.nn.functional.cosine_similarity(estimate[moving], truth[moving], dim=-1)
    assert float(cos.median()) > 0.85  # 0.93 measured; 0.97 at 256 px
    ratio = float(estimate[moving].norm(dim=-1).median() / truth[moving].norm(dim=-1).median())
    assert 0.5 < ratio < 1.3  # 0.67 measured (the flow is smoothed into the still backdrop); 0.79 at 256 px


def test_flow_tracks_follow_each_gaussian_to_the_neighbouring_frames(spinner):
    from splatreel.samples.catalog import build_model

    ds = load_dataset(spinner)
    model = build_model("spinner", frames=16)
    _, truth, _ = condition_on_time(model.covariance_4d().detach().double())
    tracks = flow_tracks(model, ds, torch.ones(3))
    step = ds.frame_times[1] - ds.frame_times[0]
    moving = (truth.norm(dim=-1) > 0.2 * truth.norm(dim=-1).median()).numpy()
    for points, seen, sign in ((tracks.next_points, tracks.next_seen, 1.0), (tracks.prev_points, tracks.prev_seen, -1.0)):
        rows = seen & moving & (tracks.frame > 0) & (tracks.frame < 15)
        assert rows.sum() > 0.3 * moving.sum()
        moved = torch.from_numpy(sign * (points[rows] - tracks.position[rows]) / step)
        assert float(torch.nn.functional.cosine_similarity(moved, truth[rows], dim=-1).median()) > 0.85
    # the velocities are the tracks' average: a Gaussian followed forward only moves at its step to the next frame
    both = tracks.next_seen & tracks.prev_seen & (tracks.count > 0)
    assert both.sum() > 0
    assert np.isfinite(tracks.velocity_sum[both]).all() and not tracks.prev_seen[tracks.frame == 0].any()
    forward = tracks.next_seen & ~tracks.prev_seen
    assert forward.sum() > 0
    np.testing.assert_allclose(tracks.velocity_sum[forward] / tracks.count[forward, None],
                               (tracks.next_points[forward] - tracks.position[forward]) / step, rtol=1e-6, atol=1e-6)


def test_the_trainer_sets_the_velocities_once(spinner, tmp_path, monkeypatch):
    ds = load_dataset(spinner)
    cfg = dataclasses.replace(preset("efficient4d"), iters=4, batch_size=1, num_gaussians=3000, confidence=False,
                              flow_motion_at=0.5, clip_duration=5.0)
    trainer = Trainer(ds, cfg, tmp_path / "m.safetensors", progress=False)
    calls, estimates = [], []

    def estimated(*args):
        estimates.append(flow_velocities(*args))
        return estimates[-1]

    def recorded():
        calls.append(original())
        # right after the step, the model moves at the flow's velocities
        torch.testing.assert_close(condition_on_time(trainer.model().covariance_4d().detach().double())[1],
                                   estimates[-1][0].double(), rtol=1e-3, atol=1e-3)
        return calls[-1]
    monkeypatch.setattr("splatreel.train.flow_step.flow_velocities", estimated)
    original = trainer.set_flow_motion
    trainer.set_flow_motion = recorded
    before = None
    for step in range(4):
        if step == 2:
            before = condition_on_time(trainer.model().covariance_4d().detach())[1]
        trainer.train_step()
        if step == 1:
            assert calls == []
    assert len(calls) == 1 and calls[0] > 0
    after = condition_on_time(trainer.model().covariance_4d().detach())[1]
    assert not torch.allclose(before, after, atol=1e-3)
    assert np.isfinite(after.numpy()).all()


def test_one_camera_per_time_changes_nothing(small_floor, tmp_path):
    ds = load_dataset(small_floor)
    cfg = dataclasses.replace(preset("efficient4d"), iters=2, batch_size=1, num_gaussians=500, confidence=False,
                              flow_motion_at=0.5)
    trainer = Trainer(ds, cfg, tmp_path / "m.safetensors", progress=False)
    assert trainer.set_flow_motion() == 0


def test_with_velocities_keeps_the_accelerations_and_the_position_at_the_frame():
    from test_model import accelerated

    model = accelerated(random_model(64, "current"))
    times = [0.0, 0.25, 0.5, 0.75, 1.0]
    velocity = torch.randn(64, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    moved = dataclasses.replace(model, **with_velocities(model, velocity, times))
    frame = torch.tensor(times, dtype=torch.float64)[torch.argmin((model.t_means.double()[:, None]
                                                                   - torch.tensor(times)[None].double()).abs(), 1)]
    for i in (0, 9, 33):  # `velocity` is the velocity at the frame; the Gaussian is still where it was there
        t = float(frame[i])
        torch.testing.assert_close(moved.slice(t).velocities[i], velocity[i], rtol=1e-4, atol=1e-4)
        torch.testing.assert_close(moved.slice(t).means[i], model.slice(t).means[i], rtol=1e-4, atol=1e-5)
