"""Writers for rendered frames: videos (PyAV), PNG sequences (OpenCV), EXR with alpha (OpenImageIO).

Frames arrive as the renderer's display images: ``[H, W, 4]`` float32 RGBA, top row first, colour premultiplied
by alpha (alpha is 1 everywhere over an opaque background). What each format stores:

* ``.mp4``: H.264 (libx264), yuv420p 8-bit, opaque (no alpha channel; even width and height).
  360° panoramas (.mp4 and .mov) carry the spherical-video tag (`splatreel.viewer.spherical`).
* ``.mov``: Apple ProRes (prores_ks), 10-bit: 422 HQ over an opaque background, 4444 with an alpha channel over a
  transparent one: the intermediate that editors and compositors (Resolve, Premiere, After Effects, Nuke) read.
* ``.webm``: VP9 (libvpx), yuv420p, or yuva420p with alpha over a transparent background, which browsers play
  as a transparent video (even width and height).
* ``.png`` (a single image, or a folder of ``frame_00000.png``...): 8-bit RGB, or RGBA with *straight* alpha
  (colour divided by alpha, the PNG convention) when the background is transparent.
* ``.exr`` (single image or folder): half-float RGBA in *scene-linear* light (the sRGB-encoded display colour
  decoded, `splatreel.colorspace`), *premultiplied* alpha (the OpenEXR convention), no clamping: what
  compositors (Nuke, Blender, OpenImageIO tools) assume an EXR holds. Every other output holds sRGB-encoded values.

Video alpha is straight, as ffmpeg and the players expect. Every video is converted to YUV with the BT.709 matrix
and tagged BT.709 (primaries, transfer, matrix, limited range), so players show the rendered sRGB colours as they
are instead of guessing the matrix of an untagged file.

Every output is written atomically (`splatreel.fileio`) and an existing one is refused without ``force``.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Iterator

import numpy as np

from splatreel.errors import SplatreelError
from splatreel.fileio import atomic_dir, atomic_path, check_writable

from .spherical import TAGGABLE_SUFFIXES, SphericalTagError, tag_equirectangular

IMAGE_SUFFIXES = (".png", ".exr")


class OutputError(SplatreelError):
    """An output file name, format or size that cannot be written."""


@dataclass(frozen=True)
class VideoFormat:
    """How one video suffix is encoded (PyAV container and codec names)."""

    name: str                     # what users call it, for messages
    container: str
    codec: str
    pix_fmt: str                  # over an opaque background
    alpha_pix_fmt: str | None     # over a transparent one; None: the codec has no alpha
    options: tuple[tuple[str, str], ...] = ()
    opaque_options: tuple[tuple[str, str], ...] = ()
    alpha_options: tuple[tuple[str, str], ...] = ()
    max_crf: int | None = None    # the codec's constant-quality scale 0..max_crf; None: no such setting
    even_size: bool = True        # 4:2:0 chroma needs an even width and height
    deep: bool = False            # more than 8 bits per channel: feed it 16-bit RGB


VIDEO_FORMATS: dict[str, VideoFormat] = {
    ".mp4": VideoFormat("H.264", "mp4", "libx264", "yuv420p", None, (("preset", "medium"),), max_crf=51),
    # profile 3 = 422 HQ, 4 = 4444; the encoder's own bit-rate control (no crf)
    ".mov": VideoFormat("ProRes", "mov", "prores_ks", "yuv422p10le", "yuva444p10le", (("vendor", "apl0"),),
                        (("profile", "3"),), (("profile", "4"), ("alpha_bits", "16")), even_size=False, deep=True),
    # b=0: constant quality; cpu-used 4 with row threads: a fraction of the default's encode time
    ".webm": VideoFormat("VP9", "webm", "libvpx-vp9", "yuv420p", "yuva420p",
                         (("b", "0"), ("deadline", "good"), ("cpu-used", "4"), ("row-mt", "1")), max_crf=63),
}
VIDEO_SUFFIXES = tuple(VIDEO_FORMATS)
DEFAULT_CRF = 18


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
    """Write a display image as a half-float RGBA OpenEXR: linear light, premultiplied alpha."""
    import OpenImageIO as oiio

    from splatreel.colorspace import premultiplied_to_linear

    h, w = rgba.shape[:2]
    spec = oiio.ImageSpec(w, h, 4, "half")
    spec.channelnames = ("R", "G", "B", "A")
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        raise OutputError(f"{path}: could not open for EXR output ({oiio.geterror()})")
    ok = out.write_image(np.ascontiguousarray(premultiplied_to_linear(rgba), np.float32))
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


def video_format(out: str | os.PathLike, width: int, height: int, transparent: bool = False,
                 crf: int | None = None) -> VideoFormat:
    """The `VideoFormat` for video file `out`, after checking that it can hold these frames (one-line
    `OutputError` otherwise): before anything is rendered."""
    fmt = VIDEO_FORMATS.get(Path(out).suffix.lower())
    if fmt is None:
        raise OutputError(f"{out}: not a video name (use {', '.join(VIDEO_SUFFIXES)})")
    if transparent and fmt.alpha_pix_fmt is None:
        raise OutputError(f"{out}: {fmt.name} video has no alpha channel; for a transparent background write "
                          ".mov (ProRes 4444), .webm (VP9) or PNG/EXR frames")
    if fmt.even_size and (width % 2 or height % 2):
        raise OutputError(f"{fmt.name} video needs an even width and height, got {width}x{height}")
    if crf is not None:
        if fmt.max_crf is None:
            raise OutputError(f"{out}: {fmt.name} has no --crf quality scale (it uses the 422 HQ / 4444 profiles)")
        if not 0 <= crf <= fmt.max_crf:
            raise OutputError(f"--crf for {fmt.name} goes from 0 (best) to {fmt.max_crf}, got {crf}")
    return fmt


class VideoWriter:
    """One video file (`VIDEO_FORMATS`, by suffix; `video_format` checks the arguments)."""

    def __init__(self, path: str | os.PathLike, width: int, height: int, fps: float, crf: int | None = None,
                 transparent: bool = False) -> None:
        import av

        self.format = fmt = video_format(path, width, height, transparent, crf)
        self.alpha = transparent
        self.container = av.open(str(path), mode="w", format=fmt.container)
        self.stream = self.container.add_stream(fmt.codec, rate=Fraction(fps).limit_denominator(1001))
        self.stream.width, self.stream.height = width, height
        self.stream.pix_fmt = fmt.alpha_pix_fmt if transparent else fmt.pix_fmt
        options = dict(fmt.options + (fmt.alpha_options if transparent else fmt.opaque_options))
        if fmt.max_crf is not None:
            options["crf"] = str(DEFAULT_CRF if crf is None else int(crf))
        self.stream.options = options
        codec = self.stream.codec_context  # BT.709, limited range: what the frames are converted with (write)
        codec.colorspace = codec.color_primaries = codec.color_trc = 1  # AVCOL_*_BT709
        codec.color_range = 1  # AVCOL_RANGE_MPEG

    def write(self, rgba: np.ndarray) -> None:
        import av

        pixels = unpremultiply(rgba) if self.alpha else rgba[..., :3]
        if self.format.deep:
            data = (np.clip(pixels, 0.0, 1.0) * 65535.0 + 0.5).astype(np.uint16)
            layout = "rgba64le" if self.alpha else "rgb48le"
        else:
            data, layout = to_uint8(pixels), "rgba" if self.alpha else "rgb24"
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(data), format=layout)
        frame = frame.reformat(format=self.stream.pix_fmt, dst_colorspace="ITU709")
        # the frame's tags too: ProRes writes them into every frame header, which decoders read over the file's
        frame.colorspace = frame.color_primaries = frame.color_trc = frame.color_range = 1
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
        raise OutputError(f"{out}: unknown output format {suffix!r} (use {', '.join(VIDEO_SUFFIXES)}, .png, .exr, "
                          "or a folder name)")
    return "sequence"


@contextlib.contextmanager
def open_output(out: str | os.PathLike, width: int, height: int, fps: float, transparent: bool = False,
                image_format: str = "png", force: bool = False, crf: int | None = None,
                frames: int | None = None, spherical: bool = False) -> Iterator:
    """Yield a writer with ``write(rgba)`` for `out`; the output appears (atomically) only if the block succeeds.

    Args:
        out: ``.mp4`` / ``.mov`` / ``.webm`` video, ``.png`` / ``.exr`` single image, or a folder name for a frame
            sequence.
        transparent: frames have a transparent background (PNG, EXR, .mov and .webm keep alpha; .mp4 refuses).
        crf: constant-quality setting of .mp4 / .webm (default `DEFAULT_CRF`); .mov refuses it.
        image_format: "png" or "exr", for sequences.
        frames: how many frames will come, if known: a single image refuses more than one before any is drawn.
        spherical: the frames are equirectangular 360° panoramas: an .mp4 / .mov gets the spherical-video tag
            (`splatreel.viewer.spherical`) so that players show it as a panorama.
    """
    kind = output_kind(out)
    path = Path(out)
    if crf is not None and kind != "video":
        raise OutputError(f"{out}: --crf sets the quality of .mp4 and .webm videos, not of images")
    if kind == "image" and frames is not None and frames > 1:
        raise OutputError(f"{out}: a single image takes one frame, not {frames}; use a folder for a sequence")
    if kind == "video":
        video_format(out, width, height, transparent, crf)
        if spherical and path.suffix.lower() not in TAGGABLE_SUFFIXES:
            warnings.warn(f"{out}: a {path.suffix.lower()} panorama carries no 360° tag (write .mp4 or .mov for "
                          "players to show it as 360°)", stacklevel=3)
        with atomic_path(path, force) as tmp:
            writer = VideoWriter(tmp, width, height, fps, crf, transparent)
            try:
                yield writer
            finally:
                writer.close()
            if spherical and path.suffix.lower() in TAGGABLE_SUFFIXES:
                try:
                    tag_equirectangular(tmp)
                except SphericalTagError as exc:  # the render itself is good: keep it, untagged
                    warnings.warn(f"{out}: written without the 360° video tag ({exc})", stacklevel=3)
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
