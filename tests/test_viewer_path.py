"""Camera path files: round trip, interpolation through the keys, looping, errors, dataset import, trajectories."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from splatreel.cameras import look_at, look_at_c2w, orbit
from splatreel.errors import CameraError, OutputExistsError
from splatreel.viewer.camera_path import CameraKey, CameraPath, dataset_views, path_from_dataset
from splatreel.viewer.trajectory import orbit_cameras, path_frame_count, scene_times


def sample_path(loop: bool = False) -> CameraPath:
    data = {
        "format": "splatreel-camera-path", "version": 1, "up": "z", "loop": loop,
        "keyframes": [
            {"time": 0.0, "position": [3.0, 0.0, 1.0], "look_at": [0.0, 0.0, 0.0], "fov": 40.0, "scene_time": 0.0},
            {"time": 1.5, "position": [0.0, 3.0, 1.5], "look_at": [0.0, 0.0, 0.2], "fov": 30.0, "scene_time": 0.5},
            {"time": 2.0, "position": [-3.0, 0.5, 0.5], "look_at": [0.0, 0.0, 0.0], "fov": 50.0,
             "scene_time": 0.6},
            {"time": 4.0, "position": [0.0, -3.0, 2.0],
             "quaternion": CameraKey.from_camera(0, look_at((0, -3, 2), (0.1, 0, 0))).quaternion.tolist(),
             "fov": 45.0, "scene_time": 1.0},
        ],
    }
    return CameraPath.from_json(data)


def test_paths_written_before_the_rename_still_load():
    data = sample_path().to_json()
    data["format"] = "splat4d-camera-path"
    assert CameraPath.from_json(data).to_json() == sample_path().to_json()


def test_path_file_round_trips(tmp_path):
    path = sample_path()
    f = tmp_path / "path.json"
    path.save(f)
    again = CameraPath.load(f)
    assert again.to_json() == path.to_json()
    assert json.loads(f.read_text())["keyframes"][0]["look_at"] == [0.0, 0.0, 0.0]
    with pytest.raises(OutputExistsError):
        path.save(f)
    path.save(f, force=True)
    for t in np.linspace(-0.5, 4.5, 23):
        np.testing.assert_allclose(again.pose(t)[0], path.pose(t)[0], atol=1e-12)


def test_interpolation_passes_through_the_keys():
    path = sample_path()
    for key in path.keys:
        c2w, fov = path.pose(key.time)
        np.testing.assert_allclose(c2w[:3, 3], key.position, atol=1e-9)
        np.testing.assert_allclose(c2w[:3, :3], key.c2w()[:3, :3], atol=1e-9)
        assert fov == pytest.approx(key.fov)
        assert path.scene_time(key.time) == pytest.approx(key.scene_time)
    # look-at keys look at their target
    k1 = path.keys[1]
    np.testing.assert_allclose(k1.c2w()[:3, :3], look_at_c2w(k1.position, k1.look_at, "z")[:3, :3], atol=1e-9)
    # C1 at the inner keys: the velocity just before equals the velocity just after
    eps = 1e-6
    for key in path.keys[1:-1]:
        p = [path.pose(key.time + d)[0][:3, 3] for d in (-eps, 0.0, eps)]
        np.testing.assert_allclose((p[1] - p[0]) / eps, (p[2] - p[1]) / eps, rtol=1e-3, atol=1e-3)
    # between keys: orthonormal rotation, linear scene time
    rot = path.pose(0.7)[0][:3, :3]
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-9)
    assert path.scene_time(1.75) == pytest.approx(0.55)
    # the held ends of an open path
    np.testing.assert_allclose(path.pose(-1.0)[0], path.pose(0.0)[0])
    np.testing.assert_allclose(path.pose(9.0)[0], path.pose(4.0)[0])


def test_looping_path_closes_smoothly():
    path = sample_path(loop=True)
    assert path.duration == pytest.approx(4.0 + 4.0 / 3.0)
    np.testing.assert_allclose(path.pose(path.duration)[0], path.pose(0.0)[0], atol=1e-9)
    eps = 1e-4
    v_end = (path.pose(path.duration)[0][:3, 3] - path.pose(path.duration - eps)[0][:3, 3]) / eps
    v_start = (path.pose(eps)[0][:3, 3] - path.pose(0.0)[0][:3, 3]) / eps
    np.testing.assert_allclose(v_end, v_start, rtol=1e-2, atol=1e-2)


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["keyframes"].clear(), "non-empty"),
    (lambda d: d["keyframes"][1].update(time=0.0), "strictly increasing"),
    (lambda d: d["keyframes"][0].pop("look_at"), "exactly one of"),
    (lambda d: d["keyframes"][0].update(position=[1, 2]), "position must be 3"),
    (lambda d: d["keyframes"][0].update(fov=200), "fov"),
    (lambda d: d["keyframes"][0].update(fov=float("nan")), "finite"),
    (lambda d: d.update(up="w"), "up"),
    (lambda d: d.update(format="other"), "not a splatreel camera path"),
])
def test_bad_path_files_raise_one_line_errors(tmp_path, edit, message):
    data = sample_path().to_json()
    edit(data)
    f = tmp_path / "bad.json"
    f.write_text(json.dumps(data))
    with pytest.raises(CameraError, match=message) as info:
        CameraPath.load(f)
    assert "\n" not in str(info.value)
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(CameraError, match="not a readable JSON"):
        CameraPath.load(tmp_path / "junk.json")


def test_dataset_cameras_become_a_path(tmp_path):
    cams = [orbit(30, a, 4.0, fov_deg=35, width=64, height=48) for a in (0, 120, 240)]
    frames = [{"file_path": f"./train/r_{i:03d}", "time": t, "transform_matrix": c.to_opengl_c2w().tolist()}
              for i, (c, t) in enumerate(zip(cams, (0.5, 0.0, 1.0)))]
    meta = {"camera_angle_x": cams[0].fov_x, "w": 64, "h": 48, "frames": frames}
    (tmp_path / "transforms_train.json").write_text(json.dumps(meta))
    views = dataset_views(tmp_path)
    assert [v.time for v in views] == [0.5, 0.0, 1.0]
    np.testing.assert_allclose(views[0].camera.c2w, cams[0].c2w, atol=1e-9)
    assert views[0].camera.fy == pytest.approx(cams[0].fy)
    path = path_from_dataset(tmp_path, seconds_per_key=2.0)
    assert [k.scene_time for k in path.keys] == [0.0, 0.5, 1.0]  # ordered by frame time
    for key, cam in zip(path.keys, (cams[1], cams[0], cams[2])):
        got = path.camera(key.time, 64, 48)
        np.testing.assert_allclose(got.c2w, cam.c2w, atol=1e-9)
        assert got.fy == pytest.approx(cam.fy)
    (tmp_path / "empty").mkdir()
    with pytest.raises(CameraError, match="transforms_train.json"):
        dataset_views(tmp_path / "empty", "train")
    # a checkpoint recording these cameras (as `splatreel train` writes them) stands in for the dataset
    from splatreel.checkpoint import save_checkpoint
    from splatreel.viewer.synthetic import synthetic_model

    model = synthetic_model(10, seed=0)
    save_checkpoint(tmp_path / "trained.safetensors", model, views=views)
    recorded = dataset_views(tmp_path / "trained.safetensors")
    assert [(v.name, v.time) for v in recorded] == [(v.name, v.time) for v in views]
    for got, want in zip(recorded, views):
        np.testing.assert_allclose(got.camera.c2w, want.camera.c2w, atol=1e-12)
        assert (got.camera.fx, got.camera.cy, got.camera.width) == (want.camera.fx, want.camera.cy, 64)
    again = path_from_dataset(tmp_path / "trained.safetensors", seconds_per_key=2.0)
    assert [k.scene_time for k in again.keys] == [k.scene_time for k in path.keys]
    save_checkpoint(tmp_path / "imported.safetensors", model)
    with pytest.raises(CameraError, match="records no training cameras"):
        dataset_views(tmp_path / "imported.safetensors")


def test_trajectories_and_time_modes():
    cams = orbit_cameras(8, 64, 48, (0, 0, 0.5), 3.0, elevation=20, fov=40, turns=1)
    assert len(cams) == 8 and all(c.width == 64 for c in cams)
    assert all(np.linalg.norm(c.position - np.array([0, 0, 0.5])) == pytest.approx(3.0) for c in cams)
    spiral = orbit_cameras(8, 64, 48, (0, 0, 0), 3.0, elevation=20, amplitude=15)
    heights = [c.position[2] for c in spiral]
    assert heights[0] == pytest.approx(3.0 * math.sin(math.radians(5)))
    assert max(heights) == pytest.approx(3.0 * math.sin(math.radians(35)))
    fps = 10
    loop = scene_times("loop", 30, fps, (0.0, 1.0), loop_seconds=1.0)
    np.testing.assert_allclose(loop[:12], np.mod(np.arange(12) / 10, 1.0))
    lapse = scene_times("timelapse", 5, fps, (2.0, 4.0))
    np.testing.assert_allclose(lapse, [2.0, 2.5, 3.0, 3.5, 4.0])
    np.testing.assert_allclose(scene_times("hold", 3, fps, (0.0, 1.0), hold=0.25), 0.25)
    path = sample_path()
    n = path_frame_count(path, fps)
    assert n == 41
    along = scene_times("path", n, fps, (0.0, 1.0), path=path)
    assert along[0] == 0.0 and along[15] == pytest.approx(0.5) and along[-1] == pytest.approx(1.0)
    with pytest.raises(CameraError, match="unknown time mode"):
        scene_times("bounce", 3, fps, (0.0, 1.0))


def test_framing_ignores_a_few_floaters():
    """The viewer frames the object, not the floaters a trained model keeps far away; exporters' bounds hold all."""
    import torch

    from splatreel.model import model_bounds, static_gaussians4d
    from splatreel.viewer.trajectory import frame_model

    gen = torch.Generator().manual_seed(0)
    body = torch.rand((2000, 3), generator=gen, dtype=torch.float64) - 0.5  # unit cube at the origin
    floaters = torch.tensor([[40.0, 0.0, 0.0], [0.0, -30.0, 5.0]], dtype=torch.float64)
    means = torch.cat([body, floaters])
    n = means.shape[0]
    model = static_gaussians4d(means, torch.full((n, 3), 0.01, dtype=torch.float64),
                               torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64).expand(n, 4),
                               torch.full((n,), 0.5, dtype=torch.float64), torch.full((n, 3), 0.5, dtype=torch.float64))
    framing = frame_model(model)
    assert np.abs(framing.center).max() < 0.05
    assert 0.8 < framing.radius < 0.9  # half the cube's diagonal, 0.87, less the outermost 0.5% per axis
    lo, hi = model_bounds(model)
    assert float(hi[0]) == pytest.approx(40.0) and float(lo[1]) == pytest.approx(-30.0)


