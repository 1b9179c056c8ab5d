"""Builders of small files that follow other tools' layouts exactly (fudan-zvg/4d-gaussian-splatting
``scene/gaussian_model.py`` ``capture()``; hustvl/4DGaussians and VITA-Group/4DGen ``scene/deformation.py``,
``scene/hexplane.py``, ``point_cloud.ply``, ``cfg_args``), used by the importer tests. No tests here.

Independent reference math (numpy, written from those sources' formulas, not from splatreel) is here too, so that the
tests check the importers against the formulas rather than against splatreel's own core.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import torch

C0 = 0.28209479177387814


# --- reference math (numpy) -------------------------------------------------------------------------------------
def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of w-first quaternions."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def rotation_4d_reference(q_l, q_r, convention: str) -> np.ndarray:
    """R4 from its definition A v = q_l ⊗ v ⊗ conj(q_r); legacy R4 = A, current R4[i,j] = A[3-i,3-j]."""
    q_l = np.asarray(q_l, float) / np.linalg.norm(q_l)
    q_r = np.asarray(q_r, float) / np.linalg.norm(q_r)
    conj = q_r * np.array([1, -1, -1, -1])
    a = np.stack([qmul(qmul(q_l, e), conj) for e in np.eye(4)], 1)  # column k = image of e_k
    return a if convention == "legacy" else a[::-1, ::-1]


def rotation_3d_reference(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def slice_reference(mean, t_mean, scales, t_scale, q_l, q_r, opacity_logit, convention, t):
    """(mean at t, conditional covariance, opacity at t) of one native 4D Gaussian (notes §1.4-1.5)."""
    r4 = rotation_4d_reference(q_l, q_r, convention)
    s = np.diag(np.r_[scales, t_scale] ** 2)
    cov = r4 @ s @ r4.T
    s12, stt = cov[:3, 3], cov[3, 3]
    mean_t = np.asarray(mean) + s12 / stt * (t - t_mean)
    cov_t = cov[:3, :3] - np.outer(s12, s12) / stt
    opacity = 1 / (1 + np.exp(-opacity_logit)) * np.exp(-0.5 * (t - t_mean) ** 2 / stt)
    return mean_t, cov_t, opacity


# --- official 4DGS capture tuple -------------------------------------------------------------------------------
def capture_tuple(n: int = 4, m: int = 48, active_sh: int = 3, active_sh_t: int = 2, rot_4d: bool = True,
                  env_map=None, spatial_lr_scale=np.float64(2.375), seed: int = 0, values: dict | None = None):
    """The 19-entry ``GaussianModel.capture()`` tuple of official 4DGS (order, types, shapes of §2.1).

    Parameters are ``torch.nn.Parameter``; entry 11 is a real Adam ``state_dict()`` (one named group per
    parameter, numpy-float learning rates in the xyz and t groups, as the official schedule writes them).
    `values` overrides raw parameters by name (_xyz, _t, _rotation, ...).
    """
    gen = torch.Generator().manual_seed(seed)
    raw = {
        "_xyz": torch.randn(n, 3, generator=gen), "_features_dc": torch.randn(n, 1, 3, generator=gen) * 0.3,
        "_features_rest": torch.randn(n, m - 1, 3, generator=gen) * 0.05,
        "_scaling": torch.randn(n, 3, generator=gen) * 0.2 - 2,
        "_rotation": torch.randn(n, 4, generator=gen), "_opacity": torch.randn(n, 1, generator=gen),
        "_t": torch.rand(n, 1, generator=gen), "_scaling_t": torch.randn(n, 1, generator=gen) * 0.2 - 1,
        "_rotation_r": torch.randn(n, 4, generator=gen) if rot_4d else torch.empty(0),
    }
    raw.update(values or {})
    params = {k: torch.nn.Parameter(v.clone().float()) for k, v in raw.items()}
    groups = [("xyz", "_xyz"), ("f_dc", "_features_dc"), ("f_rest", "_features_rest"), ("opacity", "_opacity"),
              ("scaling", "_scaling"), ("rotation", "_rotation"), ("t", "_t"), ("scaling_t", "_scaling_t")]
    if rot_4d:
        groups.append(("rotation_r", "_rotation_r"))
    opt = torch.optim.Adam([{"params": [params[p]], "lr": 0.0, "name": g} for g, p in groups], lr=0.0, eps=1e-15)
    for _, p in groups:
        params[p].grad = torch.zeros_like(params[p])
    opt.step()
    for group in opt.param_groups:  # the official xyz schedule is numpy arithmetic
        if group["name"] in ("xyz", "t"):
            group["lr"] = np.float64(1.6e-4) * spatial_lr_scale if group["name"] == "xyz" else np.float64(3.8e-4)
    return (active_sh, params["_xyz"], params["_features_dc"], params["_features_rest"], params["_scaling"],
            params["_rotation"], params["_opacity"], torch.zeros(n), torch.zeros(n, 1), torch.zeros(n, 1),
            torch.zeros(n, 1), opt.state_dict(), spatial_lr_scale, params["_t"], params["_scaling_t"],
            params["_rotation_r"], rot_4d, env_map, active_sh_t)


def as_numpy1_pickle(path: Path) -> None:
    """Rewrite a torch.save file as numpy 1.x would have pickled it (``numpy.core.multiarray.scalar``)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as dst:
        for info in src.infolist():
            data = src.read(info)
            if info.filename.endswith("data.pkl"):
                assert b"numpy._core.multiarray\nscalar" in data
                data = data.replace(b"numpy._core.multiarray\nscalar", b"numpy.core.multiarray\nscalar")
            dst.writestr(info, data)
    path.write_bytes(buf.getvalue())


