"""360° equirectangular output: directions land where the projection says, six faces leave no seam or hole, and
the render command writes panoramas (and their cameras, read back as a panorama path)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest
import torch

from splatreel.cameras import look_at
from splatreel.checkpoint import save_checkpoint
from splatreel.errors import CameraError
from splatreel.model import static_gaussians4d
from splatreel.viewer.camera_path import CameraPath
from splatreel.viewer.headless import render_frames
from splatreel.viewer.panorama import Equirect, face_rotations
from splatreel.viewer.renderer import RenderSettings

#: the panorama camera: at (1, 2, 0.5), looking along +y, z up
CAMERA = look_at((1.0, 2.0, 0.5), (1.0, 3.0, 0.5), "z", fov_deg=40, width=64, height=64)
#: (longitude, latitude) in degrees of the test Gaussians: the centre, each face, two face edges and a corner
DIRECTIONS = [(0, 0), (90, 0), (-90, 0), (179, 0), (0, 80), (0, -80), (45, 0), (0, 45), (-135, 35.26), (30, 20)]


def direction(lon_deg: float, lat_deg: float) -> np.ndarray:
    """World direction of a panorama (longitude, latitude) for `CAMERA` (module doc of splatreel.viewer.panorama)."""
    lon, lat = math.radians(lon_deg), math.radians(lat_deg)
    d = np.array([math.cos(lat) * math.sin(lon), -math.sin(lat), math.cos(lat) * math.cos(lon)])
    return CAMERA.c2w[:3, :3] @ d


def gaussians_at(points: np.ndarray, rgb: np.ndarray, std: float):
    n = len(points)
    return static_gaussians4d(torch.tensor(points, dtype=torch.float64), torch.full((n, 3), std, dtype=torch.float64),
                              torch.tensor([[1.0, 0, 0, 0]] * n, dtype=torch.float64),
                              torch.full((n,), 0.95, dtype=torch.float64), torch.tensor(rgb, dtype=torch.float64))


def test_faces_are_right_handed_and_cover_every_direction():
    rots = face_rotations()
    assert np.allclose(np.linalg.det(rots), 1.0)
    assert sorted(map(tuple, np.round(rots[:, :, 2]).astype(int).tolist())) == sorted(
        [(0, 0, 1), (1, 0, 0), (0, 0, -1), (-1, 0, 0), (0, -1, 0), (0, 1, 0)])
    face, x, y = Equirect(64, 32).maps()
    assert set(np.unique(face).tolist()) == set(range(6))
    s = Equirect(64, 32).face_size
    # every sample lies inside its face's drawn square, with room for the bilinear neighbour
    assert x.min() >= 0.5 and y.min() >= 0.5 and x.max() <= s + 2.5 and y.max() <= s + 2.5
    with pytest.raises(CameraError, match="twice as wide"):
        Equirect(300, 100)


def test_each_direction_lands_at_its_longitude_and_latitude():
    """Small Gaussians 3 units away in known directions (face centres, face edges, a cube corner) appear as blobs
    centred on the panorama pixel of their longitude and latitude, each in its own colour."""
    rng = np.random.default_rng(2)
    colors = rng.uniform(0.2, 1.0, (len(DIRECTIONS), 3))
    points = np.array([CAMERA.position + 3.0 * direction(*d) for d in DIRECTIONS])
    model = gaussians_at(points, colors, 0.06)
    eq = Equirect(720, 360)
    img = next(render_frames(model, [CAMERA], [0.5], RenderSettings(transparent=True), equirect=eq))
    assert img.shape == (360, 720, 4)
    w, h = eq.width, eq.height
    for (lon, lat), color in zip(DIRECTIONS, colors):
        u = (lon / 360 + 0.5) * w - 0.5
        v = (0.5 - lat / 180) * h - 0.5
        # the blob's alpha-weighted centroid in a window around the expected pixel (no wrap needed: |lon| < 180)
        x0, x1 = int(u) - 12, int(u) + 13
        y0, y1 = max(int(v) - 12, 0), min(int(v) + 13, h)
        a = img[y0:y1, max(x0, 0):min(x1, w), 3]
        ys, xs = np.mgrid[y0:y1, max(x0, 0):min(x1, w)]
        assert a.sum() > 1.0, (lon, lat)
        cu, cv = (a * xs).sum() / a.sum(), (a * ys).sum() / a.sum()
        assert abs(cu - u) < 1.0 and abs(cv - v) < 1.0, ((lon, lat), (cu, cv), (u, v))
        if abs(lat) < 60:  # near the poles the blob is stretched along the rows; its centre pixel still holds it
            peak = img[int(round(v)), int(round(u))]
            np.testing.assert_allclose(peak[:3] / peak[3], color, atol=0.03)
    assert img[..., 3].sum() < 0.2 * img[..., 3].size  # nothing else drawn


def test_a_surrounding_shell_leaves_no_seam_or_hole():
    """The camera inside an opaque shell of one colour: every panorama pixel, on face seams too, is that colour and
    opaque (a face drawn too narrow or sampled off its edge would show)."""
    n = 4000
    k = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * k / n)
    theta = math.pi * (1 + 5 ** 0.5) * k
    dirs = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)
    model = gaussians_at(CAMERA.position + 2.0 * dirs, np.tile([0.8, 0.5, 0.2], (n, 1)), 0.15)
    img = next(render_frames(model, [CAMERA], [0.5], RenderSettings(transparent=True), equirect=Equirect(256, 128)))
    assert img[..., 3].min() > 0.999
    np.testing.assert_allclose(img[..., :3], np.broadcast_to([0.8, 0.5, 0.2], img[..., :3].shape), atol=0.01)


def test_render_writes_panoramas_and_their_cameras_as_an_equirectangular_path(tmp_path):
    """``render --projection equirect``: 2:1 frames; ``--save-cameras`` writes nerfstudio's equirectangular camera
    type, and ``--path`` of that file renders the same panorama again; a size that is not 2:1 is a one-line
    error."""
    rng = np.random.default_rng(4)
    points = rng.normal(size=(300, 3)) * 0.4
    model = gaussians_at(points, rng.uniform(0, 1, (300, 3)), 0.05)
    ckpt = save_checkpoint(tmp_path / "m.safetensors", model)

    def render(*args):
        return subprocess.run([sys.executable, "-m", "splatreel", "render", str(ckpt), "--quiet", *args],
                              capture_output=True, text=True, timeout=300)

    first, cams = tmp_path / "pano.png", tmp_path / "cams.json"
    proc = render("--out", str(first), "--projection", "equirect", "--size", "256x128", "--save-cameras", str(cams))
    assert proc.returncode == 0, proc.stderr
    img = cv2.imread(str(first))
    assert img.shape == (128, 256, 3) and img.std() > 5
    data = json.loads(cams.read_text())
    assert data["camera_type"] == "equirectangular" and (data["render_width"], data["render_height"]) == (256, 128)
    path = CameraPath.load(cams)
    assert path.projection == "equirect"
    # the image is the panorama from the first camera's position (and not its flat view)
    key = path.keys[0]
    camera = path.camera(key.time, 256, 128)
    want = next(render_frames(model, [camera], [key.scene_time], RenderSettings(), equirect=Equirect(256, 128)))
    got = img[..., ::-1].astype(np.float64) / 255
    assert np.abs(got - np.clip(want[..., :3], 0, 1)).max() <= 1.5 / 255
    flat = next(render_frames(model, [camera], [key.scene_time], RenderSettings()))
    assert np.abs(got - np.clip(flat[..., :3], 0, 1)).mean() > 0.02
    again = tmp_path / "again.png"
    proc = render("--out", str(again), "--path", str(cams))  # size and projection from the file
    assert proc.returncode == 0, proc.stderr
    assert np.abs(cv2.imread(str(again)).astype(int) - img.astype(int)).max() <= 1
    bad = render("--out", str(tmp_path / "bad.png"), "--projection", "equirect", "--size", "300x100")
    assert bad.returncode == 1 and "twice as wide" in bad.stderr and "Traceback" not in bad.stderr


def test_panorama_videos_carry_the_spherical_tag(tmp_path):
    """An equirectangular .mp4 or .mov is tagged as a 360° video (Spherical Video V1) and still decodes frame for
    frame; a flat render is not tagged."""
    import av

    from splatreel.viewer.headless import render_to_file
    from splatreel.viewer.spherical import spherical_projection

    model = gaussians_at(np.array([direction(0, 0) * 2 + CAMERA.position]), [[1.0, 0.2, 0.1]], 0.4)
    for suffix in (".mp4", ".mov"):
        out = tmp_path / f"pano{suffix}"
        render_to_file(model, out, [CAMERA] * 3, [0.0] * 3, equirect=Equirect(64, 32))
        assert spherical_projection(out) == "equirectangular"
        with av.open(str(out)) as c:
            frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
        assert len(frames) == 3 and frames[0].shape == (32, 64, 3)
        assert frames[0][16, 32, 0] > 150  # the Gaussian straight ahead, at the panorama's centre
    flat = tmp_path / "flat.mp4"
    render_to_file(model, flat, [CAMERA] * 2, [0.0] * 2)
    assert spherical_projection(flat) is None


def test_tagging_a_fast_start_file_shifts_its_chunk_offsets(tmp_path):
    """With the 'moov' box before the media data, tagging moves the media: every chunk offset is shifted, so the
    frames decode exactly as before; tagging twice changes nothing."""
    import av

    from splatreel.viewer.spherical import spherical_projection, tag_equirectangular

    path = tmp_path / "fast.mp4"
    with av.open(str(path), "w", options={"movflags": "faststart"}) as c:
        stream = c.add_stream("libx264", rate=10)
        stream.width, stream.height, stream.pix_fmt = 64, 32, "yuv420p"
        stream.options = {"g": "2"}  # several chunks
        for i in range(12):
            img = np.zeros((32, 64, 3), np.uint8)
            img[:, 5 * i:5 * i + 5] = (200, 60, 20)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                c.mux(packet)
        for packet in stream.encode():
            c.mux(packet)

    def top_level(p):
        data, out, pos = p.read_bytes(), [], 0
        while pos < len(data):
            size = int.from_bytes(data[pos:pos + 4], "big")
            out.append(data[pos + 4:pos + 8])
            pos += size
        return out

    def decode(p):
        with av.open(str(p)) as c:
            return [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]

    kinds = top_level(path)
    assert kinds.index(b"moov") < kinds.index(b"mdat")  # a fast-start file
    before = decode(path)
    tag_equirectangular(path)
    assert spherical_projection(path) == "equirectangular"
    after = decode(path)
    assert len(after) == 12 and all(np.array_equal(a, b) for a, b in zip(before, after))
    tagged = path.read_bytes()
    tag_equirectangular(path)
    assert path.read_bytes() == tagged

    # a 'moov' at the end whose size says "to the end of the file" (0) gets its real size
    late = tmp_path / "late.mp4"
    with av.open(str(late), "w") as c:
        stream = c.add_stream("libx264", rate=10)
        stream.width, stream.height, stream.pix_fmt = 64, 32, "yuv420p"
        for i in range(4):
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.full((32, 64, 3), 40 * i, np.uint8),
                                                                   format="rgb24")):
                c.mux(packet)
        for packet in stream.encode():
            c.mux(packet)
    data = bytearray(late.read_bytes())
    kinds = top_level(late)
    assert kinds[-1] == b"moov"
    moov_at = data.rfind(b"moov") - 4
    data[moov_at:moov_at + 4] = b"\0\0\0\0"
    late.write_bytes(bytes(data))
    before = decode(late)
    tag_equirectangular(late)
    assert spherical_projection(late) == "equirectangular"
    assert int.from_bytes(late.read_bytes()[moov_at:moov_at + 4], "big") == len(late.read_bytes()) - moov_at
    after = decode(late)
    assert len(after) == 4 and all(np.array_equal(a, b) for a, b in zip(before, after))
