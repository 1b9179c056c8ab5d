"""Headless rendering: ``splatreel render`` to mp4 / mov / webm / EXR / PNG, compositing and alpha, render modes,
errors."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import av
import cv2
import numpy as np
import OpenImageIO as oiio
import pytest
import torch

from splatreel.cameras import orbit
from splatreel.checkpoint import save_checkpoint
from splatreel.colorspace import premultiplied_to_linear, srgb_to_linear
from splatreel.cli import main
from splatreel.constants import TRANSMITTANCE_THRESHOLD
from splatreel.viewer.renderer import RENDER_MODES, RenderSettings, SplatRenderer, headless_context, render_image
from splatreel.viewer.synthetic import synthetic_model


@pytest.fixture(scope="module")
def model():
    return synthetic_model(4000, seed=1, sh_degree=1, sh_degree_t=1, radius=0.4, scale=0.02)


@pytest.fixture(scope="module")
def ckpt(model, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("ckpt") / "model.safetensors"
    save_checkpoint(path, model, background=(1.0, 1.0, 1.0))
    return path


def test_mp4_decodes_with_expected_frames_size_and_fps(ckpt, tmp_path, capsys):
    out = tmp_path / "orbit.mp4"
    assert main(["render", str(ckpt), "--out", str(out), "--size", "96x64", "--fps", "12", "--frame-count", "7",
                 "--trajectory", "spiral", "--quiet"]) == 0
    assert "wrote" in capsys.readouterr().out
    with av.open(str(out)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264"
        assert (stream.width, stream.height) == (96, 64)
        assert stream.average_rate == 12
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(stream)]
    assert len(frames) == 7
    assert all(f.shape == (64, 96, 3) for f in frames)
    # white background from the checkpoint, the object in the middle, and the camera moves
    assert frames[0][0, 0].min() > 240 and frames[0][32, 48].max() < 235
    assert np.abs(frames[0].astype(int) - frames[3].astype(int)).mean() > 1.0


def test_exr_keeps_alpha(ckpt, tmp_path):
    out = tmp_path / "still.exr"
    assert main(["render", str(ckpt), "--out", str(out), "--size", "64x48", "--frame-count", "1",
                 "--background", "transparent", "--time", "0.5", "--quiet"]) == 0
    img = oiio.ImageInput.open(str(out))
    spec = img.spec()
    data = img.read_image("float")
    img.close()
    assert spec.nchannels == 4 and list(spec.channelnames) == ["R", "G", "B", "A"]
    alpha = data[..., 3]
    assert alpha[0, 0] == 0.0 and alpha.max() > 0.9  # transparent corners, opaque object
    assert 0.05 < (alpha > 0.5).mean() < 0.9
    # premultiplied: no colour where there is no coverage
    assert np.abs(data[..., :3][alpha == 0]).max() == 0.0
    # scene-linear light: the same frame's PNG (sRGB-encoded, straight alpha), decoded, times alpha
    png = tmp_path / "still.png"
    assert main(["render", str(ckpt), "--out", str(png), "--size", "64x48", "--background", "transparent",
                 "--time", "0.5", "--quiet"]) == 0
    straight = cv2.cvtColor(cv2.imread(str(png), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGRA2RGBA) / 255.0
    assert np.abs(straight[..., 3] - alpha).max() <= 0.5 / 255 + 1e-3  # alpha unchanged
    linearised = srgb_to_linear(straight[..., :3]) * alpha[..., None]
    assert np.abs(data[..., :3] - linearised).max() < 5e-3  # one 8-bit step of the PNG, in linear light
    mid = (alpha > 0.99) & (straight[..., :3].max(-1) > 0.2)
    assert (data[..., :3][mid] < straight[..., :3][mid] - 0.02).any()  # really decoded: darker than the PNG


def test_png_sequence_with_alpha_and_no_overwrite(ckpt, tmp_path, capsys):
    out = tmp_path / "frames"
    args = ["render", str(ckpt), "--out", str(out), "--size", "40x30", "--frame-count", "3", "--background",
            "transparent", "--time-mode", "timelapse", "--quiet"]
    assert main(args) == 0
    files = sorted(out.iterdir())
    assert [f.name for f in files] == ["frame_00000.png", "frame_00001.png", "frame_00002.png"]
    png = cv2.imread(str(files[0]), cv2.IMREAD_UNCHANGED)
    assert png.shape == (30, 40, 4) and png[..., 3].min() == 0 and png[..., 3].max() > 200
    assert main(args) == 1
    assert "already exists" in capsys.readouterr().err
    assert main(args + ["--force"]) == 0


def test_a_nerfstudio_camera_path_renders_its_frames_at_its_size_and_fps(model, ckpt, tmp_path, capsys):
    import json

    cams = [orbit(20, 15 * i, 1.7, fov_deg=40, width=48, height=36) for i in range(4)]
    frames = [{"camera_to_world": c.to_opengl_c2w().ravel().tolist(), "fov": math.degrees(c.fov_y),
               "render_time": i / 3} for i, c in enumerate(cams)]
    (tmp_path / "ns.json").write_text(json.dumps({"camera_type": "perspective", "render_width": 48,
                                                  "render_height": 36, "seconds": 0.5, "camera_path": frames}))
    out = tmp_path / "frames"
    assert main(["render", str(ckpt), "--out", str(out), "--path", str(tmp_path / "ns.json"), "--quiet"]) == 0
    assert "4 frames 48x36 at 8 fps" in capsys.readouterr().out  # the file's size, frame count and fps
    for i in (0, 3):
        png = cv2.imread(str(out / f"frame_{i:05d}.png"))[..., ::-1] / 255.0
        want = render_image(model, cams[i], i / 3, RenderSettings(background=(1.0, 1.0, 1.0)))[..., :3]
        assert np.abs(png - want).max() < 2.5 / 255  # the file's camera and render_time, frame for frame


def test_save_cameras_writes_a_nerfstudio_path_that_renders_the_same_frames(ckpt, tmp_path, capsys):
    """``--save-cameras`` records every frame's camera and model time as a nerfstudio camera path: rendering that
    file with ``--path`` gives the same frames, at the same size, count and fps; an existing file is kept."""
    import json

    first, again, cams = tmp_path / "first", tmp_path / "again", tmp_path / "cams.json"
    args = ["render", str(ckpt), "--size", "48x36", "--fps", "12", "--frame-count", "5", "--trajectory", "spiral",
            "--time-mode", "timelapse", "--quiet"]
    assert main([*args, "--out", str(first), "--save-cameras", str(cams)]) == 0
    data = json.loads(cams.read_text())
    assert (data["render_width"], data["render_height"], data["fps"], len(data["camera_path"])) == (48, 36, 12, 5)
    assert data["seconds"] == 5 / 12
    assert [f["render_time"] for f in data["camera_path"]] == pytest.approx([0, 0.25, 0.5, 0.75, 1.0])
    capsys.readouterr()
    assert main(["render", str(ckpt), "--out", str(again), "--path", str(cams), "--quiet"]) == 0
    assert "5 frames 48x36 at 12 fps" in capsys.readouterr().out
    for i in range(5):
        a = cv2.imread(str(first / f"frame_{i:05d}.png")).astype(int)
        b = cv2.imread(str(again / f"frame_{i:05d}.png")).astype(int)
        assert np.abs(a - b).max() <= 1
    assert main([*args, "--out", str(tmp_path / "third"), "--save-cameras", str(cams)]) == 1
    assert "already exists" in capsys.readouterr().err and not (tmp_path / "third").exists()  # refused up front


def decode_rgba(path: Path) -> tuple[list[np.ndarray], SimpleNamespace]:
    """Every frame of a video as float RGBA in [0, 1] (straight alpha; 1 where the video has none), and its
    stream's facts, read while the file is open (PyAV >= 18.1.1 refuses a closed container's stream). VP9
    alpha lives in side data that only libvpx's decoder reads, not FFmpeg's native one."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        cc = stream.codec_context
        facts = SimpleNamespace(width=stream.width, height=stream.height, average_rate=stream.average_rate,
                                metadata=dict(stream.metadata), codec=cc.name, pix_fmt=cc.pix_fmt,
                                colour=(cc.colorspace, cc.color_primaries, cc.color_trc))
        if cc.name == "vp9":
            decoder = av.CodecContext.create("libvpx-vp9", "r")
            frames = [f for packet in container.demux(stream) for f in decoder.decode(packet)]
        else:
            frames = list(container.decode(stream))
        return [f.to_ndarray(format="rgba64le").astype(np.float64) / 65535.0 for f in frames], facts


