"""Writers for rendered frames: H.264 video (PyAV), PNG sequences (OpenCV), EXR with alpha (OpenImageIO).

Frames arrive as the renderer's display images: ``[H, W, 4]`` float32 RGBA, top row first, colour premultiplied
by alpha (alpha is 1 everywhere over an opaque background). What each format stores:

* ``.mp4``: H.264, yuv420p (even width and height required), 8-bit, opaque. No alpha channel.
* ``.png`` (a single image, or a folder of ``frame_00000.png``...): 8-bit RGB, or RGBA with *straight* alpha
  (colour divided by alpha, the PNG convention) when the background is transparent.
* ``.exr`` (single image or folder): half-float RGBA, *premultiplied* alpha (the OpenEXR convention), no clamping.

Every output is written atomically (`splat4d.fileio`) and an existing one is refused without ``force``.
"""

from __future__ import annotations

import contextlib
import os
from fractions import Fraction
from pathlib import Path
from typing import Iterator

import numpy as np

from splat4d.errors import Splat4DError
from splat4d.fileio import atomic_dir, atomic_path, check_writable

VIDEO_SUFFIXES = (".mp4",)
IMAGE_SUFFIXES = (".png", ".exr")


class OutputError(Splat4DError):
    """An output file name, format or size that cannot be written."""


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """Float colour in [0, 1] -> uint8 (rounded, clamped)."""
    return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def unpremultiply(rgba: np.ndarray) -> np.ndarray:
    """``[H, W, 4]`` premultiplied -> straight alpha (colour / alpha where alpha > 0, else 0)."""
    alpha = rgba[..., 3:4]
    rgb = np.where(alpha > 1e-8, rgba[..., :3] / np.maximum(alpha, 1e-8), 0.0)
    return np.concatenate([rgb, alpha], -1)


def write_png(path: str | os.PathLike, rgba: np.ndarray, alpha: bool) -> None:
    """Write a display image as an 8-bit PNG (RGBA straight alpha if `alpha`, else RGB)."""
    import cv2

    if alpha:
        img = cv2.cvtColor(to_uint8(unpremultiply(rgba)), cv2.COLOR_RGBA2BGRA)
    else:
        img = cv2.cvtColor(to_uint8(rgba[..., :3]), cv2.COLOR_RGB2BGR)
    if not cv2.imwrite(str(path), img):
        raise OutputError(f"{path}: could not write PNG")


def write_exr(path: str | os.PathLike, rgba: np.ndarray) -> None:
    """Write a display image as a half-float RGBA OpenEXR (premultiplied alpha)."""
    import OpenImageIO as oiio

    h, w = rgba.shape[:2]
    spec = oiio.ImageSpec(w, h, 4, "half")
    spec.channelnames = ("R", "G", "B", "A")
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        raise OutputError(f"{path}: could not open for EXR output ({oiio.geterror()})")
    ok = out.write_image(np.ascontiguousarray(rgba, np.float32))
    out.close()
    if not ok:
        raise OutputError(f"{path}: could not write EXR ({oiio.geterror()})")


