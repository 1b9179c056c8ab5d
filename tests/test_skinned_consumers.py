"""Every consumer of models with a skinned model (`SkinnedGaussians`): the viewer's arrays (uploaded once, the node
poses per displayed time) and its GL image; Inspect; the web player, which carries the
Gaussians on the GPU as the viewer does; USD; ``info`` and ``convert``."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
import torch

from splatreel.cameras import look_at, orbit
from splatreel.checkpoint import save_checkpoint
from splatreel.cli import main
from splatreel.covariance import condition_on_time, visible_span
from splatreel.export.web import web_data, write_web
from splatreel.rasterize import rasterize
from splatreel.skinned import SkinnedGaussians, node_poses
from splatreel.summary import model_summary
from splatreel.viewer.pick import describe, peak_time, vector_text
from splatreel.viewer.renderer import RenderSettings, SplatRenderer, headless_context
from splatreel.viewer.selection import centres_at
from splatreel.viewer.skinning import posed
from splatreel.viewer.splats import needs_per_frame_upload, to_arrays, typical_speed
from splatreel.viewer.synthetic import synthetic_model

from test_skinned import AXIS, CENTRE, spinning
from test_viewer_parity import MIN_PSNR, psnr, value_images
from test_web import BACKGROUND, browser, check_page, geometry_texels, served, url  # noqa: F401 (fixtures)
from test_web import MIN_PSNR as WEB_MIN_PSNR

KEYS = 9  # spinning()'s node key times: 0, 1/8, ..., 1


@pytest.fixture(scope="module")
def model():
    return spinning(n=60, keys=KEYS)  # half a turn over [0, 1], float64


@pytest.fixture(scope="module")
def checkpoint(model, tmp_path_factory):
    return save_checkpoint(tmp_path_factory.mktemp("skinned") / "spin.safetensors", model.to(dtype=torch.float32))


def carried_synthetic(model, n: int = 2000, **options) -> SkinnedGaussians:
    """`synthetic_model`'s native Gaussians (each also moving on its own line, which must not move a skinned one)
    carried by `model`'s spinning nodes."""
    native = synthetic_model(n, seed=8, radius=0.6, scale=0.03, **{"sh_degree": 1, **options})
    return SkinnedGaussians(native, model.node_canonical, model.node_times, model.node_positions,
                            model.node_rotations, node_sigma=0.4)


