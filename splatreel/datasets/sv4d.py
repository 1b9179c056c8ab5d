"""SV4D / SV4D 2.0 output: one ``*_v00k.mp4`` per view plus ``*_process_input.mp4`` (white background).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from splatreel.cameras import orbit
from splatreel.errors import DatasetError

from .base import Dataset, DatasetImage, mask_from_white, time_of

# --- SV4D ----------------------------------------------------------------------------------------------------
#: Azimuths (degrees, relative to the input view) of SV4D's 9 output views and SV4D 2.0's 4- and 8-view models
#: (Xie et al. 2024, SV4D; Stability-AI/generative-models ``scripts/sampling/simple_video_sample_4d.py`` and
#: ``simple_video_sample_4d2.py``); view 0 is the input video.
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
            out.append(DatasetImage(rgb, mask_from_white(rgb), cam, time_of(f, n), v, f, f"{path}[{f}]"))
    return Dataset(out, [], "sv4d", root, background=(1.0, 1.0, 1.0),
                   background_reason="SV4D's views are generated on white", up="y",
                   meta={"variant": variant, "elevation": elev, "prefix": prefix})
