"""The procedural animated test objects: triangle meshes with per-vertex colours over scene time t in [0, 1].

Every object keeps its topology fixed (the same faces at every t), so a point with fixed barycentric coordinates on
a face has a known trajectory, and stays inside a ball of radius 0.9 around the origin (Blender world, +z up).
Colours are albedo; lighting is applied by the renderer (`splatreel.samples.render`). Times outside [0, 1] are
clamped: an object holds its first and last state.

* ``spinner``: a rigid box with six distinctly coloured, framed faces and an off-centre disc on each (so every
  rotation is observable), spinning one turn about a tilted axis while travelling along an arc.
* ``wave``: a soft striped tube swimming like an eel: a travelling sine wave runs along its body.
* ``morph``: a beach-ball blob that squashes and stretches, grows three lobes and shifts its hue from red
  to blue.
* ``texture``: a thick banner covered in fine, high-contrast texture (bars 2 to 6 px wide, a checker band and text,
  as per-vertex colours on a dense mesh) that ripples, bows and twists (`splatreel.samples.texture`).
* ``walker``: an articulated figure walking in place while it turns, with thin swinging limbs and patterned clothes
  (`splatreel.samples.walker`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import cached_property
from typing import ClassVar

import numpy as np

from splatreel.errors import SplatreelError

from .geometry import Mesh, axis_angle_matrix, grid_faces, hsv_to_rgb, mix, smoothstep, sphere_topology

#: Every object fits inside this ball around the origin at every time (tested).
BOUNDING_RADIUS = 0.9


class UnknownSampleError(SplatreelError, ValueError):
    """A sample name that is not in `SAMPLES`."""


class SampleConfigError(SplatreelError, ValueError):
    """Invalid sample settings (counts, sizes, angles)."""


class SampleObject:
    """Base of the animated objects: ``mesh(t)`` plus a name, a one-line description and its parameters."""

    name: ClassVar[str]
    description: ClassVar[str]

    def mesh(self, t: float) -> Mesh:
        raise NotImplementedError

    def center(self, t: float) -> np.ndarray:
        """``(3,)`` a point that moves with the object: its bounding-box centre unless overridden."""
        lo, hi = self.mesh(t).bounds
        return 0.5 * (lo + hi)

    def params(self) -> dict:
        """The object's parameters, JSON-able (recorded in ``sample.json``)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


def _clamp_time(t: float) -> float:
    return min(max(float(t), 0.0), 1.0)


# --- spinner -----------------------------------------------------------------------------------------------------

#: Per box face: (outward axis, sign, u axis, v axis) with cross(e_u, e_v) = sign * e_axis.
_BOX_FACES = ((0, 1, 1, 2), (0, -1, 2, 1), (1, 1, 2, 0), (1, -1, 0, 2), (2, 1, 0, 1), (2, -1, 1, 0))
_BOX_COLORS = ((0.90, 0.20, 0.16), (0.12, 0.68, 0.80), (0.96, 0.78, 0.12),
               (0.18, 0.32, 0.88), (0.22, 0.74, 0.28), (0.80, 0.24, 0.74))


