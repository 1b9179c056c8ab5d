"""Every dataset layout loads a small generated example with correct cameras (a reprojection check), and bad
datasets fail with one clear line.

Each example draws a dark dot where a known 3D point P projects, computed with an independent textbook camera
model (gluLookAt + perspective, or SyncDreamer's published matrices); the loader's `Camera.project(P)` must land
on the dot."""

import json
import math

import cv2
import numpy as np
import pytest

from splatreel.cli import main
from splatreel.errors import DatasetError
from splatreel.datasets import detect_layout
from splatreel.train.data import load_dataset

P_ZUP = np.array([0.3, -0.2, 0.25])
P_YUP = np.array([0.25, 0.3, -0.2])


def gl_look_at_project(eye, target, up, fov_y_deg, w, h, p):
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    d = p - eye
    x, y, z = s @ d, u @ d, -(f @ d)
    t = 1 / math.tan(math.radians(fov_y_deg) / 2)
    ndc = np.array([t * x / -z * h / w, t * y / -z])
    return np.array([(ndc[0] + 1) / 2 * w, (1 - ndc[1]) / 2 * h])


def gl_c2w(eye, target, up):
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = s, u, -f, eye
    return m


def dot_image(w, h, uv, alpha=False):
    img = np.full((h, w, 3), 255, np.uint8)
    # drawn with 4 bits of subpixel precision so the centroid is accurate
    cv2.circle(img, (int(round(uv[0] * 16 - 8)), int(round(uv[1] * 16 - 8))), 3 * 16, (20, 40, 200), -1,
               lineType=cv2.LINE_AA, shift=4)
    if alpha:
        a = (255 - img.min(-1)).astype(np.uint8)
        return np.dstack([img[..., ::-1], a])
    return img[..., ::-1]  # cv2 writes BGR


def centroid(view):
    dark = 255.0 - view.image.astype(np.float32).min(-1) if view.alpha is None else view.alpha.astype(np.float32)
    ys, xs = np.mgrid[: dark.shape[0], : dark.shape[1]]
    return np.array([((xs + 0.5) * dark).sum() / dark.sum(),
                     ((ys + 0.5) * dark).sum() / dark.sum()])


def check_reprojection(ds, p, tol=0.75):
    assert ds.train
    for v in ds.train + ds.test:
        uv, _ = v.camera.project(p[None])
        np.testing.assert_allclose(centroid(v), uv[0], atol=tol, err_msg=v.name)


def make_dnerf(root, w=48, h=40, split_name="test"):
    fov_x = 0.9
    fov_y = math.degrees(2 * math.atan(math.tan(fov_x / 2) * h / w))
    for split in ("train", split_name):
        frames = []
        (root / split).mkdir(parents=True)
        for i, az in enumerate([0, 70, 150, 260]):
            eye = 3.0 * np.array([math.cos(math.radians(az)), math.sin(math.radians(az)), 0.5])
            uv = gl_look_at_project(eye, (0.05, 0, 0.1), np.array([0, 0, 1.0]), fov_y, w, h, P_ZUP)
            cv2.imwrite(str(root / split / f"r_{i:03d}.png"), dot_image(w, h, uv, alpha=True))
            frames.append({"file_path": f"./{split}/r_{i:03d}", "time": i / 3,
                           "transform_matrix": gl_c2w(eye, (0.05, 0, 0.1), np.array([0, 0, 1.0])).tolist()})
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": fov_x, "frames": frames}))


def test_dnerf_layout(tmp_path):
    make_dnerf(tmp_path)
    ds = load_dataset(tmp_path)
    assert ds.layout == "dnerf" and len(ds.train) == 4 and len(ds.test) == 4
    # RGBA D-NeRF data composites on white, the layout's convention (D-NeRF's configs, 4DGaussians)
    assert ds.train[0].alpha is not None and ds.background == (1.0, 1.0, 1.0)
    assert "D-NeRF" in ds.background_reason
    assert ds.time_range == (0.0, 1.0)
    check_reprojection(ds, P_ZUP)



