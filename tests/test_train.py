"""The trainer: it learns, resumes bit for bit, densifies consistently, and its CLI behaves."""

import json
import math

import cv2
import numpy as np
import pytest
import torch

from splatreel.checkpoint import load_checkpoint
from splatreel.cli import main
from splatreel.train import strategy
from splatreel.train.confidence import confidence_maps
from splatreel.train.config import DensifyConfig, preset
from splatreel.train.data import load_dataset
from splatreel.train.evaluate import evaluate
from splatreel.train.trainer import Trainer, state_path


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A procedural sample: 4 views x 3 frames at 64x64."""
    from splatreel.samples import DatasetConfig, write_dataset

    root = tmp_path_factory.mktemp("data") / "spinner"
    write_dataset("spinner", root, DatasetConfig(views=4, frames=3, size=64, test_views=4))
    return root


def small_config(**kw):
    base = dict(iters=80, num_gaussians=2000, seed=3)
    base.update(kw)
    import dataclasses
    return dataclasses.replace(preset("efficient4d").scaled(base.pop("iters")), **base)


def test_training_lowers_loss_and_beats_initial_psnr(tiny, tmp_path):
    ds = load_dataset(tiny)
    cfg = small_config()
    tr = Trainer(ds, cfg, tmp_path / "m.safetensors", progress=False)
    before = evaluate(tr.model().detach(), ds.train, ds.background)["psnr"]
    res = tr.run()
    after = evaluate(load_checkpoint(res.out).model, ds.train, ds.background)["psnr"]
    assert np.mean(res.losses[-10:]) < 0.6 * np.mean(res.losses[:10])
    assert after > before + 6.0, (before, after)
    ck = load_checkpoint(res.out)
    # the training cameras travel with the model (viewers snap to them without the dataset)
    assert [v.time for v in ck.views] == [v.time for v in ds.train]
    assert [str(tiny / v.name) for v in ck.views] == [v.name for v in ds.train]  # names relative to the dataset
    np.testing.assert_allclose(ck.views[-1].camera.c2w, ds.train[-1].camera.c2w, atol=1e-12)
    assert ck.training["iteration"] == 80 and ck.provenance["tool"] == "splatreel train"
    assert ck.provenance["up_axis"] == ds.up == "z"  # exporters declare the dataset's up axis
    assert ck.background == ds.background and state_path(res.out).exists()


def test_resume_equals_uninterrupted_training(tiny, tmp_path):
    ds = load_dataset(tiny)
    cfg = small_config(iters=12)
    Trainer(ds, cfg, tmp_path / "a.safetensors", progress=False).run()
    Trainer(ds, cfg, tmp_path / "b.safetensors", progress=False).run(stop_at=5)
    assert load_checkpoint(tmp_path / "b.safetensors").training["iteration"] == 5
    Trainer(ds, cfg, tmp_path / "b.safetensors", resume=True, progress=False).run()
    a = load_checkpoint(tmp_path / "a.safetensors").model
    b = load_checkpoint(tmp_path / "b.safetensors").model
    for k, v in a.tensors().items():
        assert torch.equal(v, getattr(b, k)), k


def test_confidence_is_one_for_consistent_frames_and_low_where_corrupted():
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.integers(0, 255, (64, 160, 3), dtype=np.uint8), (9, 9), 3)
    frames = [np.ascontiguousarray(texture[:, 2 * k:2 * k + 64]) for k in range(7)]  # smooth pan, 2 px/frame
    c_rgb, c_ssim = confidence_maps(frames)
    assert np.all(c_rgb[0] == 1) and np.all(c_rgb[-1] == 1)
    for k in range(1, 6):
        assert c_rgb[k][8:-8, 8:-8].mean() > 0.97 and c_ssim[k][8:-8, 8:-8].mean() > 0.9, k
    bad = [f.copy() for f in frames]
    bad[3][20:40, 20:40] = 0  # a black blotch that the neighbouring frames do not have
    b_rgb, b_ssim = confidence_maps(bad)
    assert b_rgb[3][22:38, 22:38].mean() < 0.8 and b_ssim[3][22:38, 22:38].mean() < 0.5
    assert b_rgb[3][45:60, 45:60].mean() > 0.97  # the rest of the frame stays trusted



@pytest.mark.parametrize("n", [2, 4, 3000])
def test_knn_equals_the_brute_force_search(n):
    """The k-d tree search gives each point the same neighbours, at the same distances, as comparing every pair
    (what the initial scales and the trainer's neighbour lists used before)."""
    from splatreel.train.initialize import knn, nearest_neighbour_sq_dist

    points = torch.randn(n, 3, generator=torch.Generator().manual_seed(n))
    d = torch.cdist(points.double(), points.double())  # [N, N], exact in float64
    want_dist, want_idx = torch.topk(d, min(4, n), largest=False)
    idx, dist = knn(points, k=3)
    assert idx.shape == dist.shape == (n, min(3, n - 1)) and dist.dtype == points.dtype
    assert torch.equal(idx, want_idx[:, 1:])
    torch.testing.assert_close(dist.double(), want_dist[:, 1:], atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(nearest_neighbour_sq_dist(points).double(), (want_dist[:, 1:] ** 2).mean(-1),
                               atol=1e-6, rtol=1e-6)

def test_densification_keeps_every_tensor_and_adam_state_aligned():
    n = 50
    g = torch.Generator().manual_seed(0)
    params = {k: torch.nn.Parameter(v) for k, v in {
        "means": torch.randn(n, 3, generator=g), "t_means": torch.rand(n, generator=g),
        "log_scales": torch.full((n, 3), -3.0), "log_t_scales": torch.full((n,), -1.0),
        "quats_l": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1), "quats_r": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        "opacity_logits": torch.zeros(n), "sh_dc": torch.zeros(n, 1, 3), "sh_rest": torch.zeros(n, 3, 3)}.items()}
    params["log_scales"].data[:10] = 0.0  # ten large ones: split, not cloned
    params["opacity_logits"].data[-5:] = -10.0  # five transparent ones: pruned
    opt = torch.optim.Adam([{"params": [p], "lr": 1e-3, "name": k} for k, p in params.items()], eps=1e-15)
    sum(p.sum() for p in params.values()).backward()
    opt.step()
    state = strategy.initialize_state(n, "cpu")
    state["grad_accum"][:20] = 1.0
    state["count"][:] = 1
    colours = params["sh_dc"].detach().clone()
    colours[:, 0, 0] = torch.arange(n, dtype=torch.float32)  # each row's colour names it (the sum's step moved all)
    params["sh_dc"].data.copy_(colours)
    out = strategy.densify_and_prune(params, opt, state, DensifyConfig(enabled=True), extent=10.0, step=100,
                                     convention="current", generator=g)
    assert out["cloned"] == 10 and out["split"] == 10
    assert out["total"] == n + 10 + 20 - 10 - 5
    # the source of each row: kept rows name themselves, clones and split children their parents
    source = out["source"]
    assert source.shape == (out["total"],)
    assert torch.equal(params["sh_dc"].detach()[:, 0, 0], colours[source, 0, 0])
    assert torch.equal(torch.bincount(source, minlength=n)[:10], torch.full((10,), 2))  # each split: two children
    assert not torch.isin(torch.arange(n - 5, n), source).any()  # the pruned
    for group in opt.param_groups:
        p = group["params"][0]
        assert p is params[group["name"]] and p.shape[0] == out["total"]
        assert opt.state[p]["exp_avg"].shape == p.shape
    strategy.reset_opacity(params, opt)
    assert torch.sigmoid(params["opacity_logits"]).max() <= 0.01 + 1e-6


@pytest.mark.parametrize("split", ["spacetime", "space"])
def test_a_split_in_space_keeps_the_parents_temporal_extent(split):
    """Official 4DGS splits in 4D: the children are 1.6x smaller on every axis, time included. Split in space, they
    keep the parent's temporal scale, and a static parent's children stay at its temporal mean."""
    n = 6
    g = torch.Generator().manual_seed(0)
    params = {k: torch.nn.Parameter(v) for k, v in {
        "means": torch.randn(n, 3, generator=g), "t_means": torch.full((n,), 0.5),
        "log_scales": torch.zeros(n, 3), "log_t_scales": torch.full((n,), -1.0),
        "quats_l": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1), "quats_r": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        "opacity_logits": torch.zeros(n), "sh_dc": torch.zeros(n, 1, 3), "sh_rest": torch.zeros(n, 3, 3)}.items()}
    opt = torch.optim.Adam([{"params": [p], "lr": 1e-3, "name": k} for k, p in params.items()], eps=1e-15)
    state = strategy.initialize_state(n, "cpu")
    state["grad_accum"][:] = 1.0
    state["count"][:] = 1
    out = strategy.densify_and_prune(params, opt, state, DensifyConfig(enabled=True, split=split), extent=10.0,
                                     step=100, convention="current", generator=g)
    assert out["split"] == n and out["total"] == 2 * n
    torch.testing.assert_close(params["log_scales"].detach(), torch.full((2 * n, 3), -math.log(1.6)))
    t_scales, t_means = params["log_t_scales"].detach(), params["t_means"].detach()
    if split == "space":
        assert torch.equal(t_scales, torch.full((2 * n,), -1.0)) and torch.allclose(t_means, torch.tensor(0.5))
    else:
        torch.testing.assert_close(t_scales, torch.full((2 * n,), -1.0 - math.log(1.6)))
        assert (t_means - 0.5).abs().max() > 0.01


