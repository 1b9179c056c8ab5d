"""Official 4DGS / Efficient4D checkpoints: layout, conventions, colour, defaults, safe loading."""

from __future__ import annotations

import logging
import math
import os
import pickle

import numpy as np
import pytest
import torch
from test_import_helpers import C0, as_numpy1_pickle, capture_tuple, slice_reference

from splatreel.errors import CheckpointError
from splatreel.formats import read_checkpoint

Q_L = [0.9, 0.3, -0.2, 0.25]  # unnormalised on purpose: the file stores raw quaternions
Q_R = [0.8, -0.1, 0.35, 0.4]


def _one_gaussian(**extra):
    values = {"_xyz": torch.tensor([[0.2, -0.4, 1.1]]), "_t": torch.tensor([[0.45]]),
              "_scaling": torch.log(torch.tensor([[0.3, 0.12, 0.05]])), "_scaling_t": torch.log(torch.tensor([[0.2]])),
              "_rotation": torch.tensor([Q_L]), "_rotation_r": torch.tensor([Q_R]), "_opacity": torch.tensor([[0.7]])}
    values.update(extra)
    return values


@pytest.mark.parametrize("convention", ["current", "legacy"])
def test_slice_of_hand_made_gaussian_matches_formula_under_each_convention(tmp_path, convention):
    path = tmp_path / "chkpnt7000.pth"
    torch.save((capture_tuple(n=1, m=1, active_sh=0, active_sh_t=0, values=_one_gaussian()), 7000), path)
    model = read_checkpoint(path, convention=convention, time_range=(0.0, 1.0)).model
    assert model.rotation_convention == convention
    for t in (0.3, 0.45, 0.6):
        mean, cov, opacity = slice_reference([0.2, -0.4, 1.1], 0.45, [0.3, 0.12, 0.05], 0.2, Q_L, Q_R, 0.7,
                                             convention, t)
        g = model.slice(t)
        np.testing.assert_allclose(g.means[0].numpy(), mean, atol=1e-5)
        np.testing.assert_allclose(g.covariances[0].numpy(), cov, atol=1e-6)
        np.testing.assert_allclose(float(g.opacities[0]), opacity, atol=1e-6)


def test_conventions_give_different_motion(tmp_path):
    path = tmp_path / "chkpnt7000.pth"
    torch.save((capture_tuple(n=1, m=1, active_sh=0, active_sh_t=0, values=_one_gaussian()), 7000), path)
    a = read_checkpoint(path, convention="current").model.slice(0.8).means
    b = read_checkpoint(path, convention="legacy").model.slice(0.8).means
    assert float((a - b).abs().max()) > 1e-2


def test_main_checkpoint_defaults_are_assumed_and_reported(tmp_path, caplog):
    path = tmp_path / "chkpnt30000.pth"
    torch.save((capture_tuple(n=6), 30000), path)
    with caplog.at_level(logging.WARNING, logger="splatreel.importers"):
        ckpt = read_checkpoint(path)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "\n" not in lines[0]
    assert "--convention current" in lines[0] and "--time-range 0 1" in lines[0]
    model = ckpt.model
    assert (model.rotation_convention, model.time_range, ckpt.background) == ("current", (0.0, 1.0), (0, 0, 0))
    assert (model.sh_degree, model.sh_degree_t) == (3, 2)
    prov = ckpt.provenance
    assert prov["iteration"] == 30000 and prov["reader"] == "4dgs-checkpoint"
    assert prov["spatial_lr_scale"] == pytest.approx(2.375)
    assert any(a.startswith("--convention current") for a in prov["assumed"])
    assert any(a.startswith("--background 0 0 0") for a in prov["assumed"])


def test_efficient4d_bare_tuple_defaults_legacy_white_0_15(tmp_path):
    path = tmp_path / "model.pth"
    cap = capture_tuple(n=5, m=1, active_sh=0, active_sh_t=0, env_map=torch.empty(0), spatial_lr_scale=10)
    torch.save(cap, path)
    ckpt = read_checkpoint(path)
    assert ckpt.model.rotation_convention == "legacy"
    assert ckpt.model.time_range == (0.0, 15.0)
    assert ckpt.background == (1.0, 1.0, 1.0)
    assert (ckpt.model.sh_degree, ckpt.model.sh_rest.shape[1]) == (0, 0)
    assert ckpt.provenance["iteration"] is None and "Efficient4D" in ckpt.provenance["tool"]