# --- 3DGS PLY ------------------------------------------------------------------------------------------------------
def write_splat_ply(path: Path, means, log_scales, quats, opacity_logits, sh, fmt: str = "binary_little_endian",
                    comments=()) -> Path:
    """A 3DGS PLY in the Inria layout: x y z nx ny nz f_dc_0..2 f_rest_* (channel-major) opacity scale_* rot_*."""
    means, log_scales, quats = (np.asarray(a, np.float32) for a in (means, log_scales, quats))
    opacity_logits, sh = np.asarray(opacity_logits, np.float32), np.asarray(sh, np.float32)
    n, k = sh.shape[:2]
    rest = sh[:, 1:].transpose(0, 2, 1).reshape(n, 3 * (k - 1))
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + \
        [f"f_rest_{i}" for i in range(3 * (k - 1))] + ["opacity"] + \
        [f"scale_{i}" for i in range(log_scales.shape[1])] + [f"rot_{i}" for i in range(4)]
    table = np.concatenate([means, np.zeros_like(means), sh[:, 0], rest, opacity_logits[:, None], log_scales, quats],
                           1).astype(np.float32)
    header = ["ply", f"format {fmt} 1.0", *[f"comment {c}" for c in comments], f"element vertex {n}",
              *[f"property float {p}" for p in names], "end_header"]
    head = ("\n".join(header) + "\n").encode()
    if fmt == "ascii":
        body = "".join(" ".join(repr(float(v)) for v in row) + "\n" for row in table).encode()
    else:
        body = table.astype(">f4" if fmt == "binary_big_endian" else "<f4").tobytes()
    Path(path).write_bytes(head + body)
    return Path(path)


def random_splats(n: int, degree: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"means": rng.normal(size=(n, 3)), "log_scales": rng.normal(-2, 0.3, size=(n, 3)),
            "quats": rng.normal(size=(n, 4)), "opacity_logits": rng.normal(size=n),
            "sh": rng.normal(0, 0.3, size=(n, (degree + 1) ** 2, 3))}


