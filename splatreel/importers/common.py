"""Small helpers shared by the importers: safe ``cfg_args`` parsing, value checks, static models, file ordering."""

from __future__ import annotations

import ast
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from ..errors import CheckpointError
from ..model import Gaussians4D, static_gaussians4d


def parse_cfg_args(text: str) -> dict[str, Any]:
    """The keyword values of a ``Namespace(...)`` repr (the ``cfg_args`` file of 3DGS-derived trainers).

    Only literal values are read (``ast.literal_eval`` per keyword); anything else is skipped, never evaluated.
    Returns an empty dict when the text is not a ``Namespace(...)`` call.
    """
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except (SyntaxError, ValueError):
        return {}
    call = tree.body
    if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.func.id == "Namespace"):
        return {}
    out = {}
    for kw in call.keywords:
        if kw.arg is None:
            continue
        try:
            out[kw.arg] = ast.literal_eval(kw.value)
        except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
            continue
    return out


def find_cfg_args(start: Path, levels: int = 3) -> tuple[Path | None, dict[str, Any]]:
    """Look for a ``cfg_args`` file in `start` (a folder) and up to `levels` parents; (path, parsed values)."""
    folder = start
    for _ in range(levels + 1):
        candidate = folder / "cfg_args"
        if candidate.is_file():
            try:
                return candidate, parse_cfg_args(candidate.read_text(errors="replace"))
            except OSError:
                return None, {}
        if folder.parent == folder:
            break
        folder = folder.parent
    return None, {}


def background_from_cfg(cfg: dict[str, Any]) -> tuple[float, float, float] | None:
    """(1,1,1) / (0,0,0) from a cfg_args ``white_background`` flag, or None when absent."""
    if isinstance(cfg.get("white_background"), bool):
        return (1.0, 1.0, 1.0) if cfg["white_background"] else (0.0, 0.0, 0.0)
    return None


def require_finite(path: Path, name: str, value: Tensor) -> None:
    """Raise CheckpointError naming `path` and the field when `value` holds NaN or infinite numbers."""
    if value.is_floating_point() and not bool(torch.isfinite(value).all()):
        bad = int((~torch.isfinite(value)).sum())
        raise CheckpointError(f"{path}: {name} contains {bad} NaN or infinite value(s)")


def natural_key(path: Path) -> list:
    """Sort key that orders ``frame_2`` before ``frame_10``."""
    return [int(p) if p.isdigit() else p.lower() for p in re.split(r"(\d+)", path.name)]


def static_model(means: Tensor, log_scales: Tensor, quats: Tensor, opacity_logits: Tensor, sh: Tensor,
                 sh_degree: int, time_range: tuple[float, float], t_means: Tensor | None = None,
                 log_t_scales: Tensor | None = None, sh_degree_t: int = 0) -> Gaussians4D:
    """Gaussians4D whose slice at every time is the given 3D Gaussians (a 3DGS model, a non-rot 4D model).

    Built on `static_gaussians4d` (equal left/right quaternions under the 'current' convention, so that the
    spatial covariance is exactly R(quats) diag(exp(log_scales))^2 R(quats)^T and nothing moves); the raw
    log-scales and logits are then put back so that nothing is lost to an exp/log round trip.

    Args:
        means: ``[N, 3]``; log_scales: ``[N, 3]``; quats: ``[N, 4]`` w first, unnormalised;
        opacity_logits: ``[N]``; sh: ``[N, M, 3]`` colour coefficients, M = (sh_degree+1)^2 (sh_degree_t+1).
        t_means, log_t_scales: ``[N]`` temporal centres and log temporal std-devs (a model that fades in and
            out); default: centred and so wide that the opacity never fades over `time_range` (the marginal
            stays above 1 - 1e-6).
    """
    n = means.shape[0]
    duration = time_range[1] - time_range[0]
    base = static_gaussians4d(means, torch.exp(log_scales), quats, torch.full((n,), 0.5, dtype=means.dtype),
                              torch.zeros((n, 3), dtype=means.dtype), time_range=time_range,
                              t_scale=1e3 * max(1.0, duration))
    fields = dict(log_scales=log_scales, opacity_logits=opacity_logits, sh_dc=sh[:, :1].contiguous(),
                  sh_rest=sh[:, 1:].contiguous(), sh_degree=sh_degree, sh_degree_t=sh_degree_t)
    if t_means is not None:
        fields["t_means"] = t_means
    if log_t_scales is not None:
        fields["log_t_scales"] = log_t_scales
    return replace(base, **fields)


def as_float_tensor(path: Path, name: str, value: Any, shape: tuple, dtype=torch.float32) -> Tensor:
    """`value` as a detached CPU float tensor of `shape` (-1 = any size); CheckpointError naming `name` else.

    Parameters saved from CUDA arrive on the CPU already (``map_location``); gradients are dropped.
    """
    if not isinstance(value, Tensor):
        raise CheckpointError(f"{path}: {name} should be a tensor, found {type(value).__name__}")
    if value.dim() != len(shape) or any(s != -1 and s != v for s, v in zip(shape, value.shape)):
        want = "[" + ", ".join("N" if s == -1 else str(s) for s in shape) + "]"
        raise CheckpointError(f"{path}: {name} has shape {list(value.shape)}, expected {want}")
    if not (value.is_floating_point()):
        raise CheckpointError(f"{path}: {name} has dtype {value.dtype}, expected a float tensor")
    out = value.detach().to(device="cpu", dtype=dtype)
    require_finite(path, name, out)
    return out