@pytest.mark.parametrize("suffix, codec, pix_fmt, tolerance", [
    (".mp4", "h264", "yuv420p", 3.5 / 255),
    (".mov", "prores", "yuv422p10le", 1.5 / 255),
    (".webm", "vp9", "yuv420p", 3.5 / 255),
])
def test_videos_keep_the_colours_and_say_bt709(tmp_path, suffix, codec, pix_fmt, tolerance):
    """Saturated colour bars survive the RGB -> YUV -> RGB trip through every video format: the file is converted
    and tagged with one matrix (BT.709), so a decoder that follows the tags gets the colours back (the untagged
    BT.601 files of before decoded pure green as 0,215,0 in a BT.709 player)."""
    from splatreel.viewer.output import open_output

    bars = np.zeros((32, 64, 4), np.float32)
    bars[..., 3] = 1.0
    for k, colour in enumerate([(1, 0, 0), (0, 1, 0), (0, 0, 1), (0.8, 0.5, 0.15)]):
        bars[:, 16 * k:16 * (k + 1), :3] = colour
    out = tmp_path / f"bars{suffix}"
    with open_output(out, 64, 32, 24.0) as writer:
        for _ in range(3):
            writer.write(bars)
    frames, stream = decode_rgba(out)
    assert (stream.codec, stream.pix_fmt, stream.colour) == (codec, pix_fmt, (1, 1, 1))
    assert len(frames) == 3 and stream.average_rate == 24
    for k in range(4):  # bar centres (4:2:0 chroma blurs the bars' edges)
        got = frames[1][8:24, 16 * k + 4:16 * k + 12, :3].reshape(-1, 3)
        assert np.abs(got - bars[0, 16 * k + 8, :3]).max() < tolerance


