"""The Gaussian models: native 4D Gaussians, keyframed (baked) Gaussians, and the 3D slice both produce.

Data flows one way: dataset -> trainer -> checkpoint -> (viewer | exporters). All of them meet here: the trainer
optimises the tensors of a `Gaussians4D`, and the viewer and exporters only ever call ``model.slice(t)`` (or
``model.centres(times)`` when the means and visibility are all they need, e.g. for bounds and framing).

Tensors are torch (float32 or float64, any device); slicing is differentiable so the trainer can backpropagate
through it. Shapes use N = number of Gaussians, F = number of keyframes, K = (sh_degree + 1)^2 spatial SH
coefficients per channel and M = K * (sh_degree_t + 1) coefficients of a 4D colour.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Union

import torch
from torch import Tensor

from . import quaternion, sh
from .constants import TEMPORAL_CULL
from .covariance import (RotationConvention, alive_within, condition_on_time, covariance_3d, covariance_4d,
                         decompose_covariance_3d, parse_convention, temporal_marginal)
from .errors import ModelError


def _check(cond: bool, msg: str) -> None:
    if not cond:
        raise ModelError(msg)


def take_rows(x: Tensor, rows: Tensor) -> Tensor:
    """Rows `rows` (a bool mask, or indices) of `x`. Indices go through ``index_select``, whose gradient is an
    ``index_add``: the gradient of ``x[rows]`` is an accumulating ``index_put``, which sorts the indices on a GPU
    each time (about 0.2 ms of host time per call on an H100, and training gathers a dozen tensors per image)."""
    if rows.dtype == torch.bool:
        return x[rows]
    return x.index_select(0, rows.to(x.device))


@dataclass
class Gaussians3D:
    """A set of 3D Gaussians: the slice of a model at one time, ready to rasterize or export.

    Attributes:
        means: ``[N, 3]`` centres.
        covariances: ``[N, 3, 3]`` spatial covariances.
        opacities: ``[N]`` activated opacities in [0, 1], the temporal factor already applied.
        sh: ``[N, K, 3]`` spatial SH coefficients at this time (time terms folded in); colour = max(SH(d)+0.5, 0).
        visible: ``[N]`` bool; False for Gaussians culled at this time (4D: temporal marginal <= 0.05).
        sh_degree: spatial SH degree, K = (sh_degree + 1)^2.
        velocities: ``[N, 3]`` d(mean)/dt at this time, or None.
        scales, quats: ``[N, 3]`` std-devs and ``[N, 4]`` w-first quaternions when the source model stores them
            (keyframed models); otherwise None and `scales_quats()` derives them from the covariances.
    """

    means: Tensor
    covariances: Tensor
    opacities: Tensor
    sh: Tensor
    visible: Tensor
    sh_degree: int
    velocities: Tensor | None = None
    scales: Tensor | None = None
    quats: Tensor | None = None

    def __len__(self) -> int:
        return self.means.shape[0]

    def colors(self, campos: Tensor, degree: int | None = None) -> Tensor:
        """``[N, 3]`` RGB seen from camera centre ``campos`` ``[3]`` (directions from the sliced means).

        `degree` renders at a lower SH degree than the model's (the viewer's SH slider).
        """
        deg = self.sh_degree if degree is None else min(degree, self.sh_degree)
        dirs = self.means - campos.to(self.means)
        return sh.sh_to_rgb(sh.eval_sh(deg, self.sh, dirs))

    def scales_quats(self) -> tuple[Tensor, Tensor]:
        """(scales ``[N, 3]``, quats ``[N, 4]``) reproducing the covariances (exact when stored)."""
        if self.scales is not None and self.quats is not None:
            return self.scales, self.quats
        return decompose_covariance_3d(self.covariances)

    def select(self, mask: Tensor) -> "Gaussians3D":
        """The subset where `mask` (``[N]`` bool or indices) holds."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = take_rows(v, mask) if isinstance(v, Tensor) else v
        return Gaussians3D(**out)


