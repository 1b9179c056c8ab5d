"""3DGS PLY files: one as a static model, a folder or glob of per-frame files as keyframes.

The 3DGS layout (Inria ``save_ply``; 4DGaussians' ``point_cloud.ply``; the per-frame files of
``splatreel export ply`` and of other tools) is one ``vertex`` element of float properties::

    x y z  nx ny nz  f_dc_0..2  f_rest_0..(3(K-1)-1)  opacity  scale_0..2  rot_0..3

* ``f_rest`` is channel-major: ``f_rest[c*(K-1) + j-1]`` is SH coefficient j (1..K-1) of channel c, so its count
  3(K-1) = 0, 9, 24, 45 gives the SH degree 0..3;
* ``opacity`` is a logit, ``scale_*`` natural-log std-devs, ``rot_*`` an unnormalised (w, x, y, z) quaternion;
* the normals are ignored. A single ``scale_0`` (isotropic Gaussians, as some 4DGen files) is used on all axes.

The file is parsed by plyfile (the library the 3DGS reference code reads and writes these files with,
graphdeco-inria/gaussian-splatting ``scene/gaussian_model.py``): binary little/big-endian and ASCII; properties may
come in any order and any numeric type. Column names are defined here (`COLUMN_PREFIXES`); `splatreel.export.ply`
writes the same layout.
"""

from __future__ import annotations

import glob as globmod
import json
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElementParseError, PlyHeaderParseError, PlyListProperty
from torch import Tensor

from ..checkpoint import Checkpoint
from ..errors import CheckpointError
from ..model import KeyframedGaussians
from ..ply_layout import ply_columns_to_sh, sh_degree_from_rest_count
from ..quaternion import normalize
from .common import natural_key, require_finite, static_model
from .options import ImportRecord, check_options

#: The 3DGS vertex properties splatreel reads (numbered ones are ``<prefix><i>``).
COLUMN_PREFIXES = {"dc": "f_dc_", "rest": "f_rest_", "scale": "scale_", "rot": "rot_"}


