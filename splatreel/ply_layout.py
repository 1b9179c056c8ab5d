"""The standard 3DGS PLY column layout (graphdeco-inria ``GaussianModel.save_ply``), in one place for the PLY
exporter (`splatreel.export.ply`) and importer (`splatreel.importers.ply`), on numpy arrays (no USD needed).

Column layout (binary_little_endian 1.0, one ``element vertex N``, every property ``float``)::

    x y z  nx ny nz  f_dc_0 f_dc_1 f_dc_2  f_rest_0 .. f_rest_{3R-1}  opacity  scale_0 scale_1 scale_2
    rot_0 rot_1 rot_2 rot_3

with R = (degree+1)^2 - 1 rest coefficients per channel (f_rest count 0/9/24/45 for degree 0/1/2/3), so 62 floats
= 248 bytes per splat at degree 3. Spaces of the values (what other splat viewers expect):

* ``nx ny nz``: zeros (placeholders).
* ``f_dc_c``: raw SH DC coefficient of channel c (colour = 0.5 + SH_C0 f_dc).
* ``f_rest``: **channel-major**: all R coefficients of red, then green, then blue
  (``f_rest[c * R + k - 1]`` is coefficient k >= 1 of channel c).
* ``opacity``: logit of the opacity (pre-sigmoid), the opacity clipped to [1e-6, 1 - 1e-6] first.
* ``scale_i``: natural log of the std-dev (clipped to >= 1e-12 first).
* ``rot_0..3``: quaternion (w, x, y, z).

`ply_property_names`, `ply_dtype`, `sh_to_ply_columns` / `ply_columns_to_sh` (the channel-major SH columns),
`splats_to_ply_records` (activated arrays -> records) and its inverse `ply_records_to_splats`, and `ply_bytes`
(the file; the PLY itself is read and written by `plyfile <https://github.com/dranjan/python-plyfile>`_, as the
3DGS reference code does).
"""

from __future__ import annotations

import io
from typing import Sequence

import numpy as np
from plyfile import PlyData, PlyElement

from .errors import ModelError
from .sh import sh_degree_from_bases

#: Opacities are clipped to [OPACITY_EPS, 1 - OPACITY_EPS] before the logit (finite values in the file).
OPACITY_EPS = 1e-6
#: Std-devs are clipped to at least this before the log.
SCALE_EPS = 1e-12


def num_rest_coeffs(sh_degree: int) -> int:
    """Rest coefficients per channel, R = (degree+1)^2 - 1 (so 3R ``f_rest_*`` columns)."""
    return (sh_degree + 1) ** 2 - 1


def ply_property_names(sh_degree: int) -> list[str]:
    """The property names of a 3DGS PLY of SH degree `sh_degree`, in file order (17 + 3R names)."""
    rest = [f"f_rest_{i}" for i in range(3 * num_rest_coeffs(sh_degree))]
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + rest + ["opacity"]
            + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)])


def ply_dtype(sh_degree: int) -> np.dtype:
    """Structured little-endian float32 dtype of one PLY vertex record (itemsize 4 * (17 + 3R))."""
    return np.dtype([(name, "<f4") for name in ply_property_names(sh_degree)])


