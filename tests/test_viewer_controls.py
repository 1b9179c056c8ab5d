"""The desktop app's camera rig and timeline (pure math, no window)."""

from __future__ import annotations

import numpy as np
import pytest

from splatreel.cameras import look_at, orbit
from splatreel.viewer.controls import CameraController, Playback
from splatreel.viewer.trajectory import Framing


def test_orbit_pan_zoom_fly_and_snap():
    c = CameraController(target=np.array([0.0, 0.0, 0.5]), distance=3.0, azimuth=30, elevation=20)
    cam = c.camera(64, 48)
    np.testing.assert_allclose(cam.c2w, look_at(c.eye, c.target, "z", 40.0, 64, 48).c2w)
    c.orbit(100, -50)
    assert np.linalg.norm(c.eye - c.target) == pytest.approx(3.0)  # orbiting keeps the distance ...
    assert c.azimuth == pytest.approx(0.0) and c.elevation == pytest.approx(5.0)  # ... and turns by the drag
    c.orbit(0, 1e4)
    assert c.elevation == 89.0  # never over the pole
    before = c.eye - c.target
    c.pan(10, 0, 48)
    np.testing.assert_allclose(c.eye - c.target, before)  # panning moves eye and target together
    c.zoom(2)
    assert c.distance == pytest.approx(3.0 * 0.81)
    eye, target = c.eye, c.target.copy()
    _, _, forward = c.basis()
    c.fly(1, 0, 0, dt=0.5, speed=2.0)
    np.testing.assert_allclose(c.eye - eye, forward, atol=1e-9)
    np.testing.assert_allclose(c.target - target, forward, atol=1e-9)
    look_dir = c.target - c.eye
    c.look(20, 0)  # fly mode: turn in place
    np.testing.assert_allclose(c.eye, eye + forward, atol=1e-9)
    assert not np.allclose(c.target - c.eye, look_dir)
    # snapping shows a camera exactly, roll included; the next drag continues from its viewpoint
    snapped = orbit(10, 200, 2.0, fov_deg=55, width=64, height=48)
    c.snap(snapped)
    np.testing.assert_allclose(c.camera(64, 48).c2w, snapped.c2w)
    assert c.camera(64, 48).fy == pytest.approx(snapped.fy)
    c.orbit(0, 0)
    assert c.exact_c2w is None
    np.testing.assert_allclose(c.eye, snapped.position, atol=1e-9)
    np.testing.assert_allclose(c.camera(64, 48).forward, snapped.forward, atol=1e-9)
    c.reset(Framing(np.array([1.0, 2.0, 3.0]), 0.5))
    np.testing.assert_allclose(c.target, [1.0, 2.0, 3.0])
    assert c.distance == pytest.approx(1.1 * 0.5 / np.sin(np.radians(20.0)))


def test_playback_loops_stops_and_pauses():
    p = Playback(time_range=(0.0, 2.0), time=1.5, loop_seconds=2.0)
    assert p.advance(0.75) == pytest.approx(0.25)  # 0.75 s of 2 s per pass over a range of 2 -> +0.75, wraps
    p.speed = 2.0
    assert p.advance(0.25) == pytest.approx(0.75)
    p.loop = False
    p.advance(10.0)
    assert p.time == 2.0 and not p.playing  # stops at the end
    assert p.advance(1.0) == 2.0
    p.set_range((0.0, 1.0))
    assert p.time == 1.0


