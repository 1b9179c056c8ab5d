"""What every exporter shares: frame times, per-frame arrays from ``model.slice(t)``, errors and the registry.

Exporters never look inside a model: they call ``model.slice(t)`` (any `Gaussians4D`, `KeyframedGaussians` or
`SkinnedGaussians`) at the frame times and turn the resulting `Gaussians3D` into the numpy arrays of a
`SplatFrame`. Conventions fixed here and used by every format:

* Frame i of F is at model time ``t0 + i (t1 - t0) / (F - 1)`` (``t0`` alone when F = 1), where (t0, t1) is the
  model's ``time_range`` or the ``--start``/``--end`` override; a time outside the model's range is an error.
* Particle order is the model's order at every frame. A Gaussian that the slice marks invisible (temporal
  marginal <= TEMPORAL_CULL) keeps its slot with opacity 0, so arrays have the same length N at every frame.
* Colours for fallbacks (USD displayColor, mesh vertex colours) are the view-independent DC colour
  ``clip(0.5 + SH_C0 * dc, 0, 1)`` (sRGB-encoded, as the SH of a 3DGS model); `srgb_to_linear` converts it where
  a format wants linear colour (USD displayColor, glTF COLOR_0).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence

import numpy as np

import torch

from splatreel.constants import RADIUS_SIGMAS
from splatreel.covariance import decompose_covariance_3d, nearest_equivalent
from splatreel.errors import ModelError, SplatreelError
from splatreel.sh import SH_C0, sh_to_rgb


class ExportError(SplatreelError):
    """Bad export arguments (frames, times, options) or an output that cannot be produced."""


# --- frame times ---------------------------------------------------------------------------------------------

def frame_times(time_range: tuple[float, float], frames: int, start: float | None = None,
                end: float | None = None) -> np.ndarray:
    """``[F]`` float64 model times of the exported frames (see module doc).

    Raises:
        ExportError: `frames` < 1, start > end, or a start/end that is not a number. A start/end outside
        `time_range` is exported as asked, with a warning (`splatreel.argtypes.warn_outside_time_range`).
    """
    from splatreel.argtypes import warn_outside_time_range

    t0, t1 = float(time_range[0]), float(time_range[1])
    if int(frames) != frames or frames < 1:
        raise ExportError(f"--frame-count must be a positive integer, got {frames}")
    a = t0 if start is None else float(start)
    b = t1 if end is None else float(end)
    for name, v in (("--start", a), ("--end", b)):
        if not np.isfinite(v):
            raise ExportError(f"{name} must be a number, got {v}")
        warn_outside_time_range(v, (t0, t1), name)
    if a > b:
        raise ExportError(f"--start {a:g} is after --end {b:g}")
    if frames > 1 and a == b:
        raise ExportError(f"--start equals --end ({a:g}) but {frames} frames were asked for")
    if frames == 1:
        return np.array([a], dtype=np.float64)
    return np.clip(a + (b - a) * np.arange(frames, dtype=np.float64) / (frames - 1), a, b)  # no rounding past b


def time_step(times: Sequence[float]) -> float:
    """Model time between consecutive frames of uniformly spaced `times` (0 for a single frame)."""
    return (float(times[-1]) - float(times[0])) / (len(times) - 1) if len(times) > 1 else 0.0


# --- per-frame arrays ----------------------------------------------------------------------------------------

@dataclass
class SplatFrame:
    """The arrays of one exported frame (N = every Gaussian of the model, in model order; all float32).

    Attributes:
        index: frame number i (also the USD time code).
        time: model time of the frame.
        means: ``[N, 3]`` centres.
        quats: ``[N, 4]`` unit rotations, w first: a model's own (keyframed) with the sign of the previous frame's
            hemisphere, or decomposed from the covariances in the equivalent form nearest the previous frame's
            (`splatreel.covariance.nearest_equivalent`).
        scales: ``[N, 3]`` linear std-devs along the rotated axes (covariance = R diag(scales)^2 Rᵀ).
        opacities: ``[N]`` activated opacity in [0, 1] (temporal factor applied); exactly 0 where not visible.
        sh: ``[N, K, 3]`` spatial SH coefficients at this time, K = (sh_degree + 1)^2, 3DGS order.
        visible: ``[N]`` bool, the slice's visibility.
        velocities: ``[N, 3]`` d(mean)/d(model time); zeros when the model has none.
        radii: ``[N, 3]`` half-extent of each Gaussian's 3-sigma ellipsoid along the world axes, 3 sqrt(diag Σ).
        sh_degree: spatial SH degree.
    """

    index: int
    time: float
    means: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    visible: np.ndarray
    velocities: np.ndarray
    radii: np.ndarray
    sh_degree: int

    def __len__(self) -> int:
        return self.means.shape[0]

    def dc_rgb(self) -> np.ndarray:
        """``[N, 3]`` view-independent colour in [0, 1] (sRGB-encoded): clip(0.5 + SH_C0 * dc, 0, 1)."""
        return np.clip(sh_to_rgb(SH_C0 * self.sh[:, 0, :]), 0.0, 1.0)


def _numpy(x: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(x.detach().to("cpu", torch.float32).numpy())


def slice_frame(model, t: float, index: int = 0, previous: SplatFrame | None = None,
                _cache: dict | None = None) -> SplatFrame:
    """Slice `model` at time `t` into a `SplatFrame`.

    `previous` (the frame before) keeps quaternion signs continuous. `_cache` (a dict owned by the caller, e.g.
    `iter_frames`) remembers the last covariance decomposition: native 4D Gaussians have time-constant conditional
    covariances, so the eigen-decomposition is done once per export instead of once per frame.

    Raises:
        ModelError: the slice has non-finite values.
    """
    with torch.no_grad():
        g = model.slice(float(t))
        cov = g.covariances
        if g.scales is not None and g.quats is not None:
            scales, quats = g.scales, g.quats
        elif _cache is not None and _cache.get("cov") is not None and _cache["cov"].shape == cov.shape \
                and torch.equal(_cache["cov"], cov):
            scales, quats = _cache["scales"], _cache["quats"]
        else:
            scales, quats = decompose_covariance_3d(cov)
            if _cache is not None:
                _cache.update(cov=cov, scales=scales, quats=quats)
        opacities = torch.where(g.visible, g.opacities, torch.zeros_like(g.opacities))
        diag = torch.diagonal(cov, dim1=-2, dim2=-1).clamp_min(0)
        velocities = g.velocities if g.velocities is not None else torch.zeros_like(g.means)
        arrays = {"means": g.means, "quats": quats, "scales": scales, "opacities": opacities, "sh": g.sh,
                  "velocities": velocities, "radii": RADIUS_SIGMAS * diag.sqrt()}
        out = {k: _numpy(v) for k, v in arrays.items()}
    bad = [k for k, v in out.items() if not np.isfinite(v).all()]
    if bad:
        raise ModelError(f"the model gives non-finite {', '.join(bad)} at t={t:g}")
    if previous is not None and len(previous) == out["quats"].shape[0]:
        q = out["quats"]  # may share memory with the cached decomposition: never modify it in place
        if g.quats is None:  # decomposed: its axes' signs are arbitrary, take the form nearest the previous frame's
            out["quats"] = nearest_equivalent(torch.from_numpy(q), torch.from_numpy(previous.quats)).numpy()
        else:  # the model's own rotations: only the sign is free
            out["quats"] = np.where(((q * previous.quats).sum(-1) < 0)[:, None], -q, q)
    return SplatFrame(index=index, time=float(t), visible=g.visible.detach().cpu().numpy().astype(bool),
                      sh_degree=int(g.sh_degree), **out)


def iter_frames(model, times: Sequence[float], progress: bool = False, desc: str = "frames"
                ) -> Iterator[SplatFrame]:
    """Yield the `SplatFrame` of every time in `times` (a tqdm bar when `progress`)."""
    from tqdm import tqdm

    cache: dict = {}
    previous = None
    for i, t in enumerate(tqdm(list(times), desc=desc, unit="frame", disable=not progress, leave=False)):
        previous = slice_frame(model, t, i, previous, cache)
        yield previous


def with_neighbours(frames: Iterable[SplatFrame]
                    ) -> Iterator[tuple[SplatFrame | None, SplatFrame, SplatFrame | None]]:
    """Yield (previous, current, next) over `frames`, None past either end (one frame of look-ahead)."""
    prev = cur = None
    for nxt in frames:
        if cur is not None:
            yield prev, cur, nxt
        prev, cur = cur, nxt
    if cur is not None:
        yield prev, cur, None


def live_near(prev: SplatFrame | None, cur: SplatFrame, nxt: SplatFrame | None) -> np.ndarray:
    """``[N]`` bool: visible at this frame or at a neighbouring one.

    Between two samples a reader interpolates opacity linearly, so a Gaussian visible at either end is drawn in
    between; an extent built from these covers everything drawn at any in-between time.
    """
    mask = cur.visible.copy()
    for other in (prev, nxt):
        if other is not None and len(other) == len(cur):
            mask |= other.visible
    return mask


def box_of(centres: np.ndarray, half: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """``[2, 3]`` float32 (min, max) of the boxes ``centres ± half`` (``[N, 3]`` each, ``half`` may broadcast) where
    `mask`; the box of all centres when the mask selects nothing, zeros when there are no centres."""
    if mask is not None and mask.any():
        centres = centres[mask]
        half = half[mask] if np.ndim(half) and np.shape(half)[0] == mask.shape[0] else half
    elif mask is not None:
        half = 0.0
    if centres.shape[0] == 0:
        return np.zeros((2, 3), np.float32)
    return np.stack([(centres - half).min(0), (centres + half).max(0)]).astype(np.float32)


#: Formats whose readers take +Y as up whatever a file says: glTF 2.0 (its spec: "+Y is up") and OBJ (no up axis
#: of its own; Blender's and most DCC importers assume +Y)
Y_UP_FORMATS = ("glb", "gltf", "obj")


def to_y_up(vectors: np.ndarray, up_axis: str) -> np.ndarray:
    """``[..., 3]`` points or directions of a model whose up axis is `up_axis` ("Y" or "Z") in +Y-up coordinates.

    Z up: ``(x, y, z) -> (x, z, -y)``, a -90 degree turn about X (right-handed stays right-handed; the model's
    front, -Y in a Z-up scene, becomes +Z), the conversion Blender's glTF exporter makes.
    """
    if str(up_axis).upper() == "Y":
        return vectors
    v = np.asarray(vectors)
    return np.stack([v[..., 0], v[..., 2], -v[..., 1]], -1)


@dataclass(frozen=True)
class LinearMotion:
    """A native 4D model as Gaussians that move along a polynomial path and fade in and out (float64 arrays, model
    order): what formats of moving splats (``.splatv``, ``.4dgs``, the web player) store. Exact for native 4D
    Gaussians (Yang et al. 2024): the slice at t is the conditional Gaussian, whose covariance is fixed and whose mean
    is means + velocity tau + acceleration tau^2 / 2 (tau = t - mu_t): linear for native 4DGS (acceleration 0), with
    the quadratic term of Spacetime Gaussians (Li et al., CVPR 2024) for a model with `Gaussians4D.accelerations`.

    Attributes:
        means: ``[N, 3]`` mu_xyz, the conditional mean at the Gaussian's own time.
        t_means: ``[N]`` mu_t.
        velocity: ``[N, 3]`` Σ_xt / Σ_tt, per unit of model time: the velocity at mu_t.
        acceleration: ``[N, 3]`` the model's accelerations, per unit of model time squared; zeros when it has none.
        var_t: ``[N]`` Σ_tt: opacity(t) = opacity * exp(-(t - mu_t)^2 / (2 var_t)).
        scales, quats: ``[N, 3]`` std-devs and ``[N, 4]`` w-first rotations of the conditional covariance.
        opacity: ``[N]`` sigmoid of the logit.
        dc_rgb: ``[N, 3]`` the DC colour clip(0.5 + C0 d, 0, 1), sRGB-encoded, where d averages the colour's time
            terms under the Gaussian's own temporal weight: d = sum_n exp(-(2 pi n / T)^2 var_t / 2) c_n.
        sh_rest: ``[N, K - 1, 3]`` the constant spatial SH beyond the DC (time terms dropped).
    """

    means: np.ndarray
    t_means: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    var_t: np.ndarray
    scales: np.ndarray
    quats: np.ndarray
    opacity: np.ndarray
    dc_rgb: np.ndarray
    sh_rest: np.ndarray


def linear_motion(model, format_name: str) -> LinearMotion:
    """`LinearMotion` of a native 4D model (with its accelerations, if any); ExportError naming `format_name` for a
    model of another kind."""
    import math

    from splatreel.covariance import condition_on_time
    from splatreel.sh import num_sh_bases

    if model.kind != "gaussians4d":
        raise ExportError(f"{format_name} holds linearly moving Gaussians; a {model.kind} model has none (export its "
                          "frames with export ply or export gltf, or the whole model with export web)")
    span = float(model.time_range[1] - model.time_range[0])
    with torch.no_grad():
        cov3, velocity, var_t = condition_on_time(model.covariance_4d().double())
        scales, quats = decompose_covariance_3d(cov3)
        k = num_sh_bases(model.sh_degree)
        coeffs = model.sh_coeffs.double()
        dc = coeffs[:, 0]
        for n in range(1, model.sh_degree_t + 1):
            dc = dc + torch.exp(-0.5 * (2.0 * math.pi * n / span) ** 2 * var_t)[:, None] * coeffs[:, n * k]
        acceleration = model.accelerations_or_zeros().detach().to("cpu", torch.float64)
        return LinearMotion(
            means=model.means.double().numpy(), t_means=model.t_means.double().numpy(),
            velocity=velocity.numpy(), acceleration=acceleration.numpy(), var_t=var_t.numpy(), scales=scales.numpy(),
            quats=quats.numpy(),
            opacity=model.opacities.double().numpy(), dc_rgb=(0.5 + SH_C0 * dc).clamp(0.0, 1.0).numpy(),
            sh_rest=coeffs[:, 1:k].numpy())


def resolve_up_axis(explicit: str | None, provenance: dict | None) -> str:
    """The up axis to declare: `explicit` ("Y"/"Z") if given, else the checkpoint provenance's ``up_axis``, else Y."""
    up = str(explicit or (provenance or {}).get("up_axis", "Y")).upper()
    return up if up in ("Y", "Z") else "Y"


# --- sequences on disk ---------------------------------------------------------------------------------------

def frame_file_name(prefix: str, index: int, ext: str) -> str:
    """``{prefix}_{index:06d}.{ext}``, the name of frame `index` of a per-frame sequence."""
    return f"{prefix}_{index:06d}.{ext}"


def manifest(kind: str, times: Sequence[float], files: Sequence[str], fps: float, **extra) -> bytes:
    """``manifest.json`` bytes describing a per-frame sequence: the frame -> (time code, model time, file) table,
    frames per second and whatever conventions the format adds in `extra`."""
    doc = {"format": kind, "fps": float(fps), "num_frames": len(files),
           "frames": [{"index": i, "time": float(t), "file": f} for i, (t, f) in enumerate(zip(times, files))],
           **extra}
    return (json.dumps(doc, indent=2) + "\n").encode()


# --- registry ------------------------------------------------------------------------------------------------

def exporters() -> dict:
    """Name -> `splatreel.formats.Writer` of every output format (the ``splatreel export`` choices), from the one
    registry in `splatreel.formats`."""
    from splatreel.formats import writers

    return {w.name: w for w in writers()}