def test_given_options_are_not_assumed_and_folder_picks_latest(tmp_path, caplog):
    for it in (7000, 30000):
        torch.save((capture_tuple(n=3, seed=it), it), tmp_path / f"chkpnt{it}.pth")
    torch.save((capture_tuple(n=3), 999), tmp_path / "chkpnt_best.pth")
    (tmp_path / "cfg_args").write_text("Namespace(sh_degree=3, white_background=True, source_path='/data/lego')")
    with caplog.at_level(logging.WARNING, logger="splatreel.importers"):
        ckpt = read_checkpoint(tmp_path, convention="legacy", time_range=(0, 10))
    assert ckpt.provenance["iteration"] == 30000
    assert ckpt.provenance["assumed"] == [] and not caplog.records
    assert ckpt.background == (1.0, 1.0, 1.0)  # from cfg_args white_background
    assert ckpt.model.time_range == (0.0, 10.0) and ckpt.model.rotation_convention == "legacy"


def test_4d_colour_time_terms_and_cuda_degree_gating(tmp_path):
    rest = torch.zeros(1, 47, 3)
    rest[0, 15] = torch.tensor([0.4, -0.2, 0.1])  # coefficient 16 = (n=1, j=0)
    rest[0, 31] = torch.tensor([-0.3, 0.5, 0.2])  # coefficient 32 = (n=2, j=0)
    dc = torch.tensor([[[0.5, 0.1, -0.2]]])
    values = _one_gaussian(_features_dc=dc, _features_rest=rest)
    path = tmp_path / "chkpnt1.pth"
    torch.save((capture_tuple(n=1, m=48, active_sh=3, active_sh_t=2, values=values), 1), path)
    model = read_checkpoint(path, time_range=(0.0, 2.0)).model
    assert (model.sh_degree, model.sh_degree_t) == (3, 2)
    for t in (0.1, 0.9):
        tau, period = 0.45 - t, 2.0
        expected = C0 * (dc[0, 0] + math.cos(2 * math.pi * tau / period) * rest[0, 15]
                         + math.cos(4 * math.pi * tau / period) * rest[0, 31]) + 0.5
        rgb = model.slice(t).colors(torch.tensor([5.0, 1.0, 2.0]))[0]
        torch.testing.assert_close(rgb, expected.clamp_min(0), atol=1e-5, rtol=0)
    # active degree 2: the official CUDA path evaluates no time terms (they sit inside `if (deg > 2)`)
    torch.save((capture_tuple(n=1, m=48, active_sh=2, active_sh_t=2, values=values), 1), path)
    gated = read_checkpoint(path, time_range=(0.0, 2.0)).model
    assert (gated.sh_degree, gated.sh_degree_t) == (2, 0)
    rgb = gated.slice(0.9).colors(torch.tensor([5.0, 1.0, 2.0]))[0]
    torch.testing.assert_close(rgb, (C0 * dc[0, 0] + 0.5).clamp_min(0), atol=1e-5, rtol=0)


@pytest.mark.parametrize("m, degrees", [(1, (0, 0)), (16, (3, 0)), (33, (3, 0)), (6, (1, 0)), (32, (3, 1))])
def test_sh_layouts_inferred_from_coefficient_count(tmp_path, m, degrees):
    path = tmp_path / "chkpnt5.pth"
    torch.save((capture_tuple(n=2, m=m, active_sh=degrees[0], active_sh_t=degrees[1]), 5), path)
    model = read_checkpoint(path).model
    assert (model.sh_degree, model.sh_degree_t) == degrees


def test_non_rot_4d_checkpoint_is_static_with_variance_marginal(tmp_path):
    values = _one_gaussian(_scaling_t=torch.tensor([[math.log(0.04)]]))  # stored as a log VARIANCE here
    path = tmp_path / "chkpnt3.pth"
    torch.save((capture_tuple(n=1, m=1, active_sh=0, active_sh_t=0, rot_4d=False, values=values), 3), path)
    model = read_checkpoint(path).model
    g = model.slice(0.65)
    torch.testing.assert_close(g.means[0], torch.tensor([0.2, -0.4, 1.1]), atol=1e-6, rtol=0)
    expected = 1 / (1 + math.exp(-0.7)) * math.exp(-0.5 * 0.2 ** 2 / 0.04)
    assert float(g.opacities[0]) == pytest.approx(expected, abs=1e-6)


def test_numpy1_pickled_scalars_load(tmp_path):
    path = tmp_path / "chkpnt9.pth"
    torch.save((capture_tuple(n=2), 9), path)
    as_numpy1_pickle(path)
    assert read_checkpoint(path, convention="current").provenance["spatial_lr_scale"] == pytest.approx(2.375)


class _Payload:
    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.mark.parametrize("how", ["torch.save", "raw pickle"])
