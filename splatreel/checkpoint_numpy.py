"""A splatreel checkpoint read with NumPy (safetensors' numpy API; no torch), and what ``splatreel info`` reports
about it: its bounds over time, the largest std-dev of each Gaussian and its opacity at the middle of the time range.

`read_numpy_checkpoint` accepts only a file that `splatreel.checkpoint.load_checkpoint` would load without a word:
anything else (another format, a damaged or inconsistent file, a malformed camera record) gives None, and the caller
loads it the usual way, which names the problem. The layout is the one `splatreel.checkpoint` documents.
"""

from __future__ import annotations

import json
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import covariance_numpy

#: Names of the checkpoint's metadata key and format (now and before the rename), as `splatreel.checkpoint`.
FORMAT_NAMES = ("splatreel", "splat4d")
FORMAT_VERSION = 1
#: Tensors of each model kind, in checkpoint order (`Gaussians4D.TENSORS`, `KeyframedGaussians.TENSORS`).
KIND_TENSORS = {
    "gaussians4d": ("means", "t_means", "log_scales", "log_t_scales", "quats_l", "quats_r", "opacity_logits",
                    "sh_dc", "sh_rest"),
    "keyframed": ("times", "means", "quats", "scales", "opacities", "sh"),
}


@dataclass
class NumpyCheckpoint:
    """The tensors and metadata of a valid checkpoint (see `splatreel.checkpoint.Checkpoint`)."""

    kind: str
    arrays: dict[str, np.ndarray]
    model: dict[str, Any]  # sh_degree, sh_degree_t, time_range, rotation_convention
    background: tuple[float, float, float]
    provenance: dict[str, Any] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)
    format_version: int = FORMAT_VERSION
    views: list = field(default_factory=list)

    def __len__(self) -> int:
        return self.arrays["means"].shape[-2]

    @property
    def time_range(self) -> tuple[float, float]:
        if self.kind == "keyframed":
            return float(self.arrays["times"][0]), float(self.arrays["times"][-1])
        return float(self.model["time_range"][0]), float(self.model["time_range"][1])

    @property
    def sh_degree(self) -> int:
        return int(self.model["sh_degree"])

    @property
    def sh_degree_t(self) -> int:
        return int(self.model.get("sh_degree_t", 0)) if self.kind == "gaussians4d" else 0

    @property
    def rotation_convention(self) -> str | None:
        return covariance_numpy.CONVENTION_ALIASES[self.model["rotation_convention"]] \
            if self.kind == "gaussians4d" else None


def _expected_shapes(kind: str, arrays: dict[str, np.ndarray], model: dict) -> dict[str, tuple[int, ...]]:
    """The shape each tensor must have (`Gaussians4D.validate`, `KeyframedGaussians.validate`)."""
    if kind == "gaussians4d":
        n = arrays["means"].shape[0]
        m = (int(model["sh_degree"]) + 1) ** 2 * (int(model["sh_degree_t"]) + 1)
        return {"means": (n, 3), "t_means": (n,), "log_scales": (n, 3), "log_t_scales": (n,), "quats_l": (n, 4),
                "quats_r": (n, 4), "opacity_logits": (n,), "sh_dc": (n, 1, 3), "sh_rest": (n, m - 1, 3)}
    f, n = arrays["times"].shape[0], arrays["means"].shape[1]
    k = (int(model["sh_degree"]) + 1) ** 2
    return {"times": (f,), "means": (f, n, 3), "quats": (f, n, 4), "scales": (f, n, 3), "opacities": (f, n),
            "sh": (f, n, k, 3)}


def _model_is_valid(kind: str, arrays: dict[str, np.ndarray], model: dict) -> bool:
    if not 0 <= int(model["sh_degree"]) <= 3:
        return False
    if kind == "gaussians4d":
        t0, t1 = (float(x) for x in model["time_range"])
        if not (0 <= int(model["sh_degree_t"]) <= 2 and np.isfinite(t1 - t0) and t1 > t0
                and str(model["rotation_convention"]).lower() in covariance_numpy.CONVENTION_ALIASES):
            return False
        model["rotation_convention"] = str(model["rotation_convention"]).lower()
    elif arrays["times"].ndim != 1 or arrays["means"].ndim != 3 or not (np.diff(arrays["times"]) > 0).all():
        return False
    if kind == "gaussians4d" and arrays["means"].ndim != 2:
        return False
    shapes = _expected_shapes(kind, arrays, model)
    return all(arrays[name].shape == shape for name, shape in shapes.items())


