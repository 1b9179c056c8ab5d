"""Offline rendering through EGL (no display): a model, one camera and one model time per frame, to a file.

Each frame is sorted synchronously at its own (camera, t) before it is drawn, so no frame ever shows a stale order.
The depth mode's colour map spans one range for the whole sequence (`sequence_depth_range`), so colours do not
flicker from frame to frame. With an `Equirect`, each frame is a 360° panorama assembled from six cube faces drawn
from the frame camera's position (`splatreel.viewer.panorama`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from typing import Iterator, Sequence

import numpy as np
from tqdm import tqdm

from splatreel.cameras import Camera
from splatreel.errors import CameraError

from .output import open_output
from .panorama import Equirect
from .renderer import FrameStats, RenderSettings, SplatRenderer, headless_context
from .sorting import Footprint


@dataclass
class RenderSummary:
    """What `render_to_file` did."""

    frames: int = 0
    sort_ms: list[float] = field(default_factory=list)
    draw_ms: list[float] = field(default_factory=list)

    def add(self, stats: FrameStats) -> None:
        self.frames += 1
        self.sort_ms.append(stats.sort_ms)
        self.draw_ms.append(stats.draw_ms + stats.upload_ms)


def render_frames(model, cameras: Sequence[Camera], times: Sequence[float], settings: RenderSettings | None = None,
                  renderer: SplatRenderer | None = None, summary: RenderSummary | None = None,
                  progress: bool | str = False, equirect: Equirect | None = None) -> Iterator[np.ndarray]:
    """Yield the display image (``[H, W, 4]`` float32, top row first) of each (camera, time) pair; with `equirect`,
    the 360° panorama seen from each camera's position (its orientation is the panorama's centre and up)."""
    if len(cameras) != len(times):
        raise CameraError(f"{len(cameras)} cameras but {len(times)} scene times")
    settings = settings or RenderSettings()
    r = renderer or SplatRenderer(headless_context(), model)
    if settings.mode == "depth" and settings.value_range is None and (len(cameras) > 1 or equirect is not None):
        # one range for all frames, and for all six faces of a panorama (else its faces would not match)
        views = [f for c in cameras for f in equirect.face_cameras(c)] if equirect is not None else cameras
        view_times = np.repeat(np.asarray(times, np.float64), len(views) // len(cameras))
        settings = replace(settings, value_range=sequence_depth_range(r, views, view_times, settings.footprint))
    bar = tqdm(total=len(cameras), unit="frame", desc=progress if isinstance(progress, str) else "render",
               disable=not progress, dynamic_ncols=True)
    try:
        for cam, t in zip(cameras, times):
            if equirect is None:
                stats = r.render(cam, float(t), settings)
                image = r.read_display()
            else:  # six faces, each sorted for itself; the frame's cost is theirs summed
                faces, stats = [], FrameStats()
                for face in equirect.face_cameras(cam):
                    s = r.render(face, float(t), settings)
                    faces.append(r.read_display())
                    stats.sort_ms += s.sort_ms
                    stats.draw_ms += s.draw_ms + s.upload_ms
                    stats.visible += s.visible
                image = equirect.assemble(faces)
            if summary is not None:
                summary.add(stats)
            bar.update(1)
            bar.set_postfix(visible=f"{stats.visible:,}", refresh=False)
            yield image
    finally:
        bar.close()
        if renderer is None:
            r.release()


#: `sequence_depth_range` looks at this many frames, evenly spaced.
DEPTH_RANGE_SAMPLES = 8


def sequence_depth_range(renderer: SplatRenderer, cameras: Sequence[Camera], times: Sequence[float],
                         footprint: Footprint = Footprint()) -> tuple[float, float]:
    """One (near, far) for the depth colour map of a whole sequence: the union of the per-frame ranges (the 2nd to
    98th percentile of the drawn depths, `SortResult.depth_range`) of `DEPTH_RANGE_SAMPLES` frames."""
    picks = np.unique(np.linspace(0, len(cameras) - 1, min(DEPTH_RANGE_SAMPLES, len(cameras))).round().astype(int))
    ranges = [renderer.sort(cameras[i], float(times[i]), footprint).depth_range for i in picks]
    return min(near for near, _ in ranges), max(far for _, far in ranges)


def render_to_file(model, out: str | os.PathLike, cameras: Sequence[Camera], times: Sequence[float],
                   settings: RenderSettings | None = None, fps: float = 30.0, image_format: str = "png",
                   force: bool = False, progress: bool | str = False, crf: int | None = None,
                   equirect: Equirect | None = None) -> RenderSummary:
    """Render every frame and write them to `out` (.mp4/.mov/.webm video, .png/.exr image, or a folder of frames);
    with `equirect`, 360° panoramas of its size from the cameras' positions (`render_frames`)."""
    if not cameras:
        raise CameraError("nothing to render: no frames")
    settings = settings or RenderSettings()
    sizes = {(c.width, c.height) for c in cameras}
    if len(sizes) != 1 and equirect is None:
        raise CameraError(f"all frames must have one size, got {sorted(sizes)}")
    (width, height), = {(equirect.width, equirect.height)} if equirect is not None else sizes
    summary = RenderSummary()
    with open_output(out, width, height, fps, settings.transparent, image_format, force, crf,
                     frames=len(cameras), spherical=equirect is not None) as writer:
        for rgba in render_frames(model, cameras, times, settings, summary=summary, progress=progress,
                                  equirect=equirect):
            writer.write(rgba)
    return summary
