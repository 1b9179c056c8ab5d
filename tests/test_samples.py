"""Procedural samples: objects, GL rendering, the D-NeRF dataset writer, build_model and ``splatreel sample``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from splatreel.cameras import Camera, look_at_c2w
from splatreel.checkpoint import load_checkpoint
from splatreel.cli import main
from splatreel.errors import OutputExistsError
from splatreel.samples import (BOUNDING_RADIUS, SAMPLES, SCENES, DatasetConfig, SampleConfigError,
                             UnknownSampleError, build_model, get_sample, mesh_at, object_bounds, object_center,
                             write_dataset)
from splatreel.samples.geometry import (Mesh, axis_angle_matrix, face_areas, points_on_surface, sample_surface,
                                      signed_volume, vertex_normals)
from splatreel.samples.render import LIGHT_DIR, resolve_straight_alpha

SMALL = DatasetConfig(views=4, frames=3, size=64, test_views=4)
TIMES = np.linspace(0.0, 1.0, 11)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, renderer) -> Path:
    return write_dataset("spinner", tmp_path_factory.mktemp("ds") / "spinner", SMALL, renderer=renderer)


def read_rgba(path: Path) -> np.ndarray:
    bgra = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert bgra is not None and bgra.ndim == 3 and bgra.shape[2] == 4, f"{path} is not an RGBA PNG"
    return cv2.cvtColor(bgra, cv2.COLOR_BGRA2RGBA)


def alpha_centroid(rgba: np.ndarray) -> np.ndarray:
    """Alpha-weighted centroid in pixel coordinates (pixel centres at i + 0.5)."""
    a = rgba[..., 3].astype(np.float64)
    ys, xs = np.mgrid[: a.shape[0], : a.shape[1]] + 0.5
    return np.array([(a * xs).sum(), (a * ys).sum()]) / a.sum()


# --- objects ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", list(SAMPLES))
def test_objects_fixed_topology_closed_and_inside_ball(name):
    v0, f0, _ = mesh_at(name, 0.0)
    for t in TIMES:
        v, f, c = mesh_at(name, t)
        assert np.array_equal(f, f0), "topology must not change over time"
        assert v.shape == v0.shape and np.isfinite(v).all()
        assert np.linalg.norm(v, axis=1).max() < BOUNDING_RADIUS
        assert c.shape == v.shape and c.min() >= 0.0 and c.max() <= 1.0
        # closed and wound counter-clockwise seen from outside: positive enclosed volume
        assert signed_volume(v, f) > 0.02
        lo, hi = object_bounds(name, t)
        np.testing.assert_allclose(lo, v.min(0))
        np.testing.assert_allclose(hi, v.max(0))
    # it moves
    assert np.abs(mesh_at(name, 0.5)[0] - v0).max() > 0.1


def pairwise(v: np.ndarray) -> np.ndarray:
    idx = np.arange(0, len(v), max(1, len(v) // 200))
    return np.linalg.norm(v[idx, None] - v[None, idx], axis=-1)


def test_object_motions_are_what_they_claim():
    # spinner: rigid (distances kept) but it rotates and travels; its centre is the box centre
    d0 = pairwise(mesh_at("spinner", 0.0)[0])
    for t in TIMES:
        v = mesh_at("spinner", t)[0]
        np.testing.assert_allclose(pairwise(v), d0, atol=1e-9)
        np.testing.assert_allclose(v.mean(0), object_center("spinner", t), atol=1e-9)
    assert np.linalg.norm(object_center("spinner", 1.0) - object_center("spinner", 0.0)) > 0.3
    # wave: non-rigid bending, same colours (texture moves with the surface)
    assert np.abs(pairwise(mesh_at("wave", 0.25)[0]) - pairwise(mesh_at("wave", 0.0)[0])).max() > 0.1
    np.testing.assert_array_equal(mesh_at("wave", 0.0)[2], mesh_at("wave", 0.7)[2])
    # morph: shape (volume) and colour change
    v0, f, c0 = mesh_at("morph", 0.0)
    v1, _, c1 = mesh_at("morph", 1.0)
    assert abs(signed_volume(v1, f) / signed_volume(v0, f) - 1.0) > 0.3
    assert np.abs(c1 - c0).mean() > 0.1


def test_unknown_sample_lists_names():
    with pytest.raises(UnknownSampleError, match="spinner, wave, morph"):
        mesh_at("teapot", 0.0)


def test_vertex_normals_point_outward():
    v, f, _ = mesh_at("morph", 0.3)
    n = vertex_normals(v, f)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    assert (np.einsum("ij,ij->i", n, v) > 0).all()  # star-shaped about the origin


# --- rendering -------------------------------------------------------------------------------------------------

def test_straight_alpha_resolve():
    # 2x2 block, one covered sample of premultiplied colour (0.8, 0.4, 0.2): straight colour kept, alpha 1/4
    img = np.zeros((2, 2, 4), np.float32)
    img[0, 0] = (0.8, 0.4, 0.2, 1.0)
    out = resolve_straight_alpha(img, 2)
    np.testing.assert_array_equal(out[0, 0], np.rint(np.array([0.8, 0.4, 0.2, 0.25]) * 255))
    assert resolve_straight_alpha(np.zeros((4, 4, 4), np.float32), 2).sum() == 0


def test_gl_projection_matches_camera_project(renderer):
    """A small square drawn at a 3D point lands where Camera.project says (off-centre principal point,
    non-square image, so a swapped axis or a half-pixel shift would show)."""
    cam = Camera(look_at_c2w((0.3, -2.0, 0.8), (0.0, 0.0, 0.1), "z"), fx=70.0, fy=75.0, cx=41.0, cy=22.5,
                 width=80, height=48)
    for point in [(0.0, 0.0, 0.1), (0.35, 0.1, -0.1), (-0.3, 0.2, 0.3)]:
        p = np.asarray(point)
        # a square facing the camera, 0.04 wide
        right, up = cam.c2w[:3, 0] * 0.02, -cam.c2w[:3, 1] * 0.02
        quad = np.stack([p - right - up, p + right - up, p + right + up, p - right + up])
        mesh = Mesh(quad, np.array([[0, 1, 2], [0, 2, 3]], np.int32), np.full((4, 3), 0.5))
        rgba = next(renderer.render(mesh, [cam]))
        expected = cam.project(p[None])[0][0]
        np.testing.assert_allclose(alpha_centroid(rgba), expected, atol=0.1)


def test_render_is_antialiased_and_transparent(renderer):
    cam = Camera.from_opengl(_gl_pose(), 96, 96, fov_x_deg=45.0)
    rgba = next(renderer.render(get_sample("morph").mesh(0.5), [cam]))
    a = rgba[..., 3]
    assert rgba.dtype == np.uint8 and rgba.shape == (96, 96, 4)
    assert a[0, 0] == 0 and a[48, 48] == 255 and (rgba[a == 0, :3] == 0).all()
    edge = (a > 0) & (a < 255)
    assert edge.sum() > 0.5 * np.sqrt((a == 255).sum())  # smooth edges: partial coverage along the outline


def test_mesh_renderer_and_viewer_share_a_process(renderer):
    """Each renderer makes its own context current for its GL work: interleaving them changes nothing."""
    from splatreel.samples import build_model
    from splatreel.viewer.renderer import render_image

    cam = Camera.from_opengl(_gl_pose(), 48, 48, fov_x_deg=45.0)
    mesh = get_sample("spinner").mesh(0.3)
    first = next(renderer.render(mesh, [cam]))
    splat = render_image(build_model("spinner", num_gaussians=500), cam, 0.3)
    again = next(renderer.render(mesh, [cam]))
    np.testing.assert_array_equal(first, again)
    assert splat[..., 3].max() > 0


def test_render_straight_alpha_of_a_fully_lit_quad(renderer):
    """A quad facing the light (and the camera) is lit to exactly its albedo; with straight alpha its
    partially covered edge pixels keep that colour instead of fading to black."""
    light = np.asarray(LIGHT_DIR)
    cam = Camera(look_at_c2w(2.0 * light, (0.0, 0.0, 0.0), "z"), 60.0, 60.0, 24.0, 24.0, 48, 48)
    right, up = cam.c2w[:3, 0] * 0.3, -cam.c2w[:3, 1] * 0.2
    quad = np.stack([-right - up, right - up, right + up, -right + up])
    quad = quad @ axis_angle_matrix(light, 0.3).T  # turned in its plane: edges not pixel-aligned
    albedo = np.array([0.8, 0.4, 0.2])
    mesh = Mesh(quad, np.array([[0, 1, 2], [0, 2, 3]], np.int32), np.tile(albedo, (4, 1)))
    rgba = next(renderer.render(mesh, [cam]))
    a = rgba[..., 3]
    edge = (a > 20) & (a < 235)
    assert edge.sum() > 20 and (a == 255).sum() > 100
    np.testing.assert_allclose(rgba[a == 255, :3], np.tile(albedo * 255, ((a == 255).sum(), 1)), atol=1.0)
    np.testing.assert_allclose(rgba[edge, :3], np.tile(albedo * 255, (edge.sum(), 1)), atol=3.0)


def _gl_pose() -> np.ndarray:
    """OpenGL camera-to-world looking at the origin from +x, up +z."""
    c2w = look_at_c2w((2.5, 0.0, 0.0), (0.0, 0.0, 0.0), "z")
    return c2w @ np.diag([1.0, -1.0, -1.0, 1.0])


# --- dataset ---------------------------------------------------------------------------------------------------

def load_split(root: Path, split: str) -> dict:
    return json.loads((root / f"transforms_{split}.json").read_text())


def frame_camera(meta: dict, frame: dict) -> Camera:
    """The camera of a JSON frame, read back the way a D-NeRF loader does (FOV from camera_angle_x)."""
    return Camera.from_opengl(frame["transform_matrix"], frame["w"], frame["h"],
                              fov_x_deg=math.degrees(meta["camera_angle_x"]))


def orbit_angles(cam: Camera) -> tuple[float, float]:
    """(azimuth from +x towards +y, elevation) in degrees of a camera position, z up."""
    x, y, z = cam.position
    return math.degrees(math.atan2(y, x)) % 360.0, math.degrees(math.asin(z / math.hypot(x, y, z)))


def test_dataset_layout(dataset):
    train, test = load_split(dataset, "train"), load_split(dataset, "test")
    assert load_split(dataset, "val") == test
    for meta, split, count in ((train, "train", 12), (test, "test", 4)):
        assert len(meta["frames"]) == count
        f = 0.5 * 64 / math.tan(0.5 * meta["camera_angle_x"])
        assert meta["fl_x"] == pytest.approx(f) and meta["fl_y"] == pytest.approx(f)
        assert (meta["cx"], meta["cy"], meta["w"], meta["h"]) == (32.0, 32.0, 64, 64)
        for i, fr in enumerate(meta["frames"]):
            assert fr["file_path"] == f"./{split}/r_{i:03d}"
            assert 0.0 <= fr["time"] <= 1.0 and (fr["w"], fr["h"]) == (64, 64)
            assert np.asarray(fr["transform_matrix"]).shape == (4, 4)
            assert read_rgba(dataset / f"{fr['file_path']}.png").shape == (64, 64, 4)
        times = [fr["time"] for fr in meta["frames"]]
        assert times == sorted(times) and times[0] == 0.0  # grouped by time; D-NeRF asserts the start at 0
    assert sorted(p.name for p in (dataset / "train").iterdir()) == [f"r_{i:03d}.png" for i in range(12)]

    # training cameras: an image matrix on the requested orbit, ordered by time then azimuth
    train_times = sorted({fr["time"] for fr in train["frames"]})
    assert train_times == [0.0, 0.5, 1.0]
    train_angles = set()
    for i, fr in enumerate(train["frames"]):
        assert fr["time"] == train_times[i // 4]
        cam = frame_camera(train, fr)
        pos = cam.position
        assert np.linalg.norm(pos) == pytest.approx(SMALL.radius)
        az, el = orbit_angles(cam)
        assert el == pytest.approx(30.0) and az == pytest.approx(90.0 * (i % 4), abs=1e-6)
        np.testing.assert_allclose(cam.forward, -pos / np.linalg.norm(pos), atol=1e-9)  # looks at the origin
        assert cam.c2w[:3, 1] @ [0, 0, 1] < 0  # image up is world up
        train_angles.add((round(az, 6), round(el, 6)))

    # test cameras: other azimuths and elevations, times between training times (after the t = 0 one)
    for i, fr in enumerate(test["frames"]):
        az, el = orbit_angles(frame_camera(test, fr))
        assert (round(az, 6), round(el, 6)) not in train_angles
        assert min(abs(az - a) for a, _ in train_angles) == pytest.approx(45.0)
        assert el == pytest.approx(10.0 if i % 2 == 0 else 45.0)
        if i > 0:
            assert fr["time"] not in train_times and 0.0 < fr["time"] < 1.0

    info = json.loads((dataset / "sample.json").read_text())
    assert info["name"] == "spinner" and info["generator_version"] >= 1
    assert info["object"]["half_extents"] == list(get_sample("spinner").half_extents)
    assert info["render"]["views"] == 4 and info["splits"] == {"train": 12, "test": 4}


def test_dataset_is_deterministic(dataset, tmp_path, renderer):
    again = write_dataset("spinner", tmp_path / "again", SMALL, renderer=renderer)
    files = sorted(p.relative_to(dataset) for p in dataset.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    for rel in files:
        assert (dataset / rel).read_bytes() == (again / rel).read_bytes(), f"{rel} differs between two runs"


def test_reprojection_of_known_centre(dataset):
    """The rendered silhouette sits where the JSON pose (read back through Camera.from_opengl) projects the
    spinner at that time: its alpha centroid near the projected box centre, and (the box being convex) its
    bounding box on the bounding box of the projected vertices."""
    for split in ("train", "test"):
        meta = load_split(dataset, split)
        for fr in meta["frames"]:
            cam = Camera.from_opengl(fr["transform_matrix"], fr["w"], fr["h"], fx=meta["fl_x"], fy=meta["fl_y"],
                                     cx=meta["cx"], cy=meta["cy"])  # the pixel intrinsics, this time
            rgba = read_rgba(dataset / f"{fr['file_path']}.png")
            expected = cam.project(object_center("spinner", fr["time"])[None])[0][0]
            # a silhouette centroid is not exactly the projected centre (perspective): up to ~1.4 px at 64 px,
            # while a wrong time or pose is off by 5-16 px
            np.testing.assert_allclose(alpha_centroid(rgba), expected, atol=2.0)
            # the outermost lit pixel holds the extreme projected vertex, or is its neighbour when the vertex's
            # sliver of that pixel misses every antialiasing sample: within 1 px either way
            uv = cam.project(mesh_at("spinner", fr["time"])[0])[0]
            rows, cols = np.nonzero(rgba[..., 3] > 0)
            np.testing.assert_allclose([cols.min(), rows.min()], uv.min(0), atol=1.0)
            np.testing.assert_allclose([cols.max() + 1, rows.max() + 1], uv.max(0), atol=1.0)


def test_dataset_refuses_overwrite_and_bad_config(dataset, tmp_path):
    before = (dataset / "sample.json").read_bytes()
    with pytest.raises(OutputExistsError):
        write_dataset("spinner", dataset, SMALL)
    assert (dataset / "sample.json").read_bytes() == before
    with pytest.raises(SampleConfigError, match="--radius"):
        DatasetConfig(radius=0.5)
    with pytest.raises(UnknownSampleError):
        write_dataset("teapot", tmp_path / "x", SMALL)
    assert not (tmp_path / "x").exists()


# --- build_model -----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", list(SAMPLES))
def test_build_model_follows_the_surface(name):
    model = build_model(name, num_gaussians=12000, frames=16, seed=0)
    assert len(model) == 12000 and model.time_range == (0.0, 1.0) and model.rotation_convention == "current"
    obj = get_sample(name)
    for t in (0.0, 0.2, 0.5, 0.77):  # 0.2 = 3/15 is a key time: exercises the velocities
        g = model.slice(t)
        mesh = obj.mesh(t)
        size = np.linalg.norm(np.ptp(mesh.vertices, axis=0))
        fid, bary = sample_surface(face_areas(mesh.vertices, mesh.faces), 60000, np.random.default_rng(1))
        surface = points_on_surface(mesh, fid, bary)[0]
        vis = g.visible.numpy()
        opaque = vis & (g.opacities.numpy() > 0.5)
        # sliced means lie on the surface at time t (distance to the nearest of 60k surface samples)
        d_all, _ = cKDTree(surface).query(g.means.numpy()[vis])
        d_opaque, _ = cKDTree(surface).query(g.means.numpy()[opaque])
        assert d_opaque.max() < 0.02 * size, f"{name} t={t}: opaque Gaussians off the surface"
        assert np.quantile(d_all, 0.99) < 0.03 * size, f"{name} t={t}: visible Gaussians off the surface"
        # and cover it: every surface sample is within a few disc radii of an opaque Gaussian
        std = g.select(torch.from_numpy(opaque)).scales_quats()[0].max(-1).values.numpy()
        dist, nearest = cKDTree(g.means.numpy()[opaque]).query(surface[:20000])
        ratio = dist / std[nearest]
        assert np.median(ratio) < 1.2 and np.quantile(ratio, 0.999) < 3.5, f"{name} t={t}: holes in the cover"


def test_build_model_is_deterministic_and_lit():
    a, b = build_model("wave", 3000, frames=6, seed=3), build_model("wave", 3000, frames=6, seed=3)
    for k, v in a.tensors().items():
        assert torch.equal(v, getattr(b, k)), k
    c = build_model("wave", 3000, frames=6, seed=4)
    assert not torch.equal(a.means, c.means)
    # colours are the lit mesh colours (SH DC), never brighter than the albedo
    rgb = a.slice(0.5).colors(torch.zeros(3))
    assert 0.0 <= float(rgb.min()) and float(rgb.max()) <= 1.0 + 1e-5
    with pytest.raises(SampleConfigError):
        build_model("wave", 100, frames=1)


# --- CLI -------------------------------------------------------------------------------------------------------

def test_cli_help_and_list(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["sample", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for flag in ("--views", "--time-steps", "--size", "--elevation", "--radius", "--fov", "--test-views", "--force",
                 "--model", "--list"):
        assert flag in out
    assert main(["sample", "--list"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split()[0] for line in lines] == list(SAMPLES) + list(SCENES)  # objects, then scenes (floor)


def test_cli_errors_are_one_line(capsys, tmp_path):
    assert main(["sample", "teapot", "--out", str(tmp_path / "x")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "spinner, wave, morph" in err
    (tmp_path / "taken").mkdir()
    assert main(["sample", "wave", "--out", str(tmp_path / "taken"), "--size", "16"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "already exists" in err and "--force" in err
    assert main(["sample", "wave", "--out", str(tmp_path / "y"), "--views", "1001"]) == 1
    assert "--views" in capsys.readouterr().err


def test_cli_writes_dataset_and_model(tmp_path, capsys):
    out, ckpt = tmp_path / "d", tmp_path / "m.safetensors"
    args = ["sample", "morph", "--out", str(out), "--views", "2", "--time-steps", "2", "--size", "16",
            "--test-views", "1", "--model", str(ckpt), "--gaussians", "500"]
    assert main(args) == 0
    assert len(load_split(out, "train")["frames"]) == 4 and len(load_split(out, "test")["frames"]) == 1
    loaded = load_checkpoint(ckpt)
    assert len(loaded.model) == 500
    assert loaded.provenance["tool"] == "splatreel sample" and loaded.provenance["sample"] == "morph"
    assert main(args) == 1  # refuses to overwrite
    assert main(args + ["--force"]) == 0


def test_one_camera_per_time_films_each_frame_from_one_camera_of_the_matrix(tmp_path, capsys):
    """--one-camera-per-time keeps, of the matrix, frame f from camera f mod views: the same images, one per time,
    which the trainer's recipe reads as D-NeRF's monocular regime."""
    from splatreel.train.data import load_dataset
    from splatreel.train.recipe import read_traits

    common = ["--views", "3", "--time-steps", "7", "--size", "16", "--test-views", "1"]
    assert main(["sample", "wave", "--out", str(tmp_path / "matrix"), *common]) == 0
    assert main(["sample", "wave", "--out", str(tmp_path / "mono"), *common, "--one-camera-per-time"]) == 0
    mono, matrix = load_split(tmp_path / "mono", "train"), load_split(tmp_path / "matrix", "train")
    assert len(mono["frames"]) == 7 and len(matrix["frames"]) == 21
    for f, fr in enumerate(mono["frames"]):
        same = matrix["frames"][3 * f + f % 3]
        assert fr["file_path"] == f"./train/r_{f:03d}" and fr["time"] == same["time"]
        assert fr["transform_matrix"] == same["transform_matrix"]
        assert orbit_angles(frame_camera(mono, fr))[0] == pytest.approx(120.0 * (f % 3), abs=1e-6)
        assert (tmp_path / "mono" / f"{fr['file_path']}.png").read_bytes() == \
            (tmp_path / "matrix" / f"{same['file_path']}.png").read_bytes()
    assert load_split(tmp_path / "mono", "test") == load_split(tmp_path / "matrix", "test")
    info = json.loads((tmp_path / "mono" / "sample.json").read_text())
    assert info["render"]["one_camera_per_time"] is True and info["splits"]["train"] == 7
    assert read_traits(load_dataset(tmp_path / "mono")).one_view_per_time
    assert not read_traits(load_dataset(tmp_path / "matrix")).one_view_per_time
    capsys.readouterr()
    # the floor scene has its own rig, already one camera per time
    assert main(["sample", "floor", "--out", str(tmp_path / "floor"), "--one-camera-per-time"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--one-camera-per-time does not apply to sample 'floor'" in err