def read_numpy_checkpoint(path: str | Path) -> NumpyCheckpoint | None:
    """The checkpoint at `path` if `load_checkpoint` would load it without an error or a warning, else None."""
    from safetensors import safe_open

    from .cameras import views_from_json

    path = Path(path)
    if not path.is_file():
        return None
    try:
        with safe_open(str(path), framework="numpy") as f:
            header = f.metadata() or {}
            key = next((k for k in FORMAT_NAMES if k in header), None)
            meta = json.loads(header[key]) if key else None
            if not isinstance(meta, dict) or meta.get("format") not in FORMAT_NAMES:
                return None
            version, kind = meta.get("format_version"), meta.get("kind")
            if not (isinstance(version, int) and 1 <= version <= FORMAT_VERSION and kind in KIND_TENSORS):
                return None
            checksums = meta.get("checksums", {})
            arrays = {}
            for name in KIND_TENSORS[kind]:
                a = f.get_tensor(name)
                data = np.ascontiguousarray(a).view(np.uint8).reshape(-1).data
                if (name in checksums and zlib.crc32(data) != checksums[name]) or \
                        a.dtype not in (np.float32, np.float64) or not np.isfinite(a).all():
                    return None
                arrays[name] = a
        model = dict(meta["model"])
        if not _model_is_valid(kind, arrays, model):
            return None
        bg = meta.get("background", [0.0, 0.0, 0.0])
        if not (isinstance(bg, list) and len(bg) == 3 and all(isinstance(x, (int, float)) for x in bg)):
            return None
        views = views_from_json(meta["cameras"]) if "cameras" in meta else []
    except Exception:  # noqa: BLE001  (any problem: the full loader says what it is)
        return None
    return NumpyCheckpoint(kind, arrays, model, tuple(float(x) for x in bg), meta.get("provenance", {}),
                           meta.get("training", {}), version, views)


def _bracket(times: np.ndarray, t: float) -> tuple[int, int, float]:
    """Keys around t and the weight of the second (`KeyframedGaussians._bracket`)."""
    times = times.astype(np.float64)
    if len(times) == 1 or t <= times[0]:
        return 0, 0, 0.0
    if t >= times[-1]:
        return len(times) - 1, len(times) - 1, 0.0
    i = int(np.searchsorted(times, t, side="right")) - 1
    return i, i + 1, (t - float(times[i])) / float(times[i + 1] - times[i])


def _lerp(x: np.ndarray, i: int, j: int, w: float) -> np.ndarray:
    return x[i] if w == 0.0 else x[i] + (x[j] - x[i]) * x.dtype.type(w)


def centres(ckpt: NumpyCheckpoint, times) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(means [N, 3], visible [N])`` at each time (`splatreel.model` ``centres``)."""
    if ckpt.kind == "gaussians4d":
        return covariance_numpy.centres_4d(ckpt.arrays, ckpt.rotation_convention, times)
    out = []
    for t in times:
        i, j, w = _bracket(ckpt.arrays["times"], float(t))
        out.append((_lerp(ckpt.arrays["means"], i, j, w), _lerp(ckpt.arrays["opacities"], i, j, w) > 0))
    return out


def bounds(ckpt: NumpyCheckpoint, num_times: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """(min ``[3]``, max ``[3]``) of the visible means over `num_times` times (`splatreel.model.model_bounds`)."""
    t0, t1 = ckpt.time_range
    lo = hi = None
    # the times as torch.linspace makes them in float32, then read back as Python floats
    for means, visible in centres(ckpt, np.linspace(t0, t1, num_times, dtype=np.float32).tolist()):
        pts = means[visible]
        if pts.shape[0] == 0:
            continue
        a, b = pts.min(0), pts.max(0)
        lo = a if lo is None else np.minimum(lo, a)
        hi = b if hi is None else np.maximum(hi, b)
    if lo is None:
        return np.zeros(3, np.float32), np.zeros(3, np.float32)
    return lo, hi


def sizes_and_opacities(ckpt: NumpyCheckpoint) -> tuple[np.ndarray, np.ndarray]:
    """(largest std-dev ``[N]``, opacity ``[N]``) in float64: for a native 4D model its conditional covariance's and
    its opacity at the temporal peak; for a keyframed one at the middle of its time range (the largest scale: the
    eigenvalues of R diag(s)^2 Rᵀ are the squared scales)."""
    if ckpt.kind == "gaussians4d":
        std = covariance_numpy.largest_std_devs_4d(ckpt.arrays, ckpt.rotation_convention)
        logits = ckpt.arrays["opacity_logits"]
        return std, (1.0 / (1.0 + np.exp(-logits))).astype(np.float64)
    t0, t1 = ckpt.time_range
    i, j, w = _bracket(ckpt.arrays["times"], 0.5 * (t0 + t1))
    scales = _lerp(ckpt.arrays["scales"], i, j, w)
    return scales.max(-1).astype(np.float64), _lerp(ckpt.arrays["opacities"], i, j, w).astype(np.float64)