@pytest.mark.parametrize("suffix, colour_error", [(".mov", 0.005), (".webm", 0.06)])
def test_transparent_videos_keep_alpha(model, ckpt, tmp_path, suffix, colour_error):
    """ProRes 4444 and VP9 carry the alpha channel of a transparent background (straight alpha, as players
    expect): it matches the headless render's, and so does the colour wherever the object covers the pixel
    (VP9 less closely: 4:2:0 chroma over a 64x48 image of 4,000 small Gaussians)."""
    out = tmp_path / f"clip{suffix}"
    assert main(["render", str(ckpt), "--out", str(out), "--size", "64x48", "--fps", "10", "--frame-count", "3",
                 "--background", "transparent", "--time", "0.5", "--azimuth", "30", "--quiet"]) == 0
    frames, stream = decode_rgba(out)
    assert len(frames) == 3 and (stream.width, stream.height) == (64, 48) and stream.average_rate == 10
    if suffix == ".mov":
        assert stream.pix_fmt == "yuva444p12le"  # 4444 profile: alpha in the stream
    else:
        assert stream.metadata.get("alpha_mode") == "1"  # WebM's flag that browsers look for
    from splatreel.viewer.output import unpremultiply
    from splatreel.viewer.trajectory import frame_model, orbit_cameras

    framing = frame_model(model)
    cam = orbit_cameras(3, 64, 48, framing.center, framing.distance(40.0), 20.0, 40.0, "z", 1.0, 30.0)[0]
    want = unpremultiply(render_image(model, cam, 0.5, RenderSettings(transparent=True)))
    got = frames[0]
    assert got[0, 0, 3] < 0.02 and got[..., 3].max() > 0.9  # transparent corner, opaque object
    assert np.abs(got[..., 3] - want[..., 3]).mean() < 0.005
    solid = want[..., 3] > 0.5
    assert np.abs(got[..., :3] - want[..., :3])[solid].mean() < colour_error


