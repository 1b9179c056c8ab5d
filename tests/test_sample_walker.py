"""The ``walker`` sample: an articulated figure (rigid parts that stay joined), thin limbs, a walk cycle and a turn."""

from __future__ import annotations

import math

import numpy as np
import pytest

from splatreel.cameras import focal_from_fov
from splatreel.samples import OBJECTS, SAMPLES, DatasetConfig
from splatreel.samples.walker import Walker

TIMES = (0.0, 0.13, 0.25, 0.5, 0.77, 1.0)
CHAINS = (("left upper arm", "left forearm"), ("right upper arm", "right forearm"),
          ("left thigh", "left shin"), ("right thigh", "right shin"))


@pytest.fixture(scope="module")
def walker() -> Walker:
    return OBJECTS["walker"]


def _pairwise(v: np.ndarray) -> np.ndarray:
    idx = np.arange(0, len(v), max(1, len(v) // 60))
    return np.linalg.norm(v[idx, None] - v[None, idx], axis=-1)


def test_walker_is_listed(walker):
    assert isinstance(walker, Walker) and "walker" in SAMPLES and "walk" in SAMPLES["walker"]


def test_parts_are_rigid_and_the_figure_is_not(walker):
    rest = walker.mesh(0.0).vertices
    for t in TIMES:
        v = walker.mesh(t).vertices
        for name, rows in walker.part_slices.items():
            np.testing.assert_allclose(_pairwise(v[rows]), _pairwise(rest[rows]), atol=1e-9, err_msg=name)
    # the figure as a whole bends at its joints
    assert np.abs(_pairwise(walker.mesh(0.25).vertices) - _pairwise(rest)).max() > 0.2
    assert sum(s.stop - s.start for s in walker.part_slices.values()) == len(rest)


def test_limbs_stay_joined(walker):
    """A limb's lower end and the next limb's upper end sit on the same joint, each reaching past it by the 0.6 of
    its radius that the rig gives them: the figure never comes apart."""
    radius = {p.name: p.radii[0] for p in walker.parts}
    for t in TIMES:
        v = walker.mesh(t).vertices
        for upper, lower in CHAINS:
            gap = np.linalg.norm(v[walker.part_slices[upper]][0] - v[walker.part_slices[lower]][-1])
            assert gap <= 0.6 * (radius[upper] + radius[lower]) + 1e-9, (t, upper, lower)


def test_limbs_swing_and_the_figure_turns(walker):
    def axis(t, name):
        v = walker.mesh(t).vertices[walker.part_slices[name]]
        d = v[0] - v[-1]
        return d / np.linalg.norm(d)

    def angle(a, b):
        return math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))

    # the legs swing through about twice the hip amplitude over a cycle, against each other
    assert angle(axis(0.25, "left thigh"), axis(0.75, "left thigh")) > 1.5 * walker.leg_swing_deg
    assert angle(axis(0.25, "left thigh"), axis(0.25, "right thigh")) > 1.5 * walker.leg_swing_deg
    # the pelvis (no limb motion of its own) turns by turn_deg about +z
    p0, p1 = (walker.mesh(t).vertices[walker.part_slices["pelvis"]] for t in (0.0, 1.0))
    (u0, _, _), (u1, _, _) = (np.linalg.svd(p - p.mean(0), full_matrices=False)[2] for p in (p0, p1))
    turned = angle(u0, u1)  # an axis has no sign: compare as lines
    assert abs(min(turned, 180.0 - turned) - min(walker.turn_deg % 180.0, 180.0 - walker.turn_deg % 180.0)) < 1.0
    assert abs(u0[2]) < 1e-6 and abs(u1[2]) < 1e-6  # about +z


def test_forearms_are_thin_in_the_default_camera(walker):
    """The thin-parts regime: a forearm, measured on the mesh (twice its vertices' largest distance from the
    axis through its poles), is 3 to 8 px wide in the default dataset camera at the origin's distance."""
    cfg = DatasetConfig()
    fx = focal_from_fov(math.radians(cfg.fov), cfg.size)
    for t in TIMES:
        v = walker.mesh(t).vertices[walker.part_slices["right forearm"]]
        axis = (v[0] - v[-1]) / np.linalg.norm(v[0] - v[-1])
        off = v - v[-1]
        radius = np.linalg.norm(off - np.outer(off @ axis, axis), axis=1).max()
        assert 3.0 < 2.0 * radius * fx / cfg.radius <= 8.0
