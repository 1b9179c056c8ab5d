"""The ``.4dgs`` container of the ``fourdgs`` package (avala-ai/4dgs, Apache-2.0; PyPI ``fourdgs``): read it as a
native 4D model, and the mapping `splatreel.export.four_dgs` writes through the same package.

A ``.4dgs`` Gaussian ("gaussian-birth" temporal model, the spec's §3) is drawn at scene time t (seconds) at
``position + motion (t - mu_t)`` with its constant rotation and scales, opacity ``alpha exp(-((t - mu_t) /
sigma_t)^2 / 2)``, cut below 0.05 and outside its window [win_lo, win_hi). That is native 4D slicing exactly
(Yang et al. 2024: the conditional mean moves linearly, the conditional covariance is constant), with
k seconds per unit of model time: motion = v / k, mu_t = (mu_t - t0) k, sigma_t = sqrt(Σ_tt) k. Colours are the
DC colour (sRGB-encoded, clip(0.5 + C0 dc, 0, 1), as 3DGS PLY importers read them) and the spatial SH bands 1-3 as
bytes in [-4, 4]; the colour's time terms are averaged out. The file's own quantisation (profile ``fine`` by
default: positions within 2 % of the median scale) is the only other loss.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import CheckpointError

MAGIC = b"\x894DGS"
SH_RANGE = 4.0  # a byte b stands for -4 + 8 b / 255


def sniff(path: Path) -> bool:
    """Whether `path` is a ``.4dgs`` file (its magic bytes)."""
    try:
        with open(path, "rb") as f:
            return path.is_file() and f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def sh_to_bytes(sh_rest: np.ndarray) -> np.ndarray:
    """``[N, K, 3]`` SH coefficients beyond the DC -> ``[N, 3 K]`` uint8, channel-major (all R, then G, then B)."""
    clipped = np.clip(sh_rest, -SH_RANGE, SH_RANGE)
    b = np.round((clipped + SH_RANGE) * 255.0 / (2 * SH_RANGE)).astype(np.uint8)
    return np.ascontiguousarray(b.transpose(0, 2, 1).reshape(len(b), -1))


def sh_from_bytes(b: np.ndarray, count: int) -> np.ndarray:
    """Inverse of `sh_to_bytes`: ``[N, 3 K]`` uint8 -> ``[N, K, 3]`` float32."""
    k = b.shape[1] // 3
    values = b.astype(np.float32) * (2 * SH_RANGE / 255.0) - SH_RANGE
    return values.reshape(count, 3, k).transpose(0, 2, 1)


def read_four_dgs(path: Path, **options):
    """A ``.4dgs`` file as a native 4D `Checkpoint` over [0, duration] seconds (``--time-range`` rescales it)."""
    import fourdgs
    import torch

    from ..checkpoint import Checkpoint
    from ..covariance import covariance_3d, covariance_4d_from_motion, decompose_covariance_4d
    from ..model import Gaussians4D
    from ..sh import SH_C0, sh_degree_from_bases
    from .options import ImportRecord, check_options

    path = Path(path)
    record = ImportRecord(path, "4dgs", check_options(options))
    try:
        scene = fourdgs.read(str(path))
    except fourdgs.FourdgsError as exc:
        raise CheckpointError(f"{path}: not a readable .4dgs file ({exc})") from None
    g, duration = scene.gaussians, float(scene.duration_sec)
    if g.count == 0:
        raise CheckpointError(f"{path}: the .4dgs holds no Gaussians")
    t0, t1 = record.option("time_range", (0.0, duration), "the file's duration in seconds")
    seconds_per_unit = duration / (float(t1) - float(t0))
    narrow = (g.win_lo > 0) | (g.win_hi < duration)
    if narrow.any():
        record.warn(f"{int(narrow.sum()):,} Gaussians have a validity window shorter than the clip; native 4D "
                    "Gaussians have none, so they show wherever their temporal weight does")
    sigma = np.where(np.isfinite(g.sigma_t), g.sigma_t, 1e3 * duration).astype(np.float64)  # inf: never fades
    var_t = torch.as_tensor((sigma / seconds_per_unit) ** 2)
    velocity = torch.as_tensor(g.motions.astype(np.float64) * seconds_per_unit)
    quats = torch.as_tensor(np.roll(g.rotations.astype(np.float32), 1, axis=1))  # x y z w -> w x y z
    quats = quats / quats.norm(dim=1, keepdim=True).clamp_min(1e-12)
    cov3 = covariance_3d(torch.as_tensor(g.scales.astype(np.float32)).clamp_min(1e-7), quats).double()
    scales, scale_t, q_l, q_r = decompose_covariance_4d(covariance_4d_from_motion(cov3, velocity, var_t))
    rgba = g.colors.astype(np.float32)
    opacity = np.clip(rgba[:, 3], 1e-6, 1 - 1e-6)
    sh_rest = sh_from_bytes(g.sh, g.count) if g.sh is not None and g.sh_degree > 0 else np.zeros((g.count, 0, 3))
    f32 = lambda a: torch.as_tensor(np.asarray(a, np.float32))  # noqa: E731
    model = Gaussians4D(
        means=f32(g.positions), t_means=f32(float(t0) + g.mu_t.astype(np.float64) / seconds_per_unit),
        log_scales=scales.clamp_min(1e-7).log().float(), log_t_scales=scale_t.clamp_min(1e-7).log().float(),
        quats_l=q_l.float(), quats_r=q_r.float(), opacity_logits=f32(np.log(opacity / (1 - opacity))),
        sh_dc=f32((rgba[:, None, :3] - 0.5) / SH_C0), sh_rest=f32(sh_rest),
        sh_degree=sh_degree_from_bases(sh_rest.shape[1] + 1), sh_degree_t=0, time_range=(float(t0), float(t1)),
        rotation_convention="current")
    record.facts.update(count=g.count, duration_sec=duration)
    record.finish()
    return Checkpoint(model=model, background=(0.0, 0.0, 0.0), provenance=record.provenance())