def test_malicious_pickle_is_refused_and_never_runs(tmp_path, how):
    marker = tmp_path / "PWNED"
    path = tmp_path / "chkpnt1.pth"
    if how == "torch.save":
        torch.save((capture_tuple(n=1)[:11] + (_Payload(marker),), 1), path)
    else:
        path.write_bytes(pickle.dumps(((3, _Payload(marker)), 1), protocol=2))
    with pytest.raises(CheckpointError, match="refused to load.*system") as exc:
        read_checkpoint(path)
    assert "\n" not in str(exc.value)
    assert not marker.exists()


def test_cfg_args_code_is_never_evaluated(tmp_path):
    marker = tmp_path / "PWNED"
    torch.save((capture_tuple(n=1), 1), tmp_path / "chkpnt1.pth")
    (tmp_path / "cfg_args").write_text(f"Namespace(white_background=__import__('os').system('touch {marker}'))")
    ckpt = read_checkpoint(tmp_path / "chkpnt1.pth")
    assert not marker.exists() and ckpt.background == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("payload, message", [
    (lambda: tuple(range(7)), "7 entries"),
    (lambda: {"foo": torch.zeros(1)}, "not an official 4DGS"),
    (lambda: (capture_tuple(n=2)[:16] + ("yes",) + capture_tuple(n=2)[17:], 1), r"entry 16 \(rot_4d\)"),
    (lambda: (capture_tuple(n=2, values={"_scaling": torch.zeros(2, 2)}), 1), r"_scaling has shape \[2, 2\]"),
    (lambda: (capture_tuple(n=2, values={"_xyz": torch.full((2, 3), float("nan"))}), 1), "NaN"),
])
def test_bad_checkpoints_give_one_line_errors(tmp_path, payload, message):
    path = tmp_path / "chkpnt1.pth"
    torch.save(payload(), path)
    with pytest.raises(CheckpointError, match=message) as exc:
        read_checkpoint(path)
    assert "\n" not in str(exc.value) and str(path) in str(exc.value)


def test_truncated_checkpoint(tmp_path):
    path = tmp_path / "chkpnt1.pth"
    torch.save((capture_tuple(n=2), 1), path)
    path.write_bytes(path.read_bytes()[:500])
    with pytest.raises(CheckpointError, match="not a readable PyTorch file"):
        read_checkpoint(path)


def test_3d_capture_and_loaded_pth_dict(tmp_path):
    cap = capture_tuple(n=3, m=16, active_sh=3)
    cap3d = (3, *cap[1:7], torch.zeros(3), torch.zeros(3, 1), torch.zeros(3, 1), {}, np.float64(1.0))
    torch.save((cap3d, 100), tmp_path / "chkpnt100.pth")
    model = read_checkpoint(tmp_path / "chkpnt100.pth").model
    assert model.sh_degree == 3 and "gaussian_dim 3" in read_checkpoint(tmp_path / "chkpnt100.pth").provenance["tool"]
    g = model.slice(0.5)
    torch.testing.assert_close(g.means, cap[1].detach(), atol=1e-6, rtol=0)
    torch.testing.assert_close(g.sh, torch.cat([cap[2], cap[3]], 1).detach(), atol=1e-6, rtol=0)

    # the dict read by the official --loaded_pth option: features stored [N, 3, K]
    d = {"xyz": cap[1].detach(), "features_dc": cap[2].detach().transpose(1, 2),
         "features_rest": cap[3].detach().transpose(1, 2), "t": cap[13].detach(), "scaling": cap[4].detach(),
         "rotation": cap[5].detach(), "scaling_t": cap[14].detach(), "rotation_r": cap[15].detach(),
         "opacity": cap[6].detach()}
    torch.save(d, tmp_path / "init.pth")
    model = read_checkpoint(tmp_path / "init.pth").model
    torch.testing.assert_close(model.sh_rest, cap[3].detach())
    torch.testing.assert_close(model.quats_r, cap[15].detach())


def test_env_map_is_dropped_with_a_warning(tmp_path, caplog):
    path = tmp_path / "chkpnt1.pth"
    torch.save((capture_tuple(n=2, env_map=torch.nn.Parameter(torch.rand(3, 8, 8))), 1), path)
    with caplog.at_level(logging.WARNING, logger="splatreel.importers"):
        ckpt = read_checkpoint(path, convention="current", time_range=(0, 10), background=(0, 0, 0))
    assert "environment map [3, 8, 8] dropped" in ckpt.provenance["warnings"][0]
    assert [r.getMessage().count("environment map") for r in caplog.records] == [1]
