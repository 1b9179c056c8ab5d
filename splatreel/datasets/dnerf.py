"""D-NeRF layout: ``transforms_{train,test,val}.json`` + images (Blender/NeRF OpenGL c2w poses, time in [0, 1]).

RGBA images are composited on white, the layout's convention (D-NeRF's ``configs/*.txt`` set ``white_bkgd = True``,
4DGaussians' ``ModelParams`` defaults ``white_background = True``).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol, Sequence

import numpy as np

from splatreel.cameras import Camera, nerf_frame_camera
from splatreel.errors import CameraError, DatasetError

from .base import Dataset, DatasetImage, json_background, load_json, read_image, time_of

#: The image size when neither the JSON (``w``, ``h``) nor an image gives one: D-NeRF's Blender renders are
#: 800 x 800 (its ``load_blender.py`` reads them at ``H, W = imgs[0].shape[:2]``).
DEFAULT_SIZE = (800, 800)
#: The image extension when ``file_path`` has none and the JSON names no ``extension``: D-NeRF's ``load_blender.py``
#: appends ``.png``.
DEFAULT_EXTENSION = ".png"
SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class TransformsFrame:
    """One frame of a ``transforms_*.json``: where its image is, its camera and its time."""

    file_path: str  # as the JSON writes it (``./train/r_000``), the name the viewer shows
    image: Path  # the image file (`image_file`)
    camera: Camera
    time: float
    size_declared: bool  # the JSON gives the image size (w, h); else it came from the split's first image


def transforms_files(path: Path, split: str | None) -> list[Path]:
    """The transforms JSONs of a dataset folder (``transforms_<split>.json``; ``split=None``: every split there is,
    else a single ``transforms.json``), or `path` itself when it is a file."""
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise DatasetError(f"{path}: no such dataset folder or transforms file")
    files = [path / f"transforms_{s}.json" for s in ([split] if split else SPLITS)
             if (path / f"transforms_{s}.json").is_file()]
    if not files and (path / "transforms.json").is_file():
        files = [path / "transforms.json"]
    if not files:
        raise DatasetError(f"{path}: no transforms_{split or 'train'}.json (D-NeRF / Blender dataset layout)")
    return files


def image_file(root: Path, frame: dict, meta: dict) -> Path:
    """A frame's image: ``file_path`` as written when it has an extension, else plus the frame's or the JSON's
    ``extension`` (default `DEFAULT_EXTENSION`)."""
    rel = frame["file_path"]
    if not Path(rel).suffix:
        rel = rel + frame.get("extension", meta.get("extension", DEFAULT_EXTENSION))
    return (root / rel).resolve()


def _declared_size(frame: dict, meta: dict) -> tuple[int, int] | None:
    w, h = frame.get("w", meta.get("w")), frame.get("h", meta.get("h"))
    return (int(w), int(h)) if w and h else None


def _file_size(path: Path) -> tuple[int, int] | None:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
    return None if img is None else (img.shape[1], img.shape[0])


def read_transforms(path: Path) -> tuple[list[TransformsFrame], dict]:
    """The frames of one ``transforms_*.json`` and the JSON itself. A frame's image size is the JSON's ``w``/``h``
    (per frame, else top level), else the size of the split's first image, else `DEFAULT_SIZE`; its time is
    ``time``, else evenly spaced over [0, 1] in file order."""
    meta = load_json(path)
    frames = meta.get("frames")
    if not isinstance(frames, list) or not frames:
        raise DatasetError(f"{path}: no frames")
    out: list[TransformsFrame] = []
    first_size = None
    for i, fr in enumerate(frames):
        where = f"{path} frame {i}"
        try:
            image = image_file(path.parent, fr, meta)
            size = _declared_size(fr, meta)
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(f"{where}: missing or invalid {exc}") from None
        if size is None:
            first_size = first_size or _file_size(image) or DEFAULT_SIZE
        try:  # per-frame intrinsics override top-level ones, which override camera_angle_x
            cam = nerf_frame_camera(fr, meta, *(size or first_size))
        except CameraError as exc:
            raise DatasetError(f"{where}: {exc}") from None
        try:
            t = float(fr.get("time", time_of(i, len(frames))))
        except (TypeError, ValueError) as exc:
            raise DatasetError(f"{where}: invalid time ({exc})") from None
        if not math.isfinite(t):
            raise DatasetError(f"{where}: time is not finite")
        out.append(TransformsFrame(str(fr["file_path"]), image, cam, t, size is not None))
    return out, meta


def _dnerf_split(root: Path, split: str) -> tuple[list[DatasetImage], dict]:
    """The views (images read) of ``transforms_<split>.json`` and the JSON itself."""
    frames, meta = read_transforms(root / f"transforms_{split}.json")
    views = []
    for i, fr in enumerate(frames):
        rgb, alpha = read_image(fr.image)
        h, w = rgb.shape[:2]
        cw, ch = fr.camera.width, fr.camera.height
        if (w, h) != (cw, ch):
            raise DatasetError(f"{fr.image}: image is {w}x{h} but the JSON says {cw}x{ch}" if fr.size_declared else
                               f"{root}: images of different sizes in split {split}: {sorted({(w, h), (cw, ch)})}")
        views.append(DatasetImage(rgb, alpha, fr.camera, fr.time, view_id=i, frame_id=i, name=str(fr.image)))
    return views, meta


def _group_ids(views: list[DatasetImage]) -> list[DatasetImage]:
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


# --- writing ---------------------------------------------------------------------------------------------------
class TransformsEntry(Protocol):
    """What `transforms_for` needs of a view: its ``file_path`` (no extension), time and camera."""

    file_path: str
    time: float
    camera: Camera


def clean_number(x: float) -> float:
    """Round away float noise so the JSON is short and stable (-0.0 becomes 0.0)."""
    return round(float(x), 10) + 0.0


def transforms_for(views: Sequence[TransformsEntry], intrinsics: Camera) -> dict:
    """The ``transforms_<split>.json`` content for `views` (anything with ``file_path``, ``time`` and ``camera``),
    whose cameras all share the intrinsics and image size of the camera `intrinsics` (written once at the top
    level; the split may be empty). `read_transforms` reads it back."""
    cam = intrinsics
    frames = [{"file_path": v.file_path, "time": clean_number(v.time),
               "transform_matrix": [[clean_number(x) for x in row] for row in v.camera.to_opengl_c2w()],
               "w": cam.width, "h": cam.height} for v in views]
    intrinsics = {"camera_angle_x": cam.fov_x, "fl_x": cam.fx, "fl_y": cam.fy, "cx": cam.cx, "cy": cam.cy}
    return {**{k: clean_number(x) for k, x in intrinsics.items()}, "w": cam.width, "h": cam.height,
            "frames": frames}


def write_transforms(path: Path, data: dict) -> None:
    """Write a transforms (or any) JSON, with each list of numbers (a matrix row) on one line."""
    text = json.dumps(data, indent=2)
    # Keep lists of numbers (matrix rows) on one line.
    text = re.sub(r"\[\s+([-+0-9.eE,\s]+?)\s+\]", lambda m: "[" + " ".join(m.group(1).split()) + "]", text)
    path.write_text(text + "\n")
