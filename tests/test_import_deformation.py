"""4DGaussians / 4DGen folders: HexPlane + deformation MLP forward pass and the keyframe bake."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_import_helpers import deformation_state_dict, random_splats, write_deformation_folder

from splatreel.errors import CheckpointError
from splatreel.formats import read_checkpoint
from splatreel.importers.hexplane import parse_state_dict

AABB = ((2.0, 1.0, 1.5), (-1.0, -1.0, -0.5))  # row 0 = max, row 1 = min, as stored; not symmetric
RES, T = 5, 5


def _zero_layers(sd):
    for k in sd:
        if "feature_out" in k or "_deform." in k:
            sd[k].zero_()


def _known_field(variant: str, shift_x: float, shift_y: float):
    """A field whose features are known ramps: plane 2 (x,t) channel 0 rises along x, plane 5 (z,t) channel 0
    rises along t, all else 1. With the layers below, dx = shift_x * ramp_x (and, for 4DGen's concatenated
    features, dy = shift_y * ramp_t; for 4DGaussians' product, dx = shift_x * ramp_x * ramp_t)."""
    sd = deformation_state_dict(variant, channels=2, base_res=RES, time_res=T, multires=(1,), width=4,
                                depth=1 if variant == "4dgaussians" else 2, aabb=AABB)
    for p in range(6):
        sd[f"deformation_net.grid.grids.0.{p}"].fill_(1.0)
    sd["deformation_net.grid.grids.0.2"][0, 0] = torch.linspace(0, 1, RES)[None, :]  # along W = x
    sd["deformation_net.grid.grids.0.5"][0, 0] = torch.linspace(0, 1, T)[:, None]  # along H = t
    _zero_layers(sd)
    if variant == "4dgaussians":
        sd["deformation_net.feature_out.0.weight"][0, 0] = 1.0  # h0 = product feature, channel 0
        sd["deformation_net.pos_deform.1.weight"][:] = torch.eye(4)
        sd["deformation_net.pos_deform.3.weight"][0, 0] = shift_x
    else:  # features: [plane0 c0 c1, plane1 c0 c1, plane2 ..., ...] at one level
        sd["deformation_net.feature_out.0.weight"][0, 2 * 2] = 1.0  # plane 2, channel 0
        sd["deformation_net.feature_out.0.weight"][1, 5 * 2] = 1.0  # plane 5, channel 0
        sd["deformation_net.feature_out.2.weight"][:] = torch.eye(4)
        sd["deformation_net.pos_deform.fc2.weight"][:] = torch.eye(4)
        sd["deformation_net.pos_deform.fc1.weight"][0, 0] = shift_x
        sd["deformation_net.pos_deform.fc1.weight"][1, 1] = shift_y
    return sd


def _points():
    s = random_splats(5, 0, seed=1)
    s["means"] = np.array([[2.0, 0, 0], [-1.0, 0.3, 0], [0.5, -0.2, 1.0], [1.25, 0.9, -0.4], [3.0, 0, 0]])
    return s


def _ramp_x(x):  # (x̂ + 1) / 2 with x̂ = (x - max) 2 / (min - max) - 1, clamped at the border
    return np.clip((AABB[0][0] - x) / (AABB[0][0] - AABB[1][0]), 0, 1)


def test_4dgaussians_hexplane_moves_points_by_expected_offset(tmp_path):
    s = _points()
    write_deformation_folder(tmp_path, _known_field("4dgaussians", 0.8, 0.0), s)
    ckpt = read_checkpoint(tmp_path, frames=5, time_range=(0.0, 1.0))
    model = ckpt.model
    assert model.kind == "keyframed" and model.num_frames == 5
    for t in (0.0, 0.5, 1.0):
        expected = s["means"].copy()
        expected[:, 0] += 0.8 * _ramp_x(s["means"][:, 0]) * (t + 1) / 2  # t raw: upper half of the time rows
        np.testing.assert_allclose(model.slice(t).means.numpy(), expected, atol=1e-5)
    # the AABB flip: the box maximum gets no offset, the minimum the full one; outside clamps to the border
    moved = (model.slice(1.0).means - model.slice(1.0).means.new_tensor(s["means"])).numpy()[:, 0]
    np.testing.assert_allclose(moved[[0, 1, 4]], [0.0, 0.8, 0.0], atol=1e-5)
    # default heads (no cfg_args): opacity, scale and SH untouched with zero heads
    np.testing.assert_allclose(model.slice(0.5).opacities.numpy(), 1 / (1 + np.exp(-s["opacity_logits"])),
                               atol=1e-6)
    assert ckpt.provenance["deformation"]["variant"] == "4dgaussians"
    assert any(a.startswith("deformed position, scale, rotation") for a in ckpt.provenance["assumed"])


def test_4dgen_concatenated_features_and_time_rows(tmp_path):
    s = _points()
    write_deformation_folder(tmp_path, _known_field("4dgen", 0.6, -0.4), s,
                             cfg_args="Namespace(no_ds=True, no_dr=False, no_do=True, no_dc=True, grid_merge='cat')")
    ckpt = read_checkpoint(tmp_path / "point_cloud" / "iteration_3000" / "deformation.pth")
    model = ckpt.model
    assert model.num_frames == 16 and model.time_range == pytest.approx((0.0, 15 / 16))
    assert ckpt.background == (1.0, 1.0, 1.0)
    for i in (0, 7, 15):
        t = i / 16
        expected = s["means"].copy()
        expected[:, 0] += 0.6 * _ramp_x(s["means"][:, 0])
        expected[:, 1] += -0.4 * (t + 1) / 2
        np.testing.assert_allclose(model.slice(t).means.numpy(), expected, atol=1e-5)


def test_additive_rotation_opacity_head_and_static_table(tmp_path):
    sd = deformation_state_dict("4dgaussians", channels=2, base_res=RES, time_res=T, multires=(1,), width=4)
    _zero_layers(sd)
    sd["deformation_net.rotations_deform.3.bias"][:] = torch.tensor([0.0, 0.5, 0.0, 0.0])
    sd["deformation_net.opacity_deform.3.bias"][:] = 1.5
    sd["deformation_net.pos_deform.3.bias"][:] = torch.tensor([0.1, 0.2, 0.3])
    s = random_splats(4, 3, seed=3)
    s["quats"] = np.array([[1.0, 0, 0, 0]] * 4)
    table = torch.tensor([True, True, False, True])
    write_deformation_folder(tmp_path, sd, s, table=table,
                             cfg_args="Namespace(no_dx=False, no_ds=False, no_dr=False, no_do=False, no_dshs=True)")
    ckpt = read_checkpoint(tmp_path, frames=2)
    g = ckpt.model.slice(0.25)
    q = np.array([1.0, 0.5, 0, 0]) / np.linalg.norm([1.0, 0.5, 0, 0])  # raw q + dq, then normalised
    np.testing.assert_allclose(g.quats[[0, 1, 3]].numpy(), np.tile(q, (3, 1)), atol=1e-6)
    np.testing.assert_allclose(g.opacities[[0, 1, 3]].numpy(), 1 / (1 + np.exp(-(s["opacity_logits"][[0, 1, 3]]
                                                                                    + 1.5))), atol=1e-6)
    np.testing.assert_allclose(g.means[[0, 1, 3]].numpy(), s["means"][[0, 1, 3]] + [0.1, 0.2, 0.3], atol=1e-6)
    # the Gaussian the table marks static keeps its canonical values
    np.testing.assert_allclose(g.means[2].numpy(), s["means"][2], atol=1e-7)
    np.testing.assert_allclose(g.quats[2].numpy(), [1.0, 0, 0, 0], atol=1e-7)
    assert ckpt.provenance["static_gaussians"] == 1
    assert ckpt.provenance["deformation"]["deformed"] == ["position", "scale", "rotation", "opacity"]
    assert not any(a.startswith("deformed") for a in ckpt.provenance["assumed"])  # cfg_args gave the flags


def test_dnerf_lego_shapes_parse_and_bake(tmp_path):
    """The real D-NeRF (lego) config: multires [1, 2], C = 32, T = 25, width 64, defor_depth 0."""
    sd = deformation_state_dict("4dgaussians", channels=32, base_res=64, time_res=25, multires=(1, 2), width=64)
    assert sum(v.numel() for v in sd.values()) == 2_458_419  # the notes' float count for this config
    field = parse_state_dict(sd)
    info = field.describe()
    assert (info["levels"], info["channels"], info["spatial_resolutions"], info["time_resolution"],
            info["merge"], info["width"]) == (2, 32, [64, 128], 25, "mul", 64)
    write_deformation_folder(tmp_path, sd, random_splats(50, 3), iteration=20000)
    write_deformation_folder(tmp_path, sd, random_splats(40, 3), iteration=14000)
    ckpt = read_checkpoint(tmp_path, frames=3)
    assert len(ckpt.model) == 50 and ckpt.provenance["iteration"] == "iteration_20000"
    assert len(read_checkpoint(tmp_path, frames=2, iteration=14000).model) == 40


@pytest.mark.parametrize("change, message", [
    (lambda sd: sd.pop("deformation_net.grid.grids.0.4"), "planes 0..5"),
    (lambda sd: sd.__setitem__("deformation_net.feature_out.0.weight", torch.zeros(4, 7)), "takes 7 inputs"),
    (lambda sd: sd.__setitem__("deformation_net.static_mlp.1.weight", torch.zeros(4, 4)), "static_mlp"),
    (lambda sd: sd.__setitem__("deformation_net.grid.aabb", torch.zeros(2, 3)), "zero-size"),
])
def test_unexpected_state_dicts_are_refused(tmp_path, change, message):
    sd = deformation_state_dict("4dgaussians", channels=2, base_res=RES, time_res=T, multires=(1,), width=4)
    change(sd)
    write_deformation_folder(tmp_path, sd, random_splats(3, 0))
    with pytest.raises(CheckpointError, match=message):
        read_checkpoint(tmp_path)


def test_table_length_mismatch_and_missing_iteration(tmp_path):
    sd = deformation_state_dict("4dgaussians", channels=2, base_res=RES, time_res=T, multires=(1,), width=4)
    write_deformation_folder(tmp_path, sd, random_splats(3, 0), table=torch.ones(5, dtype=torch.bool))
    with pytest.raises(CheckpointError, match=r"expected a bool tensor \[N=3\]"):
        read_checkpoint(tmp_path)
    with pytest.raises(CheckpointError, match="no point_cloud/iteration_7"):
        read_checkpoint(tmp_path, iteration=7)
