"""The ``texture`` sample: a thick banner covered in fine, high-contrast texture that ripples, bows, twists and
turns over time: a benchmark of how much fine detail a trainer keeps on a deforming body.

Texture lives in per-vertex colours (the renderer interpolates them linearly across each triangle), so the banner's
two faces are dense vertex grids, one vertex every `Texture.spacing` world units: about 0.73 px of the default
dataset camera (fx = 280 px at 256 px, 2.5 from the origin: ``2.5 / 280 = 0.0089`` world units per pixel at the
origin). The finest feature is 0.018 world units (2 px, about 3 vertex spacings), so every texel that matters
spans several vertices. Each face's layout is a stack of bands (`FRONT`, `BACK`), top to bottom:

* ``text``: lines of capitals and digits rasterised once with ``cv2.putText`` (Hershey fonts), ink heights
  from 12 down to 5 px, strokes of 2 down to 1.4 px (the smallest line probes below the 2 px scale);
* ``bars``: vertical bars of several widths (2, 3, 4 and 6 px), one row of bars per width, or horizontal bars
  (``across=False``), one column per width;
* ``checker``: a checkerboard of 3 px squares.

A face's texture is the colour at each vertex of its grid (`face_textures`): the bands are drawn
`OVERSAMPLE` times finer than the grid and box-filtered down, so a bar edge between two vertices gives the edge
vertices an intermediate colour and the rendered edge lands where it should, not on the nearest vertex.

Geometry: the cross-section is a stadium (two flat faces joined by half-round edges of radius
`half_thickness`), swept along a vertical centre line ``(0, bow, half_length * s)`` for s in [-1, 1]; flat caps
close both ends, so the mesh is closed with fixed topology. Before the turn (`yaw_deg`) the front face looks
towards -y and reads left to right from there, the back face towards +y. The default turn keeps the front
facing azimuths 10 to 60 degrees, around the light's 35 (`render.LIGHT_DIR`): a vertical face catches little of
a light from above, so the cream front takes the light and the dark back gets the ambient term. Over t in
[0, 1] the banner

* twists about its centre line, the top end turning against the bottom one (`twist_deg`, eased),
* turns as a whole about +z (`yaw_deg`, eased),
* bows out along its rest normal, most at mid-animation (`bow`),
* ripples like a flag: a wave travels up along its own normal, one period over the animation (`ripple`, `waves`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar, Union

import cv2
import numpy as np

from .geometry import Mesh, axis_angle_matrix, grid_faces
from .objects import SampleConfigError, SampleObject, _clamp_time

#: Drawing resolution of a face texture per vertex spacing and axis, before the box filter down to the grid.
OVERSAMPLE = 4
#: ``cv2.putText`` scale of the reference rasterisation that a text line is cropped from and scaled down.
_TEXT_REFERENCE_SCALE = 4.0
#: Colour of the rounded edges and end caps (albedo).
RIM_COLOR = (0.22, 0.22, 0.25)

Color = tuple[float, float, float]


@dataclass(frozen=True)
class TextBand:
    """Lines of text, each centred in an equal share of the band's height.

    Attributes:
        height: band height, world units.
        lines: one string per line (capitals and digits read best at small sizes).
        ink_height: height of a line's ink (cap height; glyph tails included), world units.
        weight: stroke width as a fraction of `ink_height`.
        font: a ``cv2.FONT_HERSHEY_*`` font.
    """

    height: float
    lines: tuple[str, ...]
    ink_height: float
    weight: float
    ink: Color
    paper: Color
    font: int = cv2.FONT_HERSHEY_SIMPLEX


@dataclass(frozen=True)
class BarsBand:
    """Bars of several widths: with `across`, vertical bars (the colour changes across the face), one row of bars
    per width; otherwise horizontal bars (the colour changes along the face), one column per width.

    Attributes:
        height: band height, world units.
        widths: bar widths (a bar and its gap are equally wide), world units.
    """

    height: float
    widths: tuple[float, ...]
    across: bool
    ink: Color
    paper: Color


@dataclass(frozen=True)
class CheckerBand:
    """A checkerboard of `square`-sized squares (world units) filling the band."""

    height: float
    square: float
    ink: Color
    paper: Color


Band = Union[TextBand, BarsBand, CheckerBand]

#: Widths of the bars: 2, 3, 4 and 6 px at the default dataset camera (0.0089 world units per pixel).
BAR_WIDTHS = (0.018, 0.027, 0.036, 0.054)
#: Paper between neighbouring rows (columns) of bars, as a fraction of a row's height (column's width) per side.
BAR_GAP = 0.08
_CREAM, _NAVY, _WHITE, _BLACK = (0.97, 0.95, 0.88), (0.05, 0.07, 0.22), (0.97, 0.97, 0.97), (0.03, 0.03, 0.03)

#: The front face (towards -y at rest), top to bottom; free height is spread evenly between and around bands.
FRONT: tuple[Band, ...] = (
    TextBand(0.13, ("SPLATREEL",), 0.105, 0.17, (0.75, 0.06, 0.06), _CREAM, cv2.FONT_HERSHEY_DUPLEX),
    BarsBand(0.22, BAR_WIDTHS, True, _BLACK, _WHITE),
    TextBand(0.27, ("FINE DETAIL", "0123456789", "QUICK BROWN"), 0.064, 0.25, _NAVY, _CREAM),
    CheckerBand(0.108, 0.027, (0.80, 0.10, 0.08), _WHITE),
    BarsBand(0.15, BAR_WIDTHS, False, (0.08, 0.18, 0.65), (0.98, 0.84, 0.16)),
    TextBand(0.06, ("GAUSSIAN 4D",), 0.045, 0.27, _BLACK, _CREAM),
)
#: The back face (towards +y at rest), top to bottom: other colours, other words, the bands in another order.
BACK: tuple[Band, ...] = (
    TextBand(0.06, ("TEXTURE TEST",), 0.045, 0.27, _WHITE, _NAVY),
    CheckerBand(0.108, 0.027, (0.05, 0.45, 0.20), _WHITE),
    TextBand(0.27, ("ABCDEFGHIJ", "KLMNOPQRST", "UVWXYZ 789"), 0.064, 0.25, (0.98, 0.86, 0.20), _NAVY),
    BarsBand(0.22, BAR_WIDTHS, True, (0.95, 0.45, 0.05), _BLACK),
    BarsBand(0.15, BAR_WIDTHS, False, _WHITE, (0.55, 0.05, 0.45)),
    TextBand(0.13, ("MOTION",), 0.105, 0.17, _WHITE, (0.10, 0.35, 0.70), cv2.FONT_HERSHEY_DUPLEX),
)


# --- face textures -----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FaceGrid:
    """A face's vertex grid: ``rows x cols`` vertices, row 0 at the top (z = `half_length`), column 0 on the
    left seen from outside (a = -`half_width`), spaced `dz` along and `da` across."""

    half_length: float
    half_width: float
    rows: int
    cols: int

    @property
    def dz(self) -> float:
        return 2.0 * self.half_length / (self.rows - 1)

    @property
    def da(self) -> float:
        return 2.0 * self.half_width / (self.cols - 1)

    def fine_coords(self) -> tuple[np.ndarray, np.ndarray]:
        """World coordinates of the fine drawing raster: (z ``(rows * OVERSAMPLE,)`` top first,
        a ``(cols * OVERSAMPLE,)``); each vertex owns the ``OVERSAMPLE x OVERSAMPLE`` block of fine texels
        centred on it."""
        offsets = (np.arange(OVERSAMPLE) + 0.5) / OVERSAMPLE - 0.5
        z = self.half_length - (np.arange(self.rows)[:, None] + offsets).ravel() * self.dz
        a = -self.half_width + (np.arange(self.cols)[:, None] + offsets).ravel() * self.da
        return z, a


def band_layout(bands: tuple[Band, ...], half_length: float) -> list[tuple[float, float]]:
    """(top z, bottom z) of each band when `bands` are stacked from the top of a face of height
    ``2 * half_length``, with the free height spread evenly between and around them."""
    free = 2.0 * half_length - sum(b.height for b in bands)
    if free < 0.0:
        raise SampleConfigError(f"the texture bands need a face {sum(b.height for b in bands):.3f} long; "
                                f"half_length {half_length} gives {2.0 * half_length:.3f}")
    gap = free / (len(bands) + 1)
    out, top = [], half_length - gap
    for b in bands:
        out.append((top, top - b.height))
        top -= b.height + gap
    return out


def text_ink(text: str, font: int, weight: float, height_px: float, max_width_px: float) -> np.ndarray:
    """``(h, w)`` ink coverage in [0, 1] of `text`: rasterised large with ``cv2.putText`` (stroke `weight` x the
    ink height), cropped to its ink and scaled down with area averaging so its ink is `height_px` high (or
    `max_width_px` wide, whichever is smaller). Scaling the whole raster keeps the stroke-to-height ratio."""
    (w, h), base = cv2.getTextSize(text, font, _TEXT_REFERENCE_SCALE, 1)
    # The ink of capitals is about the font height h plus one stroke: this stroke is `weight` of that.
    thickness = max(1, round(weight / (1.0 - weight) * h))
    pad = 2 * thickness
    canvas = np.zeros((h + base + 2 * pad, w + 2 * pad), np.uint8)
    cv2.putText(canvas, text, (pad, pad + h), font, _TEXT_REFERENCE_SCALE, 255, thickness, cv2.LINE_AA)
    rows, cols = np.nonzero(canvas)
    ink = canvas[rows.min(): rows.max() + 1, cols.min(): cols.max() + 1]
    scale = min(height_px / ink.shape[0], max_width_px / ink.shape[1])
    size = (max(1, round(ink.shape[1] * scale)), max(1, round(ink.shape[0] * scale)))
    return cv2.resize(ink, size, interpolation=cv2.INTER_AREA).astype(np.float64) / 255.0


def band_ink(band: Band, z: np.ndarray, a: np.ndarray, top: float, margin: float) -> np.ndarray:
    """``(len(z), len(a))`` ink coverage of `band` on the fine raster rows `z` (its own rows, top first) and
    columns `a` (world units; the band's top edge at `top`). Text keeps `margin` clear of the face's sides."""
    if isinstance(band, CheckerBand):
        return ((np.floor(z / band.square)[:, None] + np.floor(a / band.square)[None, :]) % 2).astype(np.float64)
    if isinstance(band, BarsBand):
        k = len(band.widths)
        # Position in parts (rows or columns) of the band; a strip of paper separates neighbouring parts.
        pos = (top - z) / band.height * k if band.across else (a - a[0]) / (a[-1] - a[0]) * k
        part = np.clip(np.floor(pos).astype(int), 0, k - 1)
        inside = np.abs(pos - part - 0.5) < 0.5 - BAR_GAP
        w = np.asarray(band.widths)[part]
        if band.across:  # one row of vertical bars per width
            return ((np.floor(a[None, :] / w[:, None]) % 2) * inside[:, None]).astype(np.float64)
        return ((np.floor(z[:, None] / w[None, :]) % 2) * inside[None, :]).astype(np.float64)
    out = np.zeros((len(z), len(a)))
    step = float(z[0] - z[1])  # fine texel size (texels are about square: dz ~ da)
    line_px = band.height / len(band.lines) / step
    width_px = (a[-1] - a[0] - 2.0 * margin) / step
    for i, line in enumerate(band.lines):
        ink = text_ink(line, band.font, band.weight, min(band.ink_height / step, line_px), width_px)
        r0 = max(0, round((i + 0.5) * line_px - 0.5 * ink.shape[0]))
        c0 = round(0.5 * (len(a) - ink.shape[1]))
        ink = ink[: len(z) - r0]  # a rounding row past the band's last row
        block = out[r0: r0 + ink.shape[0], c0: c0 + ink.shape[1]]
        np.maximum(block, ink, out=block)
    return out


def draw_face(grid: FaceGrid, bands: tuple[Band, ...], margin: float) -> np.ndarray:
    """``(rows * OVERSAMPLE, cols * OVERSAMPLE, 3)`` albedo of a face drawn on the fine raster of `grid`
    (`FaceGrid.fine_coords`): `bands` stacked from the top (`band_layout`), the first band's paper between
    them, text kept `margin` from the sides. The ideal texture that the vertex colours approximate."""
    z, a = grid.fine_coords()
    fine = np.empty((len(z), len(a), 3))
    fine[:] = bands[0].paper
    for band, (top, bottom) in zip(bands, band_layout(bands, grid.half_length)):
        rows = (z <= top) & (z > bottom)
        ink = band_ink(band, z[rows], a, top, margin)[..., None]
        fine[rows] = np.asarray(band.paper) + (np.asarray(band.ink) - np.asarray(band.paper)) * ink
    return fine


def face_texture(grid: FaceGrid, bands: tuple[Band, ...], margin: float) -> np.ndarray:
    """``(rows, cols, 3)`` albedo at each vertex of `grid`: the face drawn by `draw_face`, box-filtered down to
    one colour per vertex (the mean over the block of fine texels centred on it)."""
    blocks = draw_face(grid, bands, margin).reshape(grid.rows, OVERSAMPLE, grid.cols, OVERSAMPLE, 3)
    return np.clip(blocks.mean(axis=(1, 3)), 0.0, 1.0)


# --- the object --------------------------------------------------------------------------------------------------

def _ease(t: float) -> float:
    """0 -> 1 over t in [0, 1], with zero speed at both ends."""
    return 0.5 - 0.5 * math.cos(math.pi * t)


@dataclass(frozen=True)
class Texture(SampleObject):
    """A thick banner covered in fine stripes, a checker band and text, twisting, turning, bowing and rippling."""

    name: ClassVar[str] = "texture"
    description: ClassVar[str] = ("thick banner with fine bars (2-6 px), a checker band and text on both faces: "
                                  "ripples like a flag, bows, twists about its long axis and turns")

    half_length: float = 0.56      # along z at rest
    half_width: float = 0.36
    half_thickness: float = 0.03   # also the radius of the half-round side edges
    spacing: float = 0.0065        # target vertex spacing on the faces (0.73 px at the default dataset camera)
    edge_segments: int = 6         # segments of each half-round side edge
    margin: float = 0.03           # clear paper between text and the face's sides
    twist_deg: tuple[float, float] = (40.0, -60.0)  # top end turned against the bottom end, at t = 0 and t = 1
    yaw_deg: tuple[float, float] = (100.0, 150.0)   # whole banner turned about +z, at t = 0 and t = 1
    bow: float = 0.10              # bulge of the middle along the rest normal at t = 0.5 (none at t = 0 and 1)
    ripple: float = 0.04           # amplitude of the travelling flag wave along the banner's normal
    waves: float = 1.0             # wave periods along the banner's length

    def __post_init__(self) -> None:
        if not (0.0 < self.half_thickness < self.half_width and 0.0 < self.spacing <= 0.1
                and self.edge_segments >= 2 and self.half_length > 0.0):
            raise SampleConfigError(f"invalid banner dimensions: {self.params()}")

    @cached_property
    def grid(self) -> FaceGrid:
        """The vertex grid shared by both faces."""
        return FaceGrid(self.half_length, self.half_width, round(2.0 * self.half_length / self.spacing) + 1,
                        round(2.0 * self.half_width / self.spacing) + 1)

    @cached_property
    def face_textures(self) -> tuple[np.ndarray, np.ndarray]:
        """(front, back) ``(rows, cols, 3)`` albedo at each face vertex (see `FaceGrid`): both read left to right,
        top row first, seen from outside."""
        return face_texture(self.grid, FRONT, self.margin), face_texture(self.grid, BACK, self.margin)

    @cached_property
    def _section(self) -> tuple[np.ndarray, np.ndarray]:
        """The cross-section loop, counter-clockwise seen from +z: (x across ``(C,)``, y through ``(C,)``):
        the front face (y = -h) left to right, the right edge, the back face, the left edge."""
        w, h, e = self.half_width, self.half_thickness, self.edge_segments
        a = np.linspace(-w, w, self.grid.cols)
        arc = np.pi * (np.arange(1, e) / e - 0.5)  # open half circle, from -90 to +90 degrees
        x = np.concatenate([a, w + h * np.cos(arc), a[::-1], -w - h * np.cos(arc)])
        y = np.concatenate([np.full_like(a, -h), h * np.sin(arc), np.full_like(a, h), -h * np.sin(arc)])
        return x, y

    @cached_property
    def face_vertices(self) -> tuple[np.ndarray, np.ndarray]:
        """(front, back) ``(rows, cols)`` int indices of each face's vertices in the mesh, laid out like
        `face_textures` (top row first, left to right seen from outside)."""
        rows, cols = self.grid.rows, self.grid.cols
        count = len(self._section[0])
        ring = (rows - 1 - np.arange(rows))[:, None] * count  # ring 0 is the bottom row
        back_start = cols + self.edge_segments - 1  # after the front and the right edge's inner points
        return ring + np.arange(cols), ring + back_start + np.arange(cols)

    @cached_property
    def _topology(self) -> tuple[np.ndarray, np.ndarray]:
        """(faces ``(F, 3)``, colours ``(V, 3)``): rings bottom to top, one loop per ring, then the bottom and the
        top cap centres."""
        rows, count = self.grid.rows, len(self._section[0])
        # The loop runs counter-clockwise seen from +z and rings go up, so grid_faces' normal cross(up, loop)
        # points inwards: reverse the winding.
        body = grid_faces(rows, count, wrap_cols=True)[:, ::-1]
        j = np.arange(count)
        bottom, top = rows * count, rows * count + 1
        caps = [np.stack([np.full(count, bottom), (j + 1) % count, j], -1),
                np.stack([np.full(count, top), (rows - 1) * count + j, (rows - 1) * count + (j + 1) % count], -1)]
        faces = np.concatenate([body, *caps]).astype(np.int32)
        colors = np.tile(np.asarray(RIM_COLOR), (rows * count + 2, 1))
        for ids, texture in zip(self.face_vertices, self.face_textures):
            colors[ids] = texture
        return faces, colors

    def _frames(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centre line ``(R, 3)`` at each ring and its twisted cross-section axes (across, normal) ``(R, 3)``."""
        s = np.linspace(-1.0, 1.0, self.grid.rows)
        bow = self.bow * math.sin(math.pi * t) * (1.0 - s * s)
        centre = np.stack([np.zeros_like(s), bow, self.half_length * s], -1)
        tangent = np.gradient(centre, s, axis=0)
        tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
        # Rest axes: +x made perpendicular to the centre line, and the normal completing a right-handed frame.
        side = np.array([1.0, 0.0, 0.0]) - tangent[:, :1] * tangent
        side /= np.linalg.norm(side, axis=-1, keepdims=True)
        normal = np.cross(tangent, side)
        twist0, twist1 = self.twist_deg
        phi = 0.5 * math.radians(twist0 + (twist1 - twist0) * _ease(t)) * s
        c, n = np.cos(phi)[:, None], np.sin(phi)[:, None]
        side, normal = c * side + n * normal, c * normal - n * side
        # The flag wave moves each cross-section along its own normal: faces stay parallel, thickness is kept.
        centre = centre + (self.ripple * np.sin(2.0 * np.pi * (0.5 * self.waves * (s + 1.0) - t)))[:, None] * normal
        yaw0, yaw1 = self.yaw_deg
        turn = axis_angle_matrix((0.0, 0.0, 1.0), math.radians(yaw0 + (yaw1 - yaw0) * _ease(t)))
        return centre @ turn.T, side @ turn.T, normal @ turn.T

    def mesh(self, t: float) -> Mesh:
        faces, colors = self._topology
        centre, side, normal = self._frames(_clamp_time(t))
        x, y = self._section
        rings = centre[:, None] + x[None, :, None] * side[:, None] + y[None, :, None] * normal[:, None]
        verts = np.concatenate([rings.reshape(-1, 3), centre[[0, -1]]])
        return Mesh(verts, faces, colors)
