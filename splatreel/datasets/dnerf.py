"""D-NeRF layout: ``transforms_{train,test,val}.json`` + images (Blender/NeRF OpenGL c2w poses, time in [0, 1]).

RGBA images are composited on white, the layout's convention (D-NeRF's ``configs/*.txt`` set ``white_bkgd = True``,
4DGaussians' ``ModelParams`` defaults ``white_background = True``).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from splatreel.cameras import nerf_frame_camera
from splatreel.errors import CameraError, DatasetError

from .base import Dataset, View, json_background, load_json, read_image, time_of

# --- D-NeRF ----------------------------------------------------------------------------------------------------

def _dnerf_split(root: Path, split: str) -> tuple[list[View], dict]:
    """The views of ``transforms_<split>.json`` and the JSON itself."""
    meta = load_json(root / f"transforms_{split}.json")
    frames = meta.get("frames")
    if not isinstance(frames, list) or not frames:
        raise DatasetError(f"{root / f'transforms_{split}.json'}: no frames")
    views = []
    for i, fr in enumerate(frames):
        where = f"{root / f'transforms_{split}.json'} frame {i}"
        try:
            rel = fr["file_path"]
        except (KeyError, TypeError) as exc:
            raise DatasetError(f"{where}: missing or invalid {exc}") from None
        path = (root / rel).resolve() if Path(rel).suffix else None
        if path is None:
            path = (root / (rel + fr.get("extension", meta.get("extension", ".png")))).resolve()
        rgb, alpha = read_image(path)
        h, w = rgb.shape[:2]
        if int(fr.get("w", meta.get("w", w))) != w or int(fr.get("h", meta.get("h", h))) != h:
            raise DatasetError(f"{path}: image is {w}x{h} but the JSON says "
                               f"{fr.get('w', meta.get('w'))}x{fr.get('h', meta.get('h'))}")
        try:  # per-frame intrinsics override top-level ones, which override camera_angle_x
            cam = nerf_frame_camera(fr, meta, w, h)
        except CameraError as exc:
            raise DatasetError(f"{where}: {exc}") from None
        t = float(fr.get("time", time_of(i, len(frames))))
        if not math.isfinite(t):
            raise DatasetError(f"{where}: time is not finite")
        views.append(View(rgb, alpha, cam, t, view_id=i, frame_id=i, name=str(path)))
    sizes = {v.size for v in views}
    if len(sizes) > 1:
        raise DatasetError(f"{root}: images of different sizes in split {split}: {sorted(sizes)[:3]}")
    return views, meta


def _group_ids(views: list[View]) -> list[View]:
    """Give D-NeRF views frame ids by time and view ids by camera pose (poses equal to 1e-6 share an id)."""
    times = sorted({round(v.time, 9) for v in views})
    poses: list[np.ndarray] = []
    out = []
    for v in views:
        vid = next((k for k, p in enumerate(poses) if np.allclose(p, v.camera.c2w, atol=1e-6)), None)
        if vid is None:
            poses.append(v.camera.c2w)
            vid = len(poses) - 1
        out.append(replace(v, view_id=vid, frame_id=times.index(round(v.time, 9))))
    return out


def read_dnerf(root: Path, **_) -> Dataset:
    train, meta = _dnerf_split(root, "train")
    train = _group_ids(train)
    test_split = "test" if (root / "transforms_test.json").exists() else \
        "val" if (root / "transforms_val.json").exists() else None
    test = _group_ids(_dnerf_split(root, test_split)[0]) if test_split else []
    declared = json_background(meta, root / "transforms_train.json")
    if declared is not None:
        bg, why = declared, "the 'background' of transforms_train.json"
    else:
        bg, why = (1.0, 1.0, 1.0), "the D-NeRF layout's convention (D-NeRF and 4DGaussians composite on white)"
    return Dataset(train, test, "dnerf", root, background=bg, background_reason=why, up="z",
                   meta={"test_split": test_split})
