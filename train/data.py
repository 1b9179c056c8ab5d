"""Multi-view video datasets: the layouts splatreel trains on, read into one in-memory form.

Every layout becomes a `Dataset` of `View`s (an image, its optional alpha mask, a `splatreel.cameras.Camera`, a time
and the view / frame indices). Layouts, auto-detected by `detect_layout` (see README "Training data"):

* ``dnerf``: ``transforms_{train,test,val}.json`` + images (Blender/NeRF OpenGL c2w poses, time in [0, 1]); RGBA
  images are composited on white, the layout's convention (D-NeRF's ``configs/*.txt`` set ``white_bkgd = True``,
  4DGaussians' ``ModelParams`` defaults ``white_background = True``).
* ``orbit``: a generic orbit image matrix ``views/<v>/<f>.png`` + ``cameras.json`` (elevation, azimuth, radius,
  fov per view).
* ``efficient4d``: Efficient4D stage-1 output, ``<f>.png`` strips of 16 SyncDreamer views (white background),
  optional ``ref/<f>.png`` reference video frames.
* ``sv4d``: SV4D / SV4D 2.0 output, one ``*_v00k.mp4`` per view plus ``*_process_input.mp4`` (white background).

Every reader says which background its images are composited on and why (`Dataset.background_reason`): a
``background`` key in the layout's JSON wins over the layout's convention, and the caller's override over both.

Images are kept as uint8 (RGB ``[H, W, 3]``, alpha ``[H, W]`` or None) and converted per batch by the trainer.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from splatreel.cameras import Camera, nerf_frame_camera, orbit
from splatreel.errors import CameraError, DatasetError

LAYOUTS = ("dnerf", "orbit", "efficient4d", "sv4d")
#: Pixels whose mean brightness is above this (of 255) count as white background in RGB-only generated data
#: (SV4D's preprocessing uses 250 the same way).
WHITE_THRESHOLD = 250


@dataclass(frozen=True)
class View:
    """One training or test image."""

    image: np.ndarray  # [H, W, 3] uint8 RGB
    alpha: np.ndarray | None  # [H, W] uint8, or None when the data has no mask
    camera: Camera
    time: float
    view_id: int
    frame_id: int
    name: str  # where it came from, for messages

    @property
    def size(self) -> tuple[int, int]:
        return self.camera.width, self.camera.height


@dataclass
class Dataset:
    """A multi-view video: training views, test views (may be empty), and what the layout says about them."""

    train: list[View]
    test: list[View]
    layout: str
    root: Path
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: Why this background: the layout's convention, the dataset's JSON, or the caller's override.
    background_reason: str = "the layout's default"
    up: str = "z"
    meta: dict = field(default_factory=dict)

    @property
    def time_range(self) -> tuple[float, float]:
        times = [v.time for v in self.train]
        lo, hi = min(times), max(times)
        return (lo, hi) if hi > lo else (lo, lo + 1.0)

    @property
    def frame_times(self) -> list[float]:
        return sorted({v.time for v in self.train})

    @property
    def num_views(self) -> int:
        return len({v.view_id for v in self.train})

    def camera_centre_and_radius(self) -> tuple[np.ndarray, float]:
        """Centre and radius of the training cameras (the 3DGS "extent" is 1.1 x this radius)."""
        pos = np.stack([v.camera.position for v in self.train])
        centre = pos.mean(0)
        return centre, float(np.linalg.norm(pos - centre, axis=1).max())

    def summary(self) -> str:
        w, h = self.train[0].size
        views, times = self.num_views, len(self.frame_times)
        shape = f"{views} views x {times} times" if views * times == len(self.train) else \
            f"{views} cameras, {times} times" + (", one camera per time" if times == len(self.train) else "")
        return f"{self.layout}: {len(self.train)} training images ({shape}, {w}x{h}), {len(self.test)} test images"


# --- images --------------------------------------------------------------------------------------------------

def read_image(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """An 8/16-bit PNG/JPEG/EXR as (RGB uint8 ``[H,W,3]``, alpha uint8 ``[H,W]`` or None)."""
    import cv2

    if not path.exists():
        raise DatasetError(f"missing image {path}")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(f"unreadable image {path} (corrupt or unsupported format)")
    if img.dtype == np.uint16:
        img = (img.astype(np.float32) / 257.0 + 0.5).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = (np.clip(img.astype(np.float32), 0, 1) * 255 + 0.5).astype(np.uint8)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, 2)
    if img.shape[2] == 4:
        return np.ascontiguousarray(img[:, :, 2::-1]), np.ascontiguousarray(img[:, :, 3])
    return np.ascontiguousarray(img[:, :, 2::-1]), None


def mask_from_white(rgb: np.ndarray, threshold: int = WHITE_THRESHOLD) -> np.ndarray:
    """Foreground mask ``[H,W]`` uint8 for images generated on a white background: not-white pixels, with the
    edges softened by a 3x3 blur so that anti-aliased borders get partial alpha."""
    import cv2

    fg = (rgb.astype(np.float32).mean(-1) <= threshold).astype(np.float32)
    return (cv2.blur(fg, (3, 3)) * 255 + 0.5).astype(np.uint8)


def downscale_view(view: View, factor: int) -> View:
    """The view at 1/factor resolution (area filter; the intrinsics follow)."""
    import cv2

    if factor == 1:
        return view
    w, h = view.size
    nw, nh = max(1, round(w / factor)), max(1, round(h / factor))
    image = cv2.resize(view.image, (nw, nh), interpolation=cv2.INTER_AREA)
    alpha = None if view.alpha is None else cv2.resize(view.alpha, (nw, nh), interpolation=cv2.INTER_AREA)
    return replace(view, image=image, alpha=alpha, camera=view.camera.resized(nw, nh))


def relative_name(name: str, root: Path) -> str:
    """A view's name (its image path, maybe with a frame or view suffix) relative to the dataset folder, as
    checkpoints record it and messages show it: shorter, and no user's absolute paths in a file that may be
    shared."""
    try:
        return str(Path(name).relative_to(root))
    except ValueError:  # not under the dataset folder
        return name


def _numeric_files(folder: Path, suffixes=(".png", ".jpg", ".jpeg", ".exr")) -> dict[int, Path]:
    """``{index: path}`` for files named by an integer (any zero padding)."""
    out = {}
    for p in folder.iterdir():
        if p.suffix.lower() in suffixes and re.fullmatch(r"\d+", p.stem):
            out[int(p.stem)] = p
    return out


def _check_frames(files: dict[int, Path], where: Path) -> list[Path]:
    if not files:
        raise DatasetError(f"{where}: no numbered images (expected 0.png, 1.png, ...)")
    idx = sorted(files)
    missing = sorted(set(range(idx[0], idx[-1] + 1)) - set(idx))
    if missing:
        raise DatasetError(f"{where}: missing frame(s) {', '.join(map(str, missing[:5]))}"
                           + (" ..." if len(missing) > 5 else ""))
    return [files[i] for i in idx]


def _load_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise DatasetError(f"missing {path}") from None
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: expected a JSON object")
    return data


def _time_of(i: int, n: int) -> float:
    return i / (n - 1) if n > 1 else 0.0


NAMED_BACKGROUNDS = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}


def json_background(meta: dict, where: Path) -> tuple[float, float, float] | None:
    """The ``background`` a dataset's JSON declares (``[r, g, b]`` in [0, 1], or "white" / "black"), else None."""
    value = meta.get("background")
    if value is None:
        return None
    if isinstance(value, str) and value.lower() in NAMED_BACKGROUNDS:
        return NAMED_BACKGROUNDS[value.lower()]
    try:
        rgb = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        rgb = ()
    if len(rgb) != 3 or not all(math.isfinite(x) and 0.0 <= x <= 1.0 for x in rgb):
        raise DatasetError(f"{where}: 'background' must be [r, g, b] in [0, 1], \"white\" or \"black\", "
                           f"got {value!r}")
    return rgb


