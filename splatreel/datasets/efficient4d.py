"""Efficient4D stage-1 output: ``<f>.png`` strips of 16 SyncDreamer views (white background), optional
``ref/<f>.png`` reference video frames.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from splatreel.cameras import orbit
from splatreel.errors import DatasetError

from .base import Dataset, DatasetImage, check_frames, mask_from_white, numeric_files, read_image, time_of

# --- Efficient4D stage 1 --------------------------------------------------------------------------------------
#: SyncDreamer's cameras (Liu et al. 2024, SyncDreamer; liuyuan-pal/SyncDreamer ``meta_info/camera-16.pkl``, which
#: fudan-zvg/Efficient4D ships too): 16 views, elevation 30 deg, azimuth 22.5 v, distance
#: 1.5, fx = 280 at 256 px, z-up world; the input view is azimuth 0 at elevation 0.
E4D_VIEWS, E4D_ELEVATION, E4D_RADIUS, E4D_FOV = 16, 30.0, 1.5, math.degrees(2 * math.atan(128 / 280))


def read_efficient4d(root: Path, views: int = E4D_VIEWS, **_) -> Dataset:
    files = check_frames(numeric_files(root), root)
    n = len(files)
    out = []
    for f, path in enumerate(files):
        rgb, alpha = read_image(path)
        h, w = rgb.shape[:2]
        if w != views * h:
            raise DatasetError(f"{path}: a strip of {views} square views must be {views * h}x{h}, got {w}x{h}")
        for v in range(views):
            tile = np.ascontiguousarray(rgb[:, v * h:(v + 1) * h])
            a = None if alpha is None else np.ascontiguousarray(alpha[:, v * h:(v + 1) * h])
            cam = orbit(E4D_ELEVATION, 22.5 * v * 16 / views, E4D_RADIUS, E4D_FOV, h, h, up="z")
            out.append(DatasetImage(tile, a if a is not None else mask_from_white(tile), cam, time_of(f, n), v, f,
                            f"{path}[view {v}]"))
    ref = root / "ref"
    if ref.is_dir():
        rfiles = check_frames(numeric_files(ref), ref)
        if len(rfiles) != n:
            raise DatasetError(f"{ref}: {len(rfiles)} reference frames but {n} strips")
        for f, path in enumerate(rfiles):
            rgb, alpha = read_image(path)
            h, w = rgb.shape[:2]
            cam = orbit(0.0, 0.0, E4D_RADIUS, E4D_FOV, w, h, up="z")
            if alpha is not None:  # RGBA reference frames: composite on white like the generated strips
                a = alpha[..., None].astype(np.float32) / 255
                rgb = (rgb * a + 255 * (1 - a) + 0.5).astype(np.uint8)
            out.append(DatasetImage(rgb, alpha if alpha is not None else mask_from_white(rgb), cam, time_of(f, n),
                            views, f, str(path)))
    return Dataset(out, [], "efficient4d", root, background=(1.0, 1.0, 1.0),
                   background_reason="Efficient4D's views are generated on white", up="z",
                   meta={"views": views, "frames": n, "reference": ref.is_dir()})
