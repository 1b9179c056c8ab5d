"""Generic orbit image matrix: ``views/<v>/<f>.png`` + ``cameras.json`` (elevation, azimuth, radius, fov per view).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from splatreel.cameras import orbit
from splatreel.errors import CameraError, DatasetError

from .base import (Dataset, DatasetImage, check_frames, json_background, load_json, mask_from_white, numeric_files,
                   read_image, time_of)

# --- generic orbit image matrix -------------------------------------------------------------------------------

def _orbit_views(root: Path, folder: str, specs: list, meta: dict, times: list[float] | None) -> list[DatasetImage]:
    views = []
    up = meta.get("up", "z")
    for v, spec in enumerate(specs):
        d = root / folder / str(v)
        if not d.is_dir():
            raise DatasetError(f"{d}: missing view folder (cameras.json lists {len(specs)} views)")
        files = check_frames(numeric_files(d), d)
        n = len(files)
        if times is not None and len(times) != n:
            raise DatasetError(f"{d}: {n} frames but cameras.json lists {len(times)} times")
        try:
            cam_args = dict(elevation_deg=float(spec["elevation"]), azimuth_deg=float(spec["azimuth"]),
                            radius=float(spec.get("radius", meta.get("radius", 2.0))),
                            fov_deg=float(spec.get("fov", meta.get("fov", 49.1343))), up=up)
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(f"{root / 'cameras.json'}: view {v}: missing or invalid {exc}") from None
        for f, path in enumerate(files):
            rgb, alpha = read_image(path)
            h, w = rgb.shape[:2]
            try:
                cam = orbit(width=w, height=h, **cam_args)
            except CameraError as exc:
                raise DatasetError(f"{root / 'cameras.json'}: view {v}: {exc}") from None
            t = times[f] if times is not None else time_of(f, n)
            views.append(DatasetImage(rgb, alpha, cam, float(t), v, f, str(path)))
    per_view: dict[int, int] = {}
    for x in views:
        per_view[x.view_id] = per_view.get(x.view_id, 0) + 1
    if len(set(per_view.values())) > 1:
        raise DatasetError(f"{root / folder}: views have different frame counts {per_view}")
    return views


def read_orbit(root: Path, **_) -> Dataset:
    meta = load_json(root / "cameras.json")
    specs = meta.get("views")
    if not isinstance(specs, list) or not specs:
        raise DatasetError(f"{root / 'cameras.json'}: needs a non-empty 'views' list")
    times = meta.get("times")
    train = _orbit_views(root, "views", specs, meta, times)
    test = _orbit_views(root, "test_views", meta["test_views"], meta, meta.get("test_times")) \
        if meta.get("test_views") else []
    bg = json_background(meta, root / "cameras.json")
    if bg is not None:
        why = "the 'background' of cameras.json"
    elif train[0].alpha is None:
        bg, why = (1.0, 1.0, 1.0), "RGB images generated on white"
    else:
        bg, why = (0.0, 0.0, 0.0), "the orbit layout's default for RGBA images"
    if train[0].alpha is None:
        train = [replace(v, alpha=mask_from_white(v.image)) for v in train]
    return Dataset(train, test, "orbit", root, background=bg, background_reason=why, up=meta.get("up", "z"),
                   meta=meta)
