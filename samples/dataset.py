"""Render a sample to a multi-view video dataset in the D-NeRF layout.

Layout (``OUT/``)::

    transforms_train.json   transforms_test.json   transforms_val.json (= test, for D-NeRF's own loader)
    train/r_000.png ...     test/r_000.png ...      sample.json (provenance)

Cameras (Blender world, +z up, `splatreel.cameras.orbit` with ``up='z'``: azimuth 0 on +x, increasing towards +y;
positive elevation above) all look at the origin from `radius`, with square pixels and a centred principal point.

* Training views form an image matrix: ``views`` azimuths ``360 * v / views`` at one `elevation`, times
  ``frames`` key times ``f / (frames - 1)``. Images are ordered by time, then view: ``r_{f * views + v}``.
  With ``one_camera_per_time`` the same rig films the way D-NeRF's captures do: frame f is seen by camera
  ``f mod views`` alone (``r_f``).
* Test views probe novel views AND novel times: azimuths half-way between training azimuths, elevations
  alternating ``elevation - 20`` and ``elevation + 15``, times half-way between training times. Test image 0 is at
  t = 0, because D-NeRF's loader asserts that every split starts at time 0; all others lie strictly between
  training times. Ordered by time.

JSON per split: ``camera_angle_x`` (horizontal FOV, radians), ``fl_x, fl_y, cx, cy, w, h`` (pixels), and
``frames: [{file_path: "./train/r_000" (no extension), time, transform_matrix (4x4 camera-to-world, OpenGL /
Blender camera axes = Camera.to_opengl_c2w()), w, h}]``.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from splatreel import __version__
from splatreel.cameras import Camera, fov_from_focal, orbit
from splatreel.datasets.dnerf import clean_number, transforms_for, write_transforms
from splatreel.errors import SplatreelError
from splatreel.fileio import atomic_dir, check_writable

from .objects import SampleConfigError, SampleObject
from .render import AMBIENT, DIFFUSE, FAR, LIGHT_DIR, MeshRenderer

#: Bump when the rendered bytes of a sample change (geometry, colours, lighting, cameras, antialiasing).
GENERATOR_VERSION = 1
#: Efficient4D / SyncDreamer field of view: fx = 280 px at 256 px.
DEFAULT_FOV_DEG = math.degrees(fov_from_focal(280.0, 256))
#: Test elevations relative to the training elevation.
TEST_ELEVATION_OFFSETS = (-20.0, 15.0)
PNG_COMPRESSION = 3


@dataclass(frozen=True)
class DatasetConfig:
    """How a sample is rendered to a dataset.

    Attributes:
        views: training azimuths per frame (evenly spaced, starting at 0 degrees).
        frames: training times, ``f / (frames - 1)`` (a single frame is t = 0).
        size: image width = height, pixels.
        elevation: training elevation, degrees above the horizon.
        radius: camera distance from the origin (must clear the object's 0.9 ball).
        fov: horizontal = vertical field of view, degrees.
        test_views: number of test images (0 writes empty test/val splits).
        one_camera_per_time: film frame f with camera ``f mod views`` only (D-NeRF's monocular regime) instead of
            every camera at every frame.

    Antialiasing is the renderer's (`MeshRenderer` supersample and msaa), recorded in ``sample.json``.
    """

    views: int = 16
    frames: int = 16
    size: int = 256
    elevation: float = 30.0
    radius: float = 2.5
    fov: float = DEFAULT_FOV_DEG
    test_views: int = 16
    one_camera_per_time: bool = False

    def __post_init__(self) -> None:
        def need(cond: bool, msg: str) -> None:
            if not cond:
                raise SampleConfigError(msg)

        need(1 <= self.views <= 1000, f"--views must be 1..1000, got {self.views}")
        need(1 <= self.frames <= 1000, f"--time-steps must be 1..1000, got {self.frames}")
        need(8 <= self.size <= 4096, f"--size must be 8..4096 pixels, got {self.size}")
        need(0 <= self.test_views <= 1000, f"--test-views must be 0..1000, got {self.test_views}")
        need(math.isfinite(self.elevation) and -90.0 <= self.elevation <= 90.0,
             f"--elevation must be in [-90, 90] degrees, got {self.elevation}")
        need(math.isfinite(self.radius) and self.radius > 1.0,
             f"--radius must be > 1 (the objects fill a ball of radius 0.9), got {self.radius}")
        need(math.isfinite(self.fov) and 1.0 <= self.fov <= 150.0, f"--fov must be 1..150 degrees, got {self.fov}")


@dataclass(frozen=True)
class SampleView:
    """One image a sample dataset will hold (before it is rendered): where it goes, when and from where it is seen."""

    split: str
    index: int
    time: float
    azimuth: float
    elevation: float
    camera: Camera

    @property
    def file_path(self) -> str:
        """D-NeRF style path relative to the dataset folder, without extension."""
        return f"./{self.split}/r_{self.index:03d}"


def train_times(frames: int) -> list[float]:
    """Key times ``f / (frames - 1)``; ``[0.0]`` for a single frame."""
    return [f / (frames - 1) for f in range(frames)] if frames > 1 else [0.0]


def _camera(config: DatasetConfig, elevation: float, azimuth: float) -> Camera:
    return orbit(elevation, azimuth, config.radius, fov_deg=config.fov, width=config.size, height=config.size,
                 up="z")


def train_views(config: DatasetConfig) -> list[SampleView]:
    """The training image matrix, ordered by time then azimuth; with `DatasetConfig.one_camera_per_time`, frame f by
    camera ``f mod views`` alone."""
    out = []
    for f, t in enumerate(train_times(config.frames)):
        for v in range(config.views):
            if config.one_camera_per_time and v != f % config.views:
                continue
            az = 360.0 * v / config.views
            out.append(SampleView("train", len(out), t, az, config.elevation, _camera(config, config.elevation, az)))
    return out


def test_views(config: DatasetConfig) -> list[SampleView]:
    """Novel views at novel times (see module doc), ordered by time."""
    n, steps = config.test_views, config.frames - 1
    step = 360.0 / config.views
    out = []
    for i in range(n):
        if i == 0 or steps == 0:
            t = 0.0
        else:
            t = (math.floor((i - 1) * steps / max(n - 1, 1)) + 0.5) / steps
        az = step * (math.floor(i * config.views / n) + 0.5)
        el = float(np.clip(config.elevation + TEST_ELEVATION_OFFSETS[i % 2], -89.0, 89.0))
        out.append(SampleView("test", i, t, az, el, _camera(config, el, az)))
    return out


def transforms_json(views: list[SampleView], config: DatasetConfig) -> dict:
    """The ``transforms_<split>.json`` content for `views`."""
    return transforms_for(views, _camera(config, config.elevation, 0.0))


def sample_json(obj: SampleObject, config: DatasetConfig, renderer: MeshRenderer, num_train: int,
                num_test: int) -> dict:
    """Provenance record written as ``sample.json`` (no timestamps: the dataset is byte-for-byte reproducible)."""
    return {
        "generator": "splatreel sample", "generator_version": GENERATOR_VERSION, "splatreel_version": __version__,
        "name": obj.name, "description": obj.description, "object": obj.params(),
        "render": {**asdict(config), "supersample": renderer.supersample, "msaa": renderer.msaa,
                   "light_dir": [clean_number(x) for x in LIGHT_DIR], "ambient": AMBIENT,
                   "diffuse": DIFFUSE, "background": "transparent (straight alpha)"},
        "world": "Blender: +z up; cameras: orbit(up='z'), azimuth 0 on +x towards +y, looking at the origin",
        "time_range": [0.0, 1.0],
        "frame_order": ("train: r_f, frame f by camera f mod views alone" if config.one_camera_per_time else
                        "train: r_{f*views+v}, grouped by time then view") +
                       "; test: by time (test image 0 at t=0, the others half-way between training times)",
        "splits": {"train": num_train, "test": num_test},
    }


def render_views(obj: SampleObject, views: list[SampleView], renderer: MeshRenderer,
                 far: float = FAR) -> Iterator[tuple[SampleView, np.ndarray]]:
    """Yield (view, RGBA image) in the order of `views`, evaluating the mesh once per run of equal times; `far` is
    the far clip of every image (see `MeshRenderer.draw`)."""
    current = None
    for v in views:
        if current != v.time:
            renderer.upload(obj.mesh(v.time))
            current = v.time
        yield v, renderer.draw(v.camera, far)


def write_png(path: Path, rgba: np.ndarray) -> None:
    """Write ``(H, W, 4)`` uint8 RGBA as an 8-bit RGBA PNG."""
    bgra = cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA)
    if not cv2.imwrite(str(path), bgra, [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION]):
        raise SplatreelError(f"{path}: could not write PNG")


def write_object_dataset(obj: SampleObject, out: str | os.PathLike, config: DatasetConfig | None = None,
                         force: bool = False, progress: bool = False, renderer: MeshRenderer | None = None) -> Path:
    """Render sample object `obj` on the orbit rig of `config` to a D-NeRF layout dataset folder `out` (atomically;
    see module doc and `splatreel.samples.write_dataset`)."""
    if config is not None and not isinstance(config, DatasetConfig):
        raise SampleConfigError(f"sample {obj.name!r} takes a DatasetConfig, got {type(config).__name__}")
    config = config or DatasetConfig()
    train, test = train_views(config), test_views(config)
    return write_layout(out, obj, train, test, _camera(config, config.elevation, 0.0),
                        lambda r: sample_json(obj, config, r, len(train), len(test)), force=force,
                        progress=progress, renderer=renderer)


def write_layout(out: str | os.PathLike, obj: SampleObject, train: list[SampleView], test: list[SampleView],
                 intrinsics: Camera, info: Callable[[MeshRenderer], dict], far: float = FAR, force: bool = False,
                 progress: bool = False, renderer: MeshRenderer | None = None) -> Path:
    """Render the `train` and `test` views of `obj` and write them to `out` in the D-NeRF layout, atomically.

    Args:
        intrinsics: a camera with the intrinsics and image size that every view shares (top level of the JSON).
        info: makes the ``sample.json`` content from the renderer used (its antialiasing is recorded).
        far: far clip of every image (`MeshRenderer.draw`).
    The val split repeats the test split (D-NeRF's own loader needs it).
    """
    from tqdm import tqdm

    out = check_writable(out, force)
    own = renderer is None
    if own:
        renderer = MeshRenderer()
    try:
        with atomic_dir(out, force) as tmp, tqdm(total=len(train) + len(test), desc=f"sample {obj.name}",
                                                 unit="img", disable=not progress) as bar:
            for split, views in (("train", train), ("test", test)):
                (tmp / split).mkdir()
                for view, rgba in render_views(obj, views, renderer, far):
                    write_png(tmp / f"{view.file_path}.png", rgba)
                    bar.update(1)
                write_transforms(tmp / f"transforms_{split}.json", transforms_for(views, intrinsics))
            write_transforms(tmp / "transforms_val.json", transforms_for(test, intrinsics))
            write_transforms(tmp / "sample.json", info(renderer))
    finally:
        if own:
            renderer.release()
    return Path(out)
