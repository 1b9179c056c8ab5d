"""A dataset's own point cloud, for initialisation: ``fused.ply`` (4DGaussians' D-NeRF loader writes and reads it),
``points3d.ply`` (the 3DGS/4DGS NeRF-synthetic loaders), COLMAP's ``points3D.bin`` / ``points3D.txt``.

`find_point_cloud` says which file a dataset folder has, `read_point_cloud` reads it, and `in_view_share` checks that
the points live in the cameras' frame (a COLMAP model beside data whose poses were re-centred would not).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from splatreel.errors import DatasetError

#: Looked for in this order, relative to the dataset folder.
POINT_CLOUD_NAMES = ("fused.ply", "points3d.ply", "points3D.ply", "sparse/0/points3D.bin", "sparse/0/points3D.txt",
                     "points3D.bin", "points3D.txt")


def find_point_cloud(root: Path) -> Path | None:
    """The first of `POINT_CLOUD_NAMES` that exists in dataset folder `root`, else None."""
    for name in POINT_CLOUD_NAMES:
        if (root / name).is_file():
            return root / name
    return None


def read_point_cloud(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(``[N, 3]`` float64 positions, ``[N, 3]`` float64 RGB in [0, 1] or None) of a PLY or COLMAP points3D file.
    Raises DatasetError in one line for a file that cannot be read or holds no finite point."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".ply":
            xyz, rgb = _read_ply(path)
        elif path.suffix.lower() == ".bin":
            xyz, rgb = _read_colmap_bin(path)
        else:
            xyz, rgb = _read_colmap_txt(path)
    except DatasetError:
        raise
    except Exception as exc:  # truncated or malformed files raise many kinds
        raise DatasetError(f"{path}: unreadable point cloud ({str(exc).strip() or type(exc).__name__})") from None
    ok = np.isfinite(xyz).all(1)
    if not ok.any():
        raise DatasetError(f"{path}: no finite points")
    return xyz[ok], None if rgb is None else rgb[ok]


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    import trimesh

    cloud = trimesh.load(path, process=False)
    xyz = np.asarray(getattr(cloud, "vertices", np.zeros((0, 3))), dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[0] == 0:
        raise DatasetError(f"{path}: no vertices in this PLY")
    colors = getattr(cloud, "colors", None)
    if colors is None and hasattr(cloud, "visual"):
        colors = getattr(cloud.visual, "vertex_colors", None)
    rgb = None
    if colors is not None and len(colors) == len(xyz):
        rgb = np.asarray(colors, dtype=np.float64)[:, :3] / 255.0
    return xyz, rgb


def _read_colmap_txt(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP text model: ``POINT3D_ID X Y Z R G B ERROR TRACK[]`` per line, ``#`` comments."""
    rows = [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
    if not rows:
        raise DatasetError(f"{path}: no points")
    data = np.array([[float(x) for x in r[1:7]] for r in rows])
    return data[:, :3], data[:, 3:6] / 255.0


def _read_colmap_bin(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP binary model (``read_points3D_binary`` in COLMAP's ``scripts/python/read_write_model.py``): uint64
    count, then per point uint64 id, 3 float64 xyz, 3 uint8 rgb, float64 error, uint64 track length and that many
    (uint32 image id, uint32 point2D index) pairs."""
    data = path.read_bytes()
    (count,) = struct.unpack_from("<Q", data, 0)
    off, xyz, rgb = 8, np.empty((count, 3)), np.empty((count, 3))
    for i in range(count):
        if off + 51 > len(data):
            raise DatasetError(f"{path}: truncated after {i} of {count} points")
        _, x, y, z, r, g, b, _, track = struct.unpack_from("<QdddBBBdQ", data, off)
        off += 51 + 8 * track
        if off > len(data):
            raise DatasetError(f"{path}: truncated after {i} of {count} points")
        xyz[i], rgb[i] = (x, y, z), (r, g, b)
    return xyz, rgb / 255.0


def in_view_share(points: np.ndarray, cameras) -> float:
    """Share of `points` ``[N, 3]`` in front of and inside the image of at least one of `cameras`."""
    seen = np.zeros(len(points), bool)
    for cam in cameras:
        uv, z = cam.project(points)
        seen |= (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    return float(seen.mean()) if len(points) else 0.0