@pytest.mark.parametrize("sizes_in_json", [False, True])
def test_trainer_and_viewer_read_the_same_dnerf_cameras(tmp_path, sizes_in_json):
    """One D-NeRF reader: the trainer's views and the viewer's dataset cameras agree on poses, intrinsics, image
    sizes (from the images when the JSON has no w/h) and times, for every split."""
    from splatreel.viewer.camera_path import dataset_views

    make_dnerf(tmp_path)
    if sizes_in_json:
        for split in ("train", "test"):
            f = tmp_path / f"transforms_{split}.json"
            f.write_text(json.dumps({**json.loads(f.read_text()), "w": 48, "h": 40}))
    ds = load_dataset(tmp_path)
    for split, trained in (("train", ds.train), ("test", ds.test)):
        viewed = dataset_views(tmp_path, split)
        assert len(viewed) == len(trained) == 4
        for t, v in zip(trained, viewed):
            assert (v.camera.width, v.camera.height) == (t.camera.width, t.camera.height) == (48, 40)
            np.testing.assert_allclose(v.camera.c2w, t.camera.c2w, atol=1e-12)
            assert (v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy) == \
                (t.camera.fx, t.camera.fy, t.camera.cx, t.camera.cy)
            assert v.time == t.time and t.name.endswith(v.name.lstrip("./") + ".png")


def test_dnerf_writer_and_reader_round_trip(tmp_path):
    """`transforms_for` + `write_transforms` (what `splatreel sample` writes) read back by `read_transforms`: the
    same poses, intrinsics, sizes and times, and the image path with the .png the JSON leaves out."""
    from types import SimpleNamespace

    from splatreel.cameras import orbit
    from splatreel.datasets.dnerf import read_transforms, transforms_for, write_transforms

    cams = [orbit(20, a, 2.5, fov_deg=40, width=64, height=48, up="z") for a in (0, 90, 200)]
    views = [SimpleNamespace(file_path=f"./train/r_{i:03d}", time=t, camera=c)
             for i, (c, t) in enumerate(zip(cams, (0.0, 0.5, 1.0)))]
    write_transforms(tmp_path / "transforms_train.json", transforms_for(views, cams[0]))
    frames, _ = read_transforms(tmp_path / "transforms_train.json")
    assert [f.time for f in frames] == [0.0, 0.5, 1.0] and all(f.size_declared for f in frames)
    for f, v in zip(frames, views):
        assert f.image == (tmp_path / "train" / f"{v.file_path[8:]}.png").resolve()
        np.testing.assert_allclose(f.camera.c2w, v.camera.c2w, atol=1e-9)
        assert (f.camera.width, f.camera.height) == (64, 48)
        np.testing.assert_allclose([f.camera.fx, f.camera.fy, f.camera.cx, f.camera.cy],
                                   [v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy], rtol=1e-9)

@pytest.mark.parametrize("declared, expected", [([0, 0, 0], (0.0, 0.0, 0.0)), ("black", (0.0, 0.0, 0.0)),
                                                ([0.5, 0.25, 1], (0.5, 0.25, 1.0)), ("White", (1.0, 1.0, 1.0))])
def test_dnerf_background_from_json_and_override(tmp_path, declared, expected):
    make_dnerf(tmp_path)
    meta = json.loads((tmp_path / "transforms_train.json").read_text())
    (tmp_path / "transforms_train.json").write_text(json.dumps({**meta, "background": declared}))
    ds = load_dataset(tmp_path)
    assert ds.background == expected and "transforms_train.json" in ds.background_reason
    ds = load_dataset(tmp_path, background=(0.2, 0.3, 0.4))  # the user's --background wins over the JSON
    assert ds.background == (0.2, 0.3, 0.4) and ds.background_reason == "--background"


