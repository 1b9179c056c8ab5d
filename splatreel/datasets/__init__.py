"""Multi-view video datasets: the layouts splatreel trains on, one reading module each, read into one in-memory form.

Every layout becomes a `Dataset` of `DatasetImage`s (an image, its optional alpha mask, a
`splatreel.cameras.Camera`, a time and the view / frame indices). Layouts, auto-detected by `detect_layout` (see
README "Training data"):

* ``dnerf`` (`splatreel.datasets.dnerf`): ``transforms_{train,test,val}.json`` + images.
* ``orbit`` (`splatreel.datasets.orbit`): an orbit image matrix ``views/<v>/<f>.png`` + ``cameras.json``.
* ``efficient4d`` (`splatreel.datasets.efficient4d`): strips of 16 SyncDreamer views, optional ``ref/`` frames.
* ``sv4d`` (`splatreel.datasets.sv4d`): one ``*_v00k.mp4`` per view plus ``*_process_input.mp4``.

Every reader says which background its images are composited on and why (`Dataset.background_reason`): a
``background`` key in the layout's JSON wins over the layout's convention (the trainer's override wins over both).
Every reader raises `DatasetError` (one line, naming the file).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from splatreel.errors import DatasetError

from .base import (WHITE_THRESHOLD, Dataset, DatasetImage, json_background, mask_from_white, numeric_files,
                   read_image)
from .dnerf import read_dnerf
from .efficient4d import read_efficient4d
from .orbit import read_orbit
from .sv4d import read_sv4d

__all__ = ["LAYOUTS", "READERS", "WHITE_THRESHOLD", "Dataset", "DatasetError", "DatasetImage",
           "detect_layout", "json_background", "mask_from_white", "read_dataset", "read_image"]

READERS: dict[str, Callable[..., Dataset]] = {
    "dnerf": read_dnerf, "orbit": read_orbit, "efficient4d": read_efficient4d, "sv4d": read_sv4d}
LAYOUTS = tuple(READERS)


def detect_layout(root: Path) -> str:
    """Which layout a folder holds (raises DatasetError naming what was looked for)."""
    if (root / "transforms_train.json").exists():
        return "dnerf"
    if (root / "cameras.json").exists() and (root / "views").is_dir():
        return "orbit"
    if any(root.glob("*_v0[0-9][0-9].mp4")):
        return "sv4d"
    if numeric_files(root):
        return "efficient4d"
    raise DatasetError(f"{root}: not a dataset (looked for transforms_train.json, cameras.json + views/, "
                       f"numbered Efficient4D strips, SV4D *_v001.mp4 videos)")


def read_dataset(root: str | Path, layout: str = "auto", **options) -> Dataset:
    """Read a dataset folder of `layout` ("auto": `detect_layout`); `options` go to the layout's reader. Checks
    that there are training images, all of one size."""
    root = Path(root)
    if not root.exists():
        raise DatasetError(f"{root}: no such folder")
    if not root.is_dir():
        raise DatasetError(f"{root}: expected a dataset folder, got a file")
    if layout == "auto":
        layout = detect_layout(root)
    if layout not in READERS:
        raise DatasetError(f"unknown layout {layout!r} (expected one of {', '.join(LAYOUTS)})")
    ds = READERS[layout](root, **options)
    if not ds.train:
        raise DatasetError(f"{root}: no training images")
    sizes = {v.size for v in ds.train}
    if len(sizes) > 1:
        raise DatasetError(f"{root}: training images have different sizes: {sorted(sizes)[:4]}")
    return ds
