"""4DGaussians (hustvl) and 4DGen (VITA-Group) output folders, baked into `KeyframedGaussians`.

Layout (hustvl/4DGaussians ``train.py`` / ``scene/gaussian_model.py`` ``save_ply`` and ``save_deformation``;
VITA-Group/4DGen writes the same)::

    <model>/cfg_args                                   # Namespace(...) repr: no_dx/no_ds/no_dr/no_do/no_dshs
    <model>/point_cloud/iteration_<N>/point_cloud.ply  # canonical Gaussians (3DGS PLY, raw values)
    <model>/point_cloud/iteration_<N>/deformation.pth  # state dict of the deformation network
    <model>/point_cloud/iteration_<N>/deformation_table.pth   # bool [N]: False = never deformed
    <model>/point_cloud/iteration_<N>/deformation_accum.pth   # unused

Accepted paths: the model folder (the latest ``iteration_<N>``, or ``--iteration N``; coarse-stage folders are
used only when nothing else exists), an ``iteration_<N>`` folder, or its ``deformation.pth``.

The deformation is evaluated at ``--frames`` times spread evenly over ``--time-range`` (4DGaussians: 30 frames
over 0..1; 4DGen: its 16 training times 0, 1/16, ..., 15/16) and stored as keyframes; `KeyframedGaussians`
interpolates between them. Canonical is not frame 0: every frame, t = 0 included, goes through the deformation.
"""

from __future__ import annotations

import re
import sys
from dataclasses import replace
from pathlib import Path

import torch
from torch import Tensor

from ..checkpoint import Checkpoint
from ..errors import CheckpointError
from ..model import KeyframedGaussians
from ..quaternion import normalize
from ..sh import sh_degree_from_bases
from .common import background_from_cfg, find_cfg_args
from .hexplane import (DeformationField, DeformFlags, RawGaussians, deform, detect_variant, parse_state_dict,
                       space_features)
from .options import ImportRecord, check_options
from .ply import read_splat_ply
from .safe_load import safe_torch_load

#: Gaussians evaluated together; bounds the memory of the HexPlane samples and the MLP activations.
CHUNK = 65536
_DEFAULTS = {  # variant -> (frames, time range, why)
    "4dgaussians": (30, (0.0, 1.0), "4DGaussians normalises times to 0..1"),
    "4dgen": (16, (0.0, 15.0 / 16.0), "4DGen's 16 frames at t = i/16"),
}


def _iteration_dirs(model: Path) -> list[Path]:
    root = model / "point_cloud"
    if not root.is_dir():
        return []
    return [p for p in root.iterdir() if p.is_dir() and re.fullmatch(r"(coarse_)?iteration_\d+", p.name)
            and (p / "deformation.pth").is_file()]


def _rank(p: Path) -> tuple[int, int]:
    return (0 if p.name.startswith("coarse") else 1, int(p.name.rsplit("_", 1)[1]))


def sniff(path: Path) -> bool:
    if path.is_file():
        return path.name == "deformation.pth"
    return path.is_dir() and ((path / "deformation.pth").is_file() or bool(_iteration_dirs(path)))


def resolve_folder(path: Path, iteration: int | None) -> Path:
    """The ``iteration_<N>`` folder (holding point_cloud.ply + deformation.pth) that `path` stands for."""
    if path.is_file():
        path = path.parent
    if (path / "deformation.pth").is_file():
        if iteration is not None and not path.name.endswith(f"_{iteration}"):
            raise CheckpointError(f"{path}: --iteration {iteration} given, but this is {path.name}")
        return path
    found = _iteration_dirs(path)
    if iteration is not None:
        found = [p for p in found if p.name == f"iteration_{iteration}"] or \
            [p for p in found if p.name == f"coarse_iteration_{iteration}"]
        if not found:
            have = ", ".join(sorted(p.name for p in _iteration_dirs(path))) or "none"
            raise CheckpointError(f"{path}: no point_cloud/iteration_{iteration} (found: {have})")
    if not found:
        raise CheckpointError(f"{path}: no point_cloud/iteration_*/deformation.pth")
    return max(found, key=_rank)


def _table(folder: Path, n: int) -> Tensor | None:
    """The deformation table (bool ``[N]``, True = deformed), or None when the file is absent."""
    file = folder / "deformation_table.pth"
    if not file.is_file():
        return None
    table = safe_torch_load(file)
    if not isinstance(table, Tensor) or table.dim() != 1 or table.shape[0] != n:
        shape = list(table.shape) if isinstance(table, Tensor) else type(table).__name__
        raise CheckpointError(f"{file}: expected a bool tensor [N={n}], found {shape}")
    return table.to("cpu").bool()