# --- D-NeRF ----------------------------------------------------------------------------------------------------

def _dnerf_split(root: Path, split: str) -> tuple[list[View], dict]:
    """The views of ``transforms_<split>.json`` and the JSON itself."""
    meta = _load_json(root / f"transforms_{split}.json")
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
        t = float(fr.get("time", _time_of(i, len(frames))))
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


# --- generic orbit image matrix -------------------------------------------------------------------------------

def _orbit_views(root: Path, folder: str, specs: list, meta: dict, times: list[float] | None) -> list[View]:
    views = []
    up = meta.get("up", "z")
    for v, spec in enumerate(specs):
        d = root / folder / str(v)
        if not d.is_dir():
            raise DatasetError(f"{d}: missing view folder (cameras.json lists {len(specs)} views)")
        files = _check_frames(_numeric_files(d), d)
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
            t = times[f] if times is not None else _time_of(f, n)
            views.append(View(rgb, alpha, cam, float(t), v, f, str(path)))
    per_view: dict[int, int] = {}
    for x in views:
        per_view[x.view_id] = per_view.get(x.view_id, 0) + 1
    if len(set(per_view.values())) > 1:
        raise DatasetError(f"{root / folder}: views have different frame counts {per_view}")
    return views


def read_orbit(root: Path, **_) -> Dataset:
    meta = _load_json(root / "cameras.json")
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


