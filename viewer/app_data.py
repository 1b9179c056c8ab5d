"""The desktop app's plain data (no GL, no window, no imgui): its start-up options (`AppOptions`), the panel's live
numbers (`LiveStats`), what the panels edit (the camera path being made, the crop box, deleted and selected
Gaussians, the inspected pixel, the measuring tape) and the JSON form of a camera in the app's report. `AppState`
acts on them, `panels` draws them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from splatreel.model import CropBox

from .camera_path import CameraPath
from .pick import PixelHit, PixelStack
from .render_settings import FrameStats, RenderSettings
from .selection import Edits


@dataclass
class AppOptions:
    """Start-up settings of the desktop app (the ``splatreel view`` options)."""

    size: tuple[int, int] = (1280, 720)
    up: str = "z"
    fov: float = 40.0
    #: render mode, splat scale, SH degree, blending and background at start-up ...
    settings: RenderSettings = field(default_factory=RenderSettings)
    #: ... except that the background is the checkpoint's unless this is False
    checkpoint_background: bool = True
    play: bool = True
    time: float | None = None
    loop_seconds: float = 2.0
    cameras: str | None = None
    split: str | None = "train"
    camera_path: str | None = None
    #: start playing `camera_path` at once (a presentation, a scripted capture)
    play_path: bool = False
    screenshot_dir: str = "."
    vsync: bool = True
    #: share of the window's pixels drawn per axis at rest (`Resolution.scale`) ...
    render_scale: float = 1.0
    #: ... and whether to draw fewer while the camera moves or the animation plays, to keep frames within
    #: `frame_budget_ms` ...
    adaptive_resolution: bool = True
    frame_budget_ms: float = 40.0
    #: ... and True keeps the full resolution while the animation plays under a still camera
    #: (`Resolution.sharp_playback`, ``--sharp-playback``)
    sharp_playback: bool = False
    #: automation (tests, scripted captures): stop after this many frames ...
    exit_after: int | None = None
    #: ... and save a screenshot of the last frame here, and a JSON report here
    screenshot: str | None = None
    report: str | None = None
    force: bool = False
    #: start with the crop box on, at these 6 numbers (min corner, max corner), as ``--crop``
    crop: tuple[float, ...] | None = None
    #: start with this window pixel (x, y from the top left) inspected, as a Ctrl+click there
    inspect: tuple[int, int] | None = None
    #: start with the Gaussians in this window rectangle (x0, y0, x1, y1 from the top left) selected, as a Shift+drag
    select: tuple[float, float, float, float] | None = None


@dataclass
class LiveStats:
    """The live numbers of the panel: the last frame's `FrameStats`, its wall time, the last sort, sort count."""

    frame: FrameStats = field(default_factory=FrameStats)
    frame_ms: float = 0.0
    scale: float = 1.0
    moving: bool = False
    playing: bool = False
    sort_ms: float = 0.0
    sorts: int = 0


def camera_to_json(camera) -> dict:
    """A camera as plain JSON (c2w rows, intrinsics, size)."""
    return {"c2w": np.asarray(camera.c2w).tolist(), "fx": camera.fx, "fy": camera.fy, "cx": camera.cx,
            "cy": camera.cy, "width": camera.width, "height": camera.height}


def camera_from_json(data: dict):
    """The camera `camera_to_json` wrote (e.g. a report's, to render its view headless)."""
    from splatreel.cameras import Camera

    return Camera(np.array(data["c2w"]), data["fx"], data["fy"], data["cx"], data["cy"], data["width"],
                  data["height"])


@dataclass
class PathEditor:
    """The Path tab: the camera path being made (keys added from the window's view), its playback, and its file."""

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
    #: draw the box (the edited one, whether or not it crops): off until cropping is first turned on
    show: bool = False
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



def wrap_text(text: str, width: float, measure) -> list[str]:
    """`text` broken into lines no wider than `width` by `measure(str) -> float`: at spaces, and inside a word
    too long for a line (a file path in an error) after a '/', or anywhere when it has none. Dear ImGui's own
    wrapping breaks at spaces only, so a long path ran past the panel."""
    lines: list[str] = []
    for paragraph in text.split("\n"):
        line = ""
        for word in paragraph.split(" "):
            candidate = f"{line} {word}" if line else word
            if measure(candidate) <= width:
                line = candidate
                continue
            if line:
                lines.append(line)
            line = word
            while measure(line) > width and len(line) > 1:  # split the word itself
                cut = len(line) - 1
                while cut > 1 and measure(line[:cut]) > width:
                    cut -= 1
                slash = line.rfind("/", 1, cut)
                cut = slash + 1 if slash > 0 else cut
                lines.append(line[:cut])
                line = line[cut:]
        lines.append(line)
    return lines
