"""The trainer's own time axis: the clip stretched to `TrainConfig.clip_duration` units while training, and the
model brought back to the dataset's times in every checkpoint.

Why: a native 4D Gaussian moves by tilting its 4D covariance towards the time axis; its velocity is ``Σ12 / Σtt``
(`splatreel.covariance`), about ``tan θ`` for a Gaussian much longer in time than in space. How far θ must
turn for a given motion depends on the unit of time. With D-NeRF's clip of one time unit, a box that turns 24°
between frames needs tilts near 60°, which 500 Adam steps on the rotation quaternions do not reach: the
Gaussians fade between frames instead of moving, and in-between times show two half-transparent copies.
Efficient4D's released code trains on frame numbers (0..15), a clip of 15 units, where the same motion is a tilt
of a few degrees.
Between the two, a clip of about 5 units scored best on the procedural samples (README, "What the default recipe
decides").

Re-timing is exact: t' = a t + b maps each Gaussian's temporal mean, and its covariance becomes D Σ D with
D = diag(1, 1, 1, a), factored again into scales and the two rotation quaternions
(`splatreel.covariance.decompose_covariance_4d`). The images a model draws at t and the re-timed model at a t + b
are the same.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from splatreel.covariance import decompose_covariance_4d
from splatreel.datasets import Dataset
from splatreel.model import Gaussians4D


@dataclass(frozen=True)
class TimeAxis:
    """Training time = ``scale * (dataset time - origin)``."""

    origin: float = 0.0
    scale: float = 1.0

    @classmethod
    def for_clip(cls, time_range: tuple[float, float], duration: float | None) -> "TimeAxis":
        """The axis on which `time_range` spans `duration` units from 0 (None or a single time: the dataset's
        own)."""
        t0, t1 = time_range
        if not duration or t1 <= t0:
            return cls()
        return cls(origin=t0, scale=duration / (t1 - t0))

    @property
    def identity(self) -> bool:
        return self.origin == 0.0 and self.scale == 1.0

    def to_training(self, t: float) -> float:
        return self.scale * (t - self.origin)


def retimed_dataset(ds: Dataset, axis: TimeAxis) -> Dataset:
    """`ds` with every training and test image's time on `axis` (images shared, not copied)."""
    if axis.identity:
        return ds
    return replace(ds, train=[replace(v, time=axis.to_training(v.time)) for v in ds.train],
                   test=[replace(v, time=axis.to_training(v.time)) for v in ds.test])


def retime_model(model: Gaussians4D, scale: float, shift: float) -> Gaussians4D:
    """The model whose slice at ``scale * t + shift`` is `model`'s slice at t (scale > 0)."""
    if scale == 1.0 and shift == 0.0:
        return model
    dtype = model.means.dtype
    d = torch.tensor([1.0, 1.0, 1.0, scale], dtype=torch.float64)
    cov = model.covariance_4d().detach().double() * d[:, None] * d[None, :]
    scales, scale_t, q_l, q_r = decompose_covariance_4d(cov, model.rotation_convention)
    tiny = torch.finfo(torch.float64).tiny
    t0, t1 = model.time_range
    return replace(model, t_means=(scale * model.t_means.detach().double() + shift).to(dtype),
                   log_scales=scales.clamp_min(tiny).log().to(dtype),
                   log_t_scales=scale_t.clamp_min(tiny).log().to(dtype), quats_l=q_l.to(dtype), quats_r=q_r.to(dtype),
                   time_range=(scale * t0 + shift, scale * t1 + shift),
                   accelerations=None if model.accelerations is None else model.accelerations / scale ** 2)


def model_on_training_time(model: Gaussians4D, axis: TimeAxis) -> Gaussians4D:
    """A model on the dataset's times, on `axis` (the inverse of `model_on_dataset_time`)."""
    return retime_model(model, axis.scale, -axis.scale * axis.origin)


def model_on_dataset_time(model: Gaussians4D, axis: TimeAxis) -> Gaussians4D:
    """A model trained on `axis`, on the dataset's own times."""
    return retime_model(model, 1.0 / axis.scale, axis.origin)