def bake(field: DeformationField, canonical: RawGaussians, times: Tensor, deformed: Tensor | None = None,
         progress: bool | None = None) -> KeyframedGaussians:
    """Evaluate the deformation at each of `times` ``[F]`` and store activated keyframes.

    Args:
        canonical: raw canonical Gaussians (N of them, log-scales ``[N, 3]``).
        deformed: bool ``[N]``; False keeps that Gaussian at its canonical values (None: all deformed).
    Returns:
        `KeyframedGaussians` with means, normalised quaternions, exp(scales), sigmoid(opacities) and SH per key.
    """
    from tqdm import tqdm

    f, n, k = times.shape[0], canonical.means.shape[0], canonical.sh.shape[1]
    means = canonical.means[None].repeat(f, 1, 1)
    quats = normalize(canonical.quats)[None].repeat(f, 1, 1)
    scales = torch.exp(canonical.log_scales)[None].repeat(f, 1, 1)
    opacities = torch.sigmoid(canonical.opacity_logits)[None].repeat(f, 1)
    moves_colour = field.flags.color
    sh = canonical.sh[None].repeat(f, 1, 1, 1) if moves_colour else canonical.sh[None].expand(f, n, k, 3)
    index = torch.arange(n) if deformed is None else deformed.nonzero()[:, 0]
    chunks = [index[i:i + CHUNK] for i in range(0, index.shape[0], CHUNK)]
    bar = tqdm(total=f * len(chunks), desc="baking deformation", unit="chunk", file=sys.stderr,
               disable=None if progress is None else not progress)
    with torch.no_grad():
        for idx in chunks:
            part = RawGaussians(canonical.means[idx], canonical.log_scales[idx], canonical.quats[idx],
                                canonical.opacity_logits[idx], canonical.sh[idx])
            space = space_features(field, part.means)  # the same at every time
            for i, t in enumerate(times.tolist()):
                g = deform(field, part, t, space)
                means[i, idx] = g.means
                quats[i, idx] = normalize(g.quats)
                scales[i, idx] = torch.exp(g.log_scales)
                opacities[i, idx] = torch.sigmoid(g.opacity_logits)
                if moves_colour:
                    sh[i, idx] = g.sh
                bar.update()
    bar.close()
    return KeyframedGaussians(times=times, means=means, quats=quats, scales=scales, opacities=opacities, sh=sh,
                              sh_degree=sh_degree_from_bases(k))


def read_deformation_folder(path: Path, progress: bool | None = None, **options) -> Checkpoint:
    """Import a 4DGaussians / 4DGen output (folder or deformation.pth) as baked `KeyframedGaussians`."""
    record = ImportRecord(Path(path), "deformation-folder", check_options(options))
    folder = resolve_folder(Path(path), record.given("iteration"))
    state = safe_torch_load(folder / "deformation.pth")
    try:
        variant = detect_variant(state) if isinstance(state, dict) else None
        if variant is None:
            raise CheckpointError(f"expected a state dict, found {type(state).__name__}")
        cfg_path, cfg = find_cfg_args(folder, levels=3)
        flags, missing = DeformFlags.from_cfg(variant, cfg)
        merge = cfg.get("grid_merge") if cfg.get("grid_merge") in ("mul", "cat", "plus") else None
        field = parse_state_dict(state, flags, merge)
    except CheckpointError as exc:
        raise CheckpointError(f"{folder / 'deformation.pth'}: {exc}") from None
    tool = {"4dgaussians": "4DGaussians (hustvl)", "4dgen": "4DGen (VITA-Group)"}[variant]
    if missing:
        deformed = ", ".join(flags.describe())
        record.assume(f"deformed {deformed} ({tool} defaults; "
                      f"{'no cfg_args found' if cfg_path is None else 'cfg_args lacks ' + ', '.join(missing)})",
                      f"deformed {deformed}")
    ply = folder / "point_cloud.ply"
    if not ply.is_file():
        raise CheckpointError(f"{folder}: no point_cloud.ply next to deformation.pth")
    cols = read_splat_ply(ply)
    if flags.color and variant == "4dgaussians" and cols.sh_degree != 3:
        raise CheckpointError(f"{ply}: the SH deformation head needs SH degree 3, the PLY has {cols.sh_degree}")
    n = len(cols)
    table = _table(folder, n)
    canonical = RawGaussians(cols.means, cols.log_scales, cols.quats, cols.opacity_logits, cols.sh)
    frames_default, range_default, why = _DEFAULTS[variant]
    frames = record.option("frames", frames_default, "keyframes baked; more follow the motion more closely")
    time_range = record.option("time_range", range_default, why)
    background = background_from_cfg(cfg) if record.given("background") is None else None
    if background is None:
        background = record.option("background", (1.0, 1.0, 1.0),
                                   f"{tool} trains on white (white_background defaults to True); no cfg_args "
                                   f"found")
    times = torch.linspace(time_range[0], time_range[1], frames) if frames > 1 else torch.tensor([time_range[0]])
    size = 4 * frames * n * (11 + 3 * cols.sh.shape[1])  # float32 keys: means, quats, scales, opacity, SH
    if size > 4 << 30:
        record.warn(f"{frames} keyframes of {n:,} Gaussians take {size / 2 ** 30:.1f} GiB; fewer --frames or a "
                    f"lower --sh-degree make it smaller")
    model = bake(field, canonical, times, table, progress)
    degree = record.given("sh_degree")
    if degree is not None and degree < model.sh_degree:
        model = replace(model, sh=model.sh[..., : (degree + 1) ** 2, :], sh_degree=degree)
    record.facts.update(tool=tool, folder=str(folder), iteration=folder.name, frames=frames,
                        cfg_args=str(cfg_path) if cfg_path else None, deformation=field.describe(),
                        static_gaussians=0 if table is None else int((~table).sum()))
    record.finish()
    return Checkpoint(model=model, background=tuple(background), provenance=record.provenance())
