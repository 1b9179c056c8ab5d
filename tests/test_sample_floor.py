"""The ``floor`` scene sample: D-NeRF one-camera-per-time rig whose alpha marks what lies nearer than a far clip."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from splatreel.cli import main
from splatreel.samples import (SAMPLES, SCENES, DatasetConfig, FloorConfig, SampleConfigError,
                             build_model, get_sample, shade, write_dataset)
from splatreel.samples import floor
from splatreel.samples.floor import (FAR_CLIP, FLOOR_SHARE, NUM_CAMERAS, SIDE_DISTANCE, TOP_CAMERA, TOP_HEIGHT,
                                   FloorScene, concat_meshes, default_model_gaussians, rig_cameras)
from splatreel.checkpoint import load_checkpoint
from splatreel.train.data import load_dataset
from splatreel.train.evaluate import evaluate
from splatreel.rasterize import rasterize
from test_samples import read_rgba

SMALL = FloorConfig(frames=36, size=64, test_views=12)
SCENE = FloorScene()
#: Floor points around the objects: every side camera sees them opaque, the top camera transparent.
NEAR_FLOOR = np.array([(x, y, SCENE.floor_z) for x in np.linspace(-1.0, 1.0, 9) for y in np.linspace(-1.0, 1.0, 9)])


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, renderer) -> Path:
    return write_dataset("floor", tmp_path_factory.mktemp("floor") / "floor", SMALL, renderer=renderer)


def objects_mask(renderer, camera, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixels the objects (the scene without its floor, no far clip) cover at time t: (any coverage, grown by a
    pixel; full coverage)."""
    parts = SCENE.parts(t)
    mesh = concat_meshes([m for name, m in parts.items() if name != "floor"])
    alpha = next(renderer.render(mesh, [camera]))[..., 3]
    return cv2.dilate((alpha > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0, alpha == 255


def pixels_of(camera, points: np.ndarray) -> np.ndarray:
    uv, depth = camera.project(points)
    assert (depth > 0).all() and (uv >= 0).all() and (uv < camera.width).all(), "points outside the image"
    return np.floor(uv).astype(int)


# --- scene and rig ---------------------------------------------------------------------------------------------

def test_rig_geometry():
    rig = rig_cameras(SMALL)
    assert len(rig) == NUM_CAMERAS
    for k, (el, az, cam) in enumerate(rig):
        pos = cam.position
        np.testing.assert_allclose(cam.forward, -pos / np.linalg.norm(pos), atol=1e-9)  # looks at the origin
        if k == TOP_CAMERA:
            np.testing.assert_allclose(pos, [0.0, 0.0, TOP_HEIGHT], atol=1e-12)
            np.testing.assert_allclose(cam.forward, [0.0, 0.0, -1.0], atol=1e-12)
        else:
            assert np.linalg.norm(pos) == pytest.approx(SIDE_DISTANCE)
            assert 10.0 <= el <= 45.0 and math.degrees(math.asin(pos[2] / SIDE_DISTANCE)) == pytest.approx(el)
            assert az == pytest.approx(360.0 * k / 11)
            assert cam.c2w[:3, 1] @ [0, 0, 1] < 0  # image up is world up
    side_elevations = sorted(el for el, _, _ in rig[:TOP_CAMERA])
    np.testing.assert_allclose(side_elevations, np.linspace(10.0, 45.0, 11))
    # the far clip separates the top camera's floor (beyond) from the side cameras' floor near the objects
    top = rig[TOP_CAMERA][2]
    assert (top.project(NEAR_FLOOR)[1] > FAR_CLIP).all()
    for _, _, cam in rig[:TOP_CAMERA]:
        assert (cam.project(NEAR_FLOOR)[1] < FAR_CLIP).all()


def test_objects_move_and_stay_nearer_than_the_far_clip():
    rig = rig_cameras(SMALL)
    for t in np.linspace(0.0, 1.0, 41):
        for name, mesh in SCENE.parts(t).items():
            if name == "floor":
                continue
            v = mesh.vertices
            assert np.hypot(v[:, 0], v[:, 1]).max() < 1.45 and v[:, 2].min() >= SCENE.floor_z - 1e-9
            for k, (_, _, cam) in enumerate(rig):
                uv, depth = cam.project(v)
                assert ((uv >= 0) & (uv <= SMALL.size)).all(), f"{name} at t={t} leaves the frame of camera {k}"
                beyond = depth >= FAR_CLIP
                if k != TOP_CAMERA or name != "ball":
                    assert not beyond.any(), f"{name} at t={t} reaches the far clip of camera {k}"
                else:  # only the underside of the ball where it touches the floor (hidden from above)
                    assert (v[beyond, 2] < SCENE.ball_center(t)[2]).all()
    assert 0.0 < TOP_HEIGHT - FAR_CLIP - SCENE.floor_z <= 0.05 + 1e-9  # the top camera clips just above the floor
    # every object moves by more than its own size over the clip
    times = np.linspace(0.0, 1.0, 41)
    for name in ("ball", "box", "pendulum"):
        v = np.stack([SCENE.parts(t)[name].vertices for t in times])  # (T, V, 3)
        size = np.ptp(v[0], axis=0).max()
        travel = max(np.linalg.norm(v - v[i], axis=-1).max() for i in range(len(times)))
        assert travel > size, f"{name} travels {travel:.2f}, its size is {size:.2f}"
    # the floor is big (to the horizon), and the whole scene is one mesh
    lo, hi = SCENE.parts(0.0)["floor"].bounds
    assert hi[0] - lo[0] >= 60.0 and hi[2] == lo[2] == SCENE.floor_z
    mesh = get_sample("floor").mesh(0.5)
    assert len(mesh.vertices) == sum(len(m.vertices) for m in SCENE.parts(0.5).values())


@pytest.mark.parametrize("frames,count", [(96, 12), (96, 24), (36, 12), (12, 12), (24, 5), (200, 40)])
def test_test_plan(frames, count):
    plan = floor.test_plan(frames, count)  # (module attribute: pytest would collect a bare test_plan)
    assert len(plan) == count and plan[0] == (0.0, NUM_CAMERAS // 2)
    times = [t for t, _ in plan]
    assert times == sorted(times)
    steps = frames - 1
    for t, cam in plan[1:]:
        f = t * steps - 0.5
        assert abs(f - round(f)) < 1e-9 and 0 <= round(f) < steps  # half-way between training frames f and f+1
        assert cam not in (round(f) % NUM_CAMERAS, (round(f) + 1) % NUM_CAMERAS)  # neither is seen by its camera
    if count >= NUM_CAMERAS:
        assert {c for _, c in plan} == set(range(NUM_CAMERAS))


# --- dataset ---------------------------------------------------------------------------------------------------

def test_dataset_loads_one_camera_per_time(dataset):
    ds = load_dataset(dataset)
    assert ds.layout == "dnerf" and len(ds.train) == SMALL.frames and len(ds.test) == SMALL.test_views
    train_times = [v.time for v in ds.train]
    np.testing.assert_allclose(train_times, np.arange(SMALL.frames) / (SMALL.frames - 1), atol=1e-9)
    assert ds.num_views == NUM_CAMERAS and len(ds.frame_times) == SMALL.frames  # 12 cameras, one per time
    assert [v.view_id for v in ds.train] == [i % NUM_CAMERAS for i in range(SMALL.frames)]
    poses = {v.view_id: v.camera.c2w for v in ds.train}
    assert ds.test[0].time == 0.0
    test_cameras = set()
    for v in ds.test:
        match = [k for k, p in poses.items() if np.allclose(p, v.camera.c2w, atol=1e-6)]
        assert len(match) == 1, "a test view must use one of the 12 training cameras"
        test_cameras.add(match[0])
        if v is not ds.test[0]:
            assert 0.0 < v.time < 1.0 and min(abs(v.time - t) for t in train_times) > 0.4 / (SMALL.frames - 1)
    assert test_cameras == set(range(NUM_CAMERAS))
    for v in ds.train + ds.test:
        assert v.alpha is not None and v.size == (SMALL.size, SMALL.size)
    info = json.loads((dataset / "sample.json").read_text())
    assert info["name"] == "floor" and info["render"]["far_clip"] == FAR_CLIP and "far clip" in info["alpha"]
    assert info["train_cameras"] == [i % NUM_CAMERAS for i in range(SMALL.frames)]
    assert [c["kind"] for c in info["cameras"]] == ["side"] * 11 + ["top"]
    assert info["splits"] == {"train": SMALL.frames, "test": SMALL.test_views}


def test_alpha_marks_nearer_than_the_far_clip(dataset, renderer):
    """The views disagree about the floor: transparent from the top camera, opaque from the side ones."""
    meta = json.loads((dataset / "transforms_train.json").read_text())
    rig = rig_cameras(SMALL)
    for i, frame in enumerate(meta["frames"]):
        rgba = read_rgba(dataset / f"{frame['file_path']}.png")
        alpha = rgba[..., 3]
        cam = rig[i % NUM_CAMERAS][2]
        objects, inside = objects_mask(renderer, cam, frame["time"])
        assert inside.sum() > 10 and (alpha[inside] == 255).all()  # every camera sees the objects whole
        cols, rows = pixels_of(cam, NEAR_FLOOR).T
        if i % NUM_CAMERAS == TOP_CAMERA:
            # from above only the objects are opaque: the floor, also under them, lies beyond the far clip
            assert (alpha[~objects] == 0).all()
            assert (alpha == 0).mean() > 0.8
            floor_px = ~objects[rows, cols]
            assert floor_px.sum() > 40 and (alpha[rows, cols][floor_px] == 0).all()
        else:
            # the floor around the objects is opaque, the sky and the floor past the clip transparent
            assert (alpha[rows, cols] == 255).all()
            assert (alpha[0] == 0).all() and (alpha[-1] == 255).all()
            assert 0.1 < (alpha == 0).mean() < 0.6
            # objects are visible against the floor: saturated or dark pixels, which the floor has none of
            hsv = cv2.cvtColor(rgba[..., :3], cv2.COLOR_RGB2HSV)
            coloured = (alpha == 255) & ((hsv[..., 1] > 100) | (hsv[..., 2] < 90))
            assert coloured.sum() > 0.03 * alpha.size
            floor = (alpha == 255) & ~objects
            assert hsv[..., 1][floor].max() < 40 and np.median(hsv[..., 2][floor]) > 200  # near-white floor
            assert np.ptp(rgba[..., 0][floor]) > 15  # with a tile grid, not a constant


def test_dataset_is_deterministic(dataset, tmp_path, renderer):
    again = write_dataset("floor", tmp_path / "again", SMALL, renderer=renderer)
    files = sorted(p.relative_to(dataset) for p in dataset.rglob("*") if p.is_file())
    assert len(files) == SMALL.frames + SMALL.test_views + 4
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    for rel in files:
        assert (dataset / rel).read_bytes() == (again / rel).read_bytes(), f"{rel} differs between two runs"


def test_config_errors(tmp_path):
    for kwargs, flag in [(dict(frames=11), "--time-steps"), (dict(size=4), "--size"), (dict(test_views=-1),
                                                                                      "--test-views"),
                         (dict(fov=float("nan")), "--fov")]:
        with pytest.raises(SampleConfigError, match=flag):
            FloorConfig(**kwargs)
    with pytest.raises(SampleConfigError, match="FloorConfig"):
        write_dataset("floor", tmp_path / "a", DatasetConfig())
    with pytest.raises(SampleConfigError, match="DatasetConfig"):
        write_dataset("spinner", tmp_path / "b", FloorConfig())
    with pytest.raises(SampleConfigError, match="floor"):
        build_model("floor", 1)  # objects and floor need one Gaussian each
    with pytest.raises(SampleConfigError, match="FloorConfig"):
        build_model("floor", config=DatasetConfig())
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    assert "floor" not in SAMPLES and "floor" in SCENES  # the object tests (0.9 ball) skip the scene


# --- exact model -----------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def exact_model():
    return build_model("floor", config=SMALL)


def static_part(model):
    """The floor's Gaussians: temporal std-dev 1000 (the objects' are half a key interval)."""
    return model.select(model.t_scales > 1.0)


def test_exact_model_has_a_static_floor(exact_model):
    model = exact_model
    assert len(model) == default_model_gaussians(SMALL) == 5 * SMALL.size ** 2
    floor_model = static_part(model)
    assert 0 < len(floor_model) <= FLOOR_SHARE * len(model)
    assert (model.t_scales[: len(model) - len(floor_model)] < 0.1).all()  # the objects first, then the floor
    start, end = floor_model.slice(0.0), floor_model.slice(1.0)
    assert float(start.velocities.abs().max()) < 1e-6
    np.testing.assert_allclose(start.means.numpy(), end.means.numpy(), atol=1e-6)
    np.testing.assert_allclose(start.opacities.numpy(), end.opacities.numpy(), rtol=1e-5)
    assert float(start.opacities.min()) > 0.9  # never fades
    # flat discs in the floor plane, out to the far side's clip (~4.1 from the origin) and no further
    np.testing.assert_allclose(start.means[:, 2].numpy(), SCENE.floor_z, atol=1e-6)
    cov = start.covariances
    assert (cov[:, 2, 2] < 0.02 * cov[:, 0, 0]).all() and (cov[:, 0, 0] == cov[:, 1, 1]).all()
    radius = np.hypot(start.means[:, 0].numpy(), start.means[:, 1].numpy())
    assert 3.5 < radius.max() < 4.5
    # white tiles and grey lines, lit like the mesh
    rgb = start.colors(torch.zeros(3))
    assert float(rgb.max()) == pytest.approx(float(shade(np.ones((1, 3)), np.array([[0.0, 0.0, 1.0]])).max()), abs=1e-4)
    assert float(rgb.min()) < float(rgb.max()) - 0.1


def test_exact_floor_covers_the_floor_the_side_cameras_see(exact_model, dataset, renderer):
    """The floor alone, drawn from each side camera, is opaque where the dataset's floor is and transparent past
    the far clip, except near the clip lines the views disagree on."""
    floor_model = static_part(exact_model).slice(0.5)
    meta = json.loads((dataset / "transforms_train.json").read_text())
    rig = rig_cameras(SMALL)
    agree = []
    for i, frame in enumerate(meta["frames"][:TOP_CAMERA]):
        cam = rig[i][2]
        alpha = read_rgba(dataset / f"{frame['file_path']}.png")[..., 3]
        objects, _ = objects_mask(renderer, cam, frame["time"])
        drawn = rasterize(floor_model, cam, (1.0, 1.0, 1.0)).alpha.numpy()
        cols, rows = pixels_of(cam, NEAR_FLOOR).T
        assert (drawn[rows, cols] > 0.9).all()  # a few % of white shows between coarse discs at 64 px
        agree.append(((drawn > 0.5) == (alpha > 127))[~objects].mean())
    # measured 94.7-99.5 %: the misses are the strips between a camera's own clip line and the majority's
    assert min(agree) > 0.93 and np.mean(agree) > 0.97, np.round(agree, 3)


def test_exact_model_matches_the_dataset(exact_model, dataset):
    """Rendered at a side test view it reproduces the image (measured 22.4 dB at 64 px; the top camera's view is
    lower, 17.2 dB, as its floor lies beyond the far clip in the dataset but not in a static model)."""
    ds = load_dataset(dataset)
    view = ds.test[3]
    assert np.linalg.norm(view.camera.position) == pytest.approx(SIDE_DISTANCE)
    result = evaluate(exact_model, [view], ds.background)
    assert ds.background == (1.0, 1.0, 1.0) and result["psnr"] > 21.0 and result["ssim"] > 0.8, result


def test_cli_writes_the_floor_model(tmp_path, capsys):
    path = tmp_path / "floor.safetensors"
    assert main(["sample", "floor", "--model", str(path), "--time-steps", "24", "--size", "64",
                 "--gaussians", "3000"]) == 0
    assert "3,000 Gaussians" in capsys.readouterr().out
    ck = load_checkpoint(path)
    assert len(ck.model) == 3000 and ck.background == (1.0, 1.0, 1.0)
    assert ck.provenance["sample"] == "floor" and ck.provenance["frames"] == 24


# --- CLI -------------------------------------------------------------------------------------------------------

def test_cli_writes_floor(tmp_path, capsys):
    out = tmp_path / "f"
    assert main(["sample", "floor", "--out", str(out), "--time-steps", "24", "--size", "48"]) == 0
    assert "24 training + 12 test images" in capsys.readouterr().out
    ds = load_dataset(out)
    assert len(ds.train) == 24 and len(ds.test) == 12 and ds.num_views == NUM_CAMERAS
    assert ds.train[0].size == (48, 48)
    assert main(["sample", "--list"]) == 0
    assert any(line.split()[0] == "floor" for line in capsys.readouterr().out.splitlines())


@pytest.mark.parametrize("args,needle", [
    (["--time-steps", "5"], "must be 12..1000"),
    (["--size", "2"], "--size"),
    (["--test-views", "1001"], "--test-views"),
    (["--views", "8"], "--views does not apply"),
    (["--elevation", "20", "--radius", "3"], "--elevation, --radius do not apply"),
    (["--trained", "t.safetensors"], "no trained checkpoint"),
])
def test_cli_floor_errors_are_one_line(tmp_path, capsys, monkeypatch, args, needle):
    monkeypatch.chdir(tmp_path)
    assert main(["sample", "floor", "--out", "out", *args]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err, err
    assert not any(tmp_path.iterdir()), "nothing is written on an error"