# --- generic PLY ----------------------------------------------------------------------------------------------
def is_ply(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(4) in (b"ply\n", b"ply\r")
    except OSError:
        return False


def sniff_ply(path: Path) -> bool:
    """One PLY file (the ``ply`` reader of `splatreel.formats`)."""
    return path.is_file() and is_ply(path)


def read_ply_vertices(path: Path) -> tuple[dict[str, np.ndarray], list[str]]:
    """The ``vertex`` element of a PLY file as {property name: ``[N]`` array}, and the header's comments (and
    obj_info lines). Parsing is plyfile's: binary (either endianness) or ASCII, any property order and numeric
    type, other elements before or after; its errors become one-line CheckpointErrors naming `path`."""
    try:
        ply = PlyData.read(str(path), mmap=False)
    except OSError as exc:
        raise CheckpointError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except PlyHeaderParseError as exc:
        raise CheckpointError(f"{path}: not a readable PLY header ({exc})") from None
    except PlyElementParseError as exc:
        what = "truncated PLY" if "end-of-file" in str(exc) else "malformed PLY data"
        raise CheckpointError(f"{path}: {what} ({exc})") from None
    except ValueError as exc:  # e.g. a repeated property name
        raise CheckpointError(f"{path}: malformed PLY ({exc})") from None
    if "vertex" not in [e.name for e in ply.elements]:
        raise CheckpointError(f"{path}: PLY has no 'vertex' element")
    vertex = ply["vertex"]
    if any(isinstance(p, PlyListProperty) for p in vertex.properties):
        raise CheckpointError(f"{path}: PLY vertex element has list properties; not a splat file")
    table = vertex.data
    cols = {p.name: np.ascontiguousarray(table[p.name]).astype(table[p.name].dtype.newbyteorder("="))
            for p in vertex.properties}
    return cols, list(ply.comments) + list(ply.obj_info)


# --- 3DGS columns -------------------------------------------------------------------------------------------
@dataclass
class SplatColumns:
    """Raw 3DGS values of one PLY (float32 tensors).

    Attributes:
        means: ``[N, 3]``; log_scales: ``[N, 3]``; quats: ``[N, 4]`` w first, unnormalised;
        opacity_logits: ``[N]``; sh: ``[N, K, 3]`` coefficient-major, K = (sh_degree+1)^2.
    """

    means: Tensor
    log_scales: Tensor
    quats: Tensor
    opacity_logits: Tensor
    sh: Tensor
    sh_degree: int
    comments: list[str]

    def __len__(self) -> int:
        return self.means.shape[0]


def _numbered(cols: dict[str, np.ndarray], prefix: str) -> list[str]:
    found = [(int(m.group(1)), k) for k in cols if (m := re.fullmatch(re.escape(prefix) + r"(\d+)", k))]
    found.sort()
    if [i for i, _ in found] != list(range(len(found))):
        raise CheckpointError(f"numbered columns {prefix}* are not 0..{len(found) - 1}")
    return [k for _, k in found]


def splat_columns(path: Path, cols: dict[str, np.ndarray], comments: list[str] | None = None) -> SplatColumns:
    """Turn PLY vertex columns into raw 3DGS tensors; CheckpointError naming what is missing or wrong."""
    try:
        dc, rest = _numbered(cols, COLUMN_PREFIXES["dc"]), _numbered(cols, COLUMN_PREFIXES["rest"])
        scale, rot = _numbered(cols, COLUMN_PREFIXES["scale"]), _numbered(cols, COLUMN_PREFIXES["rot"])
    except CheckpointError as exc:
        raise CheckpointError(f"{path}: {exc}") from None
    missing = [c for c in ("x", "y", "z", "opacity") if c not in cols]
    missing += ["f_dc_0..2"] if len(dc) != 3 else []
    missing += ["scale_0..2"] if len(scale) not in (1, 3) else []
    missing += ["rot_0..3"] if len(rot) != 4 else []
    if missing:
        hint = " (it looks like a plain point cloud, not Gaussian splats)" if {"red", "x"} <= set(cols) else ""
        raise CheckpointError(f"{path}: not a 3DGS splat PLY: missing {', '.join(missing)}{hint}")
    try:
        degree = sh_degree_from_rest_count(len(rest))
    except ValueError as exc:
        raise CheckpointError(f"{path}: {exc}") from None

    def columns(names: list[str]) -> np.ndarray:
        if not names:
            return np.zeros((len(cols["x"]), 0), np.float32)
        return np.stack([cols[c].astype(np.float32) for c in names], -1)

    def stack(names: list[str]) -> Tensor:
        return torch.from_numpy(columns(names))

    n = len(cols["x"])
    sh = torch.from_numpy(np.ascontiguousarray(ply_columns_to_sh(columns(dc), columns(rest))))
    log_scales = stack(scale)
    if log_scales.shape[1] == 1:
        log_scales = log_scales.expand(n, 3).contiguous()
    out = SplatColumns(means=stack(["x", "y", "z"]), log_scales=log_scales, quats=stack(rot),
                       opacity_logits=stack(["opacity"])[:, 0], sh=sh, sh_degree=degree, comments=comments or [])
    for name in ("means", "log_scales", "quats", "opacity_logits", "sh"):
        require_finite(path, name, getattr(out, name))
    return out


def read_splat_ply(path: Path) -> SplatColumns:
    """Read a 3DGS PLY file into raw tensors."""
    cols, comments = read_ply_vertices(path)
    return splat_columns(path, cols, comments)


def truncate_sh(cols: SplatColumns, record: ImportRecord) -> tuple[Tensor, int]:
    """SH coefficients at the requested ``--sh-degree`` (never above the file's)."""
    degree = record.given("sh_degree")
    if degree is None or degree >= cols.sh_degree:
        if degree is not None and degree > cols.sh_degree:
            raise CheckpointError(f"{record.source}: --sh-degree {degree} is above the file's SH degree "
                                  f"{cols.sh_degree}")
        return cols.sh, cols.sh_degree
    return cols.sh[:, : (degree + 1) ** 2].contiguous(), degree


# --- readers --------------------------------------------------------------------------------------------------
def read_ply_model(path: Path, **options) -> Checkpoint:
    """A single 3DGS PLY as a static `Gaussians4D` (it looks the same at every time)."""
    record = ImportRecord(Path(path), "ply", check_options(options))
    cols = read_splat_ply(path)
    time_range = record.option("time_range", (0.0, 1.0), "a static model; sets the playback range only")
    background = record.option("background", (0.0, 0.0, 0.0), "3DGS PLY files store no background")
    sh, degree = truncate_sh(cols, record)
    model = static_model(cols.means, cols.log_scales, cols.quats, cols.opacity_logits, sh, degree, time_range)
    record.facts.update(tool="3DGS PLY", sh_degree_in_file=cols.sh_degree)
    if (path.parent / "deformation.pth").is_file():
        record.facts["note"] = ("canonical Gaussians of a 4DGaussians/4DGen model; pass the folder to import the "
                                "animation")
    record.finish()
    return Checkpoint(model=model, background=tuple(background), provenance=record.provenance())


def has_glob(text: str) -> bool:
    return globmod.has_magic(text)


def sequence_files(path: Path) -> list[Path]:
    """The per-frame PLY files of a folder or glob pattern, in natural order."""
    if path.is_dir():
        files = [p for p in path.iterdir() if p.suffix.lower() == ".ply" and p.is_file()]
        where = f"folder {path}"
    else:
        files = [Path(p) for p in globmod.glob(str(path)) if Path(p).is_file()]
        where = f"pattern {path}"
    if not files:
        raise CheckpointError(f"{where} matches no PLY files")
    return sorted(files, key=natural_key)


def manifest_times(files: list[Path]) -> list[float] | None:
    """Frame times from the ``manifest.json`` that ``splatreel export ply`` writes next to its frames
    (``{"frames": [{"time": t, "file": name}, ...]}``), when it lists every file with increasing times."""
    folders = {f.parent for f in files}
    manifest = next(iter(folders)) / "manifest.json" if len(folders) == 1 else None
    if manifest is None or not manifest.is_file():
        return None
    try:
        doc = json.loads(manifest.read_text())
        table = {str(fr["file"]): float(fr["time"]) for fr in doc["frames"]}
        times = [table[f.name] for f in files]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    ok = all(math.isfinite(t) for t in times) and all(b > a for a, b in zip(times, times[1:]))
    return times if ok else None


def read_ply_sequence(path: Path, progress: bool | None = None, **options) -> Checkpoint:
    """Per-frame 3DGS PLYs (a folder or a glob) as `KeyframedGaussians`. Gaussian j of every file is the same
    Gaussian (same count in every file). Frame times: ``--time-range`` spread evenly (frame i of F at
    t0 + i (t1 - t0) / (F - 1)); else the times of a ``manifest.json`` from ``splatreel export ply``; else 0..1."""
    from tqdm import tqdm

    record = ImportRecord(Path(path), "ply-sequence", check_options(options))
    files = sequence_files(Path(path))
    listed = manifest_times(files) if record.given("time_range") is None else None
    if listed is not None:
        record.facts["times_from"] = "manifest.json"
        time_range = (listed[0], listed[-1])
    else:
        time_range = record.option("time_range", (0.0, 1.0), "frames evenly spaced over it")
    background = record.option("background", (0.0, 0.0, 0.0), "3DGS PLY files store no background")
    first = read_splat_ply(files[0])
    n = len(first)
    _, degree = truncate_sh(first, record)
    f = len(files)
    means = torch.empty((f, n, 3))
    quats = torch.empty((f, n, 4))
    scales = torch.empty((f, n, 3))
    opacities = torch.empty((f, n))
    sh = torch.empty((f, n, (degree + 1) ** 2, 3))
    bar = tqdm(files, desc="reading PLY frames", unit="frame", disable=None if progress is None else not progress,
               file=sys.stderr)
    for i, file in enumerate(bar):
        cols = first if i == 0 else read_splat_ply(file)
        if len(cols) != n:
            raise CheckpointError(f"{file}: {len(cols)} Gaussians, but {files[0].name} has {n}: every frame of a "
                                  f"PLY sequence must hold the same Gaussians in the same order")
        if cols.sh_degree != first.sh_degree:
            raise CheckpointError(f"{file}: SH degree {cols.sh_degree}, but {files[0].name} has "
                                  f"{first.sh_degree}")
        means[i] = cols.means
        quats[i] = normalize(cols.quats)
        scales[i] = torch.exp(cols.log_scales)
        opacities[i] = torch.sigmoid(cols.opacity_logits)
        sh[i] = cols.sh[:, : sh.shape[2]]
    if listed is not None:
        times = torch.tensor(listed, dtype=torch.float32)
    else:
        times = torch.linspace(time_range[0], time_range[1], f) if f > 1 else torch.tensor([time_range[0]])
    model = KeyframedGaussians(times=times, means=means, quats=quats, scales=scales, opacities=opacities, sh=sh,
                               sh_degree=degree)
    record.facts.update(tool="3DGS PLY sequence", frames=f, files=[p.name for p in files[:3]] +
                        (["..."] if f > 3 else []), sh_degree_in_file=first.sh_degree)
    record.finish()
    return Checkpoint(model=model, background=tuple(background), provenance=record.provenance())
