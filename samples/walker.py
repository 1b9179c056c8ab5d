"""The ``walker`` sample: an articulated figure that walks in place while turning, with thin limbs and patterned
clothes: the regime of a skinned character (the issue's walking character), which none of the recipe's
settings were measured on when it was added.

The figure is a rig of 14 rigid ellipsoids (pelvis, torso, head, two upper arms, forearms, thighs, shins and
feet), each a closed sphere-topology mesh (`geometry.sphere_topology`) carried by a kinematic chain over scene time
t in [0, 1]:

* one walk cycle: the legs swing about the hips (`leg_swing_deg`) with the knees bending on the back swing
  (`knee_bend_deg`), the arms swing against the legs (`arm_swing_deg`) with the elbows bending, the head turns
  from side to side, and the body bobs twice per cycle;
* the whole figure turns about +z by `turn_deg` (eased) as if walking a curve, so every part also rotates in the
  world, as the spinner does.

Limbs overlap their joints by a fraction of their radius, so the figure reads as one body at every pose. The
forearms are the thinnest parts (radius 0.028: about 6 px wide in the default 256 px dataset camera), the shins
the next. Colours (albedo, per vertex, so they move with the surface): a shirt with horizontal stripes about 5 px
wide, trousers with a light stripe down the outer side of each leg, skin, a dark cap of hair, eyes and a mouth on
the face, shoes with a light sole.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar, NamedTuple

import numpy as np

from .geometry import Mesh, axis_angle_matrix, mix, smoothstep, sphere_topology
from .objects import SampleObject, _clamp_time

SHIRT = (0.10, 0.55, 0.60)
SHIRT_STRIPE = (0.95, 0.90, 0.78)
TROUSERS = (0.14, 0.18, 0.42)
TROUSER_STRIPE = (0.90, 0.90, 0.92)
SKIN = (0.92, 0.70, 0.55)
HAIR = (0.20, 0.12, 0.08)
SHOE = (0.30, 0.16, 0.10)
SOLE = (0.92, 0.90, 0.85)


class Part(NamedTuple):
    """One rigid ellipsoid of the rig: its name, radii (local x, y, z; z along a limb) and the ring and segment
    counts of its mesh."""

    name: str
    radii: tuple[float, float, float]
    rings: int
    segments: int


def _rot_y(angle: float) -> np.ndarray:
    return axis_angle_matrix((0.0, 1.0, 0.0), angle)


def _rot_z(angle: float) -> np.ndarray:
    return axis_angle_matrix((0.0, 0.0, 1.0), angle)


def _rot_x(angle: float) -> np.ndarray:
    return axis_angle_matrix((1.0, 0.0, 0.0), angle)


@dataclass(frozen=True)
class Walker(SampleObject):
    """An articulated figure walking in place while it turns: thin swinging limbs and patterned clothes."""

    name: ClassVar[str] = "walker"
    description: ClassVar[str] = ("articulated figure walking in place while it turns: thin limbs swing about "
                                  "hips, knees, shoulders and elbows; striped shirt, patterned trousers, a face")

    leg_swing_deg: float = 28.0    # hip swing amplitude, forward and back
    knee_bend_deg: float = 50.0    # largest knee bend (on the back swing)
    arm_swing_deg: float = 24.0    # shoulder swing amplitude, against the legs
    turn_deg: float = 100.0        # the whole figure's turn about +z over the animation (eased)
    bob: float = 0.02              # vertical bob amplitude (twice per cycle)
    thigh_length: float = 0.33
    shin_length: float = 0.31
    upper_arm_length: float = 0.24
    forearm_length: float = 0.23
    limb_radius: tuple[float, float, float, float] = (0.058, 0.042, 0.038, 0.028)  # thigh, shin, upper arm, forearm

    @cached_property
    def parts(self) -> tuple[Part, ...]:
        """The rig's parts in mesh order (left then right for paired limbs)."""
        rt, rs, ru, rf = self.limb_radius
        overlap = 0.6  # a limb reaches this share of its radius past each joint

        def limb(name, length, r, rings=40):
            return Part(name, (r, r, 0.5 * length + overlap * r), rings, 20)

        parts = [Part("pelvis", (0.10, 0.15, 0.09), 24, 32), Part("torso", (0.10, 0.17, 0.24), 72, 40),
                 Part("head", (0.105, 0.095, 0.125), 40, 40)]
        for side in ("left", "right"):
            parts += [limb(f"{side} upper arm", self.upper_arm_length, ru), limb(f"{side} forearm",
                                                                                 self.forearm_length, rf)]
        for side in ("left", "right"):
            parts += [limb(f"{side} thigh", self.thigh_length, rt, 48), limb(f"{side} shin", self.shin_length, rs, 48),
                      Part(f"{side} foot", (0.095, 0.045, 0.035), 24, 20)]
        return tuple(parts)

    @cached_property
    def part_slices(self) -> dict[str, slice]:
        """Each part's rows of the mesh's vertices. A part's first vertex is the pole at its local +z (a limb's
        lower end), its last the opposite pole."""
        out, start = {}, 0
        for part, (unit, _) in zip(self.parts, self._topology[0]):
            out[part.name] = slice(start, start + len(unit))
            start += len(unit)
        return out

    @cached_property
    def _topology(self) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray, np.ndarray]:
        """Per part (unit-sphere points ``(V_i, 3)``, radii), then all faces and all colours (albedo)."""
        units, faces, colors, offset = [], [], [], 0
        for part in self.parts:
            theta, phi, f = sphere_topology(part.rings, part.segments)
            unit = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
            units.append((unit, part.radii))
            faces.append(f + offset)
            colors.append(self._albedo(part.name, theta, phi))
            offset += len(theta)
        return units, np.concatenate(faces).astype(np.int32), np.clip(np.concatenate(colors), 0.0, 1.0)

    @staticmethod
    def _albedo(name: str, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """``(V, 3)`` albedo of a part from its sphere coordinates (theta from local +z, phi from local +x: the
        figure's front at rest)."""
        n = len(theta)
        z = np.cos(theta)  # local height in [-1, 1]
        side = -1.0 if name.startswith("left") else 1.0
        if name == "torso":
            stripes = smoothstep(-0.25, 0.25, np.cos(2.0 * np.pi * 5.0 * z))
            c = mix(np.tile(SHIRT, (n, 1)), SHIRT_STRIPE, stripes)
            return mix(c, (0.08, 0.25, 0.28), smoothstep(0.90, 0.95, z))  # dark collar
        if name == "pelvis" or name.endswith("thigh") or name.endswith("shin"):
            # a light stripe down the outer side (+y for the right leg, -y for the left): phi = +-pi/2
            outer = np.cos(phi - side * 0.5 * np.pi) * np.sin(theta)
            stripe = 0.0 if name == "pelvis" else smoothstep(0.90, 0.96, outer)
            return mix(np.tile(TROUSERS, (n, 1)), TROUSER_STRIPE, stripe)
        if name.endswith("upper arm"):
            return mix(np.tile(SHIRT, (n, 1)), SHIRT_STRIPE, smoothstep(0.55, 0.65, -z) * smoothstep(0.8, 0.7, -z))
        if name.endswith("forearm"):
            return np.tile(SKIN, (n, 1))
        if name.endswith("foot"):
            return mix(np.tile(SHOE, (n, 1)), SOLE, smoothstep(-0.35, -0.55, z))  # the lower part: a sole
        # head: skin, hair over the top and back, two eyes and a mouth on the front (phi = 0)
        x, y = np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi)
        c = np.tile(SKIN, (n, 1))
        hair = smoothstep(0.25, 0.40, z) * (1.0 - smoothstep(0.55, 0.75, x)) + smoothstep(0.55, 0.65, z)
        c = mix(c, HAIR, np.clip(hair, 0.0, 1.0))
        for eye_y in (-0.35, 0.35):
            d = np.hypot(y - eye_y, z - 0.12)
            c = mix(c, (0.05, 0.05, 0.08), (1.0 - smoothstep(0.07, 0.10, d)) * (x > 0))
        mouth = (1.0 - smoothstep(0.05, 0.08, np.abs(z + 0.38 + 0.25 * y * y))) * (np.abs(y) < 0.3) * (x > 0)
        return mix(c, (0.70, 0.12, 0.12), mouth)

    def _poses(self, t: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per part (rotation ``(3, 3)``, centre ``(3,)``) in the world at time t."""
        t = _clamp_time(t)
        p = 2.0 * math.pi * t  # walk phase: one cycle
        turn = _rot_z(math.radians(self.turn_deg) * (0.5 - 0.5 * math.cos(math.pi * t)))
        root = np.array([0.0, 0.0, self.bob * math.cos(2.0 * p)])
        poses = [(np.eye(3), np.array([0.0, 0.0, -0.05])), (np.eye(3), np.array([0.0, 0.0, 0.19])),
                 (_rot_z(0.35 * math.sin(p)) @ _rot_y(0.1 * math.sin(2.0 * p)), np.array([0.0, 0.0, 0.555]))]

        def segment(top: np.ndarray, angle: float, length: float, roll: np.ndarray = np.eye(3)):
            """A limb hanging from `top`, swung forward (towards +x) by `angle`: (rotation, centre, bottom)."""
            rot = roll @ _rot_y(-angle) @ _rot_x(math.pi)  # local +z points down the limb
            down = rot[:, 2]
            return rot, top + 0.5 * length * down, top + length * down

        for y, phase in ((-0.18, p + math.pi), (0.18, p)):  # each arm swings with the opposite leg
            swing = math.radians(self.arm_swing_deg) * math.sin(phase)
            elbow = math.radians(18.0 + 22.0 * (0.5 + 0.5 * math.sin(phase)))
            abduct = _rot_x(math.copysign(math.radians(7.0), y))  # hanging a little away from the body
            r1, c1, at_elbow = segment(np.array([0.0, y, 0.36]), swing, self.upper_arm_length, abduct)
            r2, c2, _ = segment(at_elbow, swing + elbow, self.forearm_length, abduct)
            poses += [(r1, c1), (r2, c2)]
        for y, phase in ((-0.085, p), (0.085, p + math.pi)):
            swing = math.radians(self.leg_swing_deg) * math.sin(phase)
            knee = math.radians(self.knee_bend_deg) * (0.5 + 0.5 * math.cos(phase)) ** 2  # most on the swing
            r1, c1, at_knee = segment(np.array([0.0, y, -0.10]), swing, self.thigh_length)
            r2, c2, ankle = segment(at_knee, swing - knee, self.shin_length)
            foot = _rot_y(-0.4 * (swing - knee))  # toes down as the shin swings back
            poses += [(r1, c1), (r2, c2), (foot, ankle + foot @ np.array([0.045, 0.0, -0.012]))]
        return [(turn @ r, turn @ (c + root)) for r, c in poses]

    def mesh(self, t: float) -> Mesh:
        units, faces, colors = self._topology
        verts = [unit * np.asarray(radii) @ rot.T + centre for (unit, radii), (rot, centre) in
                 zip(units, self._poses(t))]
        return Mesh(np.concatenate(verts), faces, colors)

