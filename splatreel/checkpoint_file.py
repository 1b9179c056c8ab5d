"""The splatreel checkpoint file without torch: its metadata and its verified arrays (NumPy).

`splatreel.checkpoint` builds models from what this module reads; ``splatreel info`` reads a checkpoint through it
alone (the model's summary is stored in the metadata when the file is written), so that it starts without torch.
Every check of the file itself (format name and version, checksums, dtypes, finiteness) lives here, once.
"""

from __future__ import annotations

import json
import os
import zlib
from pathlib import Path

import numpy as np

from .errors import CameraError, CheckpointError

FORMAT_NAME = "splatreel"
FORMAT_VERSION = 1
METADATA_KEY = "splatreel"
#: the project's name until 2026-11 (renamed: another package installs a command of that name); checkpoints and
#: camera paths written before carry it as their metadata key / format name and still open
LEGACY_NAME = "splat4d"
SUFFIX = ".safetensors"


def crc32(array: np.ndarray) -> int:
    """The checksum the metadata records for a tensor: CRC-32 of its contiguous bytes."""
    return zlib.crc32(np.ascontiguousarray(array).view(np.uint8).reshape(-1).data)


def _open(path: Path):
    from safetensors import safe_open

    if not path.exists():
        raise CheckpointError(f"{path}: no such file")
    if path.is_dir():
        raise CheckpointError(f"{path}: is a folder, expected a {SUFFIX} checkpoint file")
    try:
        f = safe_open(str(path), framework="numpy")
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


def read_metadata(path: str | os.PathLike) -> dict:
    """The JSON metadata of a checkpoint without loading its tensors (CheckpointError: not a checkpoint)."""
    return _open(Path(path))[1]


def check_version(meta: dict, path: str | os.PathLike) -> int:
    """The metadata's format version, after checking that this splatreel reads it."""
    version = meta.get("format_version")
    if meta.get("format") not in (FORMAT_NAME, LEGACY_NAME) or not isinstance(version, int):
        raise CheckpointError(f"{path}: metadata does not declare a splatreel format version")
    if version > FORMAT_VERSION:
        raise CheckpointError(f"{path}: format version {version} is newer than this splatreel reads "
                              f"(up to {FORMAT_VERSION}); upgrade splatreel")
    if version < 1:
        raise CheckpointError(f"{path}: invalid format version {version}")
    return version


def read_arrays(path: str | os.PathLike, names: tuple[str, ...] | None = None,
                optional: tuple[str, ...] = ()) -> tuple[dict, dict[str, np.ndarray]]:
    """(metadata, ``name -> array``) of a checkpoint, each array checked: its recorded checksum, a float32/float64
    dtype, finite values. `names`: the tensors that must be there (default: all in the file); `optional`: tensors
    also read when the file has them. Raises `CheckpointError` (one line naming the file and the problem)."""
    path = Path(path)
    f, meta = _open(path)
    check_version(meta, path)
    present = set(f.keys())
    wanted = tuple(names) + tuple(k for k in optional if k in present) if names is not None else tuple(sorted(present))
    missing = [k for k in wanted if k not in present]
    if missing:
        raise CheckpointError(f"{path}: missing tensor(s) {', '.join(missing)}")
    checksums, shapes = meta.get("checksums", {}), meta.get("shapes", {})
    arrays = {}
    for k in wanted:
        try:
            a = f.get_tensor(k)
        except Exception as exc:
            raise CheckpointError(f"{path}: tensor {k} is unreadable ({str(exc).strip()})") from None
        if k in checksums and crc32(a) != checksums[k]:
            raise CheckpointError(f"{path}: tensor {k} is corrupted (checksum mismatch)")
        if k in shapes and list(a.shape) != list(shapes[k]):
            raise CheckpointError(f"{path}: tensor {k} has shape {tuple(a.shape)}, the checkpoint recorded "
                                  f"{tuple(shapes[k])}")
        if a.dtype not in (np.float32, np.float64):
            raise CheckpointError(f"{path}: tensor {k} has dtype {a.dtype}, expected float32 or float64")
        if not np.isfinite(a).all():
            bad = int((~np.isfinite(a)).sum())
            raise CheckpointError(f"{path}: tensor {k} contains {bad} NaN or infinite value(s)")
        arrays[k] = a
    return meta, arrays


def recorded_views(meta: dict, path: Path | str) -> list:
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
        from .cameras import views_from_json

        return views_from_json(meta["cameras"])
    except CameraError as exc:
        raise CheckpointError(f"{path}: {exc}") from None
