"""Official native-4DGS checkpoints (``fudan-zvg/4d-gaussian-splatting``) and Efficient4D ``model.pth``.

Both are ``torch.save`` pickles of ``GaussianModel.capture()`` (fudan-zvg/4d-gaussian-splatting
``scene/gaussian_model.py``, ``capture`` / ``restore``; ``train.py`` saves them):

* official main / extension: ``(capture, iteration)`` in ``chkpnt<iter>.pth`` / ``chkpnt_best.pth``;
* Efficient4D (the ``generation`` branch): the bare ``capture`` tuple in ``model.pth``.

``capture`` has 19 entries for 4D models (`CAPTURE_4D`) and 12 for 3D ones (`CAPTURE_3D`). Also accepted: the
dict that the official ``--loaded_pth`` option reads (`INIT_DICT_KEYS`, features as ``[N, 3, K]``).

The files do not store the 4D rotation convention, the time range or the background. Defaults, each reported
as an assumption: convention 'current' for files with an iteration number (official main since 2024-09-15) and
'legacy' for bare tuples (Efficient4D); time range 0..1 (D-NeRF configs) or 0..15 (Efficient4D's 16 frames);
background from a ``cfg_args`` next to the file, else black (main) or white (Efficient4D).

Colour follows the official CUDA renderer: the SH degree in use is the checkpoint's ``active_sh_degree`` and the
time terms (``active_sh_degree_t``) are evaluated only when that degree is 3.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from ..checkpoint import Checkpoint
from ..errors import CheckpointError, ModelError
from ..model import Gaussians4D
from .common import as_float_tensor, background_from_cfg, find_cfg_args, static_model
from .options import ImportRecord, check_options
from .safe_load import safe_torch_load

CAPTURE_4D = ("active_sh_degree", "_xyz", "_features_dc", "_features_rest", "_scaling", "_rotation", "_opacity",
              "max_radii2D", "xyz_gradient_accum", "t_gradient_accum", "denom", "optimizer.state_dict()",
              "spatial_lr_scale", "_t", "_scaling_t", "_rotation_r", "rot_4d", "env_map", "active_sh_degree_t")
CAPTURE_3D = ("active_sh_degree", "_xyz", "_features_dc", "_features_rest", "_scaling", "_rotation", "_opacity",
              "max_radii2D", "xyz_gradient_accum", "denom", "optimizer.state_dict()", "spatial_lr_scale")
INIT_DICT_KEYS = ("xyz", "features_dc", "features_rest", "t", "scaling", "rotation", "scaling_t", "rotation_r",
                  "opacity")
#: Coefficients per channel of a 4D model trained with max_sh_degree_t = 0 (official ``sh_channels_4d``); the
#: renderer reads only the first (L+1)^2 of them.
_LEGACY_4D_CHANNELS = {6: 1, 16: 2, 33: 3}
_SUFFIXES = (".pth", ".pt", ".ckpt", ".tar")


# --- sniffing and file choice ---------------------------------------------------------------------------------
def _checkpoint_in(folder: Path) -> Path | None:
    """The checkpoint a model folder stands for: model.pth, else the chkpnt with the highest iteration."""
    if (folder / "model.pth").is_file():
        return folder / "model.pth"
    found = [p for p in folder.glob("chkpnt*.pth") if p.is_file()]
    if not found:
        return None

    def rank(p: Path) -> tuple[int, int]:
        m = re.search(r"(\d+)", p.stem)
        return (1, int(m.group(1))) if m else (0, 0)  # numbered ones after chkpnt_best

    return max(found, key=rank)


def sniff(path: Path) -> bool:
    if path.is_dir():
        return _checkpoint_in(path) is not None and not (path / "deformation.pth").exists()
    return path.is_file() and path.suffix.lower() in _SUFFIXES and not path.name.startswith("deformation")


# --- capture tuple --------------------------------------------------------------------------------------------
def _unwrap(path: Path, obj: Any) -> tuple[str, Any, int | None]:
    """(flavour, payload, iteration): 'main' for (capture, iteration), 'efficient4d' for a bare tuple."""
    if isinstance(obj, dict):
        if all(k in obj for k in INIT_DICT_KEYS):
            return "init-dict", obj, None
        keys = ", ".join(sorted(map(str, obj))[:8])
        raise CheckpointError(f"{path}: a dict with keys {keys}: not an official 4DGS checkpoint (a "
                              f"4DGaussians deformation.pth? pass its folder)")
    if not isinstance(obj, (tuple, list)):
        raise CheckpointError(f"{path}: holds a {type(obj).__name__}, not an official 4DGS capture tuple")
    if len(obj) == 2 and isinstance(obj[0], (tuple, list)) and isinstance(obj[1], int):
        return "main", obj[0], int(obj[1])
    return "efficient4d", obj, None


def _int_entry(path: Path, cap, names: tuple[str, ...], name: str) -> int:
    v = cap[names.index(name)]
    if isinstance(v, Tensor) and v.numel() == 1:
        v = v.item()
    if isinstance(v, bool) or not isinstance(v, int) and not (hasattr(v, "__index__")):
        raise CheckpointError(f"{path}: entry {names.index(name)} ({name}) should be an integer, found "
                              f"{type(v).__name__}; is the tuple in the official order?")
    return int(v)


def _column(path: Path, name: str, value: Any, n: int) -> Tensor:
    """``[N]`` from a ``[N, 1]`` (or ``[N]``) tensor."""
    if isinstance(value, Tensor) and value.dim() == 1:
        value = value[:, None]
    return as_float_tensor(path, name, value, (n, 1))[:, 0]


def sh_layouts(m: int) -> list[tuple[int, int]]:
    """(max spatial degree L, max time degree Lt) pairs that store M coefficients per channel (notes §2.3)."""
    out = [(deg, deg_t) for deg in range(4) for deg_t in range(3) if (deg + 1) ** 2 * (deg_t + 1) == m]
    if m in _LEGACY_4D_CHANNELS:
        out.append((_LEGACY_4D_CHANNELS[m], 0))
    return sorted(set(out), key=lambda p: (-p[0], p[1]))  # highest spatial degree first (notes: 16 -> (3, 0))


def select_sh(coeffs: Tensor, layout: tuple[int, int], degree: int, degree_t: int) -> Tensor:
    """Pick the coefficients the renderer uses: ``[N, M, 3]`` -> ``[N, (degree+1)^2 (degree_t+1), 3]``.

    The stored 4D layout puts time order n at ``n * (L+1)^2 + j``; the result uses splatreel's layout for the
    (lower) degrees in use.
    """
    deg_max, deg_t_max = layout
    block = (deg_max + 1) ** 2 if deg_t_max > 0 else coeffs.shape[1]
    k = (degree + 1) ** 2
    return torch.cat([coeffs[:, n * block: n * block + k] for n in range(degree_t + 1)], 1).contiguous()


def _sh_degrees(path: Path, record: ImportRecord, m: int, active: int, active_t: int, is_4d: bool
                ) -> tuple[tuple[int, int], int, int]:
    """(stored layout, spatial degree used, time degree used)."""
    layouts = sh_layouts(m) if is_4d else [(d, 0) for d in range(4) if (d + 1) ** 2 == m]
    if not layouts:
        raise CheckpointError(f"{path}: {m} colour coefficients per channel match no SH layout of the official "
                              f"code (features_dc + features_rest)")
    wanted = record.given("sh_degree")
    if wanted is not None:
        fitting = [lay for lay in layouts if lay[0] >= wanted]
        if not fitting:
            raise CheckpointError(f"{path}: --sh-degree {wanted} is above the stored SH degree {layouts[0][0]}")
        layout, degree = fitting[0], wanted
    else:
        layout = layouts[0]
        degree = max(0, min(active, layout[0]))
    # CUDA evaluates the time terms only inside `if (deg > 2)`.
    degree_t = max(0, min(active_t, layout[1])) if degree == 3 else 0
    record.facts["sh"] = {"coefficients_per_channel": m, "stored_degrees": list(layout),
                          "active_degrees": [active, active_t], "degrees_used": [degree, degree_t]}
    return layout, degree, degree_t


def _time_hint(t_means: Tensor) -> str:
    if t_means.numel() == 0:
        return ""
    lo, hi = torch.quantile(t_means.double(), torch.tensor([0.05, 0.95], dtype=torch.float64)).tolist()
    return f"; the Gaussians' time centres span {lo:.3g}..{hi:.3g}"


def read_official(path: Path, **options) -> Checkpoint:
    """Import an official 4DGS / Efficient4D checkpoint (file or model folder) as a `Gaussians4D`."""
    record = ImportRecord(Path(path), "4dgs-checkpoint", check_options(options))
    path = Path(path)
    file = _checkpoint_in(path) if path.is_dir() else path
    if file is None:
        raise CheckpointError(f"{path}: no model.pth or chkpnt*.pth in this folder")
    flavour, cap, iteration = _unwrap(file, safe_torch_load(file))
    cfg_path, cfg = find_cfg_args(file.parent, levels=1)
    if file != path:
        record.facts["file"] = str(file)
    record.facts.update(iteration=iteration, tool={
        "main": "official 4DGS (fudan-zvg/4d-gaussian-splatting)", "efficient4d": "Efficient4D (generation branch)",
        "init-dict": "official 4DGS --loaded_pth dict"}[flavour]
        if flavour == "init-dict" or len(cap) != len(CAPTURE_3D) else "official 4DGS, gaussian_dim 3")
    if cfg_path is not None:
        record.facts["cfg_args"] = str(cfg_path)
    if flavour == "init-dict":
        model = _from_init_dict(file, cap, record)
    elif len(cap) == len(CAPTURE_4D):
        model = _from_capture_4d(file, cap, record, flavour)
    elif len(cap) == len(CAPTURE_3D):
        model = _from_capture_3d(file, cap, record)
    else:
        hint = (" (4DGaussians training checkpoints are not read: import its output folder with "
                "point_cloud/iteration_N instead)" if re.match(r"chkpnt_(coarse|fine)", file.name) else "")
        raise CheckpointError(f"{file}: a tuple of {len(cap)} entries; an official capture() tuple has 19 "
                              f"(4D) or 12 (3D){hint}")
    white = flavour == "efficient4d"
    cfg_bg = background_from_cfg(cfg)
    if cfg_bg is not None and record.given("background") is None:
        background = cfg_bg
        record.facts["background_from"] = "cfg_args white_background"
    else:
        background = record.option("background", (1.0, 1.0, 1.0) if white else (0.0, 0.0, 0.0),
                                   "Efficient4D renders on white" if white else
                                   "official D-NeRF/N3V configs use black; no cfg_args found")
    record.finish()
    return Checkpoint(model=model, background=tuple(background), provenance=record.provenance())


def _from_capture_4d(path: Path, cap, record: ImportRecord, flavour: str) -> Gaussians4D:
    names = CAPTURE_4D
    get = lambda name: cap[names.index(name)]  # noqa: E731
    xyz = get("_xyz")
    if not isinstance(xyz, Tensor) or xyz.dim() != 2:
        raise CheckpointError(f"{path}: entry 1 (_xyz) should be an [N, 3] tensor, found "
                              f"{type(xyz).__name__}; is the tuple in the official order?")
    n = xyz.shape[0]
    means = as_float_tensor(path, "_xyz", xyz, (n, 3))
    dc = as_float_tensor(path, "_features_dc", get("_features_dc"), (n, 1, 3))
    rest = as_float_tensor(path, "_features_rest", get("_features_rest"), (n, -1, 3))
    log_scales = as_float_tensor(path, "_scaling", get("_scaling"), (n, 3))
    q_l = as_float_tensor(path, "_rotation", get("_rotation"), (n, 4))
    opacity = _column(path, "_opacity", get("_opacity"), n)
    t_means = _column(path, "_t", get("_t"), n)
    log_t = _column(path, "_scaling_t", get("_scaling_t"), n)
    rot_4d = get("rot_4d")
    if not isinstance(rot_4d, bool):
        raise CheckpointError(f"{path}: entry 16 (rot_4d) should be a bool, found {type(rot_4d).__name__}; is the "
                              f"tuple in the official order?")
    env = get("env_map")
    if isinstance(env, Tensor) and env.numel() > 0:
        record.warn(f"environment map {list(env.shape)} dropped (splatreel has no environment "
                               f"background; the background colour is used instead)")
    active, active_t = _int_entry(path, cap, names, "active_sh_degree"), _int_entry(path, cap, names,
                                                                                    "active_sh_degree_t")
    lr_scale = get("spatial_lr_scale")
    try:  # a numpy.float64 (main) or the int 10 (Efficient4D)
        record.facts["spatial_lr_scale"] = float(lr_scale)
    except (TypeError, ValueError):
        pass
    coeffs = torch.cat([dc, rest], 1)
    layout, degree, degree_t = _sh_degrees(path, record, coeffs.shape[1], active, active_t, True)
    sh = select_sh(coeffs, layout, degree, degree_t)
    efficient = flavour == "efficient4d"
    time_range = record.option("time_range", (0.0, 15.0) if efficient else (0.0, 1.0),
                               ("Efficient4D: frames 0..15" if efficient else
                                "official D-NeRF configs; N3V uses 0 10") + _time_hint(t_means))
    if not rot_4d:
        # gaussian_dim 4 without rot_4d: 3D rotation, no motion, exp(_scaling_t) is the temporal VARIANCE.
        record.facts["rot_4d"] = False
        record.given("convention")
        return static_model(means, log_scales, q_l, opacity, sh, degree, time_range, t_means=t_means,
                            log_t_scales=0.5 * log_t, sh_degree_t=degree_t)
    q_r = as_float_tensor(path, "_rotation_r", get("_rotation_r"), (n, 4))
    convention = record.option("convention", "legacy" if efficient else "current",
                               "bare capture tuples come from Efficient4D, which uses the legacy rotation"
                               if efficient else "files with an iteration number come from official main; "
                               "'legacy' for files trained before 2024-09-15")
    return _model(path, means=means, t_means=t_means, log_scales=log_scales, log_t_scales=log_t, quats_l=q_l,
                  quats_r=q_r, opacity_logits=opacity, sh=sh, sh_degree=degree, sh_degree_t=degree_t,
                  time_range=time_range, rotation_convention=convention)


def _from_capture_3d(path: Path, cap, record: ImportRecord) -> Gaussians4D:
    """A 3D (gaussian_dim 3) capture: static Gaussians."""
    names = CAPTURE_3D
    xyz = cap[names.index("_xyz")]
    if not isinstance(xyz, Tensor) or xyz.dim() != 2:
        raise CheckpointError(f"{path}: entry 1 (_xyz) should be an [N, 3] tensor, found {type(xyz).__name__}")
    n = xyz.shape[0]
    coeffs = torch.cat([as_float_tensor(path, "_features_dc", cap[names.index("_features_dc")], (n, 1, 3)),
                        as_float_tensor(path, "_features_rest", cap[names.index("_features_rest")],
                                        (n, -1, 3))], 1)
    layout, degree, _ = _sh_degrees(path, record, coeffs.shape[1],
                                    _int_entry(path, cap, names, "active_sh_degree"), 0, False)
    record.facts["gaussian_dim"] = 3
    time_range = record.option("time_range", (0.0, 1.0), "a static 3D model; sets the playback range only")
    record.given("convention")
    return static_model(as_float_tensor(path, "_xyz", xyz, (n, 3)),
                        as_float_tensor(path, "_scaling", cap[names.index("_scaling")], (n, 3)),
                        as_float_tensor(path, "_rotation", cap[names.index("_rotation")], (n, 4)),
                        _column(path, "_opacity", cap[names.index("_opacity")], n),
                        select_sh(coeffs, layout, degree, 0), degree, time_range)


def _from_init_dict(path: Path, d: dict, record: ImportRecord) -> Gaussians4D:
    """The dict read by the official ``--loaded_pth`` option (4D, rot_4d; features stored ``[N, 3, K]``)."""
    xyz = d["xyz"]
    if not isinstance(xyz, Tensor) or xyz.dim() != 2:
        raise CheckpointError(f"{path}: xyz should be an [N, 3] tensor")
    n = xyz.shape[0]
    dc = as_float_tensor(path, "features_dc", d["features_dc"], (n, 3, 1)).transpose(1, 2)
    rest = as_float_tensor(path, "features_rest", d["features_rest"], (n, 3, -1)).transpose(1, 2)
    coeffs = torch.cat([dc, rest], 1)
    layouts = sh_layouts(coeffs.shape[1])
    top = layouts[0] if layouts else (0, 0)
    layout, degree, degree_t = _sh_degrees(path, record, coeffs.shape[1], top[0], top[1], True)
    sh = select_sh(coeffs, layout, degree, degree_t)
    t_means = _column(path, "t", d["t"], n)
    time_range = record.option("time_range", (0.0, 1.0), "official D-NeRF configs" + _time_hint(t_means))
    convention = record.option("convention", "current", "official main since 2024-09-15")
    return _model(path, means=as_float_tensor(path, "xyz", xyz, (n, 3)), t_means=t_means,
                  log_scales=as_float_tensor(path, "scaling", d["scaling"], (n, 3)),
                  log_t_scales=_column(path, "scaling_t", d["scaling_t"], n),
                  quats_l=as_float_tensor(path, "rotation", d["rotation"], (n, 4)),
                  quats_r=as_float_tensor(path, "rotation_r", d["rotation_r"], (n, 4)),
                  opacity_logits=_column(path, "opacity", d["opacity"], n), sh=sh, sh_degree=degree,
                  sh_degree_t=degree_t, time_range=time_range, rotation_convention=convention)


def _model(path: Path, sh: Tensor, **fields) -> Gaussians4D:
    try:
        return Gaussians4D(sh_dc=sh[:, :1].contiguous(), sh_rest=sh[:, 1:].contiguous(), **fields)
    except (ModelError, ValueError) as exc:
        raise CheckpointError(f"{path}: {exc}") from None