def read_array(data: bytes, name: str) -> np.ndarray:
    """Array `name` of a ``splats.bin`` (float32, in its header's shape)."""
    length = int(np.frombuffer(data[4:8], np.uint32)[0])
    a = json.loads(data[8:8 + length])["arrays"][name]
    assert a["type"] == "f32"
    return np.frombuffer(data, np.float32, count=a["bytes"] // 4, offset=8 + length + a["offset"]).reshape(a["shape"])


def test_viewer_arrays_are_the_canonical_gaussians_and_their_skin(model):
    """Made once, valid at every time: the canonical native Gaussians' arrays and each one's skin. Carried to t on
    the CPU (`posed`: the sort's and the selection markers', by the trainer's fused kernel) they are the
    slice's means and covariances."""
    assert not needs_per_frame_upload(model)
    arrays, native = to_arrays(model), to_arrays(model.gaussians)
    assert arrays.time is None and arrays.attributes().shape == (len(model), 28)
    np.testing.assert_array_equal(arrays.attributes()[:, :20], native.attributes())
    nodes, weights = model.skin
    np.testing.assert_array_equal(arrays.skin.nodes, nodes.numpy())
    np.testing.assert_allclose(arrays.skin.weights, weights.numpy(), rtol=1e-6)
    triu = ([0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2])
    for t in (0.3, 0.75, 1.2):  # between keys, and past the last one
        g, at = model.slice(t), posed(arrays, t)
        np.testing.assert_allclose(at.mean_t[:, :3], g.means.numpy(), rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(at.cov[:, :6], g.covariances[:, triu[0], triu[1]].numpy(), rtol=1e-4, atol=1e-7)
        assert not at.motion[:, :3].any() and not at.accel.any()  # the sort must not move them again
        np.testing.assert_array_equal(at.cov[:, 6:], arrays.cov[:, 6:])  # opacity and speed stay
        np.testing.assert_allclose(centres_at(arrays, t, np.array([4, 9])), g.means[[4, 9]].numpy(), atol=1e-5)
    part = arrays.select(np.array([3, 11]))  # a crop keeps each Gaussian's skin
    np.testing.assert_array_equal(posed(part, 0.4).mean_t, posed(arrays, 0.4).mean_t[[3, 11]])
    radius = torch.linalg.cross(AXIS.expand_as(model.gaussians.means), model.gaussians.means - CENTRE).norm(dim=1)
    # the speed colour map tops out near the fast end of pi r (half a turn per unit of time), not at 1
    top = typical_speed(model, arrays)
    assert 0.9 * math.pi * float(radius.quantile(0.9)) < top < 1.01 * math.pi * float(radius.max())


def test_inspect_reads_the_native_gaussian_and_its_nodes(model):
    i, t = 11, 0.4
    rows = dict(describe(model, i, t))
    native = model.gaussians
    assert rows["position"] == vector_text(model.slice(t).means[i])
    assert f"at t = {float(native.t_means[i]):.4g}" in rows["peak opacity"]
    _, _, var_t = condition_on_time(native.covariance_4d())
    assert rows["time std-dev"] == f"{math.sqrt(float(var_t[i])):.4g}"
    assert rows["drawn for"].startswith(f"{float(visible_span(var_t)[i]):.4g}")
    nodes, weights = model.skin
    assert rows["nodes"].startswith(f"4 of {model.num_nodes}: #{int(nodes[i, weights[i].argmax()])} (")
    assert "keyframes" not in rows
    assert peak_time(model, i) == float(native.t_means[i])
    late = model.select(torch.arange(len(model)))
    late.gaussians.t_means[i] = 1.7  # a peak past the time range is clamped to it
    assert peak_time(late, i) == 1.0


def test_export_web_writes_the_canonical_gaussians_their_skin_and_the_node_keys(model, checkpoint, tmp_path, capsys):
    out = tmp_path / "player"
    assert main(["export", "web", str(checkpoint), "--out", str(out), "--quiet"]) == 0
    data = (out / "splats.bin").read_bytes()
    header, texels = geometry_texels(data)
    assert header["kind"] == "skinned" and header["geom_texels"] == 6 and header["keys"] == 1
    assert header["count"] == len(model) and header["node_count"] == model.num_nodes
    assert header["node_times"] == pytest.approx(model.node_times.tolist())
    np.testing.assert_allclose(texels[:, 0, :3], model.gaussians.means.numpy(), rtol=1e-6, atol=1e-7)
    nodes, weights = model.skin
    np.testing.assert_array_equal(texels[:, 4], nodes.numpy())
    np.testing.assert_allclose(texels[:, 5], weights.numpy(), rtol=1e-6)
    for name in ("node_canonical", "node_positions", "node_rotations"):
        np.testing.assert_array_equal(read_array(data, name), getattr(model, name).float().numpy())
    quantized = web_data(model, quantize=True)  # half-float geometry; the node keys stay float32
    np.testing.assert_array_equal(read_array(quantized, "node_positions"), model.node_positions.float().numpy())
    assert "wrote" in capsys.readouterr().out
    # formats of linearly moving Gaussians refuse it in one line
    for fmt in ("splatv", "4dgs"):
        assert main(["export", fmt, str(checkpoint), "--out", str(tmp_path / f"m.{fmt}"), "--quiet"]) == 1
        err = capsys.readouterr().err.strip()
        assert "a skinned model has none" in err and len(err.splitlines()) == 1, err
        assert not (tmp_path / f"m.{fmt}").exists()


def test_the_web_data_of_a_skinned_model_is_about_that_of_its_canonical_gaussians(model):
    """The page used to play a skinned model baked at 2F - 1 keys: 17 copies of every Gaussian here. It now takes the
    canonical Gaussians once, 2 skin texels each, and the node keys: about the size of the native Gaussians alone,
    and far under a sixteenth of what 17 copies of them would be."""
    big = carried_synthetic(model, 3000)
    size, native = len(web_data(big)), len(web_data(big.gaussians))
    assert size < 1.5 * native and size < 17 * native / 8, (size, native)


def test_web_page_carries_a_skinned_model_as_the_desktop_renderer(model, served, browser):
    """The page against `render_image` between node keys (float and quantized); and its node poses
    (``skinning.js``) against `splatreel.skinned.node_poses` on uneven keys with turns past half a turn between
    them, before, in and after the first and last segments."""
    root, base = served
    small = carried_synthetic(model, 600, sh_degree=2, sh_degree_t=1)
    cam = look_at((1.8, -1.9, 1.0), (0.0, 0.0, 0.0), "z", fov_deg=45, width=96, height=72)
    t = 0.8  # between keys 0.75 and 0.875
    for quantize in (False, True):
        write_web(small, root / f"skinned{int(quantize)}", background=BACKGROUND, up_axis="Z", quantize=quantize)
        page = url(f"{base}/skinned{int(quantize)}/index.html", cam, t)
        _, db = check_page(browser, page, small, cam, t)
        assert db >= WEB_MIN_PSNR, (quantize, db)
    g = torch.Generator().manual_seed(5)
    times = torch.tensor([0.0, 0.2, 0.7, 1.0], dtype=torch.float64)
    positions = torch.randn(4, 5, 3, generator=g, dtype=torch.float64)
    rotations = torch.randn(4, 5, 4, generator=g, dtype=torch.float64)
    canonical = torch.randn(5, 3, generator=g, dtype=torch.float64)
    for keys in (4, 1):
        nodes = {"count": 5, "times": times[:keys].tolist(), "canonical": canonical.flatten().tolist(),
                 "positions": positions[:keys].flatten().tolist(), "rotations": rotations[:keys].flatten().tolist()}
        for at in (-0.3, 0.0, 0.1, 0.45, 0.7, 0.85, 1.0, 1.5):
            texels = np.array(browser.eval(f"Array.from(splatreelNodePoses({json.dumps(nodes)}, {at}))"))
            texels = texels.reshape(5, 4, 4)
            p, r = node_poses(times[:keys], positions[:keys], rotations[:keys], at)
            np.testing.assert_allclose(texels[:, :3, 3], p.numpy(), rtol=1e-6, atol=1e-6)
            np.testing.assert_allclose(texels[:, :3, :3], r.numpy(), rtol=1e-6, atol=1e-6)
            np.testing.assert_allclose(texels[:, 3, :3], canonical.numpy(), rtol=1e-6, atol=1e-6)


def test_usd_export_has_the_carried_means_at_each_sample(model, checkpoint, tmp_path):
    from pxr import Usd, UsdVol

    from splatreel.export.usd import PRIM_PATHS

    out = tmp_path / "spin.usda"
    assert main(["export", "usd", str(checkpoint), "--out", str(out), "--frame-count", "3", "--what", "splats",
                 "--quiet"]) == 0
    stage = Usd.Stage.Open(str(out))
    splats = UsdVol.ParticleField3DGaussianSplat(stage.GetPrimAtPath(PRIM_PATHS["splats"]))
    positions = splats.GetPositionsAttr()
    assert positions.GetTimeSamples() == [0.0, 1.0, 2.0]
    for code, t in enumerate((0.0, 0.5, 1.0)):
        np.testing.assert_allclose(np.asarray(positions.Get(code)), model.slice(t).means.numpy(), atol=1e-4)


def test_a_deforming_mesh_steps_as_its_gaussians_fade(model):
    """Each frame step is cut so that the Gaussians carrying a vertex are still drawn at its end: a skinned model's
    native Gaussians fade by their temporal std-devs (median about 0.37 here: a step of 0.5 takes 3 sub-steps)."""
    from splatreel.export import iter_frames
    from splatreel.export.deforming import substeps

    start, end = iter_frames(model, [0.0, 0.5])
    starts, ends = substeps(model, start, 0.5, end)
    assert [s.time for s in starts] == pytest.approx([0.0, 1 / 6, 1 / 3])
    assert ends[-1] is end


def test_info_and_convert_name_the_kind_and_its_nodes(model, checkpoint, tmp_path, capsys):
    summary = model_summary(model)
    assert summary["kind"] == "skinned" and summary["motion"] == "nodes"
    assert (summary["num_nodes"], summary["num_keys"]) == (model.num_nodes, KEYS)
    # the opacity statistics are the native peaks, not the faded opacities at mid-clip
    assert summary["opacity"]["median"] == pytest.approx(float(model.gaussians.opacities.median()), rel=0.05)
    assert main(["info", str(checkpoint), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "skinned" and info["num_nodes"] == model.num_nodes and info["num_keys"] == KEYS
    assert main(["info", str(checkpoint)]) == 0
    table = capsys.readouterr().out
    assert re.search(rf"kind\s+skinned\n", table)
    assert re.search(rf"control nodes\s+{model.num_nodes}, posed at {KEYS} key times", table)
    assert main(["convert", str(checkpoint), "--out", str(tmp_path / "again.safetensors")]) == 0
    assert f"skinned, {len(model)} Gaussians" in capsys.readouterr().out


def attributes_of(renderer) -> bytes:
    """The renderer's per-Gaussian buffer, read with its own context current (another test's may be: moderngl then
    cannot map the buffer)."""
    from splatreel.gl import EGLCurrent

    previous = EGLCurrent()
    try:
        with renderer.ctx:
            return renderer._gpu.attrs.read()
    finally:
        previous.restore()


def test_gl_carries_a_skinned_model_on_the_gpu_as_the_rasterizer_draws_its_slice(model):
    """The renderer uploads the Gaussians once and per displayed time only the node poses, and the pre-pass
    carries each Gaussian by its nodes: the image is the rasterizer's of `slice(t)` at a node key and between keys
    (whose Catmull-Rom poses no chord reproduces), and the speed mode composites the slice's velocities."""
    small = carried_synthetic(model)
    camera = orbit(15, 75, 2.5, fov_deg=45, width=96, height=96)
    background = (0.1, 0.2, 0.3)
    r = SplatRenderer(headless_context(), small)
    try:
        assert not r.per_frame_upload
        uploaded, images = attributes_of(r), []
        for t in (0.25, 0.8):  # a node key; between keys 0.75 and 0.875
            r.render(camera, t, RenderSettings(background=background))
            images.append(r.read_display()[..., :3])
            with torch.no_grad():
                ref = rasterize(small.slice(t), camera, background)
            assert psnr(images[-1], ref.rgb.numpy()) >= MIN_PSNR, t
            assert float(np.abs(r.read_accumulation()[..., 3] - ref.alpha.numpy()).max()) < 0.02
            assert r._gpu.nodes_time == t and attributes_of(r) == uploaded  # only the node texture changed
        assert psnr(*images) < 25  # the nodes moved the image
    finally:
        r.release()
    t = 0.55
    speed = torch.linalg.vector_norm(small.slice(t).velocities, dim=-1)
    acc, _, ref = value_images(small, camera, t, "speed", speed)
    top = float(speed.max())
    assert ref.max() > 0.2 * top and psnr(acc[..., 0] / top, ref / top) >= MIN_PSNR


def test_exported_frames_keep_each_gaussians_rotation_continuous(model):
    """USD and glTF frames decompose a skinned model's turning covariances afresh each frame; each frame must take the
    equivalent rotation nearest the one before, or a reader interpolating between samples spins Gaussians half a
    turn (a sign check alone misses a flipped pair of axes)."""
    from splatreel.export.base import iter_frames

    frames = list(iter_frames(model, np.linspace(0.0, 1.0, 41)))  # 4.5 degrees of turn a frame
    for a, b in zip(frames, frames[1:]):
        assert float(np.abs((a.quats * b.quats).sum(-1)).min()) > np.cos(np.radians(10.0) / 2)
