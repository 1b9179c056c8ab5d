"""The splatreel checkpoint: one ``.safetensors`` file of model tensors plus JSON metadata.

Layout
------
* Tensors: the model's per-Gaussian tensors under their field names (`Gaussians4D.TENSORS` or
  `KeyframedGaussians.TENSORS`), float32 or float64, contiguous.
* Metadata: the safetensors header's ``__metadata__`` holds one key ``"splatreel"`` whose value is a JSON object::

    {"format": "splatreel", "format_version": 1, "kind": "gaussians4d" | "keyframed",
     "model": {"sh_degree": .., "sh_degree_t": .., "time_range": [t0, t1], "rotation_convention": ..},
     "background": [r, g, b], "provenance": {...}, "training": {...},
     "cameras": {"cameras": [...], "views": [...]},   (optional)
     "checksums": {"<tensor>": <crc32 of its bytes>}}

  ``provenance`` says where the model came from (tool, source file, what an importer assumed);
  ``training`` holds the settings of the run that produced it; ``cameras`` the cameras of the images it was trained
  on (`splatreel.cameras.views_to_json`: each distinct camera once, each view as camera index, time, name), so that
  viewers can snap to them and render along them without the dataset. Older checkpoints have none.

Writes are atomic (temp file + rename). Loading checks the version, the metadata, a CRC-32 per tensor (so a
corrupted byte is caught, not rendered), shapes, dtypes and finiteness, and raises `CheckpointError` with one line
naming the file and the problem.
"""

from __future__ import annotations

import json
import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .cameras import views_from_json, views_to_json
from .errors import CameraError, CheckpointError, ModelError
from .fileio import atomic_write_bytes
from .model import MODEL_KINDS, Model

FORMAT_NAME = "splatreel"
FORMAT_VERSION = 1
METADATA_KEY = "splatreel"
#: the project's name until 2026-11 (renamed: another package installs a command of that name); checkpoints and
#: camera paths written before carry it as their metadata key / format name and still open
LEGACY_NAME = "splat4d"
SUFFIX = ".safetensors"


@dataclass
class Checkpoint:
    """A loaded checkpoint: the model and what was recorded with it."""

    model: Model
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    provenance: dict[str, Any] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)
    format_version: int = FORMAT_VERSION
    path: Path | None = None
    #: the cameras of the training images (`splatreel.cameras.DatasetView`), empty when none were recorded
    views: list = field(default_factory=list)


def _crc(t: torch.Tensor) -> int:
    return zlib.crc32(t.detach().cpu().contiguous().numpy().view(np.uint8).reshape(-1).data)


def checkpoint_bytes(model: Model, background=(0.0, 0.0, 0.0), provenance: dict | None = None,
                     training: dict | None = None, views=None) -> bytes:
    """Serialise to the bytes of a checkpoint file (nothing touches disk)."""
    from safetensors.torch import save

    model.validate()
    tensors = {k: v.detach().cpu().contiguous() for k, v in model.tensors().items()}
    bg = [float(x) for x in background]
    if len(bg) != 3:
        raise CheckpointError(f"background must be 3 numbers, got {background!r}")
    meta = {
        "format": FORMAT_NAME, "format_version": FORMAT_VERSION, "kind": model.kind,
        "model": model.metadata(), "background": bg,
        "provenance": provenance or {}, "training": training or {},
        **({"cameras": views_to_json(views)} if views else {}),
        "checksums": {k: _crc(v) for k, v in tensors.items()},
    }
    return save(tensors, metadata={METADATA_KEY: json.dumps(meta)})


def save_checkpoint(path: str | os.PathLike, model: Model, background=(0.0, 0.0, 0.0),
                    provenance: dict | None = None, training: dict | None = None, force: bool = False,
                    views=None) -> Path:
    """Write `model` to `path` atomically; refuses to overwrite an existing file unless `force`. `views`: the
    training cameras to record (`splatreel.cameras.DatasetView`s)."""
    return atomic_write_bytes(path, checkpoint_bytes(model, background, provenance, training, views), force)


def read_metadata(path: str | os.PathLike) -> dict:
    """The JSON metadata of a checkpoint without loading its tensors."""
    return _open(Path(path))[1]