@pytest.mark.parametrize("extra, message", [
    (["--size", "63x48", "--out", "odd.mp4"], "even width and height"),
    (["--background", "transparent", "--out", "a.mp4"], "no alpha channel"),
    (["--size", "63x48", "--out", "odd.webm"], "VP9 video needs an even width and height"),
    (["--crf", "70", "--out", "a.webm"], "--crf for VP9 goes from 0 (best) to 63"),
    (["--crf", "20", "--out", "a.mov"], "ProRes has no --crf"),
    (["--mode", "sparkle", "--out", "a.png"], "unknown render mode"),
    (["--out", "a.gif"], "unknown output format"),
    (["--path", "missing.json", "--out", "a.mp4"], "no such camera path"),
    (["--background", "purple", "--out", "a.png"], "background must be"),
    (["--mode", "depth", "--map-range", "2,1", "--out", "a.png"], "--map-range needs LO < HI"),
    (["--crf", "20", "--out", "a.png"], "--crf sets the quality of .mp4 and .webm videos"),
    (["--out", "c.png", "--save-cameras", "c.png"], "is the --out file"),
])
def test_bad_options_give_one_line_errors(ckpt, tmp_path, capsys, extra, message, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["render", str(ckpt), "--frame-count", "1", "--quiet", *extra]) == 1
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err


def test_render_crop_draws_only_the_box_and_frames_it(model, ckpt, tmp_path):
    """``render --crop`` renders the cropped model (`splatreel.model.crop`), framed by its own extent."""
    from splatreel.model import CropBox, crop
    from splatreel.viewer.trajectory import frame_model, orbit_cameras

    box = [-0.4, -0.4, -0.4, 0.0, 0.4, 0.4]
    out = tmp_path / "half.exr"
    assert main(["render", str(ckpt), "--out", str(out), "--size", "64x48", "--background", "transparent",
                 "--time", "0.5", "--quiet", "--crop", *map(str, box)]) == 0
    img = oiio.ImageInput.open(str(out))
    got = img.read_image("float")
    img.close()
    half = crop(model, CropBox.of(box))
    assert 0 < len(half) < len(model)
    framing = frame_model(half)
    cam = orbit_cameras(1, 64, 48, framing.center, framing.distance(40.0))[0]
    want = render_image(half, cam, 0.5, RenderSettings(transparent=True))
    assert np.abs(got - premultiplied_to_linear(want)).max() < 2e-3  # EXR: linear light, half floats
    whole = render_image(model, cam, 0.5, RenderSettings(transparent=True))
    assert np.abs(whole[..., 3] - want[..., 3]).mean() > 0.02  # the crop really removed something in view