# --- Efficient4D stage 1 --------------------------------------------------------------------------------------
#: SyncDreamer's cameras (shared notes 4dgs-core §5.3): 16 views, elevation 30 deg, azimuth 22.5 v, distance
#: 1.5, fx = 280 at 256 px, z-up world; the input view is azimuth 0 at elevation 0.
E4D_VIEWS, E4D_ELEVATION, E4D_RADIUS, E4D_FOV = 16, 30.0, 1.5, math.degrees(2 * math.atan(128 / 280))


def read_efficient4d(root: Path, views: int = E4D_VIEWS, **_) -> Dataset:
    files = _check_frames(_numeric_files(root), root)
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
            out.append(View(tile, a if a is not None else mask_from_white(tile), cam, _time_of(f, n), v, f,
                            f"{path}[view {v}]"))
    ref = root / "ref"
    if ref.is_dir():
        rfiles = _check_frames(_numeric_files(ref), ref)
        if len(rfiles) != n:
            raise DatasetError(f"{ref}: {len(rfiles)} reference frames but {n} strips")
        for f, path in enumerate(rfiles):
            rgb, alpha = read_image(path)
            h, w = rgb.shape[:2]
            cam = orbit(0.0, 0.0, E4D_RADIUS, E4D_FOV, w, h, up="z")
            if alpha is not None:  # RGBA reference frames: composite on white like the generated strips
                a = alpha[..., None].astype(np.float32) / 255
                rgb = (rgb * a + 255 * (1 - a) + 0.5).astype(np.uint8)
            out.append(View(rgb, alpha if alpha is not None else mask_from_white(rgb), cam, _time_of(f, n),
                            views, f, str(path)))
    return Dataset(out, [], "efficient4d", root, background=(1.0, 1.0, 1.0),
                   background_reason="Efficient4D's views are generated on white", up="z",
                   meta={"views": views, "frames": n, "reference": ref.is_dir()})


# --- SV4D ----------------------------------------------------------------------------------------------------
#: Azimuths (degrees, relative to the input view) of SV4D's 9 output views and SV4D 2.0's 4- and 8-view models
#: (shared notes formats.md C.2-C.3); view 0 is the input video.
SV4D_AZIMUTHS = {
    "sv4d": [0.0, 34.29, 85.71, 120.0, 154.29, 205.71, 240.0, 274.29, 325.71],
    "sv4d2": [0.0, 60.0, 120.0, 180.0, 240.0],
    "sv4d2_8views": [0.0, 30.0, 75.0, 120.0, 165.0, 210.0, 255.0, 300.0, 330.0],
}
SV4D_FOV, SV4D_RADIUS = 33.8, 2.0


def read_video(path: Path) -> list[np.ndarray]:
    """All frames of a video as RGB uint8 arrays (PyAV)."""
    import av

    try:
        with av.open(str(path)) as container:
            return [fr.to_ndarray(format="rgb24") for fr in container.decode(video=0)]
    except (av.error.FFmpegError, OSError) as exc:
        raise DatasetError(f"{path}: unreadable video ({str(exc).strip()})") from None