def nerfstudio_path(cameras, seconds: float, times=None, **extra) -> dict:
    """A camera path as nerfstudio writes it (viewer "Export path", Blender add-on): row-major OpenGL c2w."""
    frames = []
    for i, cam in enumerate(cameras):
        frame = {"camera_to_world": cam.to_opengl_c2w().ravel().tolist(), "fov": math.degrees(cam.fov_y),
                 "aspect": cam.width / cam.height}
        if times is not None:
            frame["render_time"] = times[i]
        frames.append(frame)
    return {"camera_type": "perspective", "render_height": cameras[0].height, "render_width": cameras[0].width,
            "seconds": seconds, "smoothness_value": 0.5, "is_cycle": False, "crop": None, "camera_path": frames,
            **extra}


def test_nerfstudio_camera_paths_load_frame_for_frame(tmp_path):
    cams = [orbit(15 + 5 * i, 20 * i, 2.0 + 0.1 * i, fov_deg=35 + i, width=80, height=60) for i in range(6)]
    data = nerfstudio_path(cams, 2.0, times=[i / 5 for i in range(6)])
    data["camera_path"][2]["camera_to_world"] = (cams[2].to_opengl_c2w() @ np.diag([2.0, 2.0, 2.0, 1.0])).tolist()
    f = tmp_path / "ns.json"
    f.write_text(json.dumps(data))
    path = CameraPath.load(f, time_range=(0.0, 10.0))
    assert path.image_size == (80, 60) and path.fps == pytest.approx(3.0)  # 6 frames over 2 s
    assert path_frame_count(path, path.fps) == 6
    for i, cam in enumerate(cams):  # frame i at i / fps; a scaled matrix (Blender object scale) is normalised
        got = path.camera(i / 3.0, 80, 60)
        np.testing.assert_allclose(got.c2w, cam.c2w, atol=1e-9)
        assert got.fy == pytest.approx(cam.fy)
        assert path.scene_time(i / 3.0) == pytest.approx(10.0 * i / 5)  # render_time in [0, 1] -> model time
    assert CameraPath.load(f).scene_time(1.0) == pytest.approx(0.6)  # without a model: as written
    again = tmp_path / "again.json"
    path.save(again)
    assert CameraPath.load(again).image_size == (80, 60) and CameraPath.load(again).fps == pytest.approx(3.0)


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.update(camera_type="fisheye"), "only perspective"),
    (lambda d: d.pop("render_height"), "missing 'render_height'"),
    (lambda d: d["camera_path"][1].update(camera_to_world=(np.diag([1.0, 1.0, -1.0, 1.0])).ravel().tolist()),
     "frame 1: camera_to_world has no proper rotation"),
    (lambda d: d["camera_path"][0].pop("fov"), "frame 0: fov must be a finite number"),
    (lambda d: d.update(seconds=0), "bad seconds or fps"),
])
def test_bad_nerfstudio_paths_raise_one_line_errors(tmp_path, edit, message):
    data = nerfstudio_path([orbit(20, a, 2.0, width=64, height=48) for a in (0, 30)], 1.0)
    edit(data)
    f = tmp_path / "bad.json"
    f.write_text(json.dumps(data))
    with pytest.raises(CameraError, match=message) as exc:
        CameraPath.load(f)
    assert "nerfstudio camera path" in str(exc.value) and "\n" not in str(exc.value)


