"""What changes over a run: the learning rates that decay and the SH degrees in use."""

from __future__ import annotations

import math

from .config import TrainConfig


def decayed_lr(step: float, iters: int, lr0: float, lr1: float) -> float:
    """Exponential decay from lr0 to lr1 over `iters` steps (official `get_expon_lr_func`)."""
    u = min(max(step / max(iters, 1), 0.0), 1.0)
    return math.exp((1 - u) * math.log(lr0) + u * math.log(lr1))


def scheduled_lrs(step: float, cfg: TrainConfig, extent: float) -> dict[str, float]:
    """The learning rates that change over the run: the means' (scaled by the scene extent) and, when
    `lr_quats_final` is set, the rotations'."""
    out = {"means": decayed_lr(step, cfg.iters, cfg.lr_means * extent, cfg.lr_means_final * extent)}
    if cfg.lr_quats_final:
        out["quats_l"] = out["quats_r"] = decayed_lr(step, cfg.iters, cfg.lr_quats, cfg.lr_quats_final)
    return out


def active_sh(step: float, cfg: TrainConfig) -> tuple[int, int]:
    """(spatial, time) SH degree in use at `step`: spatial first, then time, one more every sh_increase_every."""
    if not cfg.sh_increase_every:
        return cfg.sh_degree, cfg.sh_degree_t
    k = int(step // cfg.sh_increase_every)
    return min(k, cfg.sh_degree), min(max(0, k - cfg.sh_degree), cfg.sh_degree_t)