def test_a_still_image_is_one_frame(ckpt, tmp_path, capsys, monkeypatch):
    """An image output defaults to one frame; asking it for several fails at once, naming the user's path."""
    monkeypatch.chdir(tmp_path)
    assert main(["render", str(ckpt), "--out", "still.png", "--size", "40x30", "--quiet"]) == 0
    assert "1 frame " in capsys.readouterr().out and (tmp_path / "still.png").is_file()
    calls = []
    monkeypatch.setattr(SplatRenderer, "render", lambda *a, **k: calls.append(1))
    assert main(["render", str(ckpt), "--out", "frame_%04d.png", "--frame-count", "3", "--quiet"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("splatreel render: error: frame_%04d.png holds one image, not 3 frames") and "\n" not in err
    assert not calls and not list(tmp_path.glob("*frame*"))  # refused before drawing anything
    from splatreel.viewer.headless import render_to_file
    from splatreel.viewer.output import OutputError
    cams = [orbit(20, a, 2.0, 40, 40, 30) for a in (0, 10)]
    with pytest.raises(OutputError, match="^two.png: a single image takes one frame, not 2"):
        render_to_file(None, "two.png", cams, [0.5, 0.5])
    assert not calls and not (tmp_path / "two.png").exists()


def test_missing_and_corrupt_checkpoints(tmp_path, capsys):
    assert main(["render", str(tmp_path / "nope.safetensors"), "--out", str(tmp_path / "a.png")]) == 1
    assert "no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{garbage")
    assert main(["render", str(bad), "--out", str(tmp_path / "a.png")]) == 1
    assert "error" in capsys.readouterr().err
    assert not (tmp_path / "a.png").exists()


def test_background_compositing_and_modes(model):
    cam = orbit(20, 30, 1.6, fov_deg=45, width=64, height=64)
    r = SplatRenderer(headless_context(), model)
    try:
        r.render(cam, 0.5, RenderSettings(transparent=True))
        clear = r.read_display()
        bg = np.array([0.2, 0.6, 0.9])
        r.render(cam, 0.5, RenderSettings(background=tuple(bg)))
        over = r.read_display()
        np.testing.assert_allclose(over[..., :3], clear[..., :3] + (1 - clear[..., 3:]) * bg, atol=1e-5)
        assert np.all(over[..., 3] == 1.0)
        images = {}
        for mode in RENDER_MODES:
            r.render(cam, 0.5, RenderSettings(mode=mode))
            images[mode] = r.read_display()
        alpha = images["alpha"]
        np.testing.assert_allclose(alpha[..., 0], clear[..., 3], atol=1e-6)
        depth = images["depth"][..., :3]
        covered = clear[..., 3] > 0.99
        assert depth[covered].std() > 0.05 and depth[~(clear[..., 3] > 0)].max() == 0.0
        for mode in ("outlines", "centers"):
            assert (images[mode][..., :3].max(-1) > 0.02).mean() > 0.01, mode
            assert np.abs(images[mode] - images["color"]).mean() > 0.01, mode
        # splat scale shrinks the coverage, the SH degree changes colours only
        r.render(cam, 0.5, RenderSettings(transparent=True, splat_scale=0.3))
        assert (r.read_display()[..., 3] > 0.5).mean() < (clear[..., 3] > 0.5).mean()
        r.render(cam, 0.5, RenderSettings(transparent=True, sh_degree=0))
        dc = r.read_display()
        np.testing.assert_allclose(dc[..., 3], clear[..., 3], atol=1e-6)
        assert np.abs(dc[..., :3] - clear[..., :3]).max() > 1e-3
    finally:
        r.release()


def test_a_depth_video_keeps_one_colour_map_range_for_all_its_frames(model):
    """Per-frame depth ranges would make a moving camera's depth video flicker: `render_frames` maps every frame
    over the union of the sampled frames' ranges, and --map-range sets it by hand."""
    from splatreel.viewer.headless import render_frames, sequence_depth_range

    cams = [orbit(20, 30 + 10 * k, d, fov_deg=45, width=48, height=48) for k, d in enumerate((1.3, 1.6, 2.0, 2.6))]
    times = [0.2, 0.4, 0.6, 0.8]
    r = SplatRenderer(headless_context(), model)
    try:
        per_frame = [r.sort(c, t).depth_range for c, t in zip(cams, times)]
        whole = sequence_depth_range(r, cams, times)
    finally:
        r.release()
    assert whole == (min(n for n, _ in per_frame), max(f for _, f in per_frame))
    assert whole != per_frame[0] and whole != per_frame[-1]
    frames = list(render_frames(model, cams, times, RenderSettings(mode="depth")))
    for k in (0, 3):
        np.testing.assert_allclose(frames[k], render_image(model, cams[k], times[k],
                                                           RenderSettings(mode="depth", value_range=whole)), atol=1e-6)
        assert np.abs(frames[k] - render_image(model, cams[k], times[k], RenderSettings(mode="depth"))).max() > 0.05
    fixed = list(render_frames(model, cams[:2], times[:2], RenderSettings(mode="depth", value_range=(1.0, 3.0))))
    np.testing.assert_allclose(fixed[1], render_image(model, cams[1], times[1],
                                                      RenderSettings(mode="depth", value_range=(1.0, 3.0))), atol=1e-6)


def test_skipping_hidden_gaussians_keeps_the_image():
    """Front to back, Gaussians behind saturated tiles are skipped: fewer are drawn, the image does not change."""
    dense = synthetic_model(40000, seed=2, sh_degree=0, radius=0.3, scale=0.02, speed=0.1)
    cam = orbit(10, 20, 1.2, fov_deg=40, width=96, height=96)
    r = SplatRenderer(headless_context(), dense)
    try:
        ftb = r.render(cam, 0.5, RenderSettings(transparent=True))
        front = r.read_display()
        btf = r.render(cam, 0.5, RenderSettings(transparent=True, composite="back-to-front"))
        back = r.read_display()
    finally:
        r.release()
    assert btf.drawn == btf.visible and ftb.drawn < 0.8 * ftb.visible
    np.testing.assert_allclose(front, back, atol=2e-4)


def test_staging_is_used_only_where_saturation_can_hide_gaussians():
    from splatreel.viewer.sorting import DEPTH_TILE, hideable_fraction

    saturating = -math.log(TRANSMITTANCE_THRESHOLD)
    tile_area = DEPTH_TILE * DEPTH_TILE
    # 10 Gaussians in one tile with twice the saturating optical depth: about half lie behind the stop
    boxes = np.zeros((10, 6), np.float32)
    boxes[:, :2] = 5.0
    boxes[:, 5] = 2 * saturating * tile_area / 10
    assert hideable_fraction(boxes, 64, 64) == pytest.approx(0.5, rel=1e-5)
    # spread over separate tiles, none saturates
    boxes[:, 0] = np.arange(10) * DEPTH_TILE * 0.99
    boxes[:, 1] = 40.0
    assert hideable_fraction(boxes, 200, 64) == 0.0
    # a faint cloud is drawn in one stage (no read-backs), with the same image as back to front
    faint = synthetic_model(20000, seed=3, sh_degree=0, radius=0.3, scale=0.01, speed=0.1)
    faint.opacity_logits.data[:] = -4.0
    cam = orbit(10, 20, 1.2, fov_deg=40, width=96, height=96)
    r = SplatRenderer(headless_context(), faint)
    masks = []
    mark = r._mark_saturated
    r._mark_saturated = lambda covered: masks.append(covered) or mark(covered)
    try:
        ftb = r.render(cam, 0.5, RenderSettings(transparent=True))
        front = r.read_display()
        assert ftb.visible > 16384 and r.sort(cam, 0.5).hideable < 0.5
        assert not masks  # one stage: no saturation masks, no read-backs
        r.render(cam, 0.5, RenderSettings(transparent=True, composite="back-to-front"))
        back = r.read_display()
    finally:
        r.release()
    assert ftb.drawn == ftb.visible
    np.testing.assert_allclose(front, back, atol=2e-4)


def test_renderer_leaves_another_current_gl_context_alone(model):
    """Code that keeps its own standalone context current (and never re-enters it) still works around ours."""
    import moderngl

    other = moderngl.create_standalone_context(backend="egl")
    fbo = other.simple_framebuffer((4, 4))
    fbo.use()
    cam = orbit(20, 30, 1.6, fov_deg=45, width=32, height=32)
    first = None
    for color in ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)):
        img = render_image(model, cam, 0.5)  # the first call also creates the viewer's own context
        first = img if first is None else first
        fbo.use()
        fbo.clear(*color, 1.0)
        px = np.frombuffer(fbo.read(components=3), np.uint8)[:3]
        assert px.tolist() == [int(255 * c) for c in color]
    np.testing.assert_array_equal(img, first)
    other.release()