def read_sv4d(root: Path, variant: str | None = None, elevation: float | None = None, **_) -> Dataset:
    vids = sorted(root.glob("*_v0[0-9][0-9].mp4"))
    if not vids:
        raise DatasetError(f"{root}: no SV4D view videos (*_v001.mp4 ...)")
    prefix = vids[-1].name.rsplit("_v", 1)[0]  # newest run when several share the folder
    vids = sorted(root.glob(f"{prefix}_v0[0-9][0-9].mp4"))
    inp = root / f"{prefix}_process_input.mp4"
    if not inp.exists():
        raise DatasetError(f"{inp}: missing (the input view of SV4D output {prefix})")
    if variant is None:
        variant = "sv4d" if (root / f"{prefix}_t000.mp4").exists() else \
            {4: "sv4d2", 8: "sv4d2_8views"}.get(len(vids), "sv4d")
    azimuths = SV4D_AZIMUTHS.get(variant)
    if azimuths is None:
        raise DatasetError(f"unknown SV4D variant {variant!r} (expected one of {', '.join(SV4D_AZIMUTHS)})")
    if len(vids) != len(azimuths) - 1:
        raise DatasetError(f"{root}: {len(vids)} view videos, but {variant} has {len(azimuths) - 1}")
    elev = (10.0 if variant == "sv4d" else 0.0) if elevation is None else elevation
    out = []
    n = None
    for v, path in enumerate([inp] + vids):
        frames = read_video(path)
        if n is None:
            n = len(frames)
        if len(frames) != n or not frames:
            raise DatasetError(f"{path}: {len(frames)} frames, expected {n} like the input video")
        for f, rgb in enumerate(frames):
            h, w = rgb.shape[:2]
            cam = orbit(elev, azimuths[v], SV4D_RADIUS, SV4D_FOV, w, h, up="y")
            out.append(View(rgb, mask_from_white(rgb), cam, _time_of(f, n), v, f, f"{path}[{f}]"))
    return Dataset(out, [], "sv4d", root, background=(1.0, 1.0, 1.0),
                   background_reason="SV4D's views are generated on white", up="y",
                   meta={"variant": variant, "elevation": elev, "prefix": prefix})


# --- entry point ----------------------------------------------------------------------------------------------

READERS: dict[str, Callable[..., Dataset]] = {
    "dnerf": read_dnerf, "orbit": read_orbit, "efficient4d": read_efficient4d, "sv4d": read_sv4d}


def detect_layout(root: Path) -> str:
    """Which layout a folder holds (raises DatasetError naming what was looked for)."""
    if (root / "transforms_train.json").exists():
        return "dnerf"
    if (root / "cameras.json").exists() and (root / "views").is_dir():
        return "orbit"
    if any(root.glob("*_v0[0-9][0-9].mp4")):
        return "sv4d"
    if _numeric_files(root):
        return "efficient4d"
    raise DatasetError(f"{root}: not a dataset (looked for transforms_train.json, cameras.json + views/, "
                       f"numbered Efficient4D strips, SV4D *_v001.mp4 videos)")


def load_dataset(root: str | Path, layout: str = "auto", downscale: int = 1,
                 background: tuple[float, float, float] | None = None, **options) -> Dataset:
    """Read a dataset folder. `downscale` K trains on images K times smaller; `background` overrides the layout's
    background colour (RGB in [0, 1]); other options go to the layout reader."""
    root = Path(root)
    if not root.exists():
        raise DatasetError(f"{root}: no such folder")
    if not root.is_dir():
        raise DatasetError(f"{root}: expected a dataset folder, got a file")
    if layout == "auto":
        layout = detect_layout(root)
    if layout not in READERS:
        raise DatasetError(f"unknown layout {layout!r} (expected one of {', '.join(LAYOUTS)})")
    if int(downscale) < 1:
        raise DatasetError(f"--downscale must be a positive integer, got {downscale}")
    ds = READERS[layout](root, **options)
    if not ds.train:
        raise DatasetError(f"{root}: no training images")
    sizes = {v.size for v in ds.train}
    if len(sizes) > 1:
        raise DatasetError(f"{root}: training images have different sizes: {sorted(sizes)[:4]}")
    if downscale > 1:
        ds.train = [downscale_view(v, downscale) for v in ds.train]
        ds.test = [downscale_view(v, downscale) for v in ds.test]
    if background is not None:
        rgb = tuple(float(x) for x in background)
        if len(rgb) != 3 or not all(math.isfinite(x) and 0.0 <= x <= 1.0 for x in rgb):
            raise DatasetError(f"--background must be three numbers in [0, 1], got {' '.join(map(str, background))}")
        ds.background, ds.background_reason = rgb, "--background"
    return ds
