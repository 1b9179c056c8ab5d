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

from splatreel.errors import SplatreelError
from splatreel.fileio import atomic_path

SPHERICAL_UUID = bytes.fromhex("ffcc8263f8554a938814587a02521fdd")
#: what the tag says: stitched (one image per frame), equirectangular, made by splatreel
SPHERICAL_XML = (
    '<?xml version="1.0"?>'
    '<rdf:SphericalVideo xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#" '
    'xmlns:GSpherical="http://ns.google.com/videos/1.0/spherical/">'
    "<GSpherical:Spherical>true</GSpherical:Spherical>"
    "<GSpherical:Stitched>true</GSpherical:Stitched>"
    "<GSpherical:StitchingSoftware>splatreel</GSpherical:StitchingSoftware>"
    "<GSpherical:ProjectionType>equirectangular</GSpherical:ProjectionType>"
    "</rdf:SphericalVideo>")
#: the containers of ISO-BMFF that lead from ``moov`` to the chunk offsets and the handler
_CONTAINERS = {b"moov", b"trak", b"mdia", b"minf", b"stbl"}
#: file suffixes whose container this module can tag
TAGGABLE_SUFFIXES = (".mp4", ".mov")


class SphericalTagError(SplatreelError):
    """A file whose box structure cannot be tagged (not ISO-BMFF / QuickTime, or no video track)."""


def _header(head: bytes | bytearray, at: int, pos: int, end: int) -> tuple[bytes, int, int]:
    """(type, header length, size) of the box whose header is at ``head[at:]`` and which starts at offset `pos` of a
    range ending at `end` (size 1: a 64-bit size follows; size 0: the box runs to `end`)."""
    size, kind = struct.unpack_from(">I4s", head, at)
    header = 8
    if size == 1:
        size, header = struct.unpack_from(">Q", head, at + 8)[0], 16
    elif size == 0:
        size = end - pos
    if size < header or pos + size > end:
        raise SphericalTagError(f"broken {kind!r} box at byte {pos}")
    return kind, header, size


def _boxes(data: bytes | bytearray, start: int, end: int):
    """(type, box start, payload start, box end) of the boxes in ``data[start:end]``."""
    pos = start
    while pos + 8 <= end:
        kind, header, size = _header(data, pos, pos, end)
        yield kind, pos, pos + header, pos + size
        pos += size


def _child(data: bytes | bytearray, start: int, end: int, kind: bytes) -> tuple[int, int] | None:
    """(payload start, end) of the first `kind` box in ``data[start:end]``, or None."""
    return next(((p, e) for k, _, p, e in _boxes(data, start, end) if k == kind), None)


def _find_moov(f) -> tuple[list[tuple[bytes, int, int]], int, bytearray] | None:
    """(top-level boxes as (type, start, size), where ``moov`` starts, its bytes) of an open file, read header by
    header (the media data is not loaded); None when it has no ``moov``, an error when it has several."""
    f.seek(0, os.SEEK_END)
    total = f.tell()
    top, pos = [], 0
    while pos + 8 <= total:
        f.seek(pos)
        kind, _, size = _header(f.read(16).ljust(16, b"\0"), 0, pos, total)
        top.append((kind, pos, size))
        pos += size
    moovs = [(start, size) for kind, start, size in top if kind == b"moov"]
    if len(moovs) > 1:
        raise SphericalTagError("more than one 'moov' box")
    if not moovs:
        return None
    f.seek(moovs[0][0])
    return top, moovs[0][0], bytearray(f.read(moovs[0][1]))


def _children(moov: bytes | bytearray) -> int:
    """Where the children of the ``moov`` box in `moov` start (after a 16-byte header when its size is 64-bit)."""
    return 16 if struct.unpack_from(">I", moov, 0)[0] == 1 else 8


def _video_trak(moov: bytearray) -> tuple[int, int, int]:
    """(start, payload start, end) in `moov` of the first track whose handler is 'vide'."""
    for kind, start, payload, end in _boxes(moov, _children(moov), len(moov)):
        mdia = _child(moov, payload, end, b"mdia") if kind == b"trak" else None
        hdlr = _child(moov, *mdia, b"hdlr") if mdia else None
        if hdlr and moov[hdlr[0] + 8:hdlr[0] + 12] == b"vide":  # version/flags, pre_defined, handler type
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
        found = _find_moov(f)
    if found is None:
        raise SphericalTagError(f"{path}: not an MP4/QuickTime file (no 'moov' box)")
    top, moov_start, moov = found
    moov_size = len(moov)
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
    with atomic_path(path, force=True) as tmp, open(path, "rb") as src, open(tmp, "wb") as dst:
        _copy(src, dst, moov_start)
        dst.write(moov)
        src.seek(moov_start + moov_size)
        shutil.copyfileobj(src, dst, 1 << 20)


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
    traks = [(p, e) for kind, _, p, e in _boxes(moov, _children(moov), len(moov)) if kind == b"trak"]
    for start, end in traks:
        for kind, _, p, e in _boxes(moov, start, end):
            if kind == b"uuid" and moov[p:p + 16] == SPHERICAL_UUID:
                return bytes(moov[p + 16:e]).decode("utf-8", "replace")
    return None


def spherical_projection(path: str | os.PathLike) -> str | None:
    """The projection a file's spherical tag declares ("equirectangular"), or None when it has no tag."""
    with open(path, "rb") as f:
        found = _find_moov(f)
    xml = read_spherical_xml(found[2]) if found is not None else None
    if xml is None:
        return None
    projection = re.search(r"<GSpherical:ProjectionType>([^<]*)<", xml)
    return projection.group(1) if projection else "equirectangular"  # V1: equirectangular unless said otherwise
