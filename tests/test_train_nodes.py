"""Training with control nodes (motion 'nodes' and 'auto', `splatreel.train.nodes`, `splatreel.train.pose_fit`):
tracking on a sample whose motion is known, the rigid motions fitted to the frames, the move to the canonical frame,
the one set of Gaussians for the clip, the rigidity term, and runs that write skinned checkpoints and resume
exactly."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from splatreel import quaternion
from splatreel.checkpoint import load_checkpoint
from splatreel.cli.train import node_outcome_line
from splatreel.covariance import condition_on_time
from splatreel.model import static_gaussians4d
from splatreel.samples import build_model
from splatreel.samples.floor import concat_models
from splatreel.samples.objects import Spinner
from splatreel.pointsets import farthest_point_subset, rigid_fit
from splatreel.skinned import SkinnedGaussians
from splatreel.train.data import load_dataset
from splatreel.skinned import carry, skin_weights
from splatreel.train.nodes import (MOVING, TrackedNodes, _node_sites, coherent_travel, middle_template, node_spacing, rigidity,
                                  to_canonical, track_nodes, track_nodes_by_motion)
from splatreel.train.pose_fit import fit_tracks, template_fits
from splatreel.train.recipe import auto_recipe, read_traits
from splatreel.train.trainer import Trainer

from conftest import sample_dataset
from test_model import random_model


@pytest.fixture(scope="module")
def spinner(tmp_path_factory):
    """The spinning box as an image matrix: 8 views x 16 frames at 128 px (it turns 24 degrees per frame)."""
    return sample_dataset(tmp_path_factory, "spinner", views=8, frames=16, size=128, test_views=2)


def angle_deg(r: torch.Tensor) -> torch.Tensor:
    return torch.rad2deg(torch.arccos(((torch.diagonal(r, dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)))


def test_nodes_tracked_on_the_exact_spinner_move_and_turn_with_the_box(spinner):
    """Tracking is a start that the learned poses refine: the optical flow underestimates a 24-degree turn per frame
    (by about a sixth at 256 px, more at this test's 128 px), but a frame away from the middle the nodes are far
    closer to the box's true pose than to where they started."""
    ds = load_dataset(spinner)
    tracked = track_nodes(build_model("spinner"), ds, torch.ones(3), count=64)
    assert tracked is not None and tracked.positions.shape == (16, 64, 3) and tracked.middle == 8
    rot = quaternion.to_rotmat(tracked.rotations.reshape(-1, 4)).reshape(16, 64, 3, 3)
    box = Spinner()
    frames = np.asarray(ds.frame_times)
    share = (frames - frames[0]) / (frames[-1] - frames[0])
    centre = torch.from_numpy(box.center(share[8]))
    for k in (7, 9):
        truth = torch.from_numpy(box.rotation(share[k]) @ box.rotation(share[8]).T)
        assert float(angle_deg(truth).median()) == pytest.approx(24.0, abs=0.5)
        assert float(angle_deg(truth.T @ rot[k]).median()) < 0.75 * 24.0  # turned most of the way, the right way
        moved = (truth @ (tracked.canonical - centre)[..., None])[..., 0] + torch.from_numpy(box.center(share[k]))
        error = (tracked.positions[k] - moved).norm(dim=1).median()
        assert float(error) < 0.5 * float((moved - tracked.canonical).norm(dim=1).median())


def carried_error(model, tracked: TrackedNodes, ds, box: Spinner) -> np.ndarray:
    """``[F]`` median distance, in units of the box's half-diagonal, between the middle frame's opaque Gaussians
    carried by `tracked` to each frame and where the box's true motion takes them."""
    frames = np.asarray(ds.frame_times)
    share = (frames - frames[0]) / (frames[-1] - frames[0])
    mid = tracked.middle
    with torch.no_grad():
        s = model.slice(float(frames[mid]))
        points = s.means[s.visible & (s.opacities > 0.3)].double()
    sigma = node_spacing(tracked.canonical)
    idx, w = skin_weights(points, tracked.canonical, sigma)
    size = float(np.linalg.norm(box.half_extents))
    out = []
    for k in range(len(frames)):
        turn = box.rotation(share[k]) @ box.rotation(share[mid]).T
        truth = (points.numpy() - box.center(share[mid])) @ turn.T + box.center(share[k])
        r = quaternion.to_rotmat(quaternion.normalize(tracked.rotations[k]))
        moved, _ = carry(points, None, idx, w.double(), tracked.canonical.double(), tracked.positions[k], r)
        out.append(np.median(np.linalg.norm(moved.numpy() - truth, axis=1)) / size)
    return np.array(out)


def test_one_rigid_motion_fitted_to_the_frames_carries_the_box_where_the_flow_drifts(spinner):
    """The flow's nodes drift frame after frame (the flow falls short of a 24-degree turn); one rigid motion per key,
    fitted to each frame's images, keeps the middle frame's Gaussians on the box at every frame, and so they draw
    every frame about as well as the frame's own Gaussians do."""
    ds = load_dataset(spinner)
    model, box = build_model("spinner"), Spinner()
    tracked = track_nodes(model, ds, torch.ones(3), count=64)
    fit = fit_tracks(model, ds, torch.ones(3), tracked, node_spacing(tracked.canonical), steps=40)
    flow, fitted = carried_error(model, tracked, ds, box), carried_error(model, fit.nodes, ds, box)
    assert flow[[0, -1]].min() > 0.4  # the flow's nodes end far off (by 0.53-0.62 of the size at 128 px)
    assert fitted.max() < 0.15 and fitted.max() < 0.3 * flow[[0, -1]].min()  # 0.06-0.13
    # the nodes move alike: one rigid motion per key
    positions = fit.nodes.positions
    turn, c0, c1, _ = rigid_fit(positions[8].numpy()[None], positions[0].numpy()[None])
    moved = (positions[8].numpy() - c0[0]) @ turn[0].T + c1[0]
    assert np.abs(moved - positions[0].numpy()).max() < 1e-6
    # judged by the silhouette (the images have alpha): worst key over the middle 1.00 (colour 1.23)
    assert fit.silhouette_ratio() is not None and fit.silhouette_ratio() < 1.2, fit.silhouette_loss
    assert template_fits(fit) and fit.template_ratio() < 1.3, fit.template_loss


@pytest.mark.parametrize("alpha", ["none", "opaque"])
def test_without_a_silhouette_the_template_is_judged_by_its_colour(spinner, alpha):
    """No alpha, or an alpha opaque everywhere (no silhouette to draw): the colour ratio decides, as before."""
    ds = load_dataset(spinner)
    opaque = dataclasses.replace(ds, train=[dataclasses.replace(
        v, alpha=None if alpha == "none" else np.full(v.image.shape[:2], 255, np.uint8)) for v in ds.train])
    model = build_model("spinner")
    tracked = track_nodes(model, opaque, torch.ones(3), count=64)
    fit = fit_tracks(model, opaque, torch.ones(3), tracked, node_spacing(tracked.canonical), steps=40, give_up=True)
    assert fit.silhouette_loss is None and template_fits(fit) and fit.template_ratio() < 1.4, fit.template_loss


def test_one_set_is_refused_for_a_subject_that_bends(tmp_path_factory):
    """The exact `wave` (a sheet that bends): its silhouette drawn by the carried middle frame grows away from the
    middle (2.1 times its own at the ends), and the fit gives up a few keys out."""
    ds = load_dataset(sample_dataset(tmp_path_factory, "wave", views=8, frames=16, size=128, test_views=2))
    model = build_model("wave")
    tracked = track_nodes(model, ds, torch.ones(3), count=64)
    fit = fit_tracks(model, ds, torch.ones(3), tracked, node_spacing(tracked.canonical), steps=40, give_up=True)
    assert not template_fits(fit) and fit.silhouette_ratio() > 1.5, fit.silhouette_loss
    assert int(np.isinf(fit.silhouette_loss).sum()) >= 8  # it gave up: half the keys were not fitted


def test_a_faint_template_is_held_to_itself_and_still_fits(spinner):
    """Early in a run few Gaussians are opaque: the template takes the middle frame's faint ones too, and is held to
    its own frame's error (not to the frame's slice, which draws the neighbouring frames' Gaussians as well)."""
    import dataclasses

    ds = load_dataset(spinner)
    model = build_model("spinner")
    faint = dataclasses.replace(model, opacity_logits=torch.logit(torch.full_like(model.opacity_logits, 0.2)))
    tracked = track_nodes(faint, ds, torch.ones(3), count=64)
    fit = fit_tracks(faint, ds, torch.ones(3), tracked, node_spacing(tracked.canonical), steps=40, give_up=True)
    assert np.isfinite(fit.template_loss).all() and template_fits(fit), fit.template_loss


def test_the_middle_template_keeps_the_middle_frames_gaussians_for_the_whole_clip():
    times = torch.linspace(0.0, 4.0, 5, dtype=torch.float64)
    t_means = torch.tensor([0.1, 1.9, 2.2, 3.0, 2.49, 2.51, 2.0], dtype=torch.float32)
    means = torch.zeros(7, 3)
    means[6, 0] = 0.5  # the middle frame's, but 5 node spacings from the nodes: a floater
    nodes = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.1, 0.0]])
    mask, static = middle_template(t_means, means, times, 2, (0.0, 4.0), nodes, sigma=0.1)
    assert mask.tolist() == [False, True, True, False, True, False, False]
    assert static["t_means"].tolist() == [2.0] * 3
    torch.testing.assert_close(static["log_t_scales"], torch.full((3,), math.log(4.0)))


