"""``export splatv`` and its reader: the byte layout of splaTV / gsplat.js, the native 4D mapping (exact but for
colour and half-float precision), and the round trip through ``convert``."""

from __future__ import annotations

import json
import struct
from dataclasses import replace

import numpy as np
import pytest
import torch

from splatreel.checkpoint import save_checkpoint
from splatreel.cli import main
from splatreel.errors import CheckpointError
from splatreel.export import ExportError
from splatreel.export.splatv import splatv_records, write_splatv
from splatreel.importers.splatv import RECORD, parse_splatv, read_splatv
from splatreel.viewer.synthetic import synthetic_model

from conftest import round_trip_psnrs

from test_model import keyframed


@pytest.fixture(scope="module")
def model():
    return synthetic_model(400, seed=5, speed=0.3, lifetime=0.3, sh_degree=0, time_range=(2.0, 6.0))


def test_the_record_and_container_follow_splatv(model, tmp_path):
    offsets = {name: RECORD.fields[name][1] for name in RECORD.names}
    assert offsets == {"position": 0, "rotation": 12, "scale": 20, "rgba": 28, "motion": 32, "omega": 52,
                       "trbf": 60} and RECORD.itemsize == 64
    data = write_splatv(model, tmp_path / "m.splatv").read_bytes()
    magic, length = struct.unpack_from("<II", data)
    assert data[:2] == b"Kg" and magic == 0x674B
    chunk = json.loads(data[8:8 + length])[0]
    assert chunk["type"] == "splat" and chunk["texwidth"] == 4096 and chunk["texheight"] == 1  # 400 < 1024 a row
    assert chunk["size"] == 4096 * 16 and len(data) == 8 + length + chunk["size"]
    camera = chunk["cameras"][0]
    assert {"fx", "fy", "width", "height", "position", "rotation"} <= set(camera)
    assert np.allclose(np.asarray(camera["rotation"]) @ np.asarray(camera["rotation"]).T, np.eye(3), atol=1e-9)
    records, _ = parse_splatv(data)
    assert len(records) == len(model)  # the zero padding is not read back
    importance = records["scale"][:, :3].astype(np.float64).prod(1) * records["rgba"][:, 3]
    # biggest first, as the player streams (up to the rounding of the stored halves and bytes)
    assert importance[0] == importance.max() and (np.diff(importance) <= 0.01 * importance.max()).all()


def test_the_players_temporal_factor_is_the_native_marginal(model):
    from splatreel.covariance import condition_on_time, temporal_marginal

    records = splatv_records(model)
    t0, t1 = model.time_range
    _, velocity, var_t = condition_on_time(model.covariance_4d())
    # match records to Gaussians by position (the order is by importance)
    index = {tuple(np.round(p, 5)): i for i, p in enumerate(model.means.numpy())}
    ids = np.array([index[tuple(np.round(p, 5))] for p in records["position"]])
    for t in (2.5, 4.0, 5.2):
        tau = (t - t0) / (t1 - t0)
        c, s = records["trbf"][:, 0].astype(np.float64), records["trbf"][:, 1].astype(np.float64)
        player = np.exp(-((tau - c) / s) ** 2)
        native = temporal_marginal(t, model.t_means, var_t).numpy()[ids]
        np.testing.assert_allclose(player, native, atol=5e-3)  # half-float c and s
    np.testing.assert_allclose(records["motion"][:, :3], velocity.numpy()[ids] * (t1 - t0), rtol=2e-3, atol=1e-4)
    assert not records["motion"][:, 3:].any() and not records["omega"].any()


def test_read_back_the_slices_match(model, tmp_path):
    back = read_splatv(write_splatv(model, tmp_path / "m.splatv"), time_range=model.time_range).model
    assert back.time_range == model.time_range and len(back) == len(model)
    index = {tuple(np.round(p, 5)): i for i, p in enumerate(model.means.numpy())}
    ids = torch.tensor([index[tuple(np.round(p, 5))] for p in back.means.numpy()])
    for t in (2.5, 4.0, 5.2):
        a, b = model.slice(t).select(ids), back.slice(t)
        both = (a.visible & b.visible).numpy()
        assert both.mean() > 0.9 * a.visible.float().mean().item()
        np.testing.assert_allclose(b.means.numpy()[both], a.means.numpy()[both], atol=2e-3)
        np.testing.assert_allclose(b.covariances.numpy()[both], a.covariances.numpy()[both], atol=2e-6, rtol=5e-3)
        np.testing.assert_allclose(b.opacities.numpy()[both], a.opacities.numpy()[both], atol=8e-3)
        np.testing.assert_allclose(b.sh.numpy()[both], a.sh.numpy()[both], atol=0.5 / 255 / 0.2821 + 1e-6)


