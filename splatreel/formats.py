"""Readers for every model file splatreel accepts, chosen by content (not only by extension).

`read_checkpoint` is what every command that takes a checkpoint calls (``info``, ``view``, ``render``, ``export``).
The splatreel checkpoint is built in; importers of other tools' files register themselves with `register_reader`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from .checkpoint import Checkpoint, load_checkpoint
from .errors import CheckpointError


@dataclass(frozen=True)
class Reader:
    name: str
    description: str
    sniff: Callable[[Path], bool]
    read: Callable[..., Checkpoint]


_READERS: list[Reader] = []


def register_reader(reader: Reader) -> None:
    """Add (or replace, by name) a reader; later registrations are tried first."""
    _READERS[:] = [r for r in _READERS if r.name != reader.name]
    _READERS.insert(0, reader)


def readers() -> list[Reader]:
    _register_importers()
    return list(_READERS)


def _register_importers() -> None:
    """Importers of other tools' files (`splatreel.importers`) register their readers on first use."""
    from . import importers

    importers.register()


def _is_safetensors(path: Path) -> bool:
    # safetensors: 8-byte little-endian header length, then a JSON header starting with '{'
    try:
        with open(path, "rb") as f:
            head = f.read(9)
    except OSError:
        return False
    return path.suffix == ".safetensors" or (len(head) == 9 and head[8:9] == b"{")


register_reader(Reader("splatreel", "splatreel checkpoint (.safetensors)", _is_safetensors,
                       lambda path, **_: load_checkpoint(path)))


def read_checkpoint(path: str | os.PathLike, **options: Any) -> Checkpoint:
    """Read any supported model file as a `Checkpoint`; raises `CheckpointError` naming the file when none can
    read it. (`splatreel.checkpoint.load_checkpoint` reads only splatreel's own safetensors files.)"""
    import glob

    _register_importers()
    path = Path(path)
    if not path.exists() and not glob.has_magic(str(path)):  # a glob pattern names a PLY sequence
        raise CheckpointError(f"{path}: no such file or folder")
    for r in _READERS:
        if r.sniff(path):
            return r.read(path, **options)
    known = "; ".join(r.description for r in _READERS)
    raise CheckpointError(f"{path}: unknown model format (supported: {known})")


#: The former name of `read_checkpoint`, kept until `splatreel.cli` and `splatreel/__init__.py` call the new one.
load_model = read_checkpoint