def test_checkpoint_leaves_out_the_gaussians_no_time_of_the_clip_draws(tiny, tmp_path):
    """Gaussians whose temporal mean drifted out of the clip are culled at every time of it: the checkpoint drops
    them and draws the same images; the resumable state keeps them."""
    ds = load_dataset(tiny)
    tr = Trainer(ds, small_config(iters=1), tmp_path / "m.safetensors", progress=False)
    t_means = tr.params["t_means"].data
    t0, t1 = tr.time_range
    t_means[:7] = t1 + 50.0 * (t1 - t0)  # far past the end: asleep whatever their temporal scale
    result = tr.run()
    ck = load_checkpoint(tmp_path / "m.safetensors")
    n = len(tr.params["means"])
    assert len(ck.model) == result.n_gaussians == n - 7
    assert torch.load(state_path(tmp_path / "m.safetensors"), weights_only=False)["params"]["means"].shape[0] == n
    inner = tr.model().detach()
    for v, u in zip(ds.train[:3], tr.ds.train[:3]):
        a, b = ck.model.slice(v.time), inner.slice(u.time)
        torch.testing.assert_close(a.opacities, b.opacities[7:], rtol=2e-4, atol=2e-5)


def test_static_stage_keeps_gaussians_static(tiny, tmp_path):
    ds = load_dataset(tiny)
    cfg = small_config(iters=6, static_iters=6)
    tr = Trainer(ds, cfg, tmp_path / "s.safetensors", progress=False)
    t0 = tr.params["t_means"].detach().clone()
    tr.run()
    assert torch.equal(tr.params["t_means"].detach(), t0)
    assert torch.equal(tr.params["quats_l"].detach(), tr.params["quats_r"].detach())
    assert float(tr.model().detach().slice(0.3).velocities.abs().max()) < 1e-6


