"""The desktop app's line overlays: camera frustums and the camera path, drawn with the splats' projection."""

from __future__ import annotations

import numpy as np

from splatreel.cameras import orbit
from splatreel.viewer.camera_path import CameraKey, CameraPath
from splatreel.viewer.overlay import Frustums, LineRenderer, frustum_segments, path_segments
from splatreel.viewer.renderer import headless_context


def test_frustum_reaches_the_image_corners_at_the_given_depth():
    cam = orbit(25, 40, 3.0, fov_deg=50, width=160, height=90)
    seg = frustum_segments(cam, 0.5)
    assert seg.shape == (9, 2, 3)
    np.testing.assert_allclose(seg[:4, 0], np.repeat(cam.position[None], 4, 0))  # edges start at the centre
    uv, z = cam.project(seg[:4, 1])
    np.testing.assert_allclose(uv, [[0, 0], [160, 0], [160, 90], [0, 90]], atol=1e-9)
    np.testing.assert_allclose(z, 0.5)
    np.testing.assert_allclose(seg[4:8, 0], seg[:4, 1])  # the rectangle joins the corners
    tick_uv, _ = cam.project(seg[8])
    assert tick_uv[1, 1] < abs(tick_uv[0, 1]) < 1e-9 and abs(tick_uv[1, 0] - 80) < 1e-9  # up: image -y, mid-top


def test_frustums_leave_out_the_viewing_camera():
    cams = [orbit(20, a, 2.0, fov_deg=40, width=64, height=48) for a in (0, 90, 180)]
    f = Frustums.of(cams, [(1, 0, 0), (0, 1, 0), (0, 0, 1)], 0.3)
    segs, colors = f.lines(cams[1].position, 1e-6)  # seen from the second camera: its own frustum is dropped
    assert segs.shape == (18, 2, 3) and colors.shape == (18, 3)
    expected = np.concatenate([frustum_segments(cams[0], 0.3), frustum_segments(cams[2], 0.3)])
    np.testing.assert_array_equal(segs, expected)
    np.testing.assert_array_equal(colors[:9], np.tile([1, 0, 0], (9, 1)))
    np.testing.assert_array_equal(colors[9:], np.tile([0, 0, 1], (9, 1)))
    assert f.lines(np.zeros(3), 1e-6)[0].shape == (27, 2, 3)
    empty = Frustums.of([], [], 0.3).lines(np.zeros(3), 1e-6)
    assert empty[0].shape == (0, 2, 3) and empty[1].shape == (0, 3)


def test_path_polyline_passes_through_the_keys():
    cams = [orbit(20, a, 2.0 + 0.1 * i, fov_deg=40, width=64, height=64) for i, a in enumerate((0, 70, 160))]
    path = CameraPath([CameraKey.from_camera(2.0 * i, c) for i, c in enumerate(cams)])
    seg = path_segments(path, samples_per_key=8)
    assert seg.shape == (16, 2, 3)
    np.testing.assert_allclose(seg[1:, 0], seg[:-1, 1])  # one connected polyline
    for i, c in enumerate(cams):  # every 8th vertex is a key
        vertex = seg[8 * i, 0] if i < 2 else seg[-1, 1]
        np.testing.assert_allclose(vertex, c.position, atol=1e-9)
    looped = path_segments(CameraPath(path.keys, loop=True), samples_per_key=8)
    assert looped.shape == (24, 2, 3) and np.allclose(looped[-1, 1], cams[0].position)  # closes the loop


def test_lines_land_where_the_camera_projects_them_and_clip_at_the_near_plane():
    ctx = headless_context()
    cam = orbit(20, 30, 2.0, fov_deg=45, width=96, height=64)
    a, b = np.array([0.0, 0.0, 0.0]), np.array([0.3, -0.2, 0.25])
    behind = cam.position - cam.forward + 0.5 * cam.c2w[:3, 0]  # from the origin to behind the camera, off-axis
    with ctx:
        tex = ctx.texture((96, 64), 4, dtype="f4")
        fbo = ctx.framebuffer([tex])
        lines = LineRenderer(ctx)
        try:
            images = []
            for seg in (np.stack([a, b])[None], np.stack([a, behind])[None]):
                fbo.use()
                fbo.clear(0.0, 0.0, 0.0, 0.0)
                ctx.viewport = (0, 0, 96, 64)
                lines.draw(cam, seg, np.array([[1.0, 0.5, 0.0]], np.float32))
                images.append(np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(64, 96, 4)[::-1])
        finally:
            lines.release()
            fbo.release()
            tex.release()
    (ua, ub), _ = cam.project(np.stack([a, b]))
    ys, xs = np.nonzero(images[0][..., 0] > 0.5)
    assert len(xs) >= 0.8 * np.abs(ub - ua).max()  # a connected 1-px line
    np.testing.assert_allclose(images[0][ys[0], xs[0], :3], [1.0, 0.5, 0.0])
    # every lit pixel centre lies within a pixel of the projected segment
    p = np.stack([xs + 0.5, ys + 0.5], -1)
    d = ub - ua
    s = np.clip(((p - ua) @ d) / (d @ d), 0, 1)
    assert np.linalg.norm(p - (ua + s[:, None] * d), axis=1).max() < 1.0
    # clipped at the near plane: the part in front of the camera is drawn from the origin's pixel outwards,
    # and nothing wraps around from behind
    ys, xs = np.nonzero(images[1][..., 0] > 0.5)
    assert len(xs) > 20
    centre = np.array([48.0, 32.0])  # where the origin projects
    assert np.min(np.hypot(xs + 0.5 - centre[0], ys + 0.5 - centre[1])) < 1.5
    direction = cam.project((a + 0.01 * (behind - a))[None])[0][0] - centre
    assert np.all((np.stack([xs + 0.5, ys + 0.5], -1) - centre) @ direction > -1.5)
