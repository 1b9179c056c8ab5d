"""The default recipe reads the data, densifies under its cap, keeps to its time budget, and starts from a dataset's
own point cloud."""

import dataclasses
import shutil
import struct
import time

import numpy as np
import pytest
import torch

from splatreel.checkpoint import load_checkpoint
from splatreel.cli import main
from splatreel.train.config import preset
from splatreel.train.data import load_dataset
from splatreel.train.points import find_point_cloud, read_point_cloud
from splatreel.train.recipe import (CLIP_DURATION, FLOW_MOTION_AT, INBETWEEN_SHARE, MATRIX_MINUTES,
                                   MATRIX_TEMPORAL_STD_FRAMES, ONE_VIEW_MINUTES, ONE_VIEW_NODE_KEY_EVERY,
                                   SCALE_RATIO_WEIGHT, auto_recipe, read_traits)
from splatreel.train.trainer import BudgetBar, Trainer

from conftest import sample_dataset


@pytest.fixture(scope="module")
def matrix(tmp_path_factory):
    """A bounded object as an image matrix: 4 views x 3 frames at 64 px, transparent around it."""
    return sample_dataset(tmp_path_factory, "spinner", views=4, frames=3, size=64, test_views=4)


def decisions_text(decisions) -> str:
    return "\n".join(d.line() for d in decisions)


def test_an_image_matrix_of_a_bounded_object(matrix):
    traits = read_traits(load_dataset(matrix))
    assert traits.views_per_time == 4 and not traits.one_view_per_time
    assert traits.has_alpha and not traits.open_backdrop and traits.point_cloud is None
    cfg, decisions = auto_recipe(traits)
    assert cfg.preset == "auto" and cfg.minutes == MATRIX_MINUTES == 5.0 and cfg.init == "ball"
    assert cfg.lambda_scale_ratio == 0.1 and cfg.densify.enabled and cfg.densify.budget_curve
    assert cfg.resolution_ramp == ()  # 64 px: nothing to gain from coarser images
    assert cfg.batch_size == 8 and cfg.static_share == 0.0
    assert cfg.t_scale_init_frames == MATRIX_TEMPORAL_STD_FRAMES < preset("efficient4d").t_scale_init_frames
    text = decisions_text(decisions)
    assert "temporal std-dev 1 frame at init" in text and "--t-scale-init" in text
    assert "image matrix" in text and "a bounded object" in text and "--minutes" in text
    assert "8 images per step" in text and "--batch-size" in text
    assert "anisotropy penalty 0.1 above 10:1" in text and "--scale-ratio-weight" in text
    assert cfg.clip_duration == 5.0 and cfg.lr_quats_final == pytest.approx(0.1 * cfg.lr_quats)
    assert "time units long" in text and "--clip-duration" in text
    assert cfg.flow_motion_at == 0.3 and "optical flow" in text and "--flow-motion-at" in text
    assert cfg.inbetween_share == 0.25 and "interpolated half-way" in text and "--inbetween-share" in text
    assert cfg.motion == "auto" and "one set of Gaussians for the whole clip" in text and "--motion" in text
    assert not cfg.colour_tracks and "--colour-tracks" not in text  # every time has several views
    assert cfg.densify.split == "spacetime" and "--split" not in text  # several views a time: official
    assert cfg.densify.max_gaussians == 60_000 and "densify up to 60,000 Gaussians" in text


