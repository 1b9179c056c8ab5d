"""Per-Gaussian arrays in the layout the GL renderer uploads (one instance per Gaussian).

A native 4D model is converted **once**: everything that does not depend on t (the conditional covariance, the
velocity of the conditional mean, the temporal variance; `splatreel.covariance.condition_on_time`) is computed here
on the CPU, and the vertex shader only evaluates the t-dependent part each frame (mean moving in t, linearly or with
the model's accelerations, temporal opacity factor and its cull, SH with the cosine time terms). A skinned model
(`SkinnedGaussians`, carried by its control nodes) is its canonical native Gaussians in the same layout plus each
one's skin (`splatreel.viewer.skinning`: only its node poses change with t). A keyframed model has no closed form in
t, so its slice at t (`KeyframedGaussians.slice`) is converted instead, once per displayed time.

Layout (float32, N Gaussians, M = (sh_degree+1)^2 (sh_degree_t+1) colour coefficients)::

    mean_t  [N, 4]  mean xyz (at the temporal mean), temporal mean mu_t
    motion  [N, 4]  velocity xyz (d mean / dt at mu_t), 1 / (2 Sigma_tt)  (0: no temporal fade, e.g. a keyframed slice)
    accel   [N, 4]  acceleration xyz (`Gaussians4D.accelerations`; 0 for linear motion), 0: the mean at t is
                    mean + v dt + accel dt^2 / 2, dt = t - mu_t
    cov     [N, 8]  conditional covariance c00 c01 c02 c11 c12 c22, opacity (activated), speed |d mean / dt| at
                    mu_t (world units per unit of model time; shown by the "speed" render mode, with the
                    accelerations' term at t when there are any; kept apart from `motion` so that a keyframed slice's
                    speed does not move it)
    sh      [N, S]  the M x 3 colour coefficients flattened coefficient-major (r g b of coefficient 0, then 1, ...)
                    and zero-padded to S = 4 * ceil(3 M / 4) floats (whole RGBA texels)
    skin    [N, 8]  skinned models only (`skinning.SkinArrays`): 4 node indices, 4 blend weights
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from splatreel import sh as shlib
from splatreel.covariance import condition_on_time
from splatreel.errors import ModelError
from splatreel.model import Gaussians3D, Gaussians4D, KeyframedGaussians
from splatreel.skinned import SkinnedGaussians

from .skinning import COV_TRIU, SkinArrays


@dataclass
class SplatArrays:
    """GPU-ready per-Gaussian arrays of one model (see module doc for the layout).

    Attributes:
        mean_t, motion, accel: ``[N, 4]`` float32.
        cov: ``[N, 8]`` float32.
        sh: ``[N, S]`` float32, S a multiple of 4.
        sh_degree: spatial SH degree 0..3.
        sh_degree_t: number of cosine time terms beyond the constant one (0..2).
        duration: T = t1 - t0, the period scale of the time terms.
        time_range: (t0, t1) of the source model.
        time: the time a slice (keyframed, 3D) was taken at, the only time its arrays are valid at (None for
            native 4D and skinned arrays, valid at every t).
        skin: a skinned model's skin and nodes (None for the others).
    """

    mean_t: np.ndarray
    motion: np.ndarray
    accel: np.ndarray
    cov: np.ndarray
    sh: np.ndarray
    sh_degree: int
    sh_degree_t: int
    duration: float
    time_range: tuple[float, float]
    time: float | None = None
    skin: SkinArrays | None = None

    def __len__(self) -> int:
        return self.mean_t.shape[0]

    @property
    def num_coeffs(self) -> int:
        """M, colour coefficients per channel."""
        return shlib.num_sh_coeffs(self.sh_degree, self.sh_degree_t)

    @property
    def sh_texels(self) -> int:
        """RGBA texels per Gaussian in the SH texture."""
        return self.sh.shape[1] // 4

    @property
    def opacity(self) -> np.ndarray:
        return self.cov[:, 6]

    @property
    def speed(self) -> np.ndarray:
        return self.cov[:, 7]

    def nbytes(self) -> int:
        skin = (self.skin.nodes, self.skin.weights) if self.skin is not None else ()
        return sum(a.nbytes for a in (self.mean_t, self.motion, self.accel, self.cov, self.sh, *skin))

    def select(self, mask: np.ndarray) -> "SplatArrays":
        """The arrays of the Gaussians where `mask` (``[N]`` bool or indices) holds: the same as converting
        ``model.select(mask)``, without converting again (a gather, ~10x faster)."""
        return replace(self, mean_t=self.mean_t[mask], motion=self.motion[mask], accel=self.accel[mask],
                       cov=self.cov[mask], sh=self.sh[mask], skin=None if self.skin is None else self.skin.select(mask))

    def attributes(self) -> np.ndarray:
        """``[N, 20]`` float32 (``[N, 28]`` with a skin): the per-instance attributes the pre-pass reads (mean_t,
        motion, accel, cov, and the skin's nodes and weights)."""
        skin = [] if self.skin is None else [self.skin.columns()]
        return np.concatenate([self.mean_t, self.motion, self.accel, self.cov, *skin], axis=1).astype(np.float32)


def _np32(x: torch.Tensor) -> np.ndarray:
    return x.detach().to("cpu", torch.float32).numpy()


def _pack_sh(coeffs: torch.Tensor) -> np.ndarray:
    """``[N, M, 3]`` -> ``[N, 4 ceil(3M/4)]`` float32, coefficient-major, zero-padded."""
    n, m, _ = coeffs.shape
    flat = _np32(coeffs.reshape(n, 3 * m))
    width = 4 * ((3 * m + 3) // 4)
    out = np.zeros((n, width), np.float32)
    out[:, : 3 * m] = flat
    return out


def _pack_cov(cov3: torch.Tensor, opacity: torch.Tensor, velocity: torch.Tensor | None) -> np.ndarray:
    """``[N, 3, 3]`` covariances, ``[N]`` opacities, ``[N, 3]`` velocities (None: static) -> ``[N, 8]`` (upper
    triangle, opacity, speed)."""
    n = cov3.shape[0]
    out = np.zeros((n, 8), np.float32)
    for k, (i, j) in enumerate(COV_TRIU.tolist()):
        out[:, k] = _np32(cov3[:, i, j])
    out[:, 6] = _np32(opacity)
    if velocity is not None:
        out[:, 7] = _np32(torch.linalg.vector_norm(velocity, dim=-1))
    return out


def _check_finite(name: str, *arrays: np.ndarray) -> None:
    for a in arrays:
        if not np.isfinite(a).all():
            raise ModelError(f"{name}: model produces NaN or infinite values (bad covariances or temporal scales)")


def from_gaussians4d(model: Gaussians4D) -> SplatArrays:
    """Time-independent arrays of a native 4D model (computed in float64, stored as float32)."""
    with torch.no_grad():
        m = model.detach().to(device="cpu", dtype=torch.float64)
        cov3, velocity, var_t = condition_on_time(m.covariance_4d())
        n = len(m)
        mean_t = np.empty((n, 4), np.float32)
        mean_t[:, :3] = _np32(m.means)
        mean_t[:, 3] = _np32(m.t_means)
        motion = np.empty((n, 4), np.float32)
        motion[:, :3] = _np32(velocity)
        motion[:, 3] = _np32(0.5 / var_t)
        accel = np.zeros((n, 4), np.float32)
        accel[:, :3] = _np32(m.accelerations_or_zeros())
        out = SplatArrays(mean_t=mean_t, motion=motion, accel=accel, cov=_pack_cov(cov3, m.opacities, velocity),
                          sh=_pack_sh(m.sh_coeffs), sh_degree=m.sh_degree, sh_degree_t=m.sh_degree_t,
                          duration=m.duration, time_range=m.time_range)
    _check_finite("Gaussians4D", out.mean_t, out.motion, out.accel, out.cov, out.sh)
    return out


def from_gaussians3d(g: Gaussians3D, time: float, time_range: tuple[float, float] = (0.0, 1.0)) -> SplatArrays:
    """Arrays of a 3D slice (static at `time`): no motion, no temporal fade; Gaussians not `visible` get opacity 0.
    The slice's `velocities` (when it has them) give only the speed column."""
    with torch.no_grad():
        n = len(g)
        mean_t = np.empty((n, 4), np.float32)
        mean_t[:, :3] = _np32(g.means)
        mean_t[:, 3] = time
        motion = np.zeros((n, 4), np.float32)
        opacity = torch.where(g.visible.to(g.opacities.device), g.opacities, torch.zeros_like(g.opacities))
        out = SplatArrays(mean_t=mean_t, motion=motion, accel=np.zeros((n, 4), np.float32),
                          cov=_pack_cov(g.covariances.double(), opacity, g.velocities),
                          sh=_pack_sh(g.sh), sh_degree=g.sh_degree, sh_degree_t=0,
                          duration=float(time_range[1] - time_range[0]) or 1.0, time_range=tuple(time_range),
                          time=float(time))
    _check_finite("Gaussians3D", out.mean_t, out.cov, out.sh)
    return out


def from_skinned(model: SkinnedGaussians) -> SplatArrays:
    """Time-independent arrays of a skinned model: its canonical native Gaussians' (`from_gaussians4d`) and its skin.
    Their speed column is the native one, which does not move a skinned Gaussian: the speed mode differences the
    carried means instead (`skinning` module doc)."""
    return replace(from_gaussians4d(model.gaussians), skin=SkinArrays.of(model))


def from_slice(model, t: float) -> SplatArrays:
    """Arrays of a model's slice at `t`, for models without a closed form in t the shaders know (keyframed; any
    model with ``slice``): re-made whenever the displayed time changes."""
    with torch.no_grad():
        return from_gaussians3d(model.slice(float(t)), float(t), model.time_range)


#: Times (evenly spread over the time range) at which `typical_speed` measures a skinned model's speeds.
SPEED_TIMES = 9


#: The "speed" render mode maps 0 .. this quantile of a model's speeds to its colour map (a few fast outliers do
#: not wash out the rest).
SPEED_QUANTILE = 0.98


def typical_speed(model, arrays: SplatArrays) -> float:
    """The top of the "speed" colour map for a whole model (not per frame, so that colours mean the same at
    every time): the `SPEED_QUANTILE` of its Gaussians' speeds. `arrays` are the model's (`to_arrays`): their speeds
    for a native 4D model, valid at every time; a keyframed model's come from every key segment, a skinned model's
    from the steps between `SPEED_TIMES` times (of the Gaussians drawn at either end). 1 for a model that does not
    move."""
    if isinstance(model, KeyframedGaussians) and model.num_frames > 1:
        with torch.no_grad():
            means, times = model.means.detach().cpu().double(), model.times.detach().cpu().double()
            speeds = (torch.linalg.vector_norm(means.diff(dim=0), dim=-1) / times.diff()[:, None]).numpy()
    elif isinstance(model, SkinnedGaussians) and model.duration > 0:
        speeds = _sampled_speeds(model, np.linspace(*model.time_range, SPEED_TIMES))
    else:
        speeds = arrays.speed
    top = float(np.quantile(speeds, SPEED_QUANTILE)) if speeds.size else 0.0
    return top if np.isfinite(top) and top > 0 else 1.0


def _sampled_speeds(model, times: np.ndarray) -> np.ndarray:
    """Speeds (chord length over time) of `model`'s Gaussians over each step between consecutive `times`, of those
    drawn at either end of the step (flattened, float64)."""
    with torch.no_grad():
        centres = [(m.detach().cpu().double(), v.cpu()) for m, v in model.centres(times.tolist())]
    steps = [(torch.linalg.vector_norm(b - a, dim=-1) / (t1 - t0))[va | vb]
             for (a, va), (b, vb), t0, t1 in zip(centres, centres[1:], times, times[1:])]
    return torch.cat(steps).numpy() if steps else np.zeros(0)


def needs_per_frame_upload(model) -> bool:
    """True for models whose per-Gaussian GPU data must be re-made when t changes (keyframed), False for native 4D
    and skinned ones (whose node poses alone change)."""
    return isinstance(model, KeyframedGaussians)


def to_arrays(model, t: float | None = None) -> SplatArrays:
    """Arrays for any model: native 4D or skinned (valid for all t), keyframed (slice at `t`, default the start of
    its time range) or a `Gaussians3D`."""
    if isinstance(model, Gaussians4D):
        return from_gaussians4d(model)
    if isinstance(model, SkinnedGaussians):
        return from_skinned(model)
    t0 = float(model.time_range[0]) if hasattr(model, "time_range") else 0.0
    if isinstance(model, KeyframedGaussians):
        return from_slice(model, t0 if t is None else t)
    if isinstance(model, Gaussians3D):
        return from_gaussians3d(model, 0.0 if t is None else t)
    raise ModelError(f"cannot render a {type(model).__name__}; expected Gaussians4D, KeyframedGaussians, "
                     f"SkinnedGaussians or Gaussians3D")