def test_a_lower_resolution_frame_is_stretched_over_the_viewport(model):
    """The app draws fewer pixels while the view moves: an image rendered at half size into a full-size viewport is
    the half-size image upscaled (bilinear), close to the full-size image, and covers the whole viewport."""
    full_cam = orbit(20, 30, 1.6, fov_deg=45, width=96, height=64)
    half_cam = full_cam.resized(48, 32)
    settings = RenderSettings(background=(1.0, 1.0, 1.0))
    ctx = headless_context()
    r = SplatRenderer(ctx, model)
    with ctx:  # our own GL calls need the viewer's context current (the renderer's methods make it so)
        tex = ctx.texture((96, 64), 4, dtype="f4")
        fbo = ctx.framebuffer([tex])

    def read_target() -> np.ndarray:
        with ctx:
            return np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(64, 96, 4)[::-1, :, :3]

    try:
        r.render(full_cam, 0.5, settings)
        full = r.read_display()[..., :3]
        r.render(half_cam, 0.5, settings)
        half = r.read_display()[..., :3]
        r.render(half_cam, 0.5, settings, target=fbo, viewport=(0, 0, 96, 64))
        stretched = read_target()
        r.render(full_cam, 0.5, settings, target=fbo, viewport=(0, 0, 96, 64))
        same = read_target()
    finally:
        with ctx:
            fbo.release()
            tex.release()
        r.release()
    np.testing.assert_array_equal(same, full)  # at equal sizes the viewport shows the image's own pixels
    upscaled = cv2.resize(half, (96, 64), interpolation=cv2.INTER_LINEAR)
    # bilinear like cv2, to float rounding and GL's 8-bit filter weights; edges clamp the same way
    assert np.abs(stretched - upscaled).max() < 0.005
    mse = float(np.mean((stretched - full) ** 2))
    assert 0.0 < mse and 10 * math.log10(1.0 / mse) > 20.0  # blurrier, but the same picture
    assert (full < 0.9).any(axis=-1).mean() > 0.05  # and there is a picture


