"""What the desktop app's panels edit: plain dataclasses (the camera path being made, the crop box, deleted and
selected Gaussians, the inspected pixel, the measuring tape) that `AppState` acts on and `panels` draws. No GL, no
window, no imgui here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from splatreel.model import CropBox

from .camera_path import CameraPath
from .pick import PixelHit, PixelStack
from .selection import Edits


@dataclass
class PathEditor:
    path: CameraPath | None = None
    file: str = "camera_path.json"
    key_interval: float = 1.0
    playing: bool = False
    time: float = 0.0
    overwrite: bool = False
    show: bool = True
    #: what Save writes: a splatreel path (keyframes) or a nerfstudio one (frames at 30 FPS, for ns-render)
    nerfstudio: bool = False


#: Save's formats in the Path tab, in `PathEditor.nerfstudio` order
PATH_FORMATS = ("splatreel keys", "nerfstudio frames")


@dataclass
class CropEditor:
    """The crop box being edited, and what the renderer shows (`shown`: the box it was cropped to, or None)."""

    enabled: bool = False
    lo: list = field(default_factory=lambda: [-1.0, -1.0, -1.0])
    hi: list = field(default_factory=lambda: [1.0, 1.0, 1.0])
    show: bool = True
    shown: CropBox | None = None
    #: how long the last crop took to apply: above LIVE_CROP_MS, a drag applies when it is released
    apply_ms: float = 0.0
    #: a min/max field is being dragged
    dragging: bool = False

    def edited(self) -> CropBox:
        """The box as edited; a max below the min on some axis counts as the min (an empty slab), so that
        dragging one corner past the other never fails."""
        return CropBox(tuple(self.lo), tuple(max(a, b) for a, b in zip(self.lo, self.hi)))

    def box(self) -> CropBox | None:
        """The box to show: `edited`, or None while cropping is off."""
        return self.edited() if self.enabled else None


@dataclass
class DeletionEditor:
    """The Edit tab besides the crop box: deleted and selected Gaussians, the selection rectangle being dragged, and
    where "Save edited" writes."""

    edits: Edits = field(default_factory=lambda: Edits.of(0))
    #: indices of the loaded model's Gaussians that the renderer shows, ascending (crop box and deletions applied)
    shown_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    #: (crop box, its ``[N]`` bool mask over the loaded model): a deletion does not recompute the crop
    crop_cache: tuple | None = None
    #: the loaded model's `SplatArrays` once converted (each edit uploads a `SplatArrays.select` of them)
    full_arrays: object = None
    #: the rectangle being dragged (x0, y0, x1, y1 in window coordinates, as the mouse gives them), and whether it
    #: unselects (Shift+Alt)
    drag: list | None = None
    drag_removes: bool = False
    #: ((shown set, `Edits.revision`), the selected Gaussians shown (indices into it), (time, their centres then)):
    #: the indices are remade when the selection or the shown set changes, the centres when the time does too
    markers: tuple | None = None
    #: where Save edited writes: `edited_name` of the model's file unless the user typed another (kept for the next
    #: model)
    file: str = "edited.safetensors"
    overwrite: bool = False
    #: deletions made since the model was opened or last saved ...
    unsaved: bool = False
    #: ... and the actions ("open the file", "close the window") the user was already told would drop them
    warned: set = field(default_factory=set)


@dataclass
class Inspector:
    """The Inspect panel: the pixel last Ctrl+clicked, the Gaussians that make it, which of them is shown."""

    stack: PixelStack | None = None
    #: the Gaussian shown: 0 = the largest share of the pixel's colour, 1 the next, ...
    rank: int = 0
    #: (index, time, splat scale) -> (`describe` rows, ellipsoid segments), remade when one of them changes
    cache: tuple | None = None
    #: the camera the pixel was picked with
    camera: object = None
    #: open the panel's Inspect section on the next frame (a new pick)
    reveal: bool = False
    #: the stack's Gaussians, the largest share first
    ranked: list[PixelHit] = field(init=False)

    def __post_init__(self) -> None:
        self.ranked = sorted(self.stack.hits, key=lambda h: -h.weight) if self.stack is not None else []

    @property
    def hit(self) -> PixelHit | None:
        ranked = self.ranked
        return ranked[min(self.rank, len(ranked) - 1)] if ranked else None


@dataclass
class MeasureTape:
    """The measuring tape: up to two world points (the surfaces under two Alt+clicks) and the pixels they came from."""

    points: list = field(default_factory=list)
    pixels: list = field(default_factory=list)

    @property
    def distance(self) -> float | None:
        return float(np.linalg.norm(self.points[1] - self.points[0])) if len(self.points) == 2 else None


#: crops that apply faster than this follow the drag live; slower ones (large models) apply on release
LIVE_CROP_MS = 50.0


def edited_name(source: str) -> str:
    """Where "Save edited" writes by default: ``<model file's stem>_edited.safetensors`` in the current folder
    (like screenshots; the model's own folder may be read-only, e.g. the bundled sample's)."""
    stem = Path(source).stem if Path(source).suffix else ""
    return f"{stem}_edited.safetensors" if stem else "edited.safetensors"

