"""Atomic file output: nothing a user made is ever half-written or silently overwritten.

Every writer in splatreel goes through `atomic_write_bytes` (`atomic_write_json`), `atomic_path` or `atomic_dir`:
data is written to a temporary name in the destination folder and renamed into place (`os.replace` is atomic on
POSIX), and an existing output is refused unless `force` is set.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from .errors import OutputExistsError


def _umask() -> int:
    """The process umask, read without changing it where the OS allows (Linux), else by set-and-restore."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _output_mode(directory: bool = False) -> int:
    """The mode a plain open()/mkdir() would give now. Temp files (mkstemp: 0600, mkdtemp: 0700) get it before
    the rename, so outputs are as readable as the user's other files."""
    return (0o777 if directory else 0o666) & ~_umask()


def check_writable(path: str | os.PathLike, force: bool = False) -> Path:
    """Return `path` as a Path after checking that writing it would not clobber anything without `force`."""
    path = Path(path)
    if path.exists() and not force:
        raise OutputExistsError(f"{path} already exists (use --force to overwrite)")
    return path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, force: bool = False, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary file path next to `path`; on success it is renamed to `path`, on error removed.

    `suffix` defaults to the destination's suffix, so that libraries choosing a format by extension
    (USD, OpenImageIO, PyAV) see the right one.
    """
    path = check_writable(path, force)
    path.parent.mkdir(parents=True, exist_ok=True)
    # The temp name keeps the destination's suffix: format-by-extension writers must see it.
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.tmp.", suffix=path.suffix if suffix is None else suffix,
                               dir=path.parent)
    os.close(fd)
    os.chmod(tmp, _output_mode())
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if path.is_dir():
            shutil.rmtree(path)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def atomic_write_bytes(path: str | os.PathLike, data: bytes, force: bool = False) -> Path:
    """Write `data` to `path` atomically (temp file + fsync + rename)."""
    with atomic_path(path, force) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    return Path(path)


def atomic_write_json(path: str | os.PathLike, obj, force: bool = False) -> Path:
    """Write `obj` as indented JSON (with a final newline) to `path` atomically (`atomic_write_bytes`)."""
    return atomic_write_bytes(path, (json.dumps(obj, indent=2) + "\n").encode(), force)


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, force: bool = False) -> Iterator[Path]:
    """Yield a temporary folder next to `path`; on success it replaces `path`, on error it is removed.

    A folder output (a dataset, a frame sequence) therefore appears complete or not at all.
    """
    path = check_writable(path, force)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    os.chmod(tmp, _output_mode(directory=True))
    try:
        yield tmp
        if path.exists():
            old = path.with_name(f".{path.name}.old")
            if old.exists():
                shutil.rmtree(old) if old.is_dir() else old.unlink()
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old) if old.is_dir() else old.unlink()
        else:
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
