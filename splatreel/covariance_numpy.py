"""NumPy twins of the slice math in `splatreel.covariance` (no torch), for tools that must start fast:
``splatreel info`` reports a checkpoint's bounds and splat sizes without importing torch. Same formulas, same
operation order, in the arrays' own dtype; `tests/test_info_numpy.py` compares them with the torch originals.

The 4D rotation is R4 = L(q_l) Rbar(q_r) (flipped on both axes under the "current" convention), with L(q) and
Rbar(q) the left and right isoclinic matrices (Yang et al., "Real-time Photorealistic Dynamic Scene Representation
and Rendering with 4D Gaussian Splatting", ICLR 2024, https://arxiv.org/abs/2310.10642, eq. 5-6).
"""

from __future__ import annotations

import numpy as np

from .constants import TEMPORAL_CULL

# L(q) and Rbar(q) as (component index, sign) per matrix entry, row-major. `splatreel.covariance` builds its torch
# matrices from these same tables.
_ISOCLINIC_INDEX = (0, 1, 2, 3, 1, 0, 3, 2, 2, 3, 0, 1, 3, 2, 1, 0)
_LEFT_SIGN = (1, -1, -1, -1, 1, 1, -1, 1, 1, 1, 1, -1, 1, -1, 1, 1)
_RIGHT_CONJ_SIGN = (1, 1, 1, 1, -1, 1, -1, 1, -1, 1, 1, -1, -1, -1, 1, 1)
#: Names of the 4D rotation conventions as `splatreel.covariance.parse_convention` reads them.
CONVENTION_ALIASES = {"current": "current", "flipped": "current", "main": "current", "legacy": "legacy"}


def normalize(q: np.ndarray) -> np.ndarray:
    """``[..., 4]`` q / |q| (eps 1e-12), as `splatreel.quaternion.normalize`."""
    return q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), q.dtype.type(1e-12))


def _signed_gather(q: np.ndarray, sign: tuple) -> np.ndarray:
    return (q[..., list(_ISOCLINIC_INDEX)] * np.asarray(sign, q.dtype)).reshape(q.shape[:-1] + (4, 4))


def rotation_4d(q_l: np.ndarray, q_r: np.ndarray, convention: str = "current") -> np.ndarray:
    """``[N, 4]`` left and right quaternions -> ``[N, 4, 4]`` R4 (`splatreel.covariance.rotation_4d`)."""
    a = _signed_gather(normalize(q_l), _LEFT_SIGN) @ _signed_gather(normalize(q_r), _RIGHT_CONJ_SIGN)
    return a[..., ::-1, ::-1] if CONVENTION_ALIASES[convention] == "current" else a


def covariance_4d(scales: np.ndarray, scale_t: np.ndarray, q_l: np.ndarray, q_r: np.ndarray,
                  convention: str = "current") -> np.ndarray:
    """``[N, 4, 4]`` R4 diag(s)^2 R4ᵀ from ``[N, 3]`` spatial and ``[N]`` temporal std-devs."""
    s4 = np.concatenate([scales, scale_t[..., None]], -1)
    m = rotation_4d(q_l, q_r, convention) * s4[..., None, :]
    return m @ np.swapaxes(m, -1, -2)


def condition_on_time(cov4: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cov3 ``[N, 3, 3]``, velocity ``[N, 3]``, var_t ``[N]``) as `splatreel.covariance.condition_on_time`."""
    s12 = cov4[..., :3, 3]
    var_t = cov4[..., 3, 3]
    velocity = s12 / var_t[..., None]
    cov3 = cov4[..., :3, :3] - velocity[..., :, None] * s12[..., None, :]
    return cov3, velocity, var_t


def centres_4d(arrays: dict[str, np.ndarray], convention: str, times) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(means [N, 3], visible [N])`` of a native 4D model (its checkpoint tensors) at each time, as
    `splatreel.model.Gaussians4D.centres`."""
    cov4 = covariance_4d(np.exp(arrays["log_scales"]), np.exp(arrays["log_t_scales"]), arrays["quats_l"],
                         arrays["quats_r"], convention)
    _, velocity, var_t = condition_on_time(cov4)
    t_means = arrays["t_means"]
    out = []
    for t in times:
        dt = t_means.dtype.type(t) - t_means
        marginal = np.exp(-0.5 * dt * dt / var_t)
        out.append((arrays["means"] + velocity * dt[:, None], marginal > TEMPORAL_CULL))
    return out


def largest_std_devs_4d(arrays: dict[str, np.ndarray], convention: str) -> np.ndarray:
    """``[N]`` largest std-dev of each Gaussian's conditional 3D covariance (the same at every time), from its
    eigenvalues in float64 as ``splatreel info`` computes them."""
    cov4 = covariance_4d(np.exp(arrays["log_scales"]), np.exp(arrays["log_t_scales"]), arrays["quats_l"],
                         arrays["quats_r"], convention)
    cov3 = condition_on_time(cov4)[0]
    return np.sqrt(np.maximum(np.linalg.eigvalsh(cov3.astype(np.float64)), 0.0)[:, -1])
