"""The trainer's own time axis: a re-timed model draws the same Gaussians, and checkpoints stay on the dataset's
times."""

import dataclasses

import pytest
import torch

from splatreel.checkpoint import load_checkpoint
from splatreel.train.config import preset
from splatreel.train.data import load_dataset
from splatreel.train.time_axis import (TimeAxis, model_on_dataset_time, model_on_training_time, retime_model,
                                      retimed_dataset)
from splatreel.train.trainer import Trainer

from test_model import random_model


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A procedural sample: 4 views x 3 frames at 64x64."""
    from splatreel.samples import DatasetConfig, write_dataset

    root = tmp_path_factory.mktemp("data") / "spinner"
    write_dataset("spinner", root, DatasetConfig(views=4, frames=3, size=64, test_views=4))
    return root


def assert_same_slice(a, b, rtol=1e-7, atol=1e-9):
    for name in ("means", "covariances", "opacities", "sh", "visible"):
        torch.testing.assert_close(getattr(a, name), getattr(b, name), rtol=rtol, atol=atol, msg=name)


@pytest.mark.parametrize("convention", ["current", "legacy"])
def test_retimed_model_draws_the_same_gaussians(convention):
    model = random_model(64, convention, sh_degree=1, sh_degree_t=1)
    scale, shift = 7.5, -2.0
    moved = retime_model(model, scale, shift)
    assert moved.time_range == pytest.approx((shift, scale + shift))
    for t in (0.0, 0.3, 0.77, 1.0):
        assert_same_slice(model._slice_torch(t, None), moved._slice_torch(scale * t + shift, None))
    # velocities are per unit of time: they shrink with a longer clip
    torch.testing.assert_close(model._slice_torch(0.5, None).velocities,
                               scale * moved._slice_torch(scale * 0.5 + shift, None).velocities)


def test_back_to_dataset_time_round_trip():
    model = random_model(32, "current")
    axis = TimeAxis.for_clip((0.2, 0.7), 5.0)
    assert axis.to_training(0.2) == 0.0 and axis.to_training(0.7) == pytest.approx(5.0)
    back = model_on_dataset_time(model_on_training_time(model, axis), axis)
    for t in (0.2, 0.45):
        assert_same_slice(model._slice_torch(t, None), back._slice_torch(t, None))


def test_a_single_time_keeps_the_dataset_axis():
    assert TimeAxis.for_clip((0.5, 0.5), 5.0).identity and TimeAxis.for_clip((0.0, 1.0), None).identity


def test_checkpoint_is_on_the_dataset_times(tiny, tmp_path):
    ds = load_dataset(tiny)
    cfg = dataclasses.replace(preset("efficient4d"), iters=3, num_gaussians=300, batch_size=1, clip_duration=5.0)
    trainer = Trainer(ds, cfg, tmp_path / "m.safetensors", progress=False)
    trainer.run()
    assert trainer.ds.time_range == pytest.approx((0.0, 5.0))
    ck = load_checkpoint(tmp_path / "m.safetensors")
    assert ck.model.time_range == pytest.approx(ds.time_range)
    assert [v.time for v in ck.views] == pytest.approx([v.time for v in ds.train])
    for k, v in trainer.dataset_model().tensors().items():
        torch.testing.assert_close(v, ck.model.tensors()[k], rtol=0, atol=0)
    inner = trainer.model().detach()
    inner = inner.select(inner.drawn_in_clip())  # what the checkpoint keeps: the Gaussians drawn in the clip
    for v, u in zip(ds.train[:3], trainer.ds.train[:3]):
        assert_same_slice(ck.model.slice(v.time), inner.slice(u.time), rtol=2e-4, atol=2e-5)


def test_retimed_dataset_shares_the_images(tiny):
    ds = load_dataset(tiny)
    moved = retimed_dataset(ds, TimeAxis(origin=0.0, scale=3.0))
    last = ds.train[-1]
    assert last.time > 0 and moved.train[-1].image is last.image
    assert moved.train[-1].time == pytest.approx(3.0 * last.time)
    assert [v.time for v in moved.test] == pytest.approx([3.0 * v.time for v in ds.test])


def test_retiming_scales_the_accelerations():
    from test_model import accelerated

    model = accelerated(random_model(32, "current"), scale=3.0)
    scale, shift = 5.0, 1.0
    moved = retime_model(model, scale, shift)
    for t in (0.1, 0.6, 0.95):
        assert_same_slice(model._slice_torch(t, None), moved._slice_torch(scale * t + shift, None))