def test_one_camera_per_time_over_a_floor(small_floor):
    traits = read_traits(load_dataset(small_floor))
    assert traits.one_view_per_time and traits.open_backdrop
    cfg, decisions = auto_recipe(traits)
    assert cfg.minutes == ONE_VIEW_MINUTES == 10.0 and cfg.init == "frustum" and cfg.lambda_scale_ratio > 0
    assert cfg.t_scale_init_frames == preset("efficient4d").t_scale_init_frames  # 12 frames: a tenth is less
    text = decisions_text(decisions)
    assert "one camera per time" in text and "floor or backdrop" in text and "--init" in text
    long_clip, _ = auto_recipe(dataclasses.replace(traits, frames=96, images=96))
    assert long_clip.t_scale_init_frames == pytest.approx(9.5)  # a tenth of the clip
    assert long_clip.batch_size == cfg.batch_size == 8 and "8 images per step" in text
    assert cfg.clip_duration == 5.0 and "--clip-duration" in text
    assert cfg.inbetween_share == 0.0 and "--inbetween-share" not in text  # no camera films consecutive frames
    # control nodes tracked by the model's own motion at the flow step's share, their poses keyed every 8 frames
    assert cfg.motion == "nodes" and cfg.flow_motion_at == FLOW_MOTION_AT and cfg.node_template == "auto"
    assert "quadratic motion until 30% of the run, then control nodes" in text and "--motion to change" in text
    assert cfg.node_key_every == ONE_VIEW_NODE_KEY_EVERY == 8 and "keyed every 8 frames" in text
    assert "--node-key-every to change" in text
    assert cfg.colour_tracks and "followed by their colour in the images" in text and "--colour-tracks" in text
    assert cfg.densify.split == "space" and "split Gaussians in space only" in text and "--split" in text
    assert cfg.densify.max_gaussians == 60_000 and "densify up to 60,000 Gaussians" in text
    for pixels, cap in ((25565, 60_000), (40_000, 100_000), (80_000, 150_000)):  # 2.5 per opaque pixel
        capped, capped_decisions = auto_recipe(dataclasses.replace(traits, foreground_pixels=pixels))
        assert capped.densify.max_gaussians == cap
        assert f"densify up to {cap:,} Gaussians (2.5 per opaque pixel" in decisions_text(capped_decisions)
    single, single_decisions = auto_recipe(dataclasses.replace(traits, frames=1))
    assert single.clip_duration is None and "--clip-duration" not in decisions_text(single_decisions)
    assert single.motion == "linear" and "--motion" not in decisions_text(single_decisions)  # nothing moves


def test_static_share_starts_gaussians_static(small_floor, tmp_path, capsys):
    from splatreel.train.initialize import start_static

    ds = load_dataset(small_floor)
    cfg, _ = auto_recipe(read_traits(ds))
    cfg = dataclasses.replace(cfg.scaled(2), minutes=None, num_gaussians=2000, static_share=0.25)
    tr = Trainer(ds, cfg, tmp_path / "s.safetensors", progress=False)
    t0, t1 = tr.ds.time_range  # the trainer's own time axis (time_axis)
    model = tr.model().detach()
    static = torch.isclose(model.log_t_scales.exp(), torch.tensor(t1 - t0))
    assert abs(int(static.sum()) - 500) <= 1
    torch.testing.assert_close(model.t_means[static], torch.full((int(static.sum()),), 0.5 * (t0 + t1)))
    # visible at every time and not moving: the slices at both ends agree on their centres
    early, late = model.select(static.nonzero()[:, 0]).slice(t0), model.select(static.nonzero()[:, 0]).slice(t1)
    torch.testing.assert_close(early.means, late.means)
    assert float(early.opacities.min()) > 0.85 * float(torch.sigmoid(model.opacity_logits).min())
    raw = {"means": torch.zeros(10, 3), "t_means": torch.zeros(10), "log_t_scales": torch.zeros(10)}
    assert start_static(raw, 0.0, (0.0, 1.0), torch.Generator()) is raw
    args = ["train", str(small_floor), "--out", str(tmp_path / "x.safetensors"), "--static-share", "1.5"]
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2 and "expected a number from 0 to 1" in capsys.readouterr().err


def test_an_image_whose_time_has_no_live_gaussians_reports_a_finite_loss(small_floor, tmp_path):
    """The scale-ratio term averaged over the Gaussians alive at an image's time was NaN in the reported loss when
    none was. It now acts once per step on every Gaussian: a needle shortens even while nobody is alive."""
    ds = load_dataset(small_floor)
    cfg, _ = auto_recipe(read_traits(ds))
    cfg = dataclasses.replace(cfg.scaled(4), minutes=None, num_gaussians=500, batch_size=1)
    tr = Trainer(ds, cfg, tmp_path / "e.safetensors", progress=False)
    with torch.no_grad():
        tr.params["t_means"][:] = ds.train[0].time + 10.0  # nobody alive at any training time
        tr.params["log_scales"][0] = torch.tensor([-2.0, -6.0, -6.0])  # a needle, 55:1
    before = tr.params["log_scales"][0].detach().clone()
    loss, _ = tr.train_step()
    after = tr.params["log_scales"][0].detach()
    assert cfg.lambda_scale_ratio > 0 and np.isfinite(loss) and loss > 0
    assert after.max() - after.min() < before.max() - before.min()


