"""The splatreel checkpoint: one ``.safetensors`` file of model tensors plus JSON metadata.

Layout
------
* Tensors: the model's per-Gaussian tensors under their field names (`Gaussians4D.TENSORS` and those of its
  `OPTIONAL_TENSORS` it holds, `KeyframedGaussians.TENSORS`, or for skinned Gaussians the native ones and
  `splatreel.skinned.NODE_TENSORS` and `SKIN_TENSORS`: a checkpoint without the skin's derives it from the
  canonical means), float32 or float64, contiguous.
* Metadata: the safetensors header's ``__metadata__`` holds one key ``"splatreel"`` whose value is a JSON object::

    {"format": "splatreel", "format_version": 1, "kind": "gaussians4d" | "keyframed" | "skinned",
     "model": {"sh_degree": .., "sh_degree_t": .., "time_range": [t0, t1], "rotation_convention": ..},
     "background": [r, g, b], "provenance": {...}, "training": {...},
     "cameras": {"cameras": [...], "views": [...]},   (optional)
     "summary": {...}, "shapes": {"<tensor>": [..]},      (written since 2026-11; optional)
     "checksums": {"<tensor>": <crc32 of its bytes>}}

  ``provenance`` says where the model came from (tool, source file, what an importer assumed);
  ``training`` holds the settings of the run that produced it; ``cameras`` the cameras of the images it was trained
  on (`splatreel.cameras.views_to_json`: each distinct camera once, each view as camera index, time, name), so that
  viewers can snap to them and render along them without the dataset. Older checkpoints have none. ``summary``
  is `splatreel.summary.model_summary` of the model (what ``splatreel info`` prints without torch) and ``shapes``
  each tensor's shape as written.

Writes are atomic (temp file + rename). Loading checks the version, the metadata, a CRC-32 per tensor (so a
corrupted byte is caught, not rendered), shapes, dtypes and finiteness, and raises `CheckpointError` with one line
naming the file and the problem.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from .cameras import views_to_json
from .checkpoint_file import (FORMAT_NAME, FORMAT_VERSION, METADATA_KEY, check_version, crc32, read_arrays,
                              read_metadata, recorded_views)
from .errors import CheckpointError, ModelError
from .fileio import atomic_write_bytes
from .model import Gaussians4D, KeyframedGaussians, Model
from .skinned import SkinnedGaussians
from .summary import model_summary


#: The model kinds a checkpoint holds, by the name its metadata gives (``model.kind``).
MODEL_KINDS: dict[str, type] = {"gaussians4d": Gaussians4D, "keyframed": KeyframedGaussians,
                                "skinned": SkinnedGaussians}


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
    return crc32(t.detach().cpu().contiguous().numpy())


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
        "summary": model_summary(model),
        "shapes": {k: list(v.shape) for k, v in tensors.items()},
        "checksums": {k: _crc(v) for k, v in tensors.items()},
    }
    return save(tensors, metadata={METADATA_KEY: json.dumps(meta)})


def save_checkpoint(path: str | os.PathLike, model: Model, background=(0.0, 0.0, 0.0),
                    provenance: dict | None = None, training: dict | None = None, force: bool = False,
                    views=None) -> Path:
    """Write `model` to `path` atomically; refuses to overwrite an existing file unless `force`. `views`: the
    training cameras to record (`splatreel.cameras.DatasetView`s)."""
    return atomic_write_bytes(path, checkpoint_bytes(model, background, provenance, training, views), force)


def load_checkpoint(path: str | os.PathLike, device: str | torch.device = "cpu") -> Checkpoint:
    """Load and validate a splatreel checkpoint. Raises `CheckpointError` (one line) on any problem."""
    path = Path(path)
    meta = read_metadata(path)
    version = check_version(meta, path)
    kind = meta.get("kind")
    if kind not in MODEL_KINDS:
        raise CheckpointError(f"{path}: unknown model kind {kind!r} (expected one of {', '.join(MODEL_KINDS)})")
    cls = MODEL_KINDS[kind]
    # checksums, dtypes, finiteness, recorded shapes
    _, arrays = read_arrays(path, cls.TENSORS, getattr(cls, "OPTIONAL_TENSORS", ()))
    tensors = {k: torch.from_numpy(a).to(device) for k, a in arrays.items()}
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
                      views=recorded_views(meta, path))