def accelerated(model):
    """`model` with accelerations large enough to bend each Gaussian's path visibly within its life."""
    g = torch.Generator().manual_seed(11)
    return replace(model, accelerations=0.4 * torch.randn(len(model), 3, generator=g, dtype=model.means.dtype))


def test_accelerations_are_the_players_quadratic_term_and_come_back(model, tmp_path):
    fast = accelerated(model)
    t0, t1 = fast.time_range
    span = t1 - t0
    records = splatv_records(fast)
    index = {tuple(np.round(p, 5)): i for i, p in enumerate(fast.means.numpy())}
    ids = torch.tensor([index[tuple(np.round(p, 5))] for p in records["position"]])
    # hybrid.js: p0 + m1 dtau + m2 dtau^2 + m3 dtau^3, dtau = (t - mu_t) / T, so m2 = a T^2 / 2
    np.testing.assert_allclose(records["motion"][:, 3:6], 0.5 * fast.accelerations.numpy()[ids] * span ** 2,
                               rtol=2e-3, atol=1e-4)
    assert not records["motion"][:, 6:].any()
    path = write_splatv(fast, tmp_path / "fast.splatv")
    ck = read_splatv(path, time_range=fast.time_range)
    assert "warnings" not in ck.provenance  # nothing dropped
    back = ck.model
    assert back.accelerations is not None
    np.testing.assert_allclose(back.accelerations.numpy(), fast.accelerations.numpy()[ids], rtol=2e-3, atol=1e-4)
    linear = replace(back, accelerations=None)
    for t in (2.5, 4.0, 5.2):
        a, b = fast.slice(t).select(ids), back.slice(t)
        both = (a.visible & b.visible).numpy()
        assert both.mean() > 0.9 * a.visible.float().mean().item()
        np.testing.assert_allclose(b.means.numpy()[both], a.means.numpy()[both], atol=3e-3)
        np.testing.assert_allclose(b.velocities.numpy()[both], a.velocities.numpy()[both], atol=3e-3)
        # away from their temporal means the accelerations move the Gaussians far past that tolerance
        tau = t - fast.t_means.numpy()[ids.numpy()][both]
        away = np.abs(tau) > 0.5
        assert away.sum() > 20
        miss = np.abs(linear.slice(t).means.numpy()[both] - a.means.numpy()[both]).max(1)
        assert np.median(miss[away]) > 0.05


def test_a_sample_model_renders_the_same_after_the_round_trip(tmp_path, capsys):
    """On the spinner sample's exact model (20k Gaussians of a real object; the bundled trained model is skinned,
    which .splatv cannot hold: tests/test_skinned_consumers.py)."""
    from splatreel.samples import build_model

    ckpt = save_checkpoint(tmp_path / "spinner.safetensors", build_model("spinner"), background=(1.0, 1.0, 1.0))
    out, back = tmp_path / "s.splatv", tmp_path / "back.safetensors"
    assert main(["export", "splatv", str(ckpt), "--out", str(out), "--quiet"]) == 0
    assert "the whole animation" in capsys.readouterr().out
    assert main(["convert", str(out), "--out", str(back)]) == 0
    assert min(round_trip_psnrs(ckpt, back)) > 35.0


def test_what_splatv_cannot_hold_is_a_clear_error(tmp_path, capsys):
    with pytest.raises(ExportError, match="keyframed"):
        write_splatv(keyframed(), tmp_path / "k.splatv")
    ckpt = save_checkpoint(tmp_path / "m.safetensors", synthetic_model(20, seed=1))
    assert main(["export", "splatv", str(ckpt), "--out", str(tmp_path / "x.splatv"), "--frame-count", "4"]) == 1
    assert "do not apply" in capsys.readouterr().err
    good = write_splatv(synthetic_model(20, seed=1), tmp_path / "g.splatv").read_bytes()
    (tmp_path / "cut.splatv").write_bytes(good[: len(good) // 2])
    with pytest.raises(CheckpointError, match="truncated"):
        read_splatv(tmp_path / "cut.splatv")
    records, cameras = parse_splatv(good)
    records["motion"][:, 6] = 0.5  # a jerk: Spacetime Gaussians' cubic term, which splatreel models do not have
    from splatreel.importers.splatv import splatv_bytes

    (tmp_path / "jerk.splatv").write_bytes(splatv_bytes(records, cameras))
    ck = read_splatv(tmp_path / "jerk.splatv")
    assert any("jerk" in w for w in ck.provenance["warnings"])
    assert ck.model.accelerations is None  # the quadratic slots are all 0