@dataclass(frozen=True)
class Spinner(SampleObject):
    """A rigid box (six coloured faces) spinning about a tilted axis while travelling along an arc."""

    name: ClassVar[str] = "spinner"
    description: ClassVar[str] = ("rigid box with six coloured, marked faces: spins one turn about a tilted axis "
                                  "while travelling along an arc")

    half_extents: tuple[float, float, float] = (0.34, 0.23, 0.16)
    subdivisions: int = 20          # grid cells per face edge (colour detail, surface sampling)
    spin_axis: tuple[float, float, float] = (0.25, -0.35, 1.0)
    spin_turns: float = 1.0         # full turns over t in [0, 1]
    tilt_deg: float = 20.0          # initial tilt about +x
    arc: tuple[float, float] = (0.28, 0.20)  # travel: x from -arc[0] to +arc[0], y bulging by arc[1]
    bob: float = 0.10               # vertical bob amplitude (one period)

    @cached_property
    def _canonical(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Box at rest, centred at the origin: (vertices, faces, colors); each face has its own vertex grid."""
        n = self.subdivisions + 1
        g = np.linspace(0.0, 1.0, n)
        u, v = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
        h = np.asarray(self.half_extents, np.float64)
        verts, faces, colors = [], [], []
        for k, (axis, sign, ua, va) in enumerate(_BOX_FACES):
            p = np.zeros((n * n, 3))
            p[:, axis] = sign * h[axis]
            p[:, ua] = (2.0 * u - 1.0) * h[ua]
            p[:, va] = (2.0 * v - 1.0) * h[va]
            # Darker frame near the edges and a light disc off-centre: asymmetric, so rotations are observable.
            edge = np.minimum.reduce([u, 1.0 - u, v, 1.0 - v])
            frame = smoothstep(0.03, 0.11, edge)
            disc = 1.0 - smoothstep(0.14, 0.20, np.hypot(u - 0.32, v - 0.68))
            c = np.asarray(_BOX_COLORS[k]) * (0.45 + 0.55 * frame)[:, None]
            c = mix(c, (0.97, 0.96, 0.90), disc)
            verts.append(p)
            colors.append(c)
            faces.append(grid_faces(n, n, offset=k * n * n))
        return np.concatenate(verts), np.concatenate(faces), np.clip(np.concatenate(colors), 0.0, 1.0)

    def center(self, t: float) -> np.ndarray:
        """``(3,)`` the box centre on its travel arc."""
        t = _clamp_time(t)
        ax, ay = self.arc
        return np.array([-ax * math.cos(math.pi * t), ay * math.sin(math.pi * t) - 0.4 * ay,
                         self.bob * math.sin(2.0 * math.pi * t)])

    def rotation(self, t: float) -> np.ndarray:
        """``(3, 3)`` orientation at time t."""
        t = _clamp_time(t)
        tilt = axis_angle_matrix((1.0, 0.0, 0.0), math.radians(self.tilt_deg))
        return axis_angle_matrix(self.spin_axis, 2.0 * math.pi * self.spin_turns * t) @ tilt

    def mesh(self, t: float) -> Mesh:
        verts, faces, colors = self._canonical
        return Mesh(verts @ self.rotation(t).T + self.center(t), faces, colors)


# --- wave --------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Wave(SampleObject):
    """A closed tube whose centre line carries a travelling sine wave (an eel swimming in place)."""

    name: ClassVar[str] = "wave"
    description: ClassVar[str] = ("soft striped tube bending like a swimming eel: a sine wave travels along its "
                                  "body (one period over the animation)")

    half_length: float = 0.74
    radius: float = 0.14
    amplitude: tuple[float, float] = (0.08, 0.20)  # sideways wave amplitude at the head, at the tail
    waves: float = 0.8              # wave periods per unit of body coordinate s in [-1, 1]
    lift: float = 0.06              # vertical undulation amplitude
    rings: int = 72
    segments: int = 28

    @cached_property
    def _topology(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(theta, phi, faces, colors): fixed material coordinates, faces and the striped albedo."""
        theta, phi, faces = sphere_topology(self.rings, self.segments)
        s = -np.cos(theta)  # body coordinate: -1 at the head, +1 at the tail (rings bunch up at the ends)
        hue = 0.14 - 0.22 * (s + 1.0) / 2.0  # yellow head, through orange and red, to a pink tail
        bands = smoothstep(0.80, 0.95, np.cos(2.0 * np.pi * 3.5 * (s + 1.0)))
        colors = hsv_to_rgb(hue, 0.75, 0.95 * (1.0 - 0.5 * bands))
        back = smoothstep(0.80, 0.97, -np.sin(phi))
        belly = smoothstep(0.20, 0.70, np.sin(phi))
        colors = mix(colors, (0.12, 0.10, 0.22), 0.8 * back)
        colors = mix(colors, (1.00, 0.93, 0.78), 0.85 * belly)
        return theta, phi, faces, np.clip(colors, 0.0, 1.0)

    def _centre_line(self, s: np.ndarray, t: float) -> np.ndarray:
        """``(K, 3)`` centre line at body coordinates `s` ``(K,)``."""
        a_head, a_tail = self.amplitude
        amp = a_head + (a_tail - a_head) * (s + 1.0) / 2.0
        phase = 2.0 * np.pi * (self.waves * s - t)
        return np.stack([self.half_length * s, amp * np.sin(phase),
                         self.lift * np.sin(0.5 * phase + 1.0)], -1)

    def mesh(self, t: float) -> Mesh:
        t = _clamp_time(t)
        theta, phi, faces, colors = self._topology
        ring_theta = np.unique(theta)  # rings + 1 values, poles included
        ring_s = -np.cos(ring_theta)
        centre = self._centre_line(ring_s, t)
        tangent = np.gradient(centre, ring_s, axis=0)
        tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
        side = np.cross([0.0, 0.0, 1.0], tangent)
        side /= np.linalg.norm(side, axis=-1, keepdims=True)
        down = np.cross(side, tangent)  # (side, down, -tangent) is right-handed: outward winding
        ring = np.searchsorted(ring_theta, theta)
        s = ring_s[ring]
        r = self.radius * (1.0 - s * s) ** 0.4 * (1.15 - 0.15 * (s + 1.0))
        offset = np.cos(phi)[:, None] * side[ring] + np.sin(phi)[:, None] * down[ring]
        return Mesh(centre[ring] + r[:, None] * offset, faces, colors)


# --- morph -------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Morph(SampleObject):
    """A beach-ball blob: squash and stretch, three growing lobes, hue shift over time."""

    name: ClassVar[str] = "morph"
    description: ClassVar[str] = ("beach-ball blob that squashes and stretches, grows three twisting lobes and "
                                  "shifts its colours from red to blue")

    radius: tuple[float, float] = (0.46, 0.54)  # base radius at t = 0 and t = 1
    lobes: int = 3
    lobe_amplitude: float = 0.28    # relative radius added at the lobe tips at t = 1
    lobe_twist: float = 0.25        # turns of the lobes over the animation, as a fraction of pi
    stretch: float = 0.25           # z scale 1 + stretch * sin(2 pi t), x/y keep the volume
    hue: tuple[float, float] = (0.0, 0.62)  # hue (turns) at t = 0 and t = 1
    rings: int = 40
    segments: int = 64

    @cached_property
    def _topology(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return sphere_topology(self.rings, self.segments)

    def center(self, t: float) -> np.ndarray:
        """The blob stays centred at the origin."""
        return np.zeros(3)

    def mesh(self, t: float) -> Mesh:
        t = _clamp_time(t)
        theta, phi, faces = self._topology
        grow = 0.5 - 0.5 * math.cos(math.pi * t)  # 0 -> 1, smooth at both ends
        r0 = self.radius[0] + (self.radius[1] - self.radius[0]) * t
        lobe = np.sin(theta) ** 2 * np.cos(self.lobes * phi + math.pi * self.lobe_twist * t)
        r = r0 * (1.0 + self.lobe_amplitude * grow * lobe)
        sz = 1.0 + self.stretch * math.sin(2.0 * math.pi * t)
        sxy = 1.0 / math.sqrt(sz)
        verts = r[:, None] * np.stack([sxy * np.sin(theta) * np.cos(phi), sxy * np.sin(theta) * np.sin(phi),
                                       sz * np.cos(theta)], -1)
        # Six alternating wedges, a dark equator band, a white cap on top, lighter lobe tips; hue drifts with t.
        hue0 = self.hue[0] + (self.hue[1] - self.hue[0]) * t
        wedge = smoothstep(-0.2, 0.2, np.cos(6.0 * phi))
        colors = hsv_to_rgb(hue0 + 0.13 * wedge, 0.80, 0.95)
        colors *= (1.0 - 0.5 * smoothstep(0.985, 0.998, np.sin(theta)))[:, None]
        colors = mix(colors, (0.97, 0.97, 0.95), smoothstep(0.80, 0.86, np.cos(theta)))
        colors = mix(colors, (1.0, 1.0, 1.0), 0.45 * grow * np.clip(lobe, 0.0, 1.0) ** 2)
        return Mesh(verts, faces, np.clip(colors, 0.0, 1.0))
