"""The desktop app under Xvfb: it starts, draws frames, plays time, and its screenshot is neither empty nor
different from the headless (EGL) render of the same view."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from splatreel.cameras import orbit
from splatreel.checkpoint import load_checkpoint, save_checkpoint
from splatreel.samples import trained_checkpoint
from splatreel.train import losses
from splatreel.viewer.app_data import camera_from_json
from splatreel.viewer.camera_path import CameraKey, CameraPath
from splatreel.viewer.renderer import RenderSettings, render_image
from splatreel.viewer.synthetic import synthetic_model


@pytest.fixture(scope="module")
def display():
    """A private Xvfb server on a free display number (started here, stopped after the module)."""
    xvfb = shutil.which("Xvfb")
    assert xvfb, "Xvfb is not installed (apt-get install -y xvfb)"
    for n in range(97, 200):
        if not (Path(f"/tmp/.X{n}-lock").exists() or Path(f"/tmp/.X11-unix/X{n}").exists()):
            break
    proc = subprocess.Popen([xvfb, f":{n}", "-screen", "0", "640x480x24", "-nolisten", "tcp"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 10.0
    while not Path(f"/tmp/.X11-unix/X{n}").exists():
        assert proc.poll() is None and time.monotonic() < deadline, "Xvfb did not start"
        time.sleep(0.05)
    yield f":{n}"
    proc.terminate()
    proc.wait(timeout=10)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("app")
    model = synthetic_model(3000, seed=11, sh_degree=1, radius=0.4, scale=0.02, speed=0.3)
    ckpt = save_checkpoint(root / "model.safetensors", model, background=(1.0, 1.0, 1.0))
    cams = [orbit(20, a, 2.0, fov_deg=40, width=64, height=64) for a in (0, 90)]
    frames = [{"file_path": f"./train/r_{i}", "time": 0.5 * i, "transform_matrix": c.to_opengl_c2w().tolist()}
              for i, c in enumerate(cams)]
    (root / "transforms_train.json").write_text(json.dumps({"camera_angle_x": cams[0].fov_x, "w": 64, "h": 64,
                                                            "frames": frames}))
    CameraPath([CameraKey.from_camera(0.0, cams[0], 0.0), CameraKey.from_camera(1.0, cams[1], 1.0)]).save(
        root / "path.json")
    return root, model, ckpt


def run_view(display: str, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "DISPLAY": display}
    return subprocess.run([sys.executable, "-m", "splatreel", "view", *args], env=env, capture_output=True, text=True,
                          timeout=120)


def view_report(display: str, ckpt, tmp_path, *args: str) -> dict:
    """The ``--report`` of a 160x120 window paused at t = 0.5 for 2 frames, with `args` added."""
    report_path = tmp_path / "report.json"
    proc = run_view(display, str(ckpt), "--size", "160x120", "--paused", "--time", "0.5", *args, "--exit-after", "2",
                    "--report", str(report_path))
    assert proc.returncode == 0, proc.stderr
    return json.loads(report_path.read_text())


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """`splatreel.train.losses.psnr` (the project's one PSNR) on numpy images."""
    return losses.psnr(torch.from_numpy(np.asarray(a, np.float64)), torch.from_numpy(np.asarray(b, np.float64)))


def headless_of(report: dict, model) -> np.ndarray:
    """The EGL render of the view a screenshot recorded, quantised like the window's 8-bit framebuffer."""
    shot = report["screenshot"]
    c = shot["camera"]
    cam = camera_from_json(c)
    img = render_image(model, cam, shot["time"], RenderSettings(mode=shot["mode"], background=shot["background"],
                                                                splat_scale=shot["splat_scale"],
                                                                max_std_dev=shot["max_std_dev"],
                                                                max_screen_radius=shot["max_screen_radius"],
                                                                near_plane=shot["near_plane"],
                                                                temporal_fade=shot["temporal_fade"]))
    return np.round(np.clip(img[..., :3], 0, 1) * 255) / 255


def read_shot(path) -> np.ndarray:
    return cv2.imread(str(path))[..., ::-1].astype(np.float64) / 255


def test_app_draws_plays_and_screenshots_like_headless(display, files):
    root, model, ckpt = files
    shot, report_path = root / "shot.png", root / "report.json"
    # (a budget every frame meets: the playing frames stay at the render scale however loaded the host is)
    proc = run_view(display, str(ckpt), "--size", "200x150", "--exit-after", "12", "--screenshot", str(shot),
                    "--report", str(report_path), "--cameras", str(root), "--path", str(root / "path.json"),
                    "--render-scale", "0.5", "--frame-budget", "10000")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(report_path.read_text())
    assert report["frames"] == 12
    assert report["resolutions"] == [0.5, 1.0]  # frames at half resolution, the screenshot at full
    assert report["overlay_lines"] == 24 + 4 * 9  # the 2-key path's polyline, 2 key and 2 dataset frustums
    assert report["time_end"] != report["time_start"]  # time played
    assert report["sorts"] >= 1
    img = read_shot(shot)
    assert img.shape == (150, 200, 3)
    background = np.all(img > 0.99, axis=-1)
    assert 0.02 < (~background).mean() < 0.9 and img.std() > 0.05  # neither empty nor all splat
    assert psnr(img, headless_of(report, model)) >= 40.0


def test_playback_lowers_the_resolution_to_fit_the_frame_budget_unless_kept_sharp(display, files, tmp_path):
    """A still camera while the animation plays: with a frame budget no frame can meet, the playing frames are
    drawn below full resolution (`Resolution.sharp_playback`), with ``--sharp-playback`` at full resolution; paused,
    at full resolution (the depth-view test below)."""
    _, _, ckpt = files
    reports = []
    for extra in ([], ["--sharp-playback"]):
        report_path = tmp_path / "report.json"
        proc = run_view(display, str(ckpt), "--size", "160x120", "--frame-budget", "0.001", "--exit-after", "6",
                        "--report", str(report_path), *extra)
        assert proc.returncode == 0, proc.stderr
        reports.append(json.loads(report_path.read_text()))
    playing, sharp = reports
    assert playing["time_end"] != playing["time_start"] and playing["moving_frames"] == 0
    assert min(playing["resolutions"]) < 1.0
    assert sharp["time_end"] != sharp["time_start"] and sharp["resolutions"] == [1.0]


def test_app_draws_with_the_footprint_caps_like_headless(display, tmp_path):
    """``view --max-std-dev --max-screen-radius``: the window draws the capped splats (its screenshot is the
    headless render with the same caps, and not the uncapped one)."""
    model = load_checkpoint(trained_checkpoint("spinner")).model
    shot, report_path = tmp_path / "capped.png", tmp_path / "report.json"
    proc = run_view(display, "--size", "120x90", "--exit-after", "3", "--paused", "--time", "0.25",
                    "--max-std-dev", "1.5", "--max-screen-radius", "0.04", "--temporal-fade", "smooth",
                    "--screenshot", str(shot),
                    "--report", str(report_path))
    assert proc.returncode == 0, proc.stderr
    report = json.loads(report_path.read_text())
    assert (report["screenshot"]["max_std_dev"], report["screenshot"]["max_screen_radius"]) == (1.5, 0.04)
    assert report["screenshot"]["temporal_fade"] == "smooth"
    img = read_shot(shot)
    same = psnr(img, headless_of(report, model))
    uncapped = dict(report["screenshot"], max_std_dev=None, max_screen_radius=None, temporal_fade="cut")
    assert same >= 40.0 and psnr(img, headless_of({"screenshot": uncapped}, model)) < 38.0  # below "the same image"


def test_app_opens_the_bundled_sample_paused_in_depth_view_and_needs_a_display(display, files, tmp_path):
    root, _, ckpt = files
    model = load_checkpoint(trained_checkpoint("spinner")).model
    shot, report_path = tmp_path / "depth.png", tmp_path / "report.json"
    proc = run_view(display, "--size", "120x90", "--exit-after", "3", "--paused", "--time", "0.25",
                    "--mode", "depth", "--screenshot", str(shot), "--report", str(report_path))
    assert proc.returncode == 0, proc.stderr
    report = json.loads(report_path.read_text())
    assert report["time_start"] == report["time_end"] == 0.25
    assert report["resolutions"] == [1.0]  # the view did not move: full resolution
    assert report["moving_frames"] == 0
    assert read_shot(shot).std() > 0.05  # the spinner is in view
    assert psnr(read_shot(shot), headless_of(report, model)) >= 40.0
    # an existing screenshot is not overwritten, and no display is a one-line error
    again = run_view(display, str(ckpt), "--exit-after", "1", "--screenshot", str(shot))
    assert again.returncode == 1 and "already exists" in again.stderr
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    headless = subprocess.run([sys.executable, "-m", "splatreel", "view", str(ckpt), "--exit-after", "1"], env=env,
                              capture_output=True, text=True, timeout=60)
    assert headless.returncode == 1
    assert headless.stderr.strip().startswith("splatreel view: error:") and "Traceback" not in headless.stderr


def test_app_plays_a_camera_path_from_the_start_and_sees_the_view_move(display, files, tmp_path):
    root, model, _ = files
    report_path = tmp_path / "report.json"
    ckpt = str(root / "model.safetensors")
    proc = run_view(display, ckpt, "--size", "160x120", "--exit-after", "6", "--path", str(root / "path.json"),
                    "--play-path", "--paused", "--report", str(report_path))
    assert proc.returncode == 0, proc.stderr
    report = json.loads(report_path.read_text())
    # the path's camera moves every frame after the first (6 frames of at most 0.1 s each stay inside its 1 s),
    # and the path's scene times drive the model time although playback was paused
    assert report["moving_frames"] == 5
    assert report["time_end"] != report["time_start"]
    bad = run_view(display, ckpt, "--play-path", "--exit-after", "1")
    assert bad.returncode == 1 and "--play-path needs --path" in bad.stderr and "Traceback" not in bad.stderr


def test_app_crop_box_shows_what_save_edited_writes(display, files, tmp_path):
    """``view --crop`` starts with the crop box on: the window shows exactly the cropped model (the headless render
    of `crop(model, box)`), draws the box's 12 edges, and "Save edited" writes those Gaussians with the box in
    the provenance (refusing to overwrite unless asked)."""
    from splatreel.model import CropBox, crop
    from splatreel.viewer.state import AppOptions, AppState
    from splatreel.viewer.renderer import SplatRenderer, headless_context

    root, model, ckpt = files
    box = [-0.4, -0.4, -0.4, 0.05, 0.4, 0.4]
    cropped = crop(model, CropBox.of(box))
    assert 0 < len(cropped) < len(model)
    shot, report_path = tmp_path / "crop.png", tmp_path / "report.json"
    proc = run_view(display, str(ckpt), "--size", "160x120", "--exit-after", "3", "--paused", "--screenshot",
                    str(shot), "--report", str(report_path), "--crop", *map(str, box))
    assert proc.returncode == 0, proc.stderr
    report = json.loads(report_path.read_text())
    assert report["shown_gaussians"] == len(cropped)
    assert report["overlay_lines"] == 12
    img = read_shot(shot)
    assert psnr(img, headless_of(report, cropped)) >= 40.0
    assert psnr(img, headless_of(report, model)) < 35.0  # and not the whole model
    missed = run_view(display, str(ckpt), "--exit-after", "1", "--crop", "5", "5", "5", "6", "6", "6")
    assert missed.returncode == 1 and "holds none" in missed.stderr and "Traceback" not in missed.stderr

    app = AppState(ckpt, AppOptions(play=False))  # the panel's save action, on a headless renderer
    app.renderer = SplatRenderer(headless_context())
    app.load(str(ckpt))
    app._editor.file = str(tmp_path / "cropped.safetensors")
    assert not app._attempt(app._save_edited) and "nothing to save" in app.status
    app._crop.enabled, app._crop.lo, app._crop.hi = True, box[:3], box[3:]
    app._apply_crop_edits()
    assert app._crop.shown == CropBox.of(box) and len(app.renderer.model) == len(cropped)
    assert app._attempt(app._save_edited)
    saved = load_checkpoint(app._editor.file)
    torch.testing.assert_close(saved.model.means, cropped.means, rtol=0, atol=0)
    assert saved.provenance["crop"] == {"box": box, "kept": len(cropped), "of": len(model)}
    assert "deleted" not in saved.provenance
    assert saved.background == app.checkpoint.background
    assert not app._attempt(app._save_edited) and "already exists" in app.status
    app._editor.overwrite = True
    assert app._attempt(app._save_edited)
    app.renderer.release()


def test_frame_stepping_visits_keyframes_else_dataset_frame_times(files):
    """The app's frame steps (arrow keys and buttons) go to a keyframed model's keys, else to the frame times of the
    dataset cameras it shows, else by one 30 FPS playback frame. `load` sets them; no window is needed for that."""
    from splatreel.viewer.state import AppOptions, AppState
    from splatreel.viewer.camera_path import dataset_views
    from splatreel.viewer.renderer import SplatRenderer, headless_context
    from test_model import keyframed

    root, model, ckpt = files
    app = AppState(ckpt, AppOptions(play=False, cameras=str(root)))
    app.renderer = SplatRenderer(headless_context())
    app._views = dataset_views(root, "train")  # as `run` does for --cameras, before the model loads
    app.load(ckpt)
    assert app.playback.frame_times == (0.0, 0.5)  # the two dataset cameras' times
    app.playback.time = 0.2
    assert app.playback.step(1) == 0.5 and app.playback.step(-1) == 0.0
    keyed = keyframed()  # keys at 0, 0.5, 2
    app.load(save_checkpoint(root / "keyed.safetensors", keyed, force=True))
    assert app.playback.frame_times == (0.0, 0.5, 2.0)
    app.playback.time = 0.6
    assert app.playback.step(1) == 2.0 and app.playback.step(-1) == 0.5
    app.options.cameras = None  # and the checkpoint names no training dataset: no cameras
    app.load(ckpt)  # native, no cameras: one 30 FPS frame of playback
    app.playback.time = 0.5
    t0, t1 = model.time_range
    step = (t1 - t0) / (30 * app.playback.loop_seconds)
    assert app.playback.frame_times == () and abs(app.playback.step(1) - (0.5 + step)) < 1e-9
    app.renderer.release()


def test_app_inspects_a_pixel_given_on_the_command_line(display, files, tmp_path):
    """``view --inspect X,Y`` (a Ctrl+click at start-up): the report lists the Gaussians that make that pixel, the
    same ones, weights and alpha as a headless pick of the same view; the inspected Gaussian's 2-sigma ellipsoid
    (3 rings of 48 segments) is drawn; a pixel outside the window is a one-line error."""
    from splatreel.viewer.renderer import SplatRenderer, headless_context

    root, model, ckpt = files
    report = view_report(display, ckpt, tmp_path, "--inspect", "80,60")
    got = report["inspected"]
    assert got["pixel"] == [80, 60] and got["time"] == 0.5 and got["gaussians"] > 1
    c = got["camera"]
    cam = camera_from_json(c)
    r = SplatRenderer(headless_context(), model)
    want = r.pick(cam, 0.5, 80, 60)
    r.release()
    assert [h["index"] for h in got["hits"]] == [h.index for h in want.hits]
    np.testing.assert_allclose([h["weight"] for h in got["hits"]], [h.weight for h in want.hits], atol=1e-6)
    assert got["top"]["index"] == want.top.index and abs(got["alpha"] - want.alpha) < 1e-6
    assert got["top"]["attributes"]["index"].startswith(f"{want.top.index:,} of")
    assert report["overlay_lines"] == 3 * 48
    bad = run_view(display, str(ckpt), "--size", "160x120", "--inspect", "160,10", "--exit-after", "1")
    assert bad.returncode == 1 and "outside the 160x120 window" in bad.stderr and "Traceback" not in bad.stderr


def test_app_selects_the_gaussians_in_a_rectangle_given_on_the_command_line(display, files, tmp_path):
    """``view --select X0,Y0,X1,Y1`` (a Shift+drag at start-up): the report counts the Gaussians whose centre shows
    in that rectangle, as `selection.in_rect` finds them headless for the same view, and a cross is drawn on each;
    a malformed rectangle is a one-line error."""
    from splatreel.viewer.selection import in_rect
    from splatreel.viewer.sorting import depth_order
    from splatreel.viewer.splats import to_arrays

    root, model, ckpt = files
    report = view_report(display, ckpt, tmp_path, "--select", "90,100,20,10")
    sel = report["selection"]
    c = sel["camera"]
    cam = camera_from_json(c)
    assert (c["width"], c["height"], sel["time"]) == (160, 120, 0.5)
    want = in_rect(depth_order(to_arrays(model), cam, 0.5), (20, 10, 90, 100))
    assert 100 < len(want) < len(model)
    assert report["selected"] == sel["caught"] == len(want)
    assert report["markers"] == len(want) and report["overlay_lines"] == 3 * len(want)
    bad = run_view(display, str(ckpt), "--select", "1,2,3", "--exit-after", "1")
    assert bad.returncode == 2 and "rectangle must be 4" in bad.stderr and "Traceback" not in bad.stderr


def test_the_app_snaps_to_the_cameras_a_checkpoint_records(tmp_path):
    """A model trained by splatreel carries its training cameras: the app offers them (any layout, dataset gone);
    without them it falls back on the recorded dataset folder, and on nothing when that is gone too."""
    from splatreel.cameras import DatasetView
    from splatreel.viewer.state import AppState

    model = synthetic_model(20, seed=0)
    views = [DatasetView(f"v{i}", orbit(20, 90 * i, 3.0, fov_deg=40, width=64, height=48), 0.25 * i)
             for i in range(3)]
    from splatreel.viewer.state import AppOptions
    from splatreel.viewer.renderer import SplatRenderer, headless_context

    trained = save_checkpoint(tmp_path / "trained.safetensors", model, views=views,
                              training={"dataset": str(tmp_path / "gone")})
    app = AppState(trained, AppOptions(play=False))
    app.renderer = SplatRenderer(headless_context())
    app.load(str(trained))  # as the window does: the recorded cameras become the dataset cameras
    assert [(v.name, v.time) for v in app._views] == [(v.name, v.time) for v in views]
    np.testing.assert_array_equal(app._views[1].camera.c2w, views[1].camera.c2w)
    assert app.playback.frame_times == (0.0, 0.25, 0.5)  # and frame steps visit their times
    old = save_checkpoint(tmp_path / "old.safetensors", model, training={"dataset": str(tmp_path / "gone")})
    assert AppState._training_views(load_checkpoint(old)) == []
    app.load(str(old))
    assert app._views == [] and app.playback.frame_times == ()
    app.renderer.release()


@pytest.mark.parametrize("extra, message", [
    (["--select", "500,500,600,600"], "lies outside the 160x120 window"),
    (["--no-adaptive-resolution", "--sharp-playback"], "--no-adaptive-resolution turns off"),
    (["--no-adaptive-resolution", "--frame-budget", "20"], "--no-adaptive-resolution turns off"),
])
def test_view_options_that_cannot_apply_are_one_line_errors_before_any_window(capsys, extra, message):
    from splatreel.cli import main

    assert main(["view", "--size", "160x120", *extra]) == 1
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err


def test_the_window_title_names_the_file_and_show_box_draws_the_box_before_it_crops(tmp_path):
    from splatreel.viewer.frames import FramePlanner
    from splatreel.viewer.renderer import SplatRenderer, headless_context
    from splatreel.viewer.state import AppOptions, AppState

    model = synthetic_model(20, seed=0)
    ckpt = save_checkpoint(tmp_path / "walker.safetensors", model)
    app = AppState(str(ckpt), AppOptions(play=False))
    assert app.title == "splatreel"  # nothing open yet
    app.renderer = SplatRenderer(headless_context())
    app.load(str(ckpt))
    assert app.title == "walker.safetensors - splatreel" and app.report["title"] == app.title
    planner = FramePlanner(app)
    try:
        view = orbit(4, 30, 3.0, fov_deg=40, width=64, height=48)
        assert len(planner.overlay_lines(view)[0]) == 0  # box hidden by default
        app._crop.show = True  # "show box" ticked while "crop to box" is off: the box is placed, nothing cropped
        assert not app._crop.enabled and len(planner.overlay_lines(view)[0]) == 12
        assert len(app.renderer.model) == len(model)
    finally:
        planner.close()
        app.renderer.release()


def test_the_status_line_wraps_long_paths_inside_the_panel():
    from splatreel.viewer.app_data import wrap_text

    width = 30  # characters, with one character one unit wide
    status = ("error: /very/long/folder/name/that/does/not/fit/in/the/panel/model.safetensors: no such file or "
              "folder")
    lines = wrap_text(status, width, len)
    assert all(len(line) <= width for line in lines) and len(lines) >= 4
    assert "".join(lines).replace(" ", "") == status.replace(" ", "")  # nothing lost
    assert lines[1].endswith("/")  # the path breaks after a '/'
    assert wrap_text("short status", width, len) == ["short status"]
    assert wrap_text("x" * 70, width, len) == ["x" * 30, "x" * 30, "x" * 10]  # no '/': anywhere