def _open(path: Path):
    from safetensors import safe_open

    if not path.exists():
        raise CheckpointError(f"{path}: no such file")
    if path.is_dir():
        raise CheckpointError(f"{path}: is a folder, expected a {SUFFIX} checkpoint file")
    try:
        f = safe_open(str(path), framework="pt", device="cpu")
        header = f.metadata() or {}
    except Exception as exc:
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise CheckpointError(f"{path}: not a readable splatreel checkpoint (truncated, corrupted or another "
                              f"format): {reason}") from None
    key = next((k for k in (METADATA_KEY, LEGACY_NAME) if k in header), None)
    if key is None:
        raise CheckpointError(f"{path}: a safetensors file but not a splatreel checkpoint (no '{METADATA_KEY}' "
                              f"metadata)")
    try:
        meta = json.loads(header[key])
        if not isinstance(meta, dict):
            raise ValueError("not an object")
    except ValueError as exc:
        raise CheckpointError(f"{path}: corrupted metadata ({exc})") from None
    return f, meta


def load_checkpoint(path: str | os.PathLike, device: str | torch.device = "cpu") -> Checkpoint:
    """Load and validate a splatreel checkpoint. Raises `CheckpointError` (one line) on any problem."""
    path = Path(path)
    f, meta = _open(path)
    version = meta.get("format_version")
    if meta.get("format") not in (FORMAT_NAME, LEGACY_NAME) or not isinstance(version, int):
        raise CheckpointError(f"{path}: metadata does not declare a splatreel format version")
    if version > FORMAT_VERSION:
        raise CheckpointError(f"{path}: format version {version} is newer than this splatreel reads "
                              f"(up to {FORMAT_VERSION}); upgrade splatreel")
    if version < 1:
        raise CheckpointError(f"{path}: invalid format version {version}")
    kind = meta.get("kind")
    if kind not in MODEL_KINDS:
        raise CheckpointError(f"{path}: unknown model kind {kind!r} (expected one of {', '.join(MODEL_KINDS)})")
    cls = MODEL_KINDS[kind]
    names = set(f.keys())
    missing = [k for k in cls.TENSORS if k not in names]
    if missing:
        raise CheckpointError(f"{path}: missing tensor(s) {', '.join(missing)}")
    tensors = {}
    checksums = meta.get("checksums", {})
    for k in cls.TENSORS:
        try:
            t = f.get_tensor(k)
        except Exception as exc:
            raise CheckpointError(f"{path}: tensor {k} is unreadable ({str(exc).strip()})") from None
        if k in checksums and _crc(t) != checksums[k]:
            raise CheckpointError(f"{path}: tensor {k} is corrupted (checksum mismatch)")
        if t.dtype not in (torch.float32, torch.float64):
            raise CheckpointError(f"{path}: tensor {k} has dtype {t.dtype}, expected float32 or float64")
        if not torch.isfinite(t).all():
            bad = int((~torch.isfinite(t)).sum())
            raise CheckpointError(f"{path}: tensor {k} contains {bad} NaN or infinite value(s)")
        tensors[k] = t.to(device)
    try:
        model = cls.from_tensors(tensors, meta.get("model", {}))
    except (ModelError, KeyError, TypeError, ValueError) as exc:
        what = f"missing model metadata {exc}" if isinstance(exc, KeyError) else str(exc)
        raise CheckpointError(f"{path}: {what}") from None
    bg = meta.get("background", [0.0, 0.0, 0.0])
    if not (isinstance(bg, list) and len(bg) == 3 and all(isinstance(x, (int, float)) for x in bg)):
        raise CheckpointError(f"{path}: background must be 3 numbers, got {bg!r}")
    return Checkpoint(model=model, background=tuple(float(x) for x in bg), provenance=meta.get("provenance", {}),
                      training=meta.get("training", {}), format_version=version, path=path,
                      views=_views_or_warning(meta, path))


def _views_or_warning(meta: dict, path: Path) -> list:
    """The recorded training cameras, or none with a warning when the record is malformed: they are optional
    extras (no checksum covers them), and must not make the model itself unreadable."""
    try:
        return views_in_metadata(meta, path)
    except CheckpointError as exc:
        import warnings

        warnings.warn(f"{exc}; its training cameras are ignored", stacklevel=3)
        return []


def views_in_metadata(meta: dict, path: Path | str = "checkpoint") -> list:
    """The training cameras a checkpoint's metadata records (`splatreel.cameras.DatasetView`s; [] when none)."""
    if "cameras" not in meta:
        return []
    try:
        return views_from_json(meta["cameras"])
    except CameraError as exc:
        raise CheckpointError(f"{path}: {exc}") from None