@pytest.mark.parametrize("footprint", [{}, {"max_std_dev": 2.0}])
def test_boxes_of_an_order_sorted_at_another_resolution_hold_the_true_ones(model, footprint):
    """While the app changes resolution it draws with an order sorted for the previous size: its boxes, mapped to
    the new size, must still contain every pixel each Gaussian reaches (else points would clip and hidden-tile
    skipping would drop visible Gaussians), with a std-dev cap too, and for sizes that scale the two axes
    differently (rounding). (Orders with a screen-radius cap are sorted again instead: the next test.)"""
    from splatreel.viewer.draw_plan import rescaled_boxes as _boxes_for
    from splatreel.viewer.splats import to_arrays
    from splatreel.viewer.sorting import Footprint, depth_order

    arrays = to_arrays(model)
    fp = Footprint(**footprint)
    full_cam = orbit(20, 30, 1.6, fov_deg=45, width=120, height=80)
    for other in (full_cam.resized(30, 20), full_cam.resized(60, 40), full_cam.resized(240, 160),
                  full_cam.resized(47, 40), full_cam.resized(120, 31)):
        truth = depth_order(arrays, full_cam, 0.5, fp)
        mapped_order = depth_order(arrays, other, 0.5, fp)
        mapped = _boxes_for(mapped_order, full_cam)
        # compare the Gaussians both orders keep, by index
        common, a, b = np.intersect1d(truth.order, mapped_order.order, return_indices=True)
        assert len(common) > 0.9 * truth.visible
        t, m = truth.boxes[a], mapped[b]
        assert np.all(m[:, 0] - m[:, 2] <= t[:, 0] - t[:, 2] + 1e-3)
        assert np.all(m[:, 0] + m[:, 2] >= t[:, 0] + t[:, 2] - 1e-3)
        assert np.all(m[:, 1] - m[:, 3] <= t[:, 1] - t[:, 3] + 1e-3)
        assert np.all(m[:, 1] + m[:, 3] >= t[:, 1] + t[:, 3] - 1e-3)
        assert np.median(m[:, 2] / t[:, 2]) < 2.5  # conservative, not absurdly so
    assert _boxes_for(truth, full_cam) is truth.boxes


def test_an_order_of_another_footprint_or_screen_capped_at_another_size_is_sorted_again(model):
    """The app draws with its newest finished sort; one made with other caps or near plane, or with a screen-radius
    cap at another resolution, cannot bound this frame's splats, so `render` sorts again (and draws what a fresh
    sort draws); an uncapped order of another size is drawn as it is (its boxes rescaled)."""
    cam = orbit(20, 30, 1.6, fov_deg=45, width=120, height=80)
    small = cam.resized(60, 40)
    capped = RenderSettings(transparent=True, max_screen_radius=0.02)
    r = SplatRenderer(headless_context(), model)
    for settings, old_camera, old_settings, resorts in (
            (capped, cam, RenderSettings(), True),  # a cap came on
            (RenderSettings(), cam, capped, True),  # ... went off
            (RenderSettings(near_plane=1.5), cam, RenderSettings(), True),  # the near plane moved
            (capped, small, capped, True),  # the resolution changed under a screen cap
            (RenderSettings(transparent=True), small, RenderSettings(), False)):  # ... with no cap: rescaled
        old = r.sort(old_camera, 0.5, old_settings.footprint)
        stats = r.render(cam, 0.5, settings, order=old)
        assert stats.resorted == resorts
        img = r.read_display()
        fresh = r.render(cam, 0.5, settings)
        assert stats.visible == fresh.visible
        np.testing.assert_allclose(img, r.read_display(), atol=1e-5)
    r.release()