def test_a_keyframed_path_saves_as_nerfstudio_frames_that_load_back_onto_it(tmp_path):
    """`path_as_nerfstudio` (the app's Save as "nerfstudio frames"): one frame every 1/fps over the path, with its
    scene times; read back, each frame is the path's camera and scene time at that moment."""
    from splatreel.viewer.trajectory import path_as_nerfstudio

    path = sample_path()
    data = path_as_nerfstudio(path, 64, 48, fps=10.0, time_range=(0.0, 2.0))
    assert data["render_width"] == 64 and data["render_height"] == 48
    assert len(data["camera_path"]) == path_frame_count(path, 10.0) == 41  # 4 s at 10 FPS and the last key
    f = tmp_path / "ns.json"
    f.write_text(json.dumps(data))
    back = CameraPath.load(f, time_range=(0.0, 2.0))
    for i in (0, 7, 15, 40):
        want, got = path.camera(i / 10.0, 64, 48), back.camera(i / 10.0, 64, 48)
        np.testing.assert_allclose(got.c2w, want.c2w, atol=1e-9)
        assert got.fy == pytest.approx(want.fy)
        assert back.scene_time(i / 10.0) == pytest.approx(path.scene_time(i / 10.0))
    keyed_size = CameraPath(path.keys, path.up, image_size=(32, 24), fps=5.0)
    data = path_as_nerfstudio(keyed_size, 64, 48)  # the path's own size and fps win
    assert (data["render_width"], data["render_height"], data["fps"]) == (32, 24, 5.0)
    untimed = CameraPath([CameraKey(k.time, k.position, k.quaternion, k.fov) for k in path.keys], path.up)
    assert "render_time" not in path_as_nerfstudio(untimed, 64, 48)["camera_path"][0]


