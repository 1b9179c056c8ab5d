"""Atomic file output: nothing a user made is ever half-written or silently overwritten.

Every writer in splatreel goes through `atomic_write_bytes` (`atomic_write_json`), `atomic_path` or `atomic_dir`:
data is written to a temporary name in the destination folder and renamed into place (`os.replace` is atomic on
POSIX), and an existing output is refused unless `force` is set. An operating-system error on the way (a
read-only or full disk, no permission, a file where a folder should be) becomes one `OutputWriteError` that names
the path the user asked for, never the hidden temporary one, and leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from .errors import OutputExistsError, OutputWriteError


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


#: errno values that say the destination cannot take the output (as opposed to a missing input read on the way)
_WRITE_ERRNOS = {errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EFBIG, errno.EIO,
                 errno.ENOTDIR, errno.EEXIST, errno.EISDIR, errno.ENAMETOOLONG}


def write_error(path: Path, exc: OSError) -> OutputWriteError:
    """The one-line error for `exc` raised while writing `path`, worded for the user's path."""
    reason = exc.strerror or str(exc)
    if isinstance(exc, (FileExistsError, NotADirectoryError)) or exc.errno in (errno.EEXIST, errno.ENOTDIR):
        blocker = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
        if blocker is not None:
            return OutputWriteError(f"{path}: cannot write: {blocker} is a file, not a folder")
    return OutputWriteError(f"{path}: cannot write: {reason}")


@contextlib.contextmanager
def _writing(path: Path, tmp: str | os.PathLike | None = None) -> Iterator[None]:
    """Turn OS errors about `path`, its folder or the temporary `tmp` into `write_error(path)`."""
    try:
        yield
    except OSError as exc:
        name = str(exc.filename or "")
        temporary = Path(name).name.startswith(f".{path.name}.") or (tmp is not None and name.startswith(str(tmp)))
        ours = not name or name.startswith(str(path.parent)) or temporary
        if (exc.errno in _WRITE_ERRNOS and ours) or temporary:  # anything failing on our temp name is the output's
            raise write_error(path, exc) from None
        raise


def _make_parent(path: Path) -> None:
    with _writing(path):
        path.parent.mkdir(parents=True, exist_ok=True)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, force: bool = False, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary file path next to `path`; on success it is renamed to `path`, on error removed.

    `suffix` defaults to the destination's suffix, so that libraries choosing a format by extension
    (USD, OpenImageIO, PyAV) see the right one.
    """
    path = check_writable(path, force)
    _make_parent(path)
    # The temp name keeps the destination's suffix: format-by-extension writers must see it.
    with _writing(path):
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.tmp.", suffix=path.suffix if suffix is None else suffix,
                                   dir=path.parent)
        os.close(fd)
    tmp_path = Path(tmp)
    try:
        with _writing(path, tmp_path):
            os.chmod(tmp_path, _output_mode())
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
    _make_parent(path)
    with _writing(path):
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        with _writing(path, tmp):
            os.chmod(tmp, _output_mode(directory=True))
            yield tmp
            _replace_dir(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)


def _replace_dir(tmp: Path, path: Path) -> None:
    """Put the finished folder `tmp` in place of `path` (a previous output, if any, is removed last)."""
    if not path.exists():
        os.replace(tmp, path)
        return
    old = path.with_name(f".{path.name}.old")
    if old.exists():
        shutil.rmtree(old) if old.is_dir() else old.unlink()
    os.replace(path, old)
    os.replace(tmp, path)
    shutil.rmtree(old) if old.is_dir() else old.unlink()