@pytest.mark.parametrize("declared", [[1, 1], [0, 0, 2], "grey", [0, "x", 0], None])
def test_bad_background_in_json_is_one_line(tmp_path, declared, capsys):
    make_dnerf(tmp_path)
    meta = json.loads((tmp_path / "transforms_train.json").read_text())
    if declared is None:  # null: the key present but empty is no declaration
        (tmp_path / "transforms_train.json").write_text(json.dumps({**meta, "background": None}))
        assert load_dataset(tmp_path).background == (1.0, 1.0, 1.0)
        return
    (tmp_path / "transforms_train.json").write_text(json.dumps({**meta, "background": declared}))
    with pytest.raises(DatasetError, match="'background' must be"):
        load_dataset(tmp_path)
    assert main(["train", str(tmp_path), "--out", str(tmp_path / "m.safetensors")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'background' must be" in err


def test_dnerf_val_split_and_per_frame_intrinsics(tmp_path):
    make_dnerf(tmp_path, split_name="val")
    assert load_dataset(tmp_path).meta["test_split"] == "val"
    # explicit intrinsics override camera_angle_x: move the principal point and check the projection follows
    meta = json.loads((tmp_path / "transforms_train.json").read_text())
    for fr in meta["frames"]:
        fr.update({"fl_x": 100.0, "fl_y": 90.0, "cx": 20.0, "cy": 22.0, "w": 48, "h": 40})
    (tmp_path / "transforms_train.json").write_text(json.dumps(meta))
    cam = load_dataset(tmp_path).train[0].camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (100.0, 90.0, 20.0, 22.0)


def test_orbit_layout(tmp_path):
    views = [{"elevation": 20, "azimuth": 0}, {"elevation": -10, "azimuth": 100}, {"elevation": 45, "azimuth": 230}]
    (tmp_path / "cameras.json").write_text(json.dumps({"up": "y", "radius": 2.2, "fov": 40, "views": views}))
    for v, spec in enumerate(views):
        e, a = math.radians(spec["elevation"]), math.radians(spec["azimuth"])
        eye = 2.2 * np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
        uv = gl_look_at_project(eye, (0, 0, 0), np.array([0, 1.0, 0]), 40, 32, 32, P_YUP)
        (tmp_path / "views" / str(v)).mkdir(parents=True)
        for f in range(3):
            cv2.imwrite(str(tmp_path / "views" / str(v) / f"{f:02d}.png"), dot_image(32, 32, uv))
    ds = load_dataset(tmp_path)
    assert ds.layout == "orbit" and len(ds.train) == 9 and ds.background == (1.0, 1.0, 1.0)
    assert ds.background_reason == "RGB images generated on white"
    assert sorted({v.time for v in ds.train}) == [0.0, 0.5, 1.0]
    assert ds.train[0].alpha is not None  # mask derived from the white background
    check_reprojection(ds, P_YUP)


def test_efficient4d_layout(tmp_path):
    # SyncDreamer's published view-0 camera (OpenCV w2c) and K = 280 px at 256, checked independently
    r0 = np.array([[0, 1, 0], [0.5, 0, -math.sqrt(3) / 2], [-math.sqrt(3) / 2, 0, -0.5]])
    t0 = np.array([0, 0, 1.5])
    p = r0 @ P_ZUP + t0
    s = 64  # tiles of 64 px: K scales to 70
    uv0 = np.array([70 * p[0] / p[2] + 32, 70 * p[1] / p[2] + 32])
    strips = []
    for f in range(4):
        tiles = []
        for v in range(16):
            a = math.radians(22.5 * v)
            eye = 1.5 * np.array([math.cos(math.radians(30)) * math.cos(a), math.cos(math.radians(30)) * math.sin(a), 0.5])
            uv = gl_look_at_project(eye, (0, 0, 0), np.array([0, 0, 1.0]), 2 * math.degrees(math.atan(32 / 70)), s, s, P_ZUP)
            if v == 0:
                np.testing.assert_allclose(uv, uv0, atol=1e-6)  # our textbook model agrees with SyncDreamer's
            tiles.append(dot_image(s, s, uv))
        strips.append(np.concatenate(tiles, 1))
        cv2.imwrite(str(tmp_path / f"{f}.png"), strips[-1])
    (tmp_path / "ref").mkdir()
    uv = gl_look_at_project(np.array([1.5, 0, 0]), (0, 0, 0), np.array([0, 0, 1.0]), 2 * math.degrees(math.atan(32 / 70)), s, s, P_ZUP)
    for f in range(4):
        cv2.imwrite(str(tmp_path / "ref" / f"{f}.png"), dot_image(s, s, uv, alpha=True))
    ds = load_dataset(tmp_path)
    assert ds.layout == "efficient4d" and len(ds.train) == 4 * 17 and ds.background == (1.0, 1.0, 1.0)
    check_reprojection(ds, P_ZUP)


def write_video(path, frames):
    import av

    with av.open(str(path), "w") as c:
        st = c.add_stream("libx264", rate=10)
        st.width, st.height, st.pix_fmt = frames[0].shape[1], frames[0].shape[0], "yuv420p"
        st.options = {"crf": "10"}
        for fr in frames:
            for pkt in st.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(fr), format="rgb24")):
                c.mux(pkt)
        for pkt in st.encode():
            c.mux(pkt)


