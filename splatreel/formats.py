"""The one registry of model formats: every reader (files `read_checkpoint` accepts) and every writer (the formats
of ``splatreel export``), declared as data.

Each entry names its functions by dotted path (``"package.module:function"``) and the module is imported only when
the entry is used, so importing this module imports neither `splatreel.importers` nor `splatreel.export`, and
neither of them needs to import anything back to register (the readers and writers modules import the core
only). Readers are chosen by content (each one's ``sniff``), not only by extension; `read_checkpoint` is what every
command that takes a model calls (``info``, ``view``, ``render``, ``export``, ``convert``).

Plug-ins add entries with `register_reader` / `register_writer`.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from .checkpoint import Checkpoint, load_checkpoint
from .errors import CheckpointError


def resolve(dotted: str) -> Callable:
    """The function that ``"package.module:function"`` names (importing the module)."""
    module, _, name = dotted.partition(":")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class Reader:
    """A model file format that `read_checkpoint` accepts.

    Attributes:
        name: short name (``ply``, ``4dgs-checkpoint``).
        description: what files it reads, for messages.
        sniff: dotted path of ``sniff(path: Path) -> bool``: whether this reader takes `path` (cheap: a name, a
            header, a folder listing; sniffs are mutually exclusive).
        read: dotted path of ``read(path: Path, **options) -> Checkpoint``.
    """

    name: str
    description: str
    sniff: str
    read: str

    def accepts(self, path: Path) -> bool:
        return resolve(self.sniff)(path)

    def read_checkpoint(self, path: Path, **options: Any) -> Checkpoint:
        return resolve(self.read)(path, **options)


@dataclass(frozen=True)
class Writer:
    """An output format of ``splatreel export``.

    Attributes:
        name: the sub-subcommand (``splatreel export NAME``).
        help: one line for --help.
        output: metavar of the output argument (``OUT.usd``, ``OUTDIR``).
        module: dotted module defining ``add_args(parser)`` (the format's own options) and
            ``run(model, times, out, args) -> list[Path]`` (writes the output; ``args`` carries ``fps``, ``force``,
            ``progress`` and the format's options; returns the files written).
    """

    name: str
    help: str
    output: str
    module: str
    #: False for a format that holds the whole animation (the player evaluates it): the frame options do not apply
    sampled: bool = True

    def add_args(self, parser) -> None:
        resolve(f"{self.module}:add_args")(parser)

    def run(self, model, times, out: Path, args) -> list[Path]:
        return resolve(f"{self.module}:run")(model, times, out, args)


def is_safetensors(path: Path) -> bool:
    # safetensors: 8-byte little-endian header length, then a JSON header starting with '{'
    try:
        with open(path, "rb") as f:
            head = f.read(9)
    except OSError:
        return False
    return path.suffix == ".safetensors" or (len(head) == 9 and head[8:9] == b"{")


def read_native(path: Path, **_: Any) -> Checkpoint:
    """splatreel's own checkpoint (`splatreel.checkpoint.load_checkpoint`; import options do not apply)."""
    return load_checkpoint(path)


#: Every reader, in the order they are tried (their sniffs are mutually exclusive, so the order does not matter).
_READERS: list[Reader] = [
    Reader("4dgs-checkpoint", "official 4DGS chkpnt*.pth / Efficient4D model.pth",
           "splatreel.importers.official:sniff", "splatreel.importers.official:read_official"),
    Reader("deformation-folder", "4DGaussians / 4DGen output folder (point_cloud.ply + deformation.pth)",
           "splatreel.importers.deformation:sniff", "splatreel.importers.deformation:read_deformation_folder"),
    Reader("ply", "3DGS PLY (SH degree 0-3, binary or ASCII)",
           "splatreel.importers.ply:sniff_ply", "splatreel.importers.ply:read_ply_model"),
    Reader("ply-sequence", "folder or glob of per-frame 3DGS PLY files",
           "splatreel.importers:sniff_ply_sequence", "splatreel.importers.ply:read_ply_sequence"),
    Reader("splatv", "splaTV / gsplat.js .splatv (Spacetime Gaussians lite)",
           "splatreel.importers.splatv:sniff", "splatreel.importers.splatv:read_splatv"),
    Reader("4dgs", ".4dgs container (fourdgs package)",
           "splatreel.importers.four_dgs:sniff", "splatreel.importers.four_dgs:read_four_dgs"),
    Reader("splatreel", "splatreel checkpoint (.safetensors)",
           "splatreel.formats:is_safetensors", "splatreel.formats:read_native"),
]

#: Every writer, in the order ``splatreel export --help`` lists them.
_WRITERS: list[Writer] = [
    Writer("usd", "one OpenUSD stage with time-sampled splats, a point instancer and points",
           "OUT.usd|.usda|.usdc|.usdz", "splatreel.export.usd"),
    Writer("mesh", "surfaces per frame, or one deforming mesh (obj/ply/glb, mesh_sequence.usd)", "OUTDIR",
           "splatreel.export.mesh"),
    Writer("ply", "one standard 3DGS PLY per frame (+ manifest.json), for other splat viewers", "OUTDIR",
           "splatreel.export.ply"),
    Writer("gltf", "glTF 2.0 .glb with KHR_gaussian_splatting: one time per file (a folder for a sequence)",
           "OUT.glb|OUTDIR", "splatreel.export.gltf"),
    Writer("splatv", "the whole native 4D model as one .splatv for the splaTV / gsplat.js web players (DC colour)",
           "OUT.splatv", "splatreel.export.splatv", sampled=False),
    Writer("4dgs", "the whole native 4D model as one .4dgs container (the fourdgs package's format)", "OUT.4dgs",
           "splatreel.export.four_dgs", sampled=False),
    Writer("web", "a static WebGL2 player of the whole model (index.html, scripts, splats.bin; or one .html)",
           "OUTDIR|OUT.html", "splatreel.export.web", sampled=False),
]


def readers() -> list[Reader]:
    return list(_READERS)


def writers() -> list[Writer]:
    return list(_WRITERS)


def register_reader(reader: Reader) -> None:
    """Add (or replace, by name) a reader; it is tried first."""
    _READERS[:] = [reader] + [r for r in _READERS if r.name != reader.name]


def register_writer(writer: Writer) -> None:
    """Add (or replace, by name, in place) a writer."""
    names = [w.name for w in _WRITERS]
    if writer.name in names:
        _WRITERS[names.index(writer.name)] = writer
    else:
        _WRITERS.append(writer)


def read_checkpoint(path: str | os.PathLike, **options: Any) -> Checkpoint:
    """Read any supported model file as a `Checkpoint`; raises `CheckpointError` naming the file when none can
    read it. (`splatreel.checkpoint.load_checkpoint` reads only splatreel's own safetensors files.)"""
    import glob

    path = Path(path)
    if not path.exists() and not glob.has_magic(str(path)):  # a glob pattern names a PLY sequence
        raise CheckpointError(f"{path}: no such file or folder")
    for r in _READERS:
        if r.accepts(path):
            return r.read_checkpoint(path, **options)
    known = "; ".join(r.description for r in _READERS)
    raise CheckpointError(f"{path}: unknown model format (supported: {known})")
