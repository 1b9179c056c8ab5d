"""The spherical-video tag of 360° renders: Google's Spherical Video V1 metadata, which YouTube, Facebook, VLC and
ffmpeg read to play an equirectangular video as a panorama instead of a flat 2:1 picture.

The tag is a ``uuid`` box (UUID ffcc8263-f855-4a93-8814-587a02521fdd) holding a small RDF/XML document, placed in
the video track's ``trak`` box of an ISO-BMFF / QuickTime file (.mp4, .mov). ffmpeg's muxer writes only the newer
V2 boxes and only from stream side data, which PyAV cannot set, so the box is added after encoding: the ``moov``
box is rewritten with the new box inside (its size and the track's grow), and when ``moov`` precedes the media data
(a "fast start" file), every chunk offset (``stco`` / ``co64``) is shifted by the added bytes.
Spec: https://github.com/google/spatial-media/blob/master/docs/spherical-video-rfc.md
"""

from __future__ import annotations

import os
import re
import shutil
import struct
from pathlib import Path

from splat4d.errors import Splat4DError

SPHERICAL_UUID = bytes.fromhex("ffcc8263f8554a938814587a02521fdd")
#: what the tag says: stitched (one image per frame), equirectangular, made by splat4d
SPHERICAL_XML = (
    '<?xml version="1.0"?>'
    '<rdf:SphericalVideo xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#" '
    'xmlns:GSpherical="http://ns.google.com/videos/1.0/spherical/">'
    "<GSpherical:Spherical>true</GSpherical:Spherical>"
    "<GSpherical:Stitched>true</GSpherical:Stitched>"
    "<GSpherical:StitchingSoftware>splat4d</GSpherical:StitchingSoftware>"
    "<GSpherical:ProjectionType>equirectangular</GSpherical:ProjectionType>"
    "</rdf:SphericalVideo>")
#: the containers of ISO-BMFF that lead from ``moov`` to the chunk offsets and the handler
_CONTAINERS = {b"moov", b"trak", b"mdia", b"minf", b"stbl"}
#: file suffixes whose container this module can tag
TAGGABLE_SUFFIXES = (".mp4", ".mov")


class SphericalTagError(Splat4DError):
    """A file whose box structure cannot be tagged (not ISO-BMFF / QuickTime, or no video track)."""


def _boxes(data: bytes | bytearray, start: int, end: int):
    """(type, box start, payload start, box end) of the boxes in ``data[start:end]``."""
    pos = start
    while pos + 8 <= end:
        size, kind = struct.unpack_from(">I4s", data, pos)
        header = 8
        if size == 1:
            size, header = struct.unpack_from(">Q", data, pos + 8)[0], 16
        elif size == 0:
            size = end - pos
        if size < header or pos + size > end:
            raise SphericalTagError(f"broken {kind!r} box at byte {pos}")
        yield kind, pos, pos + header, pos + size
        pos += size


def _top_level(f) -> list[tuple[bytes, int, int]]:
    """(type, start, size) of a file's top-level boxes, read header by header (the media data is not loaded)."""
    f.seek(0, os.SEEK_END)
    total = f.tell()
    out, pos = [], 0
    while pos + 8 <= total:
        f.seek(pos)
        size, kind = struct.unpack(">I4s", f.read(8))
        if size == 1:
            size = struct.unpack(">Q", f.read(8))[0]
        elif size == 0:
            size = total - pos
        if size < 8 or pos + size > total:
            raise SphericalTagError(f"broken {kind!r} box at byte {pos}")
        out.append((kind, pos, size))
        pos += size
    return out


def _children(moov: bytes | bytearray) -> int:
    """Where the children of the ``moov`` box in `moov` start (after a 16-byte header when its size is 64-bit)."""
    return 16 if struct.unpack_from(">I", moov, 0)[0] == 1 else 8


def _video_trak(moov: bytearray) -> tuple[int, int, int]:
    """(start, payload start, end) in `moov` of the first track whose handler is 'vide'."""
    for kind, start, payload, end in _boxes(moov, _children(moov), len(moov)):
        if kind != b"trak":
            continue
        for k, s, p, e in _boxes(moov, payload, end):
            if k != b"mdia":
                continue
            for k2, s2, p2, e2 in _boxes(moov, p, e):
                if k2 == b"hdlr" and moov[p2 + 8:p2 + 12] == b"vide":  # version/flags, pre_defined, handler type
                    return start, payload, end
    raise SphericalTagError("no video track to tag")


