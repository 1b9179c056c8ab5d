"""``.splatv`` (splaTV, gsplat.js): the whole 4D model in one file that web players of Spacetime Gaussians play.

The record layout and container are in `splatreel.importers.splatv`, which reads them back. A native 4D Gaussian
(Yang et al. 2024), with or without accelerations, maps onto a record exactly, but for its colour (T = t1 - t0,
tau = (t - t0) / T the player's time):

* position p0 = mu_xyz, the conditional mean at the Gaussian's own time mu_t;
* motion: the player moves a splat by m1 dtau + m2 dtau^2 + m3 dtau^3, dtau = tau - c = (t - mu_t) / T (splaTV
  ``hybrid.js``), so m1 = T * Σ_xt / Σ_tt (the velocity per unit of tau) and m2 = a T^2 / 2, the quadratic
  coefficient of the model's acceleration a (`Gaussians4D.accelerations`, the polynomial motion of Spacetime
  Gaussians, Li et al. CVPR 2024; 0 for native linear motion); jerk m3 and rotation velocity 0 (the conditional
  covariance is constant);
* rotation and scale = the eigen-decomposition of the conditional covariance Σ_xx - Σ_xt Σ_xtᵀ / Σ_tt;
* temporal centre c = (mu_t - t0) / T and width s = sqrt(2 Σ_tt) / T, so that the player's exp(-((tau - c) / s)^2)
  equals the native temporal marginal exp(-(t - mu_t)^2 / (2 Σ_tt)) (s at least 1e-4: half floats underflow);
* opacity = sigmoid(logit), 8-bit;
* colour = the DC term, 8-bit sRGB: with time terms, their average under the Gaussian's own temporal weight,
  d = Σ_n exp(-(2 pi n / T)^2 Σ_tt / 2) c_n (the characteristic function of that weight).

What is lost: view dependence (SH degree >= 1) and the remaining time dependence of the colour, 8-bit colour and
opacity, half-float precision elsewhere; the player cuts a splat at 2.83 sigma and culls it below 0.02 of its peak
(the reference: 3 sigma, 0.05). Records are written largest (volume times opacity) first, as splaTV's own
converter does, since the player shows a file while it streams. A keyframed model has no closed-form motion: it is
refused (export its frames to PLY or glTF instead).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from splatreel.fileio import atomic_write_bytes
from splatreel.importers.splatv import MIN_WIDTH, RECORD, splatv_bytes

from .base import ExportError, linear_motion

#: image size of the camera the file suggests (splaTV reads its focal lengths; gsplat.js starts from it)
CAMERA_SIZE = (1280, 720)
CAMERA_FOV_DEG = 40.0


def splatv_records(model) -> np.ndarray:
    """The `RECORD` array of a native 4D model, in drawing-priority order (see module doc)."""
    g = linear_motion(model, ".splatv")
    t0, t1 = model.time_range
    span = float(t1) - float(t0)
    records = np.zeros(len(model), RECORD)
    records["position"] = g.means
    records["rotation"] = g.quats
    records["scale"][:, :3] = g.scales
    records["rgba"][:, :3] = np.round(g.dc_rgb * 255.0)
    records["rgba"][:, 3] = np.round(g.opacity * 255.0)
    records["motion"][:, :3] = g.velocity * span
    records["motion"][:, 3:6] = 0.5 * g.acceleration * span * span  # the coefficient of dtau^2
    records["trbf"][:, 0] = (g.t_means - t0) / span
    records["trbf"][:, 1] = np.maximum(np.sqrt(2.0 * g.var_t) / span, MIN_WIDTH)
    importance = g.scales.prod(1) * g.opacity
    return records[np.argsort(-importance, kind="stable")]


def default_camera(model) -> dict:
    """One camera in 3DGS ``cameras.json`` form (centre, camera-to-world rotation, OpenCV axes) looking at the
    model from its front-left, above it: splaTV needs its focal lengths, gsplat.js starts from it."""
    from splatreel.cameras import look_at_c2w
    from splatreel.model import model_bounds

    lo, hi = (b.double().numpy() for b in model_bounds(model))
    centre, radius = 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)
    width, height = CAMERA_SIZE
    focal = 0.5 * height / math.tan(math.radians(CAMERA_FOV_DEG) / 2)
    direction = np.array([0.6, -0.7, 0.4]) / np.linalg.norm([0.6, -0.7, 0.4])
    eye = centre + radius / math.sin(math.radians(CAMERA_FOV_DEG) / 2) * direction
    rotation = look_at_c2w(eye, centre, up="z")[:3, :3]  # OpenCV axes, as 3DGS cameras.json
    return {"id": 0, "img_name": "splatreel", "width": width, "height": height, "position": eye.tolist(),
            "rotation": rotation.tolist(), "fx": focal, "fy": focal}


def write_splatv(model, out: str | Path, force: bool = False) -> Path:
    """Write `model` (native 4D) to `out` (``*.splatv``) atomically."""
    out = Path(out)
    if out.suffix.lower() != ".splatv":
        raise ExportError(f"{out}: a .splatv file name is needed")
    return atomic_write_bytes(out, splatv_bytes(splatv_records(model), [default_camera(model)]), force)


def add_args(p: argparse.ArgumentParser) -> None:
    """The format's own options of ``splatreel export splatv`` (none beyond the common ones)."""


def run(model, times, out, args) -> list[Path]:
    """``splatreel export splatv``: the whole model (the frame options do not apply: the player animates it)."""
    return [write_splatv(model, out, force=args.force)]
