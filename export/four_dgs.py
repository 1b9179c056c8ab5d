"""``.4dgs`` (the ``fourdgs`` package's container, avala-ai/4dgs): the whole native 4D model in one file, written
through that package. The mapping and what it keeps are in `splatreel.importers.four_dgs`, which reads it back.

The container's motion is linear. A model with accelerations (`Gaussians4D.accelerations`, the quadratic term of
Spacetime Gaussians) is still written, with each Gaussian's velocity at its temporal mean (Σ_xt / Σ_tt, exact there)
and its acceleration dropped; a one-line warning gives how far that moves a Gaussian at most within its own life
(|t - mu_t| <= 2 sqrt(Σ_tt), where its temporal marginal is above e^-2): max 2 |a| Σ_tt, in model units.
"""

from __future__ import annotations

import argparse
import io
import warnings
from pathlib import Path

import numpy as np

from splatreel.fileio import atomic_write_bytes
from splatreel.importers.four_dgs import sh_to_bytes

from .base import ExportError, linear_motion

PROFILES = ("fine", "default", "coarse")


def acceleration_drift(acceleration: np.ndarray, var_t: np.ndarray) -> float:
    """The most that dropping `acceleration` (``[N, 3]``) moves a Gaussian within 2 temporal std-devs of its mean:
    max over Gaussians of |a| (2 sqrt(var_t))^2 / 2 = 2 |a| var_t (0 without accelerations)."""
    if not len(var_t):
        return 0.0
    return float((2.0 * np.linalg.norm(acceleration, axis=1) * var_t).max())


def four_dgs_bytes(model, duration_sec: float | None = None, profile: str = "fine") -> bytes:
    """The ``.4dgs`` file of a native 4D model; `duration_sec`: the clip's length in seconds (default: one second per
    unit of model time). Warns (one line) when the model's accelerations are dropped (see module doc)."""
    import fourdgs

    g = linear_motion(model, ".4dgs")
    t0, t1 = (float(t) for t in model.time_range)
    duration = (t1 - t0) if duration_sec is None else float(duration_sec)
    if not duration > 0:
        raise ExportError(f"--duration must be positive, got {duration}")
    k = duration / (t1 - t0)  # seconds per unit of model time
    dropped = acceleration_drift(g.acceleration, g.var_t)
    if dropped > 0:
        warnings.warn(f".4dgs motion is linear: the model's accelerations are dropped (velocities kept at each "
                      f"Gaussian's temporal mean), which moves a Gaussian by up to {dropped:.3g} model units within "
                      "2 sigma_t of its temporal mean; export splatv or web to keep them, or train with --motion "
                      "linear for a model .4dgs holds exactly", stacklevel=2)
    n = len(model)
    sh = sh_to_bytes(g.sh_rest) if model.sh_degree > 0 else None
    gaussians = fourdgs.GaussianSet(
        positions=g.means.astype(np.float32), scales=g.scales.astype(np.float32),
        rotations=np.roll(g.quats, -1, axis=1).astype(np.float32),  # w x y z -> x y z w
        colors=np.concatenate([g.dc_rgb, g.opacity[:, None]], 1).astype(np.float32),
        motions=(g.velocity / k).astype(np.float32), mu_t=((g.t_means - t0) * k).astype(np.float32),
        sigma_t=(np.sqrt(g.var_t) * k).astype(np.float32), win_lo=np.zeros(n), win_hi=np.full(n, duration),
        sh=sh, sh_degree=int(model.sh_degree) if sh is not None else 0)
    buffer = io.BytesIO()
    fourdgs.write(buffer, gaussians, duration, options=fourdgs.WriteOptions(profile=profile, cutoff=0.05))
    return buffer.getvalue()


def add_args(p: argparse.ArgumentParser) -> None:
    """The format's own options of ``splatreel export 4dgs``."""
    from splatreel.argtypes import positive_number

    p.add_argument("--duration", type=positive_number, default=None, metavar="SECONDS",
                   help="the clip's length in seconds (default: one second per unit of model time)")
    p.add_argument("--profile", choices=PROFILES, default="fine",
                   help="the container's quantisation profile (default fine: positions within 2%% of the median "
                        "scale)")


def run(model, times, out, args) -> list[Path]:
    """``splatreel export 4dgs``: the whole model (the player animates it)."""
    out = Path(out)
    if out.suffix.lower() != ".4dgs":
        raise ExportError(f"{out}: a .4dgs file name is needed")
    return [atomic_write_bytes(out, four_dgs_bytes(model, args.duration, args.profile), args.force)]
