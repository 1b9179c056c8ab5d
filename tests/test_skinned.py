"""Skinned 4D Gaussians: carried by control nodes exactly as a rigid motion moves them, the splines through the
node keys, anchors, selection, and the checkpoint round trip."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from splatreel import quaternion
from splatreel.checkpoint import load_checkpoint, save_checkpoint
from splatreel.errors import CheckpointError, ModelError
from splatreel.skinned import SkinnedGaussians, catmull_rom, key_segments, skin_weights
from test_model import random_model

AXIS = torch.tensor([0.3, 1.0, -0.2], dtype=torch.float64) / math.sqrt(0.09 + 1.0 + 0.04)
CENTRE = torch.tensor([0.5, -0.2, 0.1], dtype=torch.float64)


def turn(angle: float) -> torch.Tensor:
    """The rotation by `angle` about AXIS, as a w-first quaternion."""
    return torch.cat([torch.tensor([math.cos(angle / 2)], dtype=torch.float64), math.sin(angle / 2) * AXIS])


def spinning(n=200, m=40, keys=9, turns=0.5, seed=0) -> SkinnedGaussians:
    """Nodes in a box, all turning rigidly about AXIS through CENTRE, `turns` whole turns over the keys."""
    g = torch.Generator().manual_seed(seed)
    canonical = torch.rand(m, 3, generator=g, dtype=torch.float64) * 2 - 1
    times = torch.linspace(0, 1, keys, dtype=torch.float64)
    quats = torch.stack([turn(2 * math.pi * turns * float(s)).expand(m, 4) for s in times])
    positions = torch.stack([(quaternion.to_rotmat(q) @ (canonical - CENTRE)[..., None])[..., 0] + CENTRE
                             for q in quats])
    return SkinnedGaussians(random_model(n, "current"), canonical, times, positions, quats, node_sigma=0.4)


def test_identity_nodes_leave_the_canonical_gaussians():
    model = spinning(turns=0.0)
    native = model.gaussians.slice(0.3)
    g = model.slice(0.3)
    torch.testing.assert_close(g.means, model.gaussians.means)
    torch.testing.assert_close(g.covariances, native.covariances)
    torch.testing.assert_close(g.opacities, native.opacities)
    torch.testing.assert_close(g.sh, native.sh)


def test_rigid_nodes_carry_means_and_covariances_rigidly():
    """At key times the blend of identical rigid motions is that motion, whatever the weights."""
    model = spinning(turns=0.5)
    native = model.gaussians.slice(0.25)
    g = model.slice(0.25)  # a key (9 keys over [0, 1])
    r = quaternion.to_rotmat(turn(2 * math.pi * 0.5 * 0.25)[None])[0]
    torch.testing.assert_close(g.means, (r @ (model.gaussians.means - CENTRE)[..., None])[..., 0] + CENTRE)
    torch.testing.assert_close(g.covariances, r @ native.covariances @ r.T)
    # the velocity of a point turning at 2 pi * 0.5 rad per unit time about the axis, within a few percent: the
    # spline's tangent at a key is the chord's between its neighbours (sin(22.5 deg) / 22.5 deg = 0.974 of the
    # arc's), and a normalised lerp turns slower than its mean rate at its ends
    speed = torch.linalg.cross(AXIS.expand_as(g.means), g.means - CENTRE) * math.pi
    err = (g.velocities - speed).norm(dim=1) / speed.norm(dim=1)
    assert float(err.max()) < 0.05


def test_between_keys_the_spline_follows_the_arc_far_closer_than_a_chord():
    keys = 9
    model = spinning(turns=0.5, keys=keys)
    t = 0.5 / (keys - 1) * 3  # half-way between keys 1 and 2 (22.5 degrees apart)
    g = model.slice(t)
    r = quaternion.to_rotmat(turn(2 * math.pi * 0.5 * t)[None])[0]
    truth = (r @ (model.gaussians.means - CENTRE)[..., None])[..., 0] + CENTRE
    radius = torch.linalg.cross(AXIS.expand_as(truth), truth - CENTRE).norm(dim=1)
    chord = radius * (1 - math.cos(math.radians(22.5) / 2))  # how far a chord cuts inside the arc half-way
    err = (g.means - truth).norm(dim=1)
    assert float(err.max()) < 0.1 * float(chord.max())
    assert float((err / chord.clamp_min(1e-9)).median()) < 0.1


def test_catmull_rom_passes_through_its_keys_and_straight_lines_stay_straight():
    keys = torch.tensor([[0.0, 0], [1, 2], [2, 4], [3, 6], [4, 8]], dtype=torch.float64)
    times = torch.linspace(0, 4, 5, dtype=torch.float64)
    for t in (0.0, 1.0, 2.0, 3.0, 4.0, 0.5, 1.25, 3.9):
        i, u = key_segments(times, torch.tensor([t]))
        torch.testing.assert_close(catmull_rom(keys, i, u)[0], torch.tensor([t, 2 * t], dtype=torch.float64))
    i, u = key_segments(times, torch.tensor([-3.0, 9.0]))  # held outside the keys
    torch.testing.assert_close(catmull_rom(keys, i, u), keys[[0, -1]])


def test_skin_weights_take_the_nearest_nodes_and_sum_to_one():
    nodes = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [0, 0, 1]])
    points = torch.tensor([[0.1, 0.1, 0.1], [4.9, 5, 5]])
    idx, w = skin_weights(points, nodes, sigma=0.5, k=2)
    assert set(idx[0].tolist()) <= {0, 1, 2, 4} and idx[0, 0] == 0
    assert idx[1, 0] == 3
    torch.testing.assert_close(w.sum(1), torch.ones(2))
    assert float(w[1, 0]) > 0.999  # the far second node weighs nothing


def test_anchors_are_where_each_gaussian_is_at_its_temporal_mean():
    model = spinning(n=50)
    anchors = model.anchors()
    for j in range(0, 50, 7):
        t = float(model.gaussians.t_means[j].clamp(0, 1))
        torch.testing.assert_close(anchors[j], model.slice(t).means[j])


def test_rows_select_and_to_agree_with_the_whole_model():
    model = spinning()
    rows = torch.tensor([3, 17, 42, 199])
    whole = model.slice(0.61)
    part = model.slice(0.61, rows=rows)
    torch.testing.assert_close(part.means, whole.means[rows])
    torch.testing.assert_close(part.covariances, whole.covariances[rows])
    picked = model.select(rows).to(dtype=torch.float32).slice(0.61)
    torch.testing.assert_close(picked.means, whole.means[rows].float(), rtol=1e-5, atol=1e-5)
    means, visible = model.centres([0.61])[0]
    torch.testing.assert_close(means, whole.means)
    assert torch.equal(visible, whole.visible)


def test_checkpoint_round_trip(tmp_path):
    model = spinning().to(dtype=torch.float32)
    path = save_checkpoint(tmp_path / "skinned.safetensors", model)
    back = load_checkpoint(path).model
    assert back.kind == "skinned" and back.num_nodes == 40 and back.num_keys == 9
    assert back.node_sigma == pytest.approx(0.4)
    for t in (0.0, 0.33, 1.0):
        torch.testing.assert_close(back.slice(t).means, model.slice(t).means)


def test_the_checkpoint_keeps_a_given_skin_and_refuses_a_bad_one(tmp_path):
    """A trainer's skin (here each Gaussian's nodes in reverse order of nearness, weights swapped alike) is what the
    checkpoint's model draws with, not one derived afresh from the canonical means; a skin naming a node the model
    lacks is a one-line error."""
    spun = spinning().to(dtype=torch.float32)  # the nodes moved apart (a rigid motion draws alike with any skin)
    model = replace(spun, node_positions=spun.node_positions + 0.3 * torch.randn(spun.node_positions.shape,
                                                                                generator=torch.Generator().manual_seed(1)))
    nodes, weights = model.skin
    given = replace(model, skin=(nodes.flip(1), weights.roll(1, 1)))
    back = load_checkpoint(save_checkpoint(tmp_path / "given.safetensors", given)).model
    assert torch.equal(back.skin[0], given.skin[0]) and back.skin[0].dtype == torch.int64
    torch.testing.assert_close(back.skin[1], given.skin[1])
    assert (back.slice(0.5).means - model.slice(0.5).means).abs().max() > 1e-2  # the derived skin draws elsewhere
    torch.testing.assert_close(back.slice(0.5).means, given.slice(0.5).means)
    with pytest.raises(ModelError, match="node indices"):
        replace(model, skin=(nodes + model.num_nodes, weights))


def test_bad_node_tensors_fail_in_one_line(tmp_path):
    model = spinning()
    with pytest.raises(ModelError, match="node_positions has shape"):
        SkinnedGaussians(model.gaussians, model.node_canonical, model.node_times, model.node_positions[:, :5],
                         model.node_rotations, 0.4)
    with pytest.raises(ModelError, match="strictly increasing"):
        SkinnedGaussians(model.gaussians, model.node_canonical, model.node_times.flip(0), model.node_positions,
                         model.node_rotations, 0.4)
    path = save_checkpoint(tmp_path / "m.safetensors", model)
    data = bytearray(path.read_bytes())
    data[-8:] = np.frombuffer(np.float64([np.nan]).tobytes(), np.uint8).tobytes()  # the last tensor's last value
    path.write_bytes(bytes(data))
    with pytest.raises(CheckpointError):
        load_checkpoint(path)