def rigid_nodes(m=30, frames=5, seed=0) -> tuple[TrackedNodes, torch.Tensor]:
    """Nodes that all turn by 20 degrees per frame about one axis through the origin."""
    g = torch.Generator().manual_seed(seed)
    canonical = torch.rand(m, 3, generator=g, dtype=torch.float64) * 2 - 1
    axis = torch.tensor([0.2, 1.0, 0.3], dtype=torch.float64)
    axis = axis / axis.norm()
    quats = torch.stack([torch.cat([torch.tensor([math.cos(a / 2)], dtype=torch.float64), math.sin(a / 2) * axis])
                         .expand(m, 4) for a in np.radians(20.0 * (np.arange(frames) - frames // 2))])
    positions = (quaternion.to_rotmat(quats) @ canonical[None, ..., None])[..., 0]
    return TrackedNodes(positions, quats, frames // 2), torch.linspace(0, 1, frames, dtype=torch.float64)


def test_gaussians_moved_to_the_canonical_frame_are_where_they_were_at_their_own_time():
    nodes, times = rigid_nodes()
    native = random_model(40, "current")
    native = dataclasses.replace(native, t_means=times[torch.arange(40) % 5])  # each at a key
    sigma = node_spacing(nodes.canonical)
    skinned = SkinnedGaussians(dataclasses.replace(native, **to_canonical(native, times, nodes, sigma)),
                               nodes.canonical, times, nodes.positions, nodes.rotations, sigma)
    for k in range(5):
        rows = (torch.arange(40) % 5 == k).nonzero()[:, 0]
        t = float(times[k])
        before, after = native.slice(t, rows=rows), skinned.slice(t, rows=rows)
        torch.testing.assert_close(after.means, native.means[rows])  # at its temporal mean, a Gaussian is at its mean
        torch.testing.assert_close(after.covariances, before.covariances)
        torch.testing.assert_close(after.opacities, before.opacities)
    # no native velocity is left: a split's children are placed in the canonical frame, not along an old motion
    velocity = condition_on_time(skinned.gaussians.covariance_4d())[1]
    assert float(velocity.abs().max()) < 1e-9


def test_rigidity_is_zero_for_a_rigid_motion_only():
    nodes, _ = rigid_nodes()
    d = torch.cdist(nodes.canonical, nodes.canonical)
    dist, pairs = d.topk(5, dim=1, largest=False)
    pairs, w = pairs[:, 1:], torch.exp(-0.5 * dist[:, 1:] ** 2)
    assert float(rigidity(nodes.canonical, nodes.positions, nodes.rotations, pairs, w, 0.5)) < 1e-20
    bent = nodes.positions.clone()
    bent[3, :10] += 0.1
    assert float(rigidity(nodes.canonical, bent, nodes.rotations, pairs, w, 0.5)) > 1e-4


def test_nodes_are_never_drawn_twice_at_one_place():
    """Tracks repeat positions (a tiny run had 1,047 tracks at 250 places): asked for more nodes than places, the
    sampling gives one node per place, not copies whose zero median spacing would make the skin weights a delta."""
    rng = np.random.default_rng(0)
    places = rng.normal(size=(250, 3))
    points = places[rng.integers(0, 250, 1047)]
    picked = farthest_point_subset(points, 512, np.random.default_rng(1))
    assert len(np.unique(points[picked], axis=0)) == len(picked) == len(np.unique(points, axis=0))
    assert node_spacing(torch.from_numpy(points[picked])) > 0.05
    distinct = farthest_point_subset(places, 100, np.random.default_rng(1))
    assert len(distinct) == 100 and len(set(distinct.tolist())) == 100  # distinct points: as many as asked


def test_nodes_tracked_by_the_models_own_motion_follow_a_moving_box_and_a_still_floor():
    """One camera per time has no videos to track: the model's own motion is the scene flow. On the spinner's exact
    model (velocities from the box's known motion) beside a still plane of Gaussians, the nodes on the box turn and
    travel with it to the ends of the clip, and the nodes on the plane stay put."""
    box = Spinner()
    times = np.linspace(0.0, 1.0, 16)
    moving = build_model("spinner", frames=16)
    grid = torch.stack(torch.meshgrid(torch.linspace(-2, 2, 30), torch.linspace(-2, 2, 30), indexing="ij"), -1)
    plane = torch.cat([grid.reshape(-1, 2), torch.full((900, 1), -1.2)], 1)
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(900, 4)
    still = static_gaussians4d(plane, torch.full((900, 3), 0.05), identity, torch.full((900,), 0.9),
                               torch.full((900, 3), 0.5), time_range=moving.time_range)
    model = concat_models([moving, still])
    tracked = track_nodes_by_motion(model, list(times), count=96)
    assert tracked is not None and tracked.positions.shape[:2] == (16, 96) and tracked.middle == 8
    rot = quaternion.to_rotmat(tracked.rotations.reshape(-1, 4)).reshape(16, 96, 3, 3)
    on_plane = (tracked.canonical[:, 2] + 1.2).abs() < 1e-6
    assert 10 < int(on_plane.sum()) < 86
    torch.testing.assert_close(tracked.positions[:, on_plane], tracked.canonical[on_plane].expand(16, -1, -1))
    on_box = ~on_plane
    centre = torch.from_numpy(box.center(times[8]))
    for k in (0, 7, 9, 15):
        truth = torch.from_numpy(box.rotation(times[k]) @ box.rotation(times[8]).T)
        assert float(angle_deg(truth.T @ rot[k, on_box]).median()) < 3.0
        moved = (truth @ (tracked.canonical[on_box] - centre)[..., None])[..., 0] + torch.from_numpy(box.center(times[k]))
        assert float((tracked.positions[k, on_box] - moved).norm(dim=1).median()) < 0.03


def test_node_sites_go_where_neighbourhoods_move_together_not_where_gaussians_jitter_alone():
    """A floor fitted by one camera per time jitters each Gaussian its own way, often further than an object moves:
    the median over each Gaussian's neighbours cancels that and keeps the object's shared motion, so the nodes meant
    for what moves land on the object, not across the floor."""
    rng = np.random.default_rng(0)
    box = rng.uniform(-0.2, 0.2, (400, 3))
    floor = np.concatenate([rng.uniform(-4, 4, (3000, 2)), np.full((3000, 1), -1.0)], 1)
    points = np.concatenate([box, floor])
    shift = np.zeros_like(points)
    shift[:400] = (0.05, 0.0, 0.0)  # the box moves as one
    jitter = rng.normal(0.0, 0.03, floor.shape)  # each floor Gaussian its own way, |jitter| ~ the box's travel
    displacements = [shift + np.concatenate([np.zeros_like(box), jitter]),
                     -shift + np.concatenate([np.zeros_like(box), -jitter])]
    travel = coherent_travel(points, displacements)
    np.testing.assert_allclose(np.median(travel[:400]), 0.05, atol=0.005)
    threshold = MOVING * np.sqrt(((points - points.mean(0)) ** 2).sum(1).mean())  # what _node_sites calls moving
    assert (np.linalg.norm(jitter, axis=1) > threshold).mean() > 0.6  # one by one, most of the floor "moves"
    assert (travel[400:] > threshold).mean() < 0.05 and (travel[:400] > threshold).all()
    sites, still = _node_sites(points, travel, 96, np.random.default_rng(0))
    assert (sites < 400).sum() >= 48  # most of the three quarters meant for what moves land on the box (before: 1)
    assert not still[sites < 400].any() and still[sites >= 400].sum() == 24  # a quarter still, all on the floor
    # three quarters of the still ones among the quarter of the floor nearest what moves (spread over the whole
    # floor, about a quarter would be): the floor around the box takes still nodes, not the box's
    moves = points[travel > threshold]
    gap = np.linalg.norm(floor[:, None] - moves[None], axis=-1).min(1)
    assert int((gap[sites[still] - 400] <= np.quantile(gap, 0.25)).sum()) >= 18


@pytest.fixture(scope="module")
def small_spinner(tmp_path_factory):
    """4 views x 4 frames at 64 px."""
    return sample_dataset(tmp_path_factory, "spinner", views=4, frames=4, size=64, test_views=2)


@pytest.mark.parametrize("template", ["off", "on"])
def test_a_run_with_nodes_writes_a_skinned_checkpoint_and_resumes_exactly(small_spinner, tmp_path, template):
    ds = load_dataset(small_spinner)
    cfg, _ = auto_recipe(read_traits(ds))
    cfg = dataclasses.replace(cfg.scaled(14), minutes=None, num_gaussians=800, seed=3, motion="nodes", node_count=24,
                              node_template=template)
    a = Trainer(ds, cfg, tmp_path / "a.safetensors", progress=False)
    a.run()
    assert a.nodes is not None and a.node_outcome["template"] == (template == "on")  # tracked at the flow step
    Trainer(ds, cfg, tmp_path / "b.safetensors", progress=False).run(stop_at=int(cfg.flow_motion_at * 14) + 2)
    Trainer(ds, cfg, tmp_path / "b.safetensors", resume=True, progress=False).run()
    ma, mb = load_checkpoint(tmp_path / "a.safetensors").model, load_checkpoint(tmp_path / "b.safetensors").model
    assert ma.kind == "skinned" and ma.num_nodes == 24 and ma.num_keys == 4 and ma.gaussians.accelerations is None
    assert not torch.equal(ma.node_positions, a.nodes.canonical.expand_as(ma.node_positions))  # the nodes move
    for k, v in ma.tensors().items():
        torch.testing.assert_close(v, mb.tensors()[k], rtol=0, atol=0)
    g = ma.slice(float(np.mean(ds.frame_times)))
    assert torch.isfinite(g.means).all() and torch.isfinite(g.covariances).all()
    if template == "on":  # one set for the clip: nearly all are drawn at both ends (a split's children live shorter)
        for t in (ds.frame_times[0], ds.frame_times[-1]):
            assert float(ma.slice(float(t)).visible.float().mean()) > 0.9
    else:  # each frame its own: most are drawn near their own time only
        assert float(ma.slice(float(ds.frame_times[0])).visible.float().mean()) < 0.6


def test_one_camera_per_time_with_nodes_tracks_them_by_the_models_motion_and_resumes_exactly(small_floor, tmp_path):
    """No camera films consecutive frames: the nodes are tracked by the model's own motion, their poses keyed every
    `node_key_every` frames (and at the last: 12 frames, every 4 -> 0, 4, 8, 11), those on the still floor pinned,
    and the run still resumes exactly."""
    ds = load_dataset(small_floor)
    cfg, _ = auto_recipe(read_traits(ds))
    cfg = dataclasses.replace(cfg.scaled(10), minutes=None, num_gaussians=600, seed=2, motion="nodes", node_count=24,
                              flow_motion_at=0.3, node_key_every=4)
    a = Trainer(ds, cfg, tmp_path / "a.safetensors", progress=False)
    a.run()
    assert a.nodes is not None and a.node_outcome["tracked_by"] == "motion"
    assert node_outcome_line(a.node_outcome, "nodes").startswith("control nodes tracked by the model's own motion")
    Trainer(ds, cfg, tmp_path / "b.safetensors", progress=False).run(stop_at=5)
    Trainer(ds, cfg, tmp_path / "b.safetensors", resume=True, progress=False).run()
    ma, mb = load_checkpoint(tmp_path / "a.safetensors").model, load_checkpoint(tmp_path / "b.safetensors").model
    assert ma.kind == "skinned" and ma.num_keys == 4
    torch.testing.assert_close(ma.node_times, torch.tensor([ds.frame_times[k] for k in (0, 4, 8, 11)]))
    for k, v in ma.tensors().items():
        torch.testing.assert_close(v, mb.tensors()[k], rtol=0, atol=0)
    # the nodes on the still floor stay put at every key, through the learning; the others move
    pinned = a.nodes.still.cpu()
    assert 0 < int(pinned.sum()) < 24
    torch.testing.assert_close(ma.node_positions[:, pinned], ma.node_canonical[pinned].expand(4, -1, -1))
    torch.testing.assert_close(ma.node_rotations[:, pinned], torch.tensor([1.0, 0, 0, 0]).expand(4, int(pinned.sum()), 4))
    assert not torch.equal(ma.node_positions[:, ~pinned], ma.node_canonical[~pinned].expand(4, -1, -1))


def test_motion_auto_stays_quadratic_where_one_set_of_gaussians_does_not_fit(small_spinner, tmp_path):
    """Motion 'auto' with the template refused: no nodes, the velocities from the flow, a native checkpoint."""
    ds = load_dataset(small_spinner)
    cfg, _ = auto_recipe(read_traits(ds))
    cfg = dataclasses.replace(cfg.scaled(12), minutes=None, num_gaussians=600, seed=1, motion="auto", node_count=16,
                              node_template="off")
    run = Trainer(ds, cfg, tmp_path / "a.safetensors", progress=False)
    run.run()
    assert run.nodes is None and run.node_outcome is not None and not run.node_outcome["template"]
    assert node_outcome_line(run.node_outcome, "auto").endswith("; the motion stays quadratic")
    assert node_outcome_line({"template": True, "template_ratio": 1.2}, "auto").startswith(
        "one set of Gaussians for the whole clip") and node_outcome_line(None, "auto") is None
    model = load_checkpoint(tmp_path / "a.safetensors").model
    assert model.kind != "skinned" and model.accelerations is not None


def test_the_outcome_line_names_the_measure_that_decided():
    """Where the images have alpha the silhouette ratio decides, and the line reports it rather than the colour's."""
    both = node_outcome_line({"template": True, "template_ratio": 1.5, "silhouette_ratio": 1.1}, "auto")
    assert "1.10 times its silhouette error" in both and "1.50" not in both
    colour = node_outcome_line({"template": False, "template_ratio": 1.5, "silhouette_ratio": None}, "auto")
    assert "1.50 times its error" in colour and colour.endswith("; the motion stays quadratic")


def test_the_silhouette_decides_where_it_was_measured():
    """One set fits by its silhouette whatever its colour ratio (a rigid subject's shading changes under a fixed
    light), is refused by it whatever its colour's, and by the colour where no silhouette was measured."""
    from splatreel.train.pose_fit import FittedTracks

    nodes = TrackedNodes(torch.zeros(3, 4, 3, dtype=torch.float64), torch.zeros(3, 4, 4, dtype=torch.float64), 1)
    steady, shaded = np.array([1.1, 1.0, 1.05]), np.array([1.6, 1.0, 1.3])
    assert template_fits(FittedTracks(nodes, shaded, steady))
    assert not template_fits(FittedTracks(nodes, steady, shaded))
    assert template_fits(FittedTracks(nodes, steady)) and not template_fits(FittedTracks(nodes, shaded))
    assert not template_fits(FittedTracks(nodes, np.array([np.inf, 1.0, 1.0]), steady))  # a key given up on