@dataclass
class Gaussians4D:
    """Native 4D Gaussians (Yang et al. 2024), stored raw exactly like the official code (notes §1.1).

    Attributes:
        means: ``[N, 3]`` spatial mean mu_xyz.
        t_means: ``[N]`` temporal mean mu_t, in the units of `time_range`.
        log_scales: ``[N, 3]`` log spatial std-devs.
        log_t_scales: ``[N]`` log temporal std-dev.
        quats_l, quats_r: ``[N, 4]`` left / right quaternions, w first, unnormalised (normalised on use).
        opacity_logits: ``[N]`` logit of the opacity.
        sh_dc: ``[N, 1, 3]`` first colour coefficient.
        sh_rest: ``[N, M - 1, 3]`` the others, M = (sh_degree+1)^2 (sh_degree_t+1), layout of `splatreel.sh`.
        sh_degree: spatial SH degree 0..3.
        sh_degree_t: time (Fourier) degree 0..2.
        time_range: (t0, t1); T = t1 - t0 scales the time terms of the colour.
        rotation_convention: 'current' (official main since 2024-09-15) or 'legacy' (older, Efficient4D).
        accelerations: ``[N, 3]`` or None. None is native 4DGS: the conditional mean moves linearly. Set, the mean
            is mu_xyz + v tau + a tau^2 / 2 (tau = t - mu_t): the quadratic term of the polynomial motion of
            Spacetime Gaussians (Li et al., CVPR 2024), so that a Gaussian can follow a curved path (a turning
            surface) over its life; the covariance and the temporal marginal stay native.
    """

    means: Tensor
    t_means: Tensor
    log_scales: Tensor
    log_t_scales: Tensor
    quats_l: Tensor
    quats_r: Tensor
    opacity_logits: Tensor
    sh_dc: Tensor
    sh_rest: Tensor
    sh_degree: int = 0
    sh_degree_t: int = 0
    time_range: tuple[float, float] = (0.0, 1.0)
    rotation_convention: RotationConvention = "current"
    accelerations: Tensor | None = None

    #: Names of the per-Gaussian tensors, in checkpoint order.
    TENSORS = ("means", "t_means", "log_scales", "log_t_scales", "quats_l", "quats_r", "opacity_logits",
               "sh_dc", "sh_rest")
    #: Tensors a model may hold or not (None when absent).
    OPTIONAL_TENSORS = ("accelerations",)

    def __post_init__(self) -> None:
        self.rotation_convention = parse_convention(self.rotation_convention)
        self.time_range = (float(self.time_range[0]), float(self.time_range[1]))
        self.validate()

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def kind(self) -> str:
        return "gaussians4d"

    @property
    def duration(self) -> float:
        return self.time_range[1] - self.time_range[0]

    def validate(self) -> None:
        """Raise ModelError naming the first tensor whose shape or dtype is wrong."""
        n = self.means.shape[0] if self.means.dim() == 2 else -1
        _check(0 <= self.sh_degree <= sh.MAX_SH_DEGREE, f"sh_degree must be 0..3, got {self.sh_degree}")
        _check(0 <= self.sh_degree_t <= sh.MAX_SH_DEGREE_T, f"sh_degree_t must be 0..2, got {self.sh_degree_t}")
        m = sh.num_sh_coeffs(self.sh_degree, self.sh_degree_t)
        expected = {
            "means": (n, 3), "t_means": (n,), "log_scales": (n, 3), "log_t_scales": (n,), "quats_l": (n, 4),
            "quats_r": (n, 4), "opacity_logits": (n,), "sh_dc": (n, 1, 3), "sh_rest": (n, m - 1, 3),
        }
        if self.accelerations is not None:
            expected["accelerations"] = (n, 3)
        for name, shape in expected.items():
            v = getattr(self, name)
            _check(isinstance(v, Tensor), f"{name} must be a torch tensor, got {type(v).__name__}")
            _check(tuple(v.shape) == shape and n >= 0,
                   f"{name} has shape {list(v.shape)}, expected {[('N' if s == n else s) for s in shape]} "
                   f"with N = {n}" + (f" (sh degrees {self.sh_degree}, {self.sh_degree_t})" if name == "sh_rest" else ""))
            _check(v.dtype in (torch.float32, torch.float64), f"{name} has dtype {v.dtype}, expected float32/64")
        _check(math.isfinite(self.duration) and self.duration > 0,
               f"time_range must satisfy t0 < t1, got {self.time_range}")

    # --- activated quantities ---------------------------------------------------------------------------------
    @property
    def scales(self) -> Tensor:
        return torch.exp(self.log_scales)

    @property
    def t_scales(self) -> Tensor:
        return torch.exp(self.log_t_scales)

    @property
    def opacities(self) -> Tensor:
        return torch.sigmoid(self.opacity_logits)

    @property
    def sh_coeffs(self) -> Tensor:
        """``[N, M, 3]`` all colour coefficients (dc first)."""
        return torch.cat([self.sh_dc, self.sh_rest], 1)

    def covariance_4d(self) -> Tensor:
        """``[N, 4, 4]`` full covariance in (x, y, z, t)."""
        return covariance_4d(self.scales, self.t_scales, self.quats_l, self.quats_r, self.rotation_convention)

    def slice(self, t: float, sh_degree_t: int | None = None, rows: Tensor | None = None) -> Gaussians3D:
        """The conditional 3D Gaussians at time `t` (differentiable).

        Means move linearly (plus the accelerations' term when the model has them), covariances are the
        (time-constant) conditional ones, opacities are multiplied by the unnormalised temporal marginal, and
        `visible` is False where that marginal is <= 0.05.
        `sh_degree_t` uses fewer cosine time terms of the colour than the model has (0: none).
        `rows` (distinct indices, or a bool mask) slices only those Gaussians, as ``select(rows).slice(t)`` does, without
        gathering every tensor first: training slices the Gaussians alive at each image's time.

        Float32 CPU tensors take the fused kernel of `splatreel.slicing` (the same math, one pass); others the
        torch composition of `splatreel.covariance`.
        """
        geometry = (self.means, self.t_means, self.log_scales, self.log_t_scales, self.quats_l, self.quats_r)
        if not all(x.device.type == "cpu" and x.dtype == torch.float32 for x in geometry):
            return (self if rows is None else self.select(rows))._slice_torch(t, sh_degree_t)
        from .slicing import slice_geometry  # numba: imported on first use, not with the model

        if rows is None:
            rows = torch.arange(len(self))
        elif rows.dtype == torch.bool:
            rows = rows.nonzero()[:, 0]
        means, cov3, velocity, marginal = slice_geometry(*geometry, rows, t, self.rotation_convention)
        means, velocity = self._accelerated(t, rows, means, velocity)
        return self._sliced(t, sh_degree_t, rows, means, cov3, velocity, marginal)

    def _slice_torch(self, t: float, sh_degree_t: int | None) -> Gaussians3D:
        """`slice` of every Gaussian as a torch composition (any dtype and device)."""
        cov3, velocity, var_t = condition_on_time(self.covariance_4d())
        means, marginal, _ = self._at_time(t, velocity, var_t)
        means, velocity = self._accelerated(t, None, means, velocity)
        return self._sliced(t, sh_degree_t, None, means, cov3, velocity, marginal)

    def drawn_in_clip(self) -> Tensor:
        """``[N]`` bool: whether each Gaussian is drawn at some time of `time_range` (`covariance.alive_within`);
        one that is not shows nothing at any time of the clip."""
        with torch.no_grad():
            return alive_within(*self.time_range, self.t_means, self.covariance_4d()[:, 3, 3])

    def accelerations_or_zeros(self) -> Tensor:
        """``[N, 3]`` the accelerations, zeros for native (linear) motion: for consumers that treat both alike."""
        return torch.zeros_like(self.means) if self.accelerations is None else self.accelerations

    def _accelerated(self, t: float, rows: Tensor | None, means: Tensor, velocity: Tensor) -> tuple[Tensor, Tensor]:
        """The linearly moved `means` and their `velocity` (of rows `rows`, None: all) with the acceleration term
        added at time t: + a tau^2 / 2 and + a tau. Unchanged without accelerations."""
        if self.accelerations is None:
            return means, velocity
        a = self.accelerations if rows is None else take_rows(self.accelerations, rows)
        tau = (t - (self.t_means if rows is None else take_rows(self.t_means, rows)))[:, None]
        return means + 0.5 * a * tau * tau, velocity + a * tau

    def _sliced(self, t: float, sh_degree_t: int | None, rows: Tensor | None, means: Tensor, cov3: Tensor,
                velocity: Tensor, marginal: Tensor) -> Gaussians3D:
        """The `Gaussians3D` of rows `rows` (None: all) from their sliced geometry: opacity times the marginal, colour
        collapsed to time `t`."""
        def pick(x: Tensor) -> Tensor:
            return x if rows is None else take_rows(x, rows)

        degree_t = self.sh_degree_t if sh_degree_t is None else max(0, min(sh_degree_t, self.sh_degree_t))
        coeffs = torch.cat([pick(self.sh_dc), pick(self.sh_rest)[:, : sh.num_sh_coeffs(self.sh_degree, degree_t) - 1]],
                           1)
        return Gaussians3D(
            means=means,
            covariances=cov3,
            opacities=torch.sigmoid(pick(self.opacity_logits)) * marginal,
            sh=sh.collapse_time(coeffs, self.sh_degree, degree_t, pick(self.t_means) - t, self.duration),
            visible=marginal > TEMPORAL_CULL,
            sh_degree=self.sh_degree,
            velocities=velocity,
        )

    def centres(self, times) -> list[tuple[Tensor, Tensor]]:
        """``(means [N, 3], visible [N])`` of `slice(t)` for each t in `times`, without the covariances and colours
        (the conditioning is done once): what framing and bounds need, ~10x cheaper than slicing."""
        _, velocity, var_t = condition_on_time(self.covariance_4d())
        out = []
        for t in times:
            means, marginal, _ = self._at_time(float(t), velocity, var_t)
            means, _ = self._accelerated(float(t), None, means, velocity)
            out.append((means, marginal > TEMPORAL_CULL))
        return out

    def _at_time(self, t: float, velocity: Tensor, var_t: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Conditional means, temporal marginal and t - mu_t at time t (velocity, var_t from condition_on_time)."""
        dt = t - self.t_means
        return self.means + velocity * dt[:, None], temporal_marginal(t, self.t_means, var_t), dt

    def tensors(self) -> dict[str, Tensor]:
        """The per-Gaussian tensors by name: `TENSORS`, then the `OPTIONAL_TENSORS` the model holds."""
        return {name: getattr(self, name) for name in self.TENSORS + self.OPTIONAL_TENSORS
                if getattr(self, name) is not None}

    def metadata(self) -> dict:
        return {"sh_degree": self.sh_degree, "sh_degree_t": self.sh_degree_t,
                "time_range": list(self.time_range), "rotation_convention": self.rotation_convention}

    @classmethod
    def from_tensors(cls, tensors: dict[str, Tensor], meta: dict) -> "Gaussians4D":
        return cls(**{k: tensors[k] for k in cls.TENSORS},
                   **{k: tensors[k] for k in cls.OPTIONAL_TENSORS if k in tensors}, sh_degree=int(meta["sh_degree"]),
                   sh_degree_t=int(meta["sh_degree_t"]), time_range=tuple(meta["time_range"]),
                   rotation_convention=meta["rotation_convention"])

    def to(self, device=None, dtype=None) -> "Gaussians4D":
        return replace(self, **{k: v.to(device=device, dtype=dtype) for k, v in self.tensors().items()})

    def detach(self) -> "Gaussians4D":
        return replace(self, **{k: v.detach() for k, v in self.tensors().items()})

    def select(self, mask: Tensor) -> "Gaussians4D":
        """The Gaussians where `mask` (``[N]`` bool or indices) holds."""
        return replace(self, **{k: take_rows(v, mask) for k, v in self.tensors().items()})

    def anchors(self) -> Tensor:
        """``[N, 3]`` where each Gaussian is when it shows most: its spatial mean, the position at its temporal
        mean mu_t, where the temporal marginal peaks."""
        return self.means


@dataclass
class KeyframedGaussians:
    """Gaussians sampled at keyframe times (baked deformation models, PLY sequences), interpolated between keys.

    Attributes:
        times: ``[F]`` strictly increasing keyframe times.
        means: ``[F, N, 3]``.
        quats: ``[F, N, 4]`` w first.
        scales: ``[F, N, 3]`` activated std-devs.
        opacities: ``[F, N]`` activated opacities; 0 marks a Gaussian absent at that key.
        sh: ``[F, N, K, 3]`` spatial SH coefficients, K = (sh_degree + 1)^2.
        sh_degree: 0..3.

    `slice(t)` interpolates linearly (slerp for rotations) between the two keys around t and holds the first/last
    key outside [times[0], times[-1]].
    """

    times: Tensor
    means: Tensor
    quats: Tensor
    scales: Tensor
    opacities: Tensor
    sh: Tensor
    sh_degree: int = 0

    TENSORS = ("times", "means", "quats", "scales", "opacities", "sh")

    def __post_init__(self) -> None:
        self.validate()

    def __len__(self) -> int:
        return self.means.shape[1]

    @property
    def kind(self) -> str:
        return "keyframed"

    @property
    def time_range(self) -> tuple[float, float]:
        return float(self.times[0]), float(self.times[-1])

    @property
    def num_frames(self) -> int:
        return self.times.shape[0]

    def validate(self) -> None:
        f = self.times.shape[0] if self.times.dim() == 1 else -1
        n = self.means.shape[1] if self.means.dim() == 3 else -1
        _check(f >= 1, f"times must be a 1-D tensor of keyframe times, got shape {list(self.times.shape)}")
        k = sh.num_sh_bases(self.sh_degree)
        expected = {"means": (f, n, 3), "quats": (f, n, 4), "scales": (f, n, 3), "opacities": (f, n),
                    "sh": (f, n, k, 3)}
        for name, shape in expected.items():
            v = getattr(self, name)
            _check(isinstance(v, Tensor), f"{name} must be a torch tensor, got {type(v).__name__}")
            _check(tuple(v.shape) == shape and n >= 0,
                   f"{name} has shape {list(v.shape)}, expected [F={f}, N={n}, ...] = {list(shape)}")
            _check(v.dtype in (torch.float32, torch.float64), f"{name} has dtype {v.dtype}, expected float32/64")
        _check(bool((self.times[1:] > self.times[:-1]).all()), "keyframe times must be strictly increasing")

    def _bracket(self, t: float) -> tuple[int, int, float]:
        """Indices of the keys around t and the blend weight of the second."""
        times = self.times.detach().double().cpu()
        if self.num_frames == 1 or t <= times[0]:
            return 0, 0, 0.0
        if t >= times[-1]:
            return self.num_frames - 1, self.num_frames - 1, 0.0
        i = int(torch.searchsorted(times, torch.tensor([float(t)], dtype=torch.float64), right=True)[0]) - 1
        w = (t - float(times[i])) / float(times[i + 1] - times[i])
        return i, i + 1, w

    def centres(self, times) -> list[tuple[Tensor, Tensor]]:
        """``(means [N, 3], visible [N])`` of `slice(t)` for each t in `times` (see `Gaussians4D.centres`)."""
        out = []
        for t in times:
            i, j, w = self._bracket(float(t))
            out.append((_lerp(self.means, i, j, w), _lerp(self.opacities, i, j, w) > 0))
        return out

    def slice(self, t: float) -> Gaussians3D:
        i, j, w = self._bracket(t)

        def lerp(x: Tensor) -> Tensor:
            return _lerp(x, i, j, w)

        quats = self.quats[i] if w == 0.0 else quaternion.slerp(self.quats[i], self.quats[j], w)
        quats = quaternion.normalize(quats)
        scales = lerp(self.scales)
        opacities = lerp(self.opacities)
        if self.num_frames > 1:
            a, b = (i, j) if i != j else ((i - 1, i) if i > 0 else (0, 1))
            velocities = (self.means[b] - self.means[a]) / (self.times[b] - self.times[a])
        else:
            velocities = torch.zeros_like(self.means[0])
        return Gaussians3D(
            means=lerp(self.means), covariances=covariance_3d(scales, quats), opacities=opacities,
            sh=lerp(self.sh), visible=opacities > 0, sh_degree=self.sh_degree, velocities=velocities,
            scales=scales, quats=quats)

    def tensors(self) -> dict[str, Tensor]:
        return {name: getattr(self, name) for name in self.TENSORS}

    def metadata(self) -> dict:
        return {"sh_degree": self.sh_degree, "time_range": list(self.time_range)}

    @classmethod
    def from_tensors(cls, tensors: dict[str, Tensor], meta: dict) -> "KeyframedGaussians":
        return cls(**{k: tensors[k] for k in cls.TENSORS}, sh_degree=int(meta["sh_degree"]))

    def to(self, device=None, dtype=None) -> "KeyframedGaussians":
        return replace(self, **{k: v.to(device=device, dtype=dtype) for k, v in self.tensors().items()})

    def select(self, mask: Tensor) -> "KeyframedGaussians":
        """The Gaussians where `mask` (``[N]`` bool or indices) holds, at every key."""
        return replace(self, **{k: (v if k == "times" else v[:, mask]) for k, v in self.tensors().items()})

    def anchors(self) -> Tensor:
        """``[N, 3]`` where each Gaussian is when it shows most: its mean at the key of its highest opacity."""
        key = self.opacities.argmax(0)
        return self.means[key, torch.arange(self.means.shape[1], device=key.device)]


def _lerp(x: Tensor, i: int, j: int, w: float) -> Tensor:
    """Keys i and j of `x` (``[F, ...]``) blended with weight w on the second."""
    return x[i] if w == 0.0 else x[i] + (x[j] - x[i]) * w


#: Any model a checkpoint can hold (and `splatreel.skinned.SkinnedGaussians`); each has ``slice(t)``,
#: ``centres(times)``, ``select(mask)``, ``anchors()``, ``time_range``, ``sh_degree`` and ``len()``.
#: `splatreel.checkpoint.MODEL_KINDS` names them.
Model = Union[Gaussians4D, KeyframedGaussians]


@dataclass(frozen=True)
class CropBox:
    """An axis-aligned box of world space: `crop` keeps the Gaussians whose anchor (`anchors()`: where the
    Gaussian is when it shows most) lies inside it, corners included. One rule for the whole time range, so a
    cropped model shows exactly what the viewer's crop preview showed, at every time."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    def __post_init__(self) -> None:
        lo, hi = tuple(float(x) for x in self.lo), tuple(float(x) for x in self.hi)
        _check(len(lo) == 3 and len(hi) == 3, "a crop box needs 3 numbers for each corner")
        _check(all(math.isfinite(x) for x in lo + hi), f"crop box corners must be finite, got {lo}, {hi}")
        _check(all(a <= b for a, b in zip(lo, hi)),
               f"crop box needs min <= max on every axis, got min {lo} and max {hi}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    @classmethod
    def of(cls, values) -> "CropBox":
        """From 6 numbers: the min corner, then the max corner (the ``--crop`` option's order)."""
        v = [float(x) for x in values]
        _check(len(v) == 6, f"a crop box is 6 numbers (min corner, then max corner), got {len(v)}")
        return cls(tuple(v[:3]), tuple(v[3:]))

    def provenance(self, kept: int, of: int) -> dict:
        """What a checkpoint records of the crop that made it (``provenance["crop"]``)."""
        return {"box": [*self.lo, *self.hi], "kept": int(kept), "of": int(of)}

    def contains(self, points: Tensor) -> Tensor:
        """``[N]`` bool: which of ``[N, 3]`` `points` lie in the box."""
        lo = torch.tensor(self.lo, dtype=points.dtype, device=points.device)
        hi = torch.tensor(self.hi, dtype=points.dtype, device=points.device)
        return ((points >= lo) & (points <= hi)).all(-1)


def crop_mask(model: Model, box: CropBox, require_any: bool = False) -> Tensor:
    """``[N]`` bool: which Gaussians of `model` `crop` keeps; with `require_any`, a ModelError instead of an
    all-False mask (a command line's box that missed the model)."""
    with torch.no_grad():
        inside = box.contains(model.anchors())
    _check(not require_any or bool(inside.any()),
           f"the crop box {box.lo} .. {box.hi} holds none of the {len(model):,} Gaussians")
    return inside


def crop(model: Model, box: CropBox, require_any: bool = False) -> Model:
    """The Gaussians of `model` whose anchor lies in `box` (`CropBox`, `crop_mask`)."""
    return model.select(crop_mask(model, box, require_any))


def model_bounds(model: Model, num_times: int = 9, quantile: float = 0.0) -> tuple[Tensor, Tensor]:
    """Axis-aligned box (min ``[3]``, max ``[3]``) of the visible means over `num_times` times in the time range.

    With ``quantile = q > 0`` each time contributes the box between the q and 1 - q quantiles of its means per
    axis instead of their extremes: a few floaters far from the object (common in trained models) then do not
    stretch the box. The default (0) holds every mean, as exporters need.
    """
    if not 0.0 <= quantile < 0.5:
        raise ModelError(f"bounds quantile must be in [0, 0.5), got {quantile}")
    t0, t1 = model.time_range
    lo, hi = None, None
    with torch.no_grad():
        for means, visible in model.centres(torch.linspace(t0, t1, num_times).tolist()):
            pts = means[visible]
            if pts.shape[0] == 0:
                continue
            if quantile > 0.0:  # order statistics (torch.quantile refuses inputs over 16M elements)
                k = int(quantile * (pts.shape[0] - 1))
                a = pts.kthvalue(k + 1, dim=0).values
                b = pts.kthvalue(pts.shape[0] - k, dim=0).values
            else:
                a, b = pts.min(0).values, pts.max(0).values
            lo = a if lo is None else torch.minimum(lo, a)
            hi = b if hi is None else torch.maximum(hi, b)
    if lo is None:
        z = torch.zeros(3)
        return z, z
    return lo, hi


def static_gaussians4d(means: Tensor, scales: Tensor, quats: Tensor, opacities: Tensor, rgb: Tensor,
                       time_range: tuple[float, float] = (0.0, 1.0), t_scale: float = 1e3) -> Gaussians4D:
    """Gaussians4D that do not move and never fade: equal left/right quaternions under the 'current' convention
    give R4 = block-diag(R3', 1), and a huge temporal std-dev keeps the marginal ~1 over the time range.

    `quats` are the desired 3D rotations (w first); under 'current' the 3D block of R4 is the axis-reversed R3,
    so the quaternion is remapped to produce exactly R3(quats).
    """
    w, x, y, z = quaternion.normalize(quats).unbind(-1)
    # current: R4 = P A P, A = block(1, R3(q)) for q_l = q_r = q; with P reversing (x,y,z) the spatial block is
    # P3 R3(q) P3 = R3(q') where q' = (w, -z, -y, -x) (conjugation by the reflection P3 = det -1 permutation).
    q = torch.stack([w, -z, -y, -x], -1)
    n = means.shape[0]
    dtype = means.dtype
    return Gaussians4D(
        means=means, t_means=torch.full((n,), 0.5 * (time_range[0] + time_range[1]), dtype=dtype),
        log_scales=torch.log(scales), log_t_scales=torch.full((n,), math.log(t_scale), dtype=dtype),
        quats_l=q, quats_r=q.clone(), opacity_logits=torch.logit(opacities.clamp(1e-6, 1 - 1e-6)),
        sh_dc=sh.rgb_to_sh(rgb)[:, None, :], sh_rest=torch.zeros((n, 0, 3), dtype=dtype),
        sh_degree=0, sh_degree_t=0, time_range=time_range, rotation_convention="current")
