"""The training side of a dataset: read it with `splatreel.datasets` (one module per layout), then downscale the
images and override the background as the trainer was asked.

Images stay uint8 and are converted per batch by the trainer.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

from splatreel.datasets import Dataset, DatasetImage, read_dataset
from splatreel.errors import DatasetError

__all__ = ["camera_videos", "downscale_view", "load_dataset", "relative_name"]


def downscale_view(view: DatasetImage, factor: int) -> DatasetImage:
    """The view at 1/factor resolution (area filter; the intrinsics follow)."""
    import cv2

    if factor == 1:
        return view
    w, h = view.size
    nw, nh = max(1, round(w / factor)), max(1, round(h / factor))
    image = cv2.resize(view.image, (nw, nh), interpolation=cv2.INTER_AREA)
    alpha = None if view.alpha is None else cv2.resize(view.alpha, (nw, nh), interpolation=cv2.INTER_AREA)
    return replace(view, image=image, alpha=alpha, camera=view.camera.resized(nw, nh))


def camera_videos(ds: Dataset) -> list[list[int]]:
    """Training images grouped by camera (``view_id``), each group ordered by time and cut into runs of consecutive
    frames of at least two: the videos whose frame-to-frame flow means motion."""
    rank = {t: k for k, t in enumerate(ds.frame_times)}
    by_view: dict[int, list[int]] = {}
    for i, v in enumerate(ds.train):
        by_view.setdefault(v.view_id, []).append(i)
    videos = []
    for idx in by_view.values():
        idx = sorted(idx, key=lambda i: ds.train[i].time)
        run = [idx[0]]
        for i in idx[1:]:
            if rank[ds.train[i].time] == rank[ds.train[run[-1]].time] + 1:
                run.append(i)
            else:
                if len(run) > 1:
                    videos.append(run)
                run = [i]
        if len(run) > 1:
            videos.append(run)
    return videos


def relative_name(name: str, root: Path) -> str:
    """A view's name (its image path, maybe with a frame or view suffix) relative to the dataset folder, as
    checkpoints record it and messages show it: shorter, and no user's absolute paths in a file that may be
    shared."""
    try:
        return str(Path(name).relative_to(root))
    except ValueError:  # not under the dataset folder
        return name




def load_dataset(root: str | Path, layout: str = "auto", downscale: int = 1,
                 background: tuple[float, float, float] | None = None, **options) -> Dataset:
    """Read a dataset folder. `downscale` K trains on images K times smaller; `background` overrides the layout's
    background colour (RGB in [0, 1]); other options go to the layout reader."""
    if int(downscale) < 1:
        raise DatasetError(f"--downscale must be a positive integer, got {downscale}")
    ds = read_dataset(root, layout, **options)
    if downscale > 1:
        ds.train = [downscale_view(v, downscale) for v in ds.train]
        ds.test = [downscale_view(v, downscale) for v in ds.test]
    if background is not None:
        rgb = tuple(float(x) for x in background)
        if len(rgb) != 3 or not all(math.isfinite(x) and 0.0 <= x <= 1.0 for x in rgb):
            raise DatasetError(f"--background must be three numbers in [0, 1], got {' '.join(map(str, background))}")
        ds.background, ds.background_reason = rgb, "--background"
    return ds