def test_init_from_mesh(tiny, tmp_path):
    import trimesh

    box = trimesh.creation.box(extents=(0.4, 0.4, 0.4))
    box.visual.vertex_colors = np.tile([255, 0, 0, 255], (len(box.vertices), 1))
    path = tmp_path / "box.ply"
    box.export(path)
    ds = load_dataset(tiny)
    tr = Trainer(ds, small_config(init_mesh=str(path), num_gaussians=500), tmp_path / "i.safetensors",
                 progress=False)
    m = tr.model().detach()
    assert float(m.means.abs().max()) <= 0.2 + 1e-5  # on the box's surface
    rgb = m.slice(0.5).colors(torch.zeros(3))
    assert float(rgb[:, 0].min()) > 0.9 and float(rgb[:, 1:].max()) < 0.1


def test_cli_train_refuse_stop_resume_and_eval(tiny, tmp_path, capsys):
    out = tmp_path / "c.safetensors"
    args = ["train", str(tiny), "--out", str(out), "--iters", "6", "--num-gaussians", "800", "--quiet"]
    assert main(args + ["--stop-at", "3"]) == 0
    assert load_checkpoint(out).training["iteration"] == 3
    assert main(args) == 1  # exists, no --force
    assert "already exists" in capsys.readouterr().err
    assert main(["train", str(tmp_path / "no-such-dataset"), "--out", str(out)]) == 1  # refused before reading data
    assert "already exists" in capsys.readouterr().err
    assert main(args + ["--resume"]) == 0
    assert load_checkpoint(out).training["iteration"] == 6
    js = tmp_path / "eval.json"
    assert main(["eval", str(out), str(tiny), "--out", str(js)]) == 0
    res = json.loads(js.read_text())
    assert {"psnr", "ssim", "per_view", "seconds"} <= set(res) and len(res["per_view"]) == 4
    assert all(np.isfinite(v["psnr"]) for v in res["per_view"])
    assert main(["eval", str(out), str(tiny), "--out", str(js)]) == 1  # no clobbering without --force


def test_cli_train_says_which_background_and_resume_keeps_the_recorded_one(tiny, tmp_path, capsys):
    out = tmp_path / "bg.safetensors"
    args = ["train", str(tiny), "--out", str(out), "--iters", "4", "--num-gaussians", "300", "--quiet"]
    assert main(args + ["--stop-at", "2"]) == 0
    said = capsys.readouterr().out
    assert "background white: the D-NeRF layout's convention" in said  # the samples are D-NeRF layout RGBA
    assert "alpha agrees between views" in said
    assert load_checkpoint(out).background == (1.0, 1.0, 1.0)
    assert load_checkpoint(out).training["background_reason"].startswith("the D-NeRF layout's convention")
    # a run started on black (e.g. before the white convention) resumes on black, not on today's default
    black = tmp_path / "black.safetensors"
    args_black = ["train", str(tiny), "--out", str(black), "--iters", "4", "--num-gaussians", "300", "--quiet"]
    assert main(args_black + ["--stop-at", "2", "--background", "0", "0", "0"]) == 0
    assert "background black: --background\n" in capsys.readouterr().out
    assert main(args_black + ["--resume"]) == 0
    assert "background black: the resumed checkpoint's" in capsys.readouterr().out
    ck = load_checkpoint(black)
    assert ck.background == (0.0, 0.0, 0.0) and ck.training["iteration"] == 4
    assert main(args + ["--resume", "--background", "2", "0", "0"]) == 1
    assert "--background must be three numbers in [0, 1]" in capsys.readouterr().err