def test_playback_steps_frame_by_frame_through_frame_times_or_playback_frames():
    p = Playback(time_range=(0.0, 1.0), time=0.3, frame_times=(0.0, 0.25, 0.5, 0.75, 1.0))
    assert p.step(1) == 0.5 and not p.playing  # from between frames: the next one, and playback pauses
    assert p.step(1) == 0.75
    assert p.step(-2) == 0.25
    p.time = 0.3
    assert p.step(-1) == 0.25  # from between frames: the one before
    p.time = 0.25 + 1e-9
    assert p.step(1) == 0.5  # within rounding of a frame counts as on it
    p.time = 1.0
    assert p.step(1) == 0.0  # looping wraps round ...
    p.loop, p.time = False, 1.0
    assert p.step(1) == 1.0 and p.step(-5) == 0.0  # ... otherwise the ends hold
    q = Playback(time_range=(0.0, 2.0), time=1.0, loop_seconds=2.0)  # no frame times: 60 frames over the range
    assert q.step(1) == pytest.approx(1.0 + 2.0 / 60)
    assert q.step(-3) == pytest.approx(1.0 - 2 * 2.0 / 60)


def test_resolution_drops_while_moving_to_fit_the_budget_and_is_sharp_at_rest():
    from splatreel.viewer.controls import RESOLUTION_STEPS, Resolution, scaled_size

    r = Resolution(budget_ms=40.0)
    assert r.choose(True, 1280, 720) == 1.0  # nothing measured yet
    r.observe(160.0, 1.0)  # a full frame took 160 ms: by pixels, half the width and height fits 40 ms
    assert r.choose(False, 1280, 720) == 1.0  # at rest: full resolution
    assert r.choose(True, 1280, 720) == 0.5
    r.observe(60.0, 0.5)  # but half took 60 ms (per-splat costs do not shrink with the pixels)
    assert r.choose(True, 1280, 720) == 0.375
    r.observe(50.0, 0.375)  # and 0.375 50 ms: the budget is out of reach; 0.25 is predicted at 22 ms ...
    assert r.choose(True, 1280, 720) == 0.25
    r.observe(45.0, 0.25)  # ... but takes 45: take the sharpest step within 25% of the fastest, not the smallest
    assert r.choose(True, 1280, 720) == 0.375
    assert r.choose(True, 1280, 720) == 0.375  # and stay there
    # a view 10x cheaper (measured at the current step): the other steps are expected to follow, so up it goes
    for _ in range(10):
        r.observe(5.0, 0.375)
    assert r.choose(True, 1280, 720) == 1.0
    # a view 4x dearer at full size: to unmeasured steps only with margin
    r = Resolution(budget_ms=40.0)
    r.observe(160.0, 1.0)
    assert r.choose(True, 1280, 720) == 0.5
    r.observe(36.0, 0.5)  # measured: fits, stays
    assert r.choose(True, 1280, 720) == 0.5
    r.observe(20.0, 0.5)  # average 29.6 ms: 0.625 is predicted at 46 ms (by pixels from 0.5), over budget
    assert r.choose(True, 1280, 720) == 0.5
    # another window size forgets the measurements and keeps the step until it has measured one
    assert r.choose(True, 800, 600) == 0.5
    # the user's scale caps it, and with adaptivity off only the user's scale is used
    r = Resolution(scale=0.5)
    r.observe(1000.0, 0.5)
    assert r.choose(False, 1280, 720) == 0.5 and r.choose(True, 1280, 720) == RESOLUTION_STEPS[0]
    r.adaptive = False
    assert r.choose(True, 1280, 720) == 0.5
    # measurements expire
    r = Resolution(memory=5)
    r.observe(500.0, 1.0)
    for _ in range(5):
        r.observe(1.0, 0.25)
    assert r.predicted_ms(1.0) == (pytest.approx(16.0), False)  # from the fresh 0.25 step, not the old 500 ms
    assert scaled_size(1280, 720, 0.375) == (480, 270) and scaled_size(3, 3, 0.25) == (1, 1)


def test_playing_counts_as_a_changing_view_unless_playback_is_kept_sharp():
    from splatreel.viewer.controls import Resolution

    r = Resolution()
    assert r.changing(moving=True, playing=False) and r.changing(moving=False, playing=True)
    assert not r.changing(moving=False, playing=False)
    r.sharp_playback = True
    assert r.changing(moving=True, playing=True) and not r.changing(moving=False, playing=True)
