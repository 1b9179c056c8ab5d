"""What every dataset layout reads into: `DatasetImage`s (an image, its mask, a camera, a time) gathered in a
`Dataset`, and the image, JSON and background helpers the layout readers share.

Images are kept as uint8 (RGB ``[H, W, 3]``, alpha ``[H, W]`` or None); the trainer converts them per batch.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from splatreel.cameras import Camera
from splatreel.errors import DatasetError

#: Pixels whose mean brightness is above this (of 255) count as white background in RGB-only generated data
#: (SV4D's preprocessing uses 250 the same way).
WHITE_THRESHOLD = 250


@dataclass(frozen=True)
class DatasetImage:
    """One training or test image of a dataset: its pixels, its camera and its time (what the trainer fits)."""

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

    train: list[DatasetImage]
    test: list[DatasetImage]
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


def numeric_files(folder: Path, suffixes=(".png", ".jpg", ".jpeg", ".exr")) -> dict[int, Path]:
    """``{index: path}`` for files named by an integer (any zero padding)."""
    out = {}
    for p in folder.iterdir():
        if p.suffix.lower() in suffixes and re.fullmatch(r"\d+", p.stem):
            out[int(p.stem)] = p
    return out


def check_frames(files: dict[int, Path], where: Path) -> list[Path]:
    if not files:
        raise DatasetError(f"{where}: no numbered images (expected 0.png, 1.png, ...)")
    idx = sorted(files)
    missing = sorted(set(range(idx[0], idx[-1] + 1)) - set(idx))
    if missing:
        raise DatasetError(f"{where}: missing frame(s) {', '.join(map(str, missing[:5]))}"
                           + (" ..." if len(missing) > 5 else ""))
    return [files[i] for i in idx]


def load_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise DatasetError(f"missing {path}") from None
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: expected a JSON object")
    return data


def time_of(i: int, n: int) -> float:
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
