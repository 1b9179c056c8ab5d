"""The ``.splatv`` format of splaTV and gsplat.js (Spacetime Gaussians "lite" for the web): read, and the bytes
`splatreel.export.splatv` writes.

Container (antimatter15/splaTV ``hybrid.js``; huggingface/gsplat.js ``src/loaders/SplatvLoader.ts``), little-endian:
u32 magic ``0x674B``, u32 length L of a JSON array of chunk descriptors, the JSON, then the chunks' bytes in order.
The one chunk, ``{"type": "splat", "size", "texwidth": 4096, "texheight": H, "cameras": [...]}``, is an RGBA32UI
texture of 64-byte records, 1024 per row, the last row zero-padded:

==========  =========  =====================================================================================
bytes       type       field
==========  =========  =====================================================================================
0-11        f32 x3     position p0 at the temporal centre
12-19       f16 x4     rotation (w, x, y, z)
20-27       f16 x4     scale (linear std-devs), 0
28-31       u8 x4      colour R, G, B (sRGB-encoded DC), opacity A
32-51       f16 x10    motion: the coefficients m1, m2, m3 (x, y, z each) of dtau, dtau^2, dtau^3, then 0
52-59       f16 x4     rotation velocity omega (w, x, y, z)
60-63       f16 x2     temporal centre c and width s (opacity times exp(-((tau - c) / s)^2)), tau in [0, 1]
==========  =========  =====================================================================================

The player draws a splat at its time tau in [0, 1] at p0 + m1 dtau + m2 dtau^2 + m3 dtau^3, dtau = tau - c, with
the rotation (w, x, y, z) + omega dtau (``hybrid.js``; Spacetime Gaussians' polynomial motion, Li et al. CVPR 2024).

A native 4D Gaussian, with or without accelerations, maps onto a record exactly but for its colour's view and time
dependence (only the DC is kept; see `splatreel.export.splatv`). Read back, a record becomes a native 4D Gaussian
over the time range (t0, t1) given by ``--time-range`` (default [0, 1]: the format stores no duration), T = t1 - t0:
p0, the velocity m1 / T, the record's covariance as the conditional one, a temporal variance s^2 / 2 (in the
player's time), and the acceleration a = 2 m2 / T^2 (`Gaussians4D.accelerations`; none when every m2 is 0). Jerk m3
and rotation velocity omega have no counterpart and are dropped with a warning when non-zero.
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np

from ..errors import CheckpointError

MAGIC = 0x674B
TEXTURE_WIDTH = 4096
PER_ROW = TEXTURE_WIDTH // 4  # four RGBA32UI texels (64 bytes) per record
RECORD = np.dtype([("position", "<f4", 3), ("rotation", "<f2", 4), ("scale", "<f2", 4), ("rgba", "u1", 4),
                   ("motion", "<f2", 10), ("omega", "<f2", 4), ("trbf", "<f2", 2)])
assert RECORD.itemsize == 64
#: the player culls a splat whose temporal factor is below this (splaTV ``hybrid.js``)
PLAYER_CULL = 0.02
MIN_WIDTH = 1e-4  # half floats underflow below ~6e-5: s -> 0 would give NaN in the player


def splatv_bytes(records: np.ndarray, cameras: list[dict]) -> bytes:
    """The file of `records` (`RECORD` array, already in drawing-priority order) and `cameras` (3DGS
    ``cameras.json`` entries; splaTV reads ``cameras[0].fx/fy``, so give at least one)."""
    rows = max(1, math.ceil(len(records) / PER_ROW))
    padded = np.zeros(rows * PER_ROW, RECORD)
    padded[: len(records)] = records
    payload = padded.tobytes()
    header = json.dumps([{"type": "splat", "size": len(payload), "texwidth": TEXTURE_WIDTH, "texheight": rows,
                          "cameras": cameras}]).encode()
    return struct.pack("<II", MAGIC, len(header)) + header + payload


def sniff(path: Path) -> bool:
    """Whether `path` is a ``.splatv`` file (its magic number)."""
    try:
        with open(path, "rb") as f:
            return path.is_file() and f.read(4) == struct.pack("<I", MAGIC)
    except OSError:
        return False


def parse_splatv(data: bytes, name: str = "splatv") -> tuple[np.ndarray, list]:
    """(`RECORD` array without the zero padding, cameras) of a ``.splatv`` file's bytes; CheckpointError when the
    container is damaged."""
    if len(data) < 8 or struct.unpack_from("<I", data)[0] != MAGIC:
        raise CheckpointError(f"{name}: not a .splatv file (no 'Kg' magic)")
    (length,) = struct.unpack_from("<I", data, 4)
    try:
        chunks = json.loads(data[8:8 + length])
    except ValueError as exc:
        raise CheckpointError(f"{name}: damaged .splatv header ({exc})") from None
    offset = 8 + length
    for chunk in chunks:
        size = int(chunk.get("size", 0))
        if chunk.get("type") == "splat":
            if size % RECORD.itemsize or offset + size > len(data):
                raise CheckpointError(f"{name}: truncated .splatv ({len(data)} bytes, the splat chunk needs "
                                      f"{offset + size})")
            records = np.frombuffer(data, RECORD, size // RECORD.itemsize, offset)
            used = records.view(np.uint8).reshape(len(records), -1).any(1)  # padding records are all zero bytes
            return records[used].copy(), list(chunk.get("cameras", []))
        offset += size
    raise CheckpointError(f"{name}: no splat chunk in this .splatv")


def read_splatv(path: Path, **options):
    """A ``.splatv`` file as a native 4D `Checkpoint` (with accelerations where the file has any) over the time
    range [0, 1] or ``time_range`` (see module doc)."""
    import torch

    from ..checkpoint import Checkpoint
    from ..covariance import covariance_3d, covariance_4d_from_motion, decompose_covariance_4d
    from ..model import Gaussians4D
    from ..sh import SH_C0
    from .options import ImportRecord, check_options

    path = Path(path)
    record = ImportRecord(path, "splatv", check_options(options))
    t0, t1 = record.option("time_range", (0.0, 1.0), "a .splatv stores no duration; its player's time runs 0..1")
    background = record.option("background", (0.0, 0.0, 0.0), "a .splatv stores no background; splaTV draws on "
                               "black")
    span = float(t1) - float(t0)
    records, cameras = parse_splatv(path.read_bytes(), str(path))
    if not len(records):
        raise CheckpointError(f"{path}: the .splatv holds no Gaussians")
    f32 = lambda a: torch.as_tensor(np.asarray(a, np.float32))  # noqa: E731
    jerk = np.abs(records["motion"][:, 6:9].astype(np.float32)).max(initial=0.0)
    spin = np.abs(records["omega"].astype(np.float32)).max(initial=0.0)
    if jerk > 0 or spin > 0:
        record.warn(f"jerk (up to {jerk:.3g}) and rotation velocity (up to {spin:.3g}) have no 4D counterpart and "
                    "were dropped: motion is at most quadratic, rotation constant")
    quadratic = records["motion"][:, 3:6].astype(np.float64)  # the coefficient of dtau^2 = a T^2 / 2
    accelerations = f32(2.0 * quadratic / (span * span)) if quadratic.any() else None
    c = float(t0) + span * records["trbf"][:, 0].astype(np.float64)  # the player's time tau -> model time
    s = span * np.maximum(records["trbf"][:, 1].astype(np.float64), MIN_WIDTH)
    quats = f32(records["rotation"])
    quats = quats / quats.norm(dim=1, keepdim=True).clamp_min(1e-12)
    cov3 = covariance_3d(f32(records["scale"][:, :3]).clamp_min(1e-7), quats).double()
    var_t = torch.as_tensor(0.5 * s * s)  # exp(-(dt/s)^2) = exp(-dt^2 / (2 var_t))
    velocity = torch.as_tensor(records["motion"][:, :3].astype(np.float64) / span)
    scales, scale_t, q_l, q_r = decompose_covariance_4d(covariance_4d_from_motion(cov3, velocity, var_t))
    rgba = records["rgba"].astype(np.float32) / 255.0
    opacity = np.clip(rgba[:, 3], 1e-6, 1 - 1e-6)
    model = Gaussians4D(
        means=f32(records["position"]), t_means=f32(c), log_scales=scales.clamp_min(1e-7).log().float(),
        log_t_scales=scale_t.clamp_min(1e-7).log().float(), quats_l=q_l.float(), quats_r=q_r.float(),
        opacity_logits=f32(np.log(opacity / (1 - opacity))), sh_dc=f32((rgba[:, None, :3] - 0.5) / SH_C0),
        sh_rest=torch.zeros(len(records), 0, 3), sh_degree=0, sh_degree_t=0, time_range=(float(t0), float(t1)),
        rotation_convention="current", accelerations=accelerations)
    record.facts.update(count=len(records), cameras=len(cameras))
    record.finish()
    return Checkpoint(model=model, background=tuple(float(x) for x in background), provenance=record.provenance())