def sh_degree_from_rest_count(rest: int) -> int:
    """SH degree of `rest` ``f_rest_*`` columns (0, 9, 24, 45 -> 0..3); ValueError otherwise."""
    if rest % 3:
        raise ValueError(f"{rest} f_rest columns is not a multiple of 3")
    try:
        return sh_degree_from_bases(rest // 3 + 1)
    except ValueError:
        raise ValueError(f"{rest} f_rest columns match no SH degree 0..3 (expected 0, 9, 24 or 45)") from None


def sh_degree_from_property_names(names: Sequence[str]) -> int:
    """SH degree implied by the number of ``f_rest_*`` properties; ValueError when it matches none."""
    return sh_degree_from_rest_count(sum(1 for n in names if n.startswith("f_rest_")))


def sh_to_ply_columns(sh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[N, K, 3]`` coefficient-major SH -> (f_dc ``[N, 3]``, f_rest ``[N, 3(K-1)]`` channel-major)."""
    n, k = sh.shape[0], sh.shape[1]
    return sh[:, 0, :], sh[:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (k - 1))  # explicit sizes: n may be 0


def ply_columns_to_sh(f_dc: np.ndarray, f_rest: np.ndarray) -> np.ndarray:
    """Inverse of `sh_to_ply_columns`: (``[N, 3]``, ``[N, 3R]``) -> ``[N, R+1, 3]``."""
    n = f_dc.shape[0]
    rest = f_rest.reshape(n, 3, f_rest.shape[1] // 3).transpose(0, 2, 1)  # explicit sizes: n may be 0
    return np.concatenate([f_dc[:, None, :], rest], axis=1)


def splats_to_ply_records(means: np.ndarray, quats: np.ndarray, scales: np.ndarray, opacities: np.ndarray,
                          sh: np.ndarray) -> np.ndarray:
    """Activated arrays -> structured PLY records (see module doc for the spaces).

    Args:
        means: ``[N, 3]``. quats: ``[N, 4]`` w first. scales: ``[N, 3]`` linear std-devs.
        opacities: ``[N]`` in [0, 1]. sh: ``[N, K, 3]`` coefficient-major, K = (degree+1)^2.
    Returns:
        ``[N]`` records of `ply_dtype` (degree from K).
    Raises:
        ModelError: inconsistent shapes or a K that is not (degree+1)^2.
    """
    n = means.shape[0]
    try:
        degree = sh_degree_from_bases(sh.shape[1]) if sh.ndim == 3 else -1
    except ValueError as exc:
        raise ModelError(f"sh: {exc}") from None
    shapes = {"means": (means.shape, (n, 3)), "quats": (quats.shape, (n, 4)), "scales": (scales.shape, (n, 3)),
              "opacities": (opacities.shape, (n,)), "sh": (sh.shape, (n, sh.shape[1] if sh.ndim == 3 else -1, 3))}
    for name, (got, want) in shapes.items():
        if tuple(got) != want or degree < 0:
            raise ModelError(f"{name} has shape {list(got)}, expected {list(want)}")
    a = np.clip(opacities.astype(np.float64), OPACITY_EPS, 1.0 - OPACITY_EPS)
    f_dc, f_rest = sh_to_ply_columns(sh)
    columns = np.concatenate([
        means, np.zeros((n, 3)), f_dc, f_rest, np.log(a / (1.0 - a))[:, None],
        np.log(np.maximum(scales, SCALE_EPS)), quats], axis=1).astype("<f4")
    return columns.view(ply_dtype(degree)).reshape(n)


def ply_records_to_splats(records: np.ndarray) -> dict[str, np.ndarray]:
    """Inverse of `splats_to_ply_records`: ``[N]`` records (any field order, degree from the ``f_rest`` count) ->
    ``{"means" [N,3], "quats" [N,4] (normalised, w first), "scales" [N,3], "opacities" [N], "sh" [N,K,3]}``,
    float32, activated."""
    names = records.dtype.names or ()
    degree = sh_degree_from_property_names(names)

    def cols(*keys: str) -> np.ndarray:
        return np.stack([records[k].astype(np.float32) for k in keys], axis=1) if keys \
            else np.zeros((records.shape[0], 0), np.float32)

    r = num_rest_coeffs(degree)
    quats = cols("rot_0", "rot_1", "rot_2", "rot_3")
    quats /= np.maximum(np.linalg.norm(quats, axis=1, keepdims=True), 1e-12)
    return {
        "means": cols("x", "y", "z"),
        "quats": quats,
        "scales": np.exp(cols("scale_0", "scale_1", "scale_2")),
        "opacities": (1.0 / (1.0 + np.exp(-records["opacity"].astype(np.float64)))).astype(np.float32),
        "sh": ply_columns_to_sh(cols("f_dc_0", "f_dc_1", "f_dc_2"),
                                cols(*[f"f_rest_{i}" for i in range(3 * r)])).astype(np.float32),
    }


def ply_bytes(records: np.ndarray, comments: Sequence[str] = ()) -> bytes:
    """A whole 3DGS PLY file (binary little-endian, one ``vertex`` element) from `splats_to_ply_records` output,
    written by plyfile."""
    degree = sh_degree_from_property_names(records.dtype.names or ())
    vertex = PlyElement.describe(records.astype(ply_dtype(degree), copy=False), "vertex")
    out = io.BytesIO()
    PlyData([vertex], text=False, byte_order="<", comments=list(comments)).write(out)
    return out.getvalue()