def test_the_app_saves_its_path_in_either_format(tmp_path):
    from splatreel.checkpoint import save_checkpoint
    from splatreel.viewer.state import AppOptions, AppState as ViewerApp
    from splatreel.viewer.renderer import SplatRenderer, headless_context
    from splatreel.viewer.synthetic import synthetic_model

    ckpt = save_checkpoint(tmp_path / "m.safetensors", synthetic_model(100, seed=1))
    app = ViewerApp(ckpt, AppOptions(size=(80, 60)))
    app.renderer = SplatRenderer(headless_context())
    app.load(ckpt)
    pe = app._path
    pe.path, pe.file = sample_path(), str(tmp_path / "p.json")
    assert app._attempt(app._save_path)
    assert json.loads((tmp_path / "p.json").read_text())["format"] == "splatreel-camera-path"
    pe.nerfstudio = True
    assert not app._attempt(app._save_path) and "already exists" in app.status  # no overwrite unless ticked
    pe.overwrite = True
    assert app._attempt(app._save_path)
    data = json.loads((tmp_path / "p.json").read_text())
    assert (data["render_width"], data["render_height"]) == (80, 60) and data["fps"] == 30.0
    assert CameraPath.load(tmp_path / "p.json", app.model.time_range).scene_time(2.0) == pytest.approx(0.6)
    app.renderer.release()