def test_data_without_alpha_is_an_open_scene(matrix):
    ds = load_dataset(matrix)
    ds.train = [dataclasses.replace(v, alpha=None) for v in ds.train]
    traits = read_traits(ds)
    assert not traits.has_alpha and traits.open_backdrop
    cfg, decisions = auto_recipe(traits)
    assert cfg.init == "frustum" and "no alpha" in decisions_text(decisions)


def test_large_images_train_coarse_to_fine():
    from splatreel.train.recipe import DataTraits

    traits = DataTraits(images=256, frames=16, views_per_time=16, has_alpha=True, border_opaque=0.0,
                        width=256, height=256, point_cloud=None)
    cfg, decisions = auto_recipe(traits)
    assert cfg.resolution_ramp and all(k > 1 for _, k in cfg.resolution_ramp)
    assert "--resolution-ramp" in decisions_text(decisions)
    # the cap follows the pixels the subject covers: 10 per opaque pixel of an image, within 60k-150k
    assert cfg.densify.max_gaussians == 150_000  # nothing known of the alpha: every pixel counts
    for pixels, cap in ((4381, 60_000), (6858, 70_000), (11081, 110_000), (25565, 150_000)):
        cfg, decisions = auto_recipe(dataclasses.replace(traits, foreground_pixels=pixels))
        assert cfg.densify.max_gaussians == cap and f"densify up to {cap:,} Gaussians" in decisions_text(decisions)


def write_ply(path, points, colors):
    import trimesh

    trimesh.PointCloud(points, colors=colors).export(path)


def test_point_cloud_init_is_used_when_the_dataset_ships_one(matrix, tmp_path):
    root = tmp_path / "withcloud"
    shutil.copytree(matrix, root)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.3, 0.3, (300, 3))
    cols = np.tile([[255, 0, 0, 255]], (300, 1)).astype(np.uint8)
    write_ply(root / "fused.ply", pts, cols)
    ds = load_dataset(root)
    traits = read_traits(ds)
    assert traits.point_cloud == root / "fused.ply"
    cfg, decisions = auto_recipe(traits)
    assert cfg.init == "points" and "fused.ply" in decisions_text(decisions)
    tr = Trainer(ds, dataclasses.replace(cfg.scaled(2), minutes=None, num_gaussians=1000), tmp_path / "p.safetensors",
                 progress=False)
    means = tr.params["means"].detach().double().numpy()
    assert len(means) == 300  # every point of the cloud, no more
    assert np.abs(np.sort(means, 0) - np.sort(pts, 0)).max() < 1e-6
    rgb = tr.model().detach().slice(0.5).colors(torch.zeros(3))
    assert float(rgb[:, 0].min()) > 0.9 and float(rgb[:, 1:].max()) < 0.1  # the cloud's colours