def write_image(path: str | os.PathLike, rgba: np.ndarray, alpha: bool) -> None:
    """PNG or EXR by suffix (EXR always keeps alpha)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".png":
        write_png(path, rgba, alpha)
    elif suffix == ".exr":
        write_exr(path, rgba)
    else:
        raise OutputError(f"{path}: unknown image format (use .png or .exr)")


class VideoWriter:
    """H.264 mp4 writer (PyAV, libx264, yuv420p)."""

    def __init__(self, path: str | os.PathLike, width: int, height: int, fps: float, crf: int = 18) -> None:
        import av

        if width % 2 or height % 2:
            raise OutputError(f"H.264 video needs an even width and height, got {width}x{height}")
        self.container = av.open(str(path), mode="w", format="mp4")
        rate = Fraction(fps).limit_denominator(1001)
        self.stream = self.container.add_stream("libx264", rate=rate)
        self.stream.width, self.stream.height = width, height
        self.stream.pix_fmt = "yuv420p"
        self.stream.options = {"crf": str(int(crf)), "preset": "medium"}

    def write(self, rgba: np.ndarray) -> None:
        import av

        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(to_uint8(rgba[..., :3])), format="rgb24")
        for packet in self.stream.encode(frame):
            self.container.mux(packet)

    def close(self) -> None:
        for packet in self.stream.encode():
            self.container.mux(packet)
        self.container.close()


class SequenceWriter:
    """Numbered frames ``frame_00000.<png|exr>`` in a folder."""

    def __init__(self, folder: Path, suffix: str, alpha: bool) -> None:
        self.folder, self.suffix, self.alpha, self.count = folder, suffix, alpha, 0

    def write(self, rgba: np.ndarray) -> None:
        write_image(self.folder / f"frame_{self.count:05d}{self.suffix}", rgba, self.alpha)
        self.count += 1

    def close(self) -> None:
        pass


class SingleImageWriter:
    """Exactly one frame to one image file (`path`, possibly a temporary name for `name`)."""

    def __init__(self, path: Path, alpha: bool, name: str | os.PathLike | None = None) -> None:
        self.path, self.alpha, self.count = path, alpha, 0
        self.name = path if name is None else name

    def write(self, rgba: np.ndarray) -> None:
        if self.count:
            raise OutputError(f"{self.name}: a single image takes one frame; use a folder for a sequence")
        write_image(self.path, rgba, self.alpha)
        self.count += 1

    def close(self) -> None:
        pass


def output_kind(out: str | os.PathLike) -> str:
    """'video', 'image' or 'sequence' (a path without a suffix is a folder of frames)."""
    suffix = Path(out).suffix.lower()
    if suffix in VIDEO_SUFFIXES:
        return "video"
    if suffix in IMAGE_SUFFIXES:
        return "image"
    if suffix:
        raise OutputError(f"{out}: unknown output format {suffix!r} (use .mp4, .png, .exr, or a folder name)")
    return "sequence"


@contextlib.contextmanager
def open_output(out: str | os.PathLike, width: int, height: int, fps: float, transparent: bool = False,
                image_format: str = "png", force: bool = False, crf: int = 18, frames: int | None = None) -> Iterator:
    """Yield a writer with ``write(rgba)`` for `out`; the output appears (atomically) only if the block succeeds.

    Args:
        out: ``.mp4`` video, ``.png`` / ``.exr`` single image, or a folder name for a frame sequence.
        transparent: frames have a transparent background (PNG keeps alpha; mp4 refuses).
        image_format: "png" or "exr", for sequences.
        frames: how many frames will come, if known: a single image refuses more than one before any is drawn.
    """
    kind = output_kind(out)
    path = Path(out)
    if kind == "image" and frames is not None and frames > 1:
        raise OutputError(f"{out}: a single image takes one frame, not {frames}; use a folder for a sequence")
    if kind == "video":
        if transparent:
            raise OutputError(f"{out}: H.264 video has no alpha channel; write PNG or EXR frames for a "
                              f"transparent background")
        if width % 2 or height % 2:
            raise OutputError(f"H.264 video needs an even width and height, got {width}x{height}")
        with atomic_path(path, force) as tmp:
            writer = VideoWriter(tmp, width, height, fps, crf)
            try:
                yield writer
            finally:
                writer.close()
    elif kind == "image":
        with atomic_path(path, force) as tmp:
            writer = SingleImageWriter(tmp, transparent, out)
            yield writer
    else:
        fmt = image_format.lower().lstrip(".")
        if fmt not in ("png", "exr"):
            raise OutputError(f"unknown frame format {image_format!r}; expected png or exr")
        check_writable(path, force)
        if path.exists() and not path.is_dir():
            raise OutputError(f"{out}: exists and is not a folder")
        with atomic_dir(path, force) as tmp:
            yield SequenceWriter(tmp, f".{fmt}", transparent)