def test_sv4d_layout(tmp_path):
    az = [0.0, 34.29, 85.71, 120.0, 154.29, 205.71, 240.0, 274.29, 325.71]
    s = 64
    for v, a in enumerate(az):
        e, ar = math.radians(10), math.radians(a)
        eye = 2.0 * np.array([math.cos(e) * math.sin(ar), math.sin(e), math.cos(e) * math.cos(ar)])
        uv = gl_look_at_project(eye, (0, 0, 0), np.array([0, 1.0, 0]), 33.8, s, s, P_YUP)
        frames = [dot_image(s, s, uv)[..., ::-1] for _ in range(5)]  # RGB for the encoder
        name = "000000_process_input.mp4" if v == 0 else f"000000_v{v:03d}.mp4"
        write_video(tmp_path / name, frames)
    write_video(tmp_path / "000000_t000.mp4", [np.full((s, s, 3), 255, np.uint8)] * 9)
    ds = load_dataset(tmp_path)
    assert ds.layout == "sv4d" and ds.meta["variant"] == "sv4d" and len(ds.train) == 45
    assert ds.time_range == (0.0, 1.0)
    check_reprojection(ds, P_YUP, tol=1.0)


def test_downscale_keeps_cameras_consistent(tmp_path):
    make_dnerf(tmp_path, w=48, h=40)
    ds = load_dataset(tmp_path, downscale=2)
    assert ds.train[0].size == (24, 20)
    check_reprojection(ds, P_ZUP, tol=0.6)


@pytest.mark.parametrize("case", ["empty", "missing_frame", "mismatched", "nan_pose", "bad_json", "not_a_dir"])
def test_bad_datasets_fail_clearly(tmp_path, case, capsys):
    root = tmp_path / "ds"
    root.mkdir()
    expected = {"empty": "not a dataset", "missing_frame": "missing image", "mismatched": "different sizes",
                "nan_pose": "NaN", "bad_json": "not valid JSON", "not_a_dir": "expected a dataset folder"}[case]
    if case != "empty":
        make_dnerf(root)
    if case == "missing_frame":
        (root / "train" / "r_002.png").unlink()
    elif case == "mismatched":
        cv2.imwrite(str(root / "train" / "r_001.png"), np.zeros((10, 12, 4), np.uint8))
    elif case == "nan_pose":
        meta = json.loads((root / "transforms_train.json").read_text())
        meta["frames"][1]["transform_matrix"][0][3] = float("nan")
        (root / "transforms_train.json").write_text(json.dumps(meta))
    elif case == "bad_json":
        (root / "transforms_train.json").write_text("{not json")
    elif case == "not_a_dir":
        root = tmp_path / "file.txt"
        root.write_text("x")
    with pytest.raises(DatasetError, match=expected):
        load_dataset(root)
    capsys.readouterr()
    # the training command reports the same thing on one line
    assert main(["train", str(root), "--out", str(tmp_path / "m.safetensors")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expected in err


def test_detect_layout_names_what_it_looked_for(tmp_path):
    with pytest.raises(DatasetError, match="transforms_train.json"):
        detect_layout(tmp_path)