def test_smooth_temporal_fade_fades_to_zero_at_the_cull_and_leaves_the_rest(tmp_path):
    """One Gaussian with a short time window (var_t 0.01: marginal exp(-t^2 / 0.02)), seen head-on at several
    times: with the smooth fade its alpha is the cut one's times smoothstep(0.05, 0.1, marginal)
    (`covariance.temporal_factor`), the same from a marginal of 0.1 up, and 0 from the cull on, like the cut."""
    from splatreel.constants import TEMPORAL_FADES
    from splatreel.covariance import temporal_factor, temporal_marginal

    from test_viewer_sort import gaussians_from_motion

    var_t = torch.full((1,), 0.01, dtype=torch.float64)
    model = gaussians_from_motion([[0.0, 0.0, 0.0]], torch.eye(3) * 0.1 ** 2, [0.0] * 3, var_t,
                                  0.0, [1.0, 1.0, 1.0], time_range=(-1.0, 1.0))  # opacity 0.5
    cam = orbit(0, 0, 3.0, fov_deg=30, width=33, height=33)  # the Gaussian on the centre pixel's centre
    r = SplatRenderer(headless_context(), model)

    def centre_alpha(t: float, fade: str) -> float:
        r.render(cam, t, RenderSettings(transparent=True, temporal_fade=fade))
        return float(r.read_display()[16, 16, 3])

    for t in (0.1, 0.2, 0.224, 0.232, 0.25, 0.3):
        m = temporal_marginal(t, model.t_means, var_t)
        cut, smooth = centre_alpha(t, "cut"), centre_alpha(t, "smooth")
        want = cut * float(temporal_factor(m, "smooth") / temporal_factor(m, "cut")) if m > 0.05 else 0.0
        assert smooth == pytest.approx(want, rel=1e-4, abs=1e-7), (t, float(m))
        assert (cut > 0) == bool(m > 0.05) and (smooth == cut) == bool(m >= 0.1 or m <= 0.05)
    # the cut drops a Gaussian from 0.05 of its peak alpha to nothing; the smooth fade is nearly 0 there already
    assert centre_alpha(0.2445, "cut") > 0.02 and centre_alpha(0.2445, "smooth") < 1e-3
    # the command line draws the same: `render --temporal-fade` at one of those times, from the same camera
    ckpt = save_checkpoint(tmp_path / "fading.safetensors", model)
    for fade in TEMPORAL_FADES:
        out = tmp_path / f"{fade}.exr"
        assert main(["render", str(ckpt), "--out", str(out), "--size", "33x33", "--elevation", "0", "--azimuth", "0",
                     "--distance", "3", "--target", "0,0,0", "--fov", "30", "--time", "0.232", "--background",
                     "transparent", "--temporal-fade", fade, "--quiet"]) == 0
        got = float(oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)[16, 16, 3])
        assert got == pytest.approx(centre_alpha(0.232, fade), rel=2e-3), fade  # (EXR holds half floats)
    r.release()
    assert TEMPORAL_FADES == ("cut", "smooth")
    with pytest.raises(Exception, match="unknown temporal fade"):
        RenderSettings(temporal_fade="soft")


def test_render_without_a_checkpoint_renders_the_bundled_sample(tmp_path):
    out = tmp_path / "sample.png"
    assert main(["render", "--out", str(out), "--size", "64x48", "--quiet"]) == 0
    img = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert img.shape[:2] == (48, 64) and img[..., :3].std() > 5  # the spinner, not an empty frame