def test_point_cloud_in_another_frame_or_corrupt_is_one_line(matrix, tmp_path, capsys):
    root = tmp_path / "badcloud"
    shutil.copytree(matrix, root)
    write_ply(root / "fused.ply", np.random.default_rng(0).uniform(50, 60, (100, 3)), None)
    args = ["train", str(root), "--out", str(tmp_path / "x.safetensors"), "--iters", "2", "--quiet"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "fused.ply" in err and "lie in view" in err and len(err.strip().splitlines()) == 1
    (root / "fused.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 100\n")
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "fused.ply" in err and len(err.strip().splitlines()) == 1


def test_colmap_points3d_text_and_binary(tmp_path):
    pts = np.array([[0.1, 0.2, 0.3], [-1.0, 2.0, 0.5]])
    rgb = np.array([[255, 0, 0], [0, 128, 255]])
    text = "# 3D point list\n" + "".join(f"{i + 1} {p[0]} {p[1]} {p[2]} {c[0]} {c[1]} {c[2]} 0.5 1 0 2 3\n"
                                          for i, (p, c) in enumerate(zip(pts, rgb)))
    (tmp_path / "points3D.txt").write_text(text)
    blob = struct.pack("<Q", 2)
    for i, (p, c) in enumerate(zip(pts, rgb)):
        blob += struct.pack("<QdddBBBdQ", i + 1, *p, *map(int, c), 0.5, 2) + struct.pack("<IIII", 1, 0, 2, 3)
    (tmp_path / "sparse" / "0").mkdir(parents=True)
    (tmp_path / "sparse" / "0" / "points3D.bin").write_bytes(blob)
    assert find_point_cloud(tmp_path) == tmp_path / "sparse" / "0" / "points3D.bin"
    for name in ("points3D.txt", "sparse/0/points3D.bin"):
        xyz, col = read_point_cloud(tmp_path / name)
        np.testing.assert_allclose(xyz, pts)
        np.testing.assert_allclose(col, rgb / 255.0)
    (tmp_path / "cut.bin").write_bytes(blob[:-20])
    with pytest.raises(Exception, match="truncated"):
        read_point_cloud(tmp_path / "cut.bin")


def test_densification_grows_under_the_cap_along_the_budget_curve(matrix, tmp_path):
    ds = load_dataset(matrix)
    cfg, _ = auto_recipe(read_traits(ds))
    cfg = dataclasses.replace(cfg.scaled(40), minutes=None, num_gaussians=1500, seed=1)
    cfg = dataclasses.replace(cfg, densify=dataclasses.replace(cfg.densify, max_gaussians=2500))
    tr = Trainer(ds, cfg, tmp_path / "d.safetensors", progress=False)
    counts = []
    for _ in range(cfg.iters):
        tr.train_step()
        counts.append(len(tr.params["means"]))
    d = cfg.densify
    assert max(counts) <= 2500 and counts[-1] > 1500 + 300, counts[::5]
    for step, n in enumerate(counts, start=1):  # never ahead of the linear budget curve
        share = min(max((step - d.start) / (d.stop - d.start), 0.0), 1.0)
        assert n <= 1500 + share * 1000 + 1, (step, n)
    assert len(tr.optimizer.state[tr.params["means"]]["exp_avg"]) == counts[-1]


def test_help_states_the_recipes_budgets_and_motion(capsys):
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    said = " ".join(capsys.readouterr().out.split())
    assert "5 for an image matrix, 10 for one camera per time" in said
    assert "auto for an image matrix, nodes for one camera per time" in said
    assert f"(default: the recipe's, {ONE_VIEW_NODE_KEY_EVERY} for one camera per time, else 1;" in said
    # the help states the recipe's own values
    assert f"more than 10:1 anisotropic (default: the recipe's, {SCALE_RATIO_WEIGHT:g};" in said
    assert f"(default: the recipe's, {CLIP_DURATION:g}; the checkpoint keeps" in said
    assert f"(default: the recipe's, {FLOW_MOTION_AT:g}; 0 = never" in said
    assert f"(default: the recipe's, {INBETWEEN_SHARE:g} for an image matrix; 0 = none" in said


def test_the_bar_shows_the_budget_less_the_seconds_spent():
    import io

    out = io.StringIO()
    # a set-up of 12.6 s, then a first update that rounds the other way: tqdm's own estimate went negative here
    bar = BudgetBar(total=300.0, initial=12.6, unit="s", desc="train", file=out, ncols=100)
    bar.update(-0.3)
    bar.refresh()
    assert out.getvalue().endswith("12/300 s, 04:47 left")
    bar.update(300.0 - bar.n)
    bar.set_postfix(it=7)
    assert out.getvalue().endswith("300/300 s, 00:00 left, it=7")
    bar.close()


def test_minutes_ends_on_time(matrix, tmp_path, capsys):
    out = tmp_path / "timed.safetensors"
    t = time.perf_counter()
    assert main(["train", str(matrix), "--out", str(out), "--minutes", "0.5", "--num-gaussians", "800",
                 "--quiet"]) == 0
    wall = time.perf_counter() - t
    said = capsys.readouterr().out
    assert "preset auto, 0.5 minutes" in said and "test views: PSNR" in said
    assert "image matrix" in said and "--minutes 0.5 given" in said  # the recipe's choice, overridden
    assert 0.9 * 30.0 <= wall <= 1.1 * 30.0, wall
    ck = load_checkpoint(out)
    assert ck.training["minutes"] == 0.5 and ck.training["iteration"] > 5


def test_resume_with_densification_equals_uninterrupted(matrix, tmp_path):
    ds = load_dataset(matrix)
    cfg, _ = auto_recipe(read_traits(ds))
    cfg = dataclasses.replace(cfg.scaled(16), minutes=None, num_gaussians=1000, seed=2)
    assert cfg.densify.stop > 8  # densification goes on after the resumption
    Trainer(ds, cfg, tmp_path / "a.safetensors", progress=False).run()
    Trainer(ds, cfg, tmp_path / "b.safetensors", progress=False).run(stop_at=8)
    Trainer(ds, cfg, tmp_path / "b.safetensors", resume=True, progress=False).run()
    a, b = load_checkpoint(tmp_path / "a.safetensors").model, load_checkpoint(tmp_path / "b.safetensors").model
    assert len(a) > 1000  # it did densify
    # the recipe's motion auto on a rigid box: one set of Gaussians carried by the nodes from the flow step (step 5)
    # on, so the resumption (at step 8) restores the node poses and their optimizer too
    assert a.kind == "skinned" and a.num_nodes > 100
    for k, v in a.tensors().items():
        torch.testing.assert_close(v, b.tensors()[k], rtol=0, atol=0)


def test_named_presets_are_kept():
    assert preset("efficient4d").preset == "efficient4d" and preset("full").densify.enabled
    assert preset("efficient4d").motion == preset("full").motion == "linear"
    assert preset("full").densify.split == "spacetime"  # the official 4D split


def test_flow_options_on_data_without_videos_say_they_do_nothing(small_floor, tmp_path, capsys):
    out = tmp_path / "floor.safetensors"
    assert main(["train", str(small_floor), "--out", str(out), "--iters", "2", "--num-gaussians", "300",
                 "--motion", "quadratic", "--inbetween-share", "0.3", "--flow-motion-at", "0.5", "--quiet"]) == 0
    said = capsys.readouterr().out
    assert "--flow-motion-at and --inbetween-share ignored: no camera films two consecutive frames" in said
    assert "preset auto, 2 iterations" in said and "10 minutes (" in said and "--iters 2 given instead)" in said
    assert out.exists()
    # with --motion nodes the flow step's share is when the nodes are tracked (by the model's own motion): used
    out = tmp_path / "nodes.safetensors"
    assert main(["train", str(small_floor), "--out", str(out), "--iters", "6", "--num-gaussians", "300",
                 "--motion", "nodes", "--flow-motion-at", "0.5", "--node-key-every", "4", "--colour-tracks", "off",
                 "--quiet"]) == 0
    said = capsys.readouterr().out
    assert "ignored" not in said and "control nodes tracked by the model's own motion" in said
    loaded = load_checkpoint(out)
    assert loaded.model.kind == "skinned" and loaded.model.num_keys == 4  # 12 frames keyed at 0, 4, 8, 11
    assert loaded.training["colour_tracks"] is False
    # the recipe's own: nodes at 30% of the run, keyed every 8 frames; its flow share is no news to the user
    out = tmp_path / "recipe.safetensors"
    assert main(["train", str(small_floor), "--out", str(out), "--iters", "6", "--num-gaussians", "300",
                 "--quiet"]) == 0
    said = capsys.readouterr().out
    assert "ignored" not in said and "control nodes tracked by the model's own motion" in said
    loaded = load_checkpoint(out)
    assert loaded.model.kind == "skinned" and loaded.model.num_keys == 3  # 12 frames keyed at 0, 8, 11
    assert loaded.training["colour_tracks"] is True


def test_split_option_overrides_the_recipe(small_floor, tmp_path, capsys):
    for given, expect in ((None, "space"), ("spacetime", "spacetime")):
        out = tmp_path / f"{expect}.safetensors"
        assert main(["train", str(small_floor), "--out", str(out), "--iters", "2", "--num-gaussians", "300",
                     "--quiet", *(["--split", given] if given else [])]) == 0
        said = capsys.readouterr().out
        assert ("--split spacetime given)" in said) == (given is not None)
        assert load_checkpoint(out).training["densify"]["split"] == expect


def test_motion_option_overrides_the_recipe(matrix, tmp_path, capsys):
    for given, expect in ((None, "auto"), ("linear", "linear")):
        out = tmp_path / f"{expect}.safetensors"
        assert main(["train", str(matrix), "--out", str(out), "--iters", "2", "--num-gaussians", "300", "--quiet",
                     *(["--motion", given] if given else [])]) == 0
        said = capsys.readouterr().out
        assert ("--motion linear given)" in said) == (given is not None)
        written = load_checkpoint(out)
        assert written.training["motion"] == expect
        if written.model.kind != "skinned":  # auto: quadratic unless one set of Gaussians fitted every frame
            assert (written.model.accelerations is None) == (expect == "linear")