def _shift_chunk_offsets(moov: bytearray, start: int, end: int, delta: int, after: int) -> None:
    """Add `delta` to every chunk offset (stco, co64) under ``moov[start:end]`` that points at or past file offset
    `after` (the media behind ``moov``, which moves), in place."""
    for kind, s, p, e in _boxes(moov, start, end):
        if kind in _CONTAINERS:
            _shift_chunk_offsets(moov, p, e, delta, after)
        elif kind in (b"stco", b"co64"):
            count = struct.unpack_from(">I", moov, p + 4)[0]
            fmt, width = (">I", 4) if kind == b"stco" else (">Q", 8)
            for i in range(count):
                at = p + 8 + i * width
                value = struct.unpack_from(fmt, moov, at)[0]
                if value < after:
                    continue
                value += delta
                if kind == b"stco" and value >= 1 << 32:
                    raise SphericalTagError("chunk offsets overflow 32 bits; cannot tag this file")
                struct.pack_into(fmt, moov, at, value)


def _grow(moov: bytearray, box_start: int, size: int, delta: int) -> None:
    """Set the size field of the box at `box_start`, `size` bytes long, to ``size + delta`` (64-bit when it was; a
    size of 0, "to the end of the file", becomes the real one)."""
    if struct.unpack_from(">I", moov, box_start)[0] == 1:
        struct.pack_into(">Q", moov, box_start + 8, size + delta)
    elif size + delta < 1 << 32:
        struct.pack_into(">I", moov, box_start, size + delta)
    else:
        raise SphericalTagError("a box would outgrow its 32-bit size field")


def tag_equirectangular(path: str | os.PathLike) -> None:
    """Mark the video track of .mp4 / .mov file `path` as a stitched equirectangular 360° video (see module doc),
    in place. A file already tagged is left as it is."""
    path = Path(path)
    with open(path, "rb") as f:
        top = _top_level(f)
        moovs = [(start, size) for kind, start, size in top if kind == b"moov"]
        if len(moovs) != 1:
            raise SphericalTagError(f"{path}: not an MP4/QuickTime file with one 'moov' box")
        moov_start, moov_size = moovs[0]
        f.seek(moov_start)
        moov = bytearray(f.read(moov_size))
    if read_spherical_xml(moov) is not None:
        return
    xml = SPHERICAL_XML.encode()
    box = struct.pack(">I4s", 8 + 16 + len(xml), b"uuid") + SPHERICAL_UUID + xml
    trak_start, _, trak_end = _video_trak(moov)
    if any(kind == b"mdat" and start > moov_start for kind, start, _ in top):  # media after moov: it moves
        _shift_chunk_offsets(moov, _children(moov), len(moov), len(box), moov_start + moov_size)
    moov[trak_end:trak_end] = box
    _grow(moov, trak_start, trak_end - trak_start, len(box))
    _grow(moov, 0, moov_size, len(box))
    tmp = path.with_name(path.name + ".tagging")
    try:
        with open(path, "rb") as src, open(tmp, "wb") as dst:
            _copy(src, dst, moov_start)
            dst.write(moov)
            src.seek(moov_start + moov_size)
            shutil.copyfileobj(src, dst, 1 << 20)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _copy(src, dst, count: int) -> None:
    src.seek(0)
    while count > 0:
        chunk = src.read(min(count, 1 << 20))
        if not chunk:
            raise SphericalTagError("file ended early")
        dst.write(chunk)
        count -= len(chunk)


def read_spherical_xml(moov: bytes | bytearray) -> str | None:
    """The Spherical Video V1 XML of the first track of ``moov`` box bytes that has one, else None."""
    for kind, _, payload, end in _boxes(moov, _children(moov), len(moov)):
        if kind != b"trak":
            continue
        for k, _, p, e in _boxes(moov, payload, end):
            if k == b"uuid" and moov[p:p + 16] == SPHERICAL_UUID:
                return bytes(moov[p + 16:e]).decode("utf-8", "replace")
    return None


def spherical_projection(path: str | os.PathLike) -> str | None:
    """The projection a file's spherical tag declares ("equirectangular"), or None when it has no tag."""
    with open(path, "rb") as f:
        for kind, start, size in _top_level(f):
            if kind == b"moov":
                f.seek(start)
                xml = read_spherical_xml(f.read(size))
                if xml is None:
                    return None
                found = re.search(r"<GSpherical:ProjectionType>([^<]*)<", xml)
                return found.group(1) if found else "equirectangular"  # V1: equirectangular unless said otherwise
    return None
