"""Camera conventions: conversions round-trip, look-at centres its target, orbit angles, projection."""

import math

import numpy as np
import pytest

from splatreel.cameras import (Camera, focal_from_fov, look_at, look_at_c2w, opencv_to_opengl, opengl_to_opencv,
                             orbit, orbit_position)
from splatreel.errors import CameraError


def random_pose(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = q, rng.normal(size=3)
    return c2w


def test_opengl_opencv_roundtrip():
    rng = np.random.default_rng(0)
    for _ in range(5):
        c2w = random_pose(rng)
        np.testing.assert_allclose(opencv_to_opengl(opengl_to_opencv(c2w)), c2w)
        cam = Camera.from_opengl(c2w, 64, 48, fov_x_deg=60)
        np.testing.assert_allclose(cam.to_opengl_c2w(), c2w)
        np.testing.assert_allclose(cam.w2c @ cam.c2w, np.eye(4), atol=1e-12)
        # an OpenGL camera looks down its -z: the OpenCV forward is the GL -z column
        np.testing.assert_allclose(cam.forward, -c2w[:3, 2])
        w2c = cam.w2c
        again = Camera.from_opencv_w2c(w2c[:3], cam.fx, cam.fy, cam.cx, cam.cy, 64, 48)
        np.testing.assert_allclose(again.c2w, cam.c2w, atol=1e-12)


@pytest.mark.parametrize("up", ["z", "y", (0.3, 0.2, 1.0)])
def test_look_at_projects_target_to_image_centre(up):
    cam = look_at((2.0, -3.0, 1.5), (0.1, 0.2, 0.3), up=up, fov_deg=40, width=320, height=240)
    uv, depth = cam.project(np.array([[0.1, 0.2, 0.3]]))
    np.testing.assert_allclose(uv[0], [160.0, 120.0], atol=1e-9)
    assert depth[0] == pytest.approx(math.dist((2.0, -3.0, 1.5), (0.1, 0.2, 0.3)))
    # "up" is up on screen: a point above the target projects above the centre (smaller v)
    upv = np.array({"z": (0, 0, 1), "y": (0, 1, 0)}.get(up, up), dtype=float) if isinstance(up, str) else np.array(up)
    uv2, _ = cam.project(np.array([[0.1, 0.2, 0.3]]) + 0.1 * upv / np.linalg.norm(upv))
    assert uv2[0, 1] < 120.0
    assert cam.fov_y == pytest.approx(math.radians(40))


def test_orbit_conventions():
    np.testing.assert_allclose(orbit_position(0, 0, 2, "z"), [2, 0, 0], atol=1e-12)
    np.testing.assert_allclose(orbit_position(0, 90, 2, "z"), [0, 2, 0], atol=1e-12)
    np.testing.assert_allclose(orbit_position(90, 0, 2, "z"), [0, 0, 2], atol=1e-12)
    np.testing.assert_allclose(orbit_position(0, 0, 2, "y"), [0, 0, 2], atol=1e-12)
    np.testing.assert_allclose(orbit_position(0, 90, 2, "y"), [2, 0, 0], atol=1e-12)
    np.testing.assert_allclose(orbit_position(30, 0, 2, "y")[1], 1.0, atol=1e-12)
    cam = orbit(30, 45, 2.5, fov_deg=49.1343, width=256, height=256)
    assert cam.fx == pytest.approx(280.0, abs=1e-3)
    np.testing.assert_allclose(np.linalg.norm(cam.position), 2.5)
    np.testing.assert_allclose(cam.project(np.zeros((1, 3)))[0][0], [128, 128], atol=1e-9)


def test_projection_matches_pixel_convention_and_gl_matrix():
    cam = Camera(look_at_c2w((0, 0, -5), (0, 0, 0), up="-y"), 100.0, 120.0, 40.0, 30.0, 80, 60)
    pts = np.array([[0.3, -0.2, 1.0], [-1.0, 0.5, 2.0]])
    uv, z = cam.project(pts)
    # same through the OpenGL view + projection matrices (NDC -> pixels with y flipped)
    view = np.linalg.inv(cam.to_opengl_c2w())
    clip = (cam.opengl_projection() @ view @ np.c_[pts, np.ones(2)].T).T
    ndc = clip[:, :3] / clip[:, 3:]
    px = np.stack([(ndc[:, 0] + 1) * 0.5 * 80, (1 - ndc[:, 1]) * 0.5 * 60], -1)
    np.testing.assert_allclose(px, uv, atol=1e-9)
    small = cam.resized(40, 30)
    np.testing.assert_allclose(small.project(pts)[0], uv / 2, atol=1e-9)
    np.testing.assert_allclose(cam.unproject(uv, z), pts, atol=1e-12)  # the inverse, through non-square pixels


def test_bad_cameras_are_rejected():
    with pytest.raises(CameraError, match="NaN"):
        Camera(np.full((4, 4), np.nan), 1, 1, 0, 0, 2, 2)
    with pytest.raises(CameraError, match="orthonormal"):
        Camera(np.diag([2.0, 1, 1, 1]), 1, 1, 0, 0, 2, 2)
    with pytest.raises(CameraError, match="size"):
        Camera(np.eye(4), 1, 1, 0, 0, 0, 2)
    with pytest.raises(CameraError, match="distinct"):
        look_at((1, 1, 1), (1, 1, 1))
    with pytest.raises(CameraError, match="up axis"):
        look_at((1, 1, 1), (0, 0, 0), up="w")
    assert focal_from_fov(math.radians(90), 100) == pytest.approx(50)