# --- 4DGaussians / 4DGen deformation state dicts -----------------------------------------------------------------
def deformation_state_dict(variant: str, channels: int, base_res: int, time_res: int, multires=(1, 2),
                           width: int = 64, depth: int = 1, aabb=((1.3,) * 3, (-1.3,) * 3), seed: int = 0
                           ) -> dict[str, torch.Tensor]:
    """A state dict with the real key names and shapes of `deform_network` (notes A.3 for '4dgaussians', B.6
    for '4dgen'); planes initialised as upstream (space U(0.1, 0.5), time planes 1), layers small random."""
    gen = torch.Generator().manual_seed(seed)
    sd: dict[str, torch.Tensor] = {}
    if variant == "4dgaussians":
        sd["time_poc"] = torch.tensor([1.0, 2.0, 4.0, 8.0])
    sd["pos_poc"] = 2.0 ** torch.arange(10.0)
    sd["rotation_scaling_poc"] = torch.tensor([1.0, 2.0])
    sd["opacity_poc"] = torch.tensor([1.0, 2.0])
    if variant == "4dgaussians":
        sd["timenet.0.weight"], sd["timenet.0.bias"] = torch.randn(64, 9, generator=gen), torch.zeros(64)
        sd["timenet.2.weight"], sd["timenet.2.bias"] = torch.randn(32, 64, generator=gen), torch.zeros(32)
    sd["deformation_net.grid.aabb"] = torch.tensor(aabb, dtype=torch.float32)
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    for level, mult in enumerate(multires):
        res = [base_res * mult] * 3 + [time_res]
        for p, (a, b) in enumerate(pairs):
            shape = (1, channels, res[b], res[a])
            plane = torch.ones(shape) if b == 3 else torch.rand(shape, generator=gen) * 0.4 + 0.1
            sd[f"deformation_net.grid.grids.{level}.{p}"] = plane
    features = channels * len(multires) * (6 if variant == "4dgen" else 1)
    sd["deformation_net.feature_out.0.weight"] = torch.randn(width, features, generator=gen) * 0.1
    sd["deformation_net.feature_out.0.bias"] = torch.zeros(width)
    for i in range(1, max(depth, 1)):
        sd[f"deformation_net.feature_out.{2 * i}.weight"] = torch.randn(width, width, generator=gen) * 0.1
        sd[f"deformation_net.feature_out.{2 * i}.bias"] = torch.zeros(width)
    if variant == "4dgaussians":
        outs = {"pos_deform": 3, "scales_deform": 3, "rotations_deform": 4, "opacity_deform": 1, "shs_deform": 48}
        hidden, last = "1", "3"
    else:
        outs = {"pos_deform": 3, "scales_deform": 1, "rotations_deform": 4, "opacity_deform": 1, "color_deform": 3}
        hidden, last = "fc2", "fc1"
    for name, out in outs.items():
        sd[f"deformation_net.{name}.{hidden}.weight"] = torch.randn(width, width, generator=gen) * 0.1
        sd[f"deformation_net.{name}.{hidden}.bias"] = torch.zeros(width)
        sd[f"deformation_net.{name}.{last}.weight"] = torch.randn(out, width, generator=gen) * 0.01
        sd[f"deformation_net.{name}.{last}.bias"] = torch.zeros(out)
    return sd


def write_deformation_folder(root: Path, state: dict, splats: dict, cfg_args: str | None = None,
                             iteration: int = 3000, table=None) -> Path:
    """A trained-model folder: cfg_args + point_cloud/iteration_N/{point_cloud.ply, deformation*.pth}."""
    folder = Path(root) / "point_cloud" / f"iteration_{iteration}"
    folder.mkdir(parents=True, exist_ok=True)
    write_splat_ply(folder / "point_cloud.ply", **splats)
    torch.save(state, folder / "deformation.pth")
    n = len(splats["means"])
    torch.save(torch.ones(n, dtype=torch.bool) if table is None else torch.as_tensor(table),
               folder / "deformation_table.pth")
    torch.save(torch.zeros(n, 3), folder / "deformation_accum.pth")
    if cfg_args is not None:
        (Path(root) / "cfg_args").write_text(cfg_args)
    return folder
