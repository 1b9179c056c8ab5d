"""``export 4dgs`` and its reader: written and read through the ``fourdgs`` package, whose own reconstruction
(``state_at``) matches native slicing, and which round-trips a sample's model."""

from __future__ import annotations

import numpy as np
import pytest

from splatreel.checkpoint import load_checkpoint, save_checkpoint
from splatreel.cli import main
from splatreel.export import ExportError
from splatreel.export.four_dgs import four_dgs_bytes
from splatreel.importers.four_dgs import read_four_dgs, sh_from_bytes, sh_to_bytes
from splatreel.viewer.synthetic import synthetic_model

from conftest import round_trip_psnrs

from test_model import keyframed


def file_order(model_means: np.ndarray, file_positions: np.ndarray) -> np.ndarray:
    """For each Gaussian of the file, the model's index: the container reorders Gaussians (for chunking and
    compression) and quantises positions, so match each to the model's nearest mean."""
    from scipy.spatial import cKDTree

    dist, index = cKDTree(model_means).query(file_positions)
    assert dist.max() < 5e-3 and len(np.unique(index)) == len(index)
    return index


@pytest.fixture(scope="module")
def model():
    return synthetic_model(300, seed=7, speed=0.3, lifetime=0.3, sh_degree=2, time_range=(1.0, 3.0))


def test_the_packages_own_reconstruction_is_the_native_slice(model, tmp_path):
    import fourdgs

    path = tmp_path / "m.4dgs"
    path.write_bytes(four_dgs_bytes(model, duration_sec=4.0))  # 2 model units -> 4 s
    scene = fourdgs.read(str(path))
    assert scene.duration_sec == pytest.approx(4.0) and scene.gaussians.count == len(model)
    ids = file_order(model.means.numpy(), scene.gaussians.positions)
    for t in (1.5, 2.0, 2.6):
        state = scene.gaussians.state_at((t - 1.0) * 2.0)  # seconds
        g = model.slice(t)
        shown = ids[state["indices"]]  # the model's indices of the Gaussians the package shows
        # the package cuts at >= 0.05 of the quantised width, native slicing at > 0.05: the same Gaussians but for
        # a few on the edge
        assert len(np.setxor1d(shown, np.flatnonzero(g.visible.numpy()))) <= 0.03 * len(model)
        np.testing.assert_allclose(state["centers"], g.means.numpy()[shown], atol=3e-3)  # the "fine" profile's bound


def test_read_back_through_the_package(model, tmp_path):
    path = tmp_path / "m.4dgs"
    path.write_bytes(four_dgs_bytes(model))
    back = read_four_dgs(path, time_range=model.time_range).model
    assert back.sh_degree == 2 and back.time_range == model.time_range
    import torch

    ids = torch.as_tensor(file_order(model.means.numpy(), back.means.numpy()))
    for t in (1.5, 2.6):
        a, b = model.slice(t).select(ids), back.slice(t)
        both = (a.visible & b.visible).numpy()
        assert both.sum() > 0.9 * a.visible.sum().item()
        np.testing.assert_allclose(b.means.numpy()[both], a.means.numpy()[both], atol=3e-3)
        np.testing.assert_allclose(b.opacities.numpy()[both], a.opacities.numpy()[both], atol=0.02)
        np.testing.assert_allclose(b.sh.numpy()[both][:, 1:], np.clip(a.sh.numpy()[both][:, 1:], -4, 4),
                                   atol=4.0 / 255 + 1e-6)  # SH bands 1-2 as bytes in [-4, 4]
    sh = np.random.default_rng(0).uniform(-5, 5, (10, 8, 3))
    np.testing.assert_allclose(sh_from_bytes(sh_to_bytes(sh), 10), np.clip(sh, -4, 4), atol=4.0 / 255 + 1e-6)


def test_a_sample_model_renders_the_same_after_the_round_trip(tmp_path, capsys):
    """The container's own fidelity on a model of a real object (the spinner sample's exact model: 20k Gaussians,
    linear motion; accelerations, which .4dgs cannot hold, are dropped with a warning: the test below). The bundled
    trained model is skinned, which .4dgs cannot hold either (tests/test_skinned_consumers.py)."""
    from splatreel.samples import build_model

    ckpt = save_checkpoint(tmp_path / "linear.safetensors", build_model("spinner"), background=(1.0, 1.0, 1.0))
    out, back = tmp_path / "s.4dgs", tmp_path / "back.safetensors"
    assert main(["export", "4dgs", str(ckpt), "--out", str(out), "--quiet"]) == 0
    assert out.stat().st_size < 0.5 * ckpt.stat().st_size  # quantised and compressed
    assert main(["convert", str(out), "--out", str(back)]) == 0
    assert min(round_trip_psnrs(ckpt, back)) > 35.0


def test_accelerations_are_dropped_with_a_warning_and_the_velocity_at_the_temporal_mean_kept(model, tmp_path):
    import dataclasses
    import warnings

    import fourdgs
    import torch

    g = torch.Generator().manual_seed(3)
    fast = dataclasses.replace(model, accelerations=0.5 * torch.randn(len(model), 3, generator=g))
    var_t = model.covariance_4d().double()[:, 3, 3].numpy()  # Σ_tt
    worst = float((2.0 * fast.accelerations.double().norm(dim=1).numpy() * var_t).max())  # |a| (2 σ_t)^2 / 2
    with pytest.warns(UserWarning, match="accelerations are dropped") as caught:
        data = four_dgs_bytes(fast)
    (message,) = [str(w.message) for w in caught]
    assert f"up to {worst:.3g} model units" in message and "\n" not in message
    # still written: the linear model's own file, with each Gaussian's velocity at its temporal mean
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a linear model: no warning
        assert data == four_dgs_bytes(model)
    (tmp_path / "fast.4dgs").write_bytes(data)
    assert fourdgs.read(str(tmp_path / "fast.4dgs")).gaussians.count == len(model)
    ckpt = save_checkpoint(tmp_path / "fast.safetensors", fast)
    with pytest.warns(UserWarning, match="accelerations are dropped"):  # the CLI prints it as one warning line
        assert main(["export", "4dgs", str(ckpt), "--out", str(tmp_path / "cli.4dgs"), "--quiet"]) == 0
    assert (tmp_path / "cli.4dgs").read_bytes() == data


def test_what_4dgs_cannot_hold_is_a_clear_error(tmp_path, capsys):
    with pytest.raises(ExportError, match="keyframed"):
        four_dgs_bytes(keyframed())
    ckpt = save_checkpoint(tmp_path / "m.safetensors", synthetic_model(20, seed=1))
    assert main(["export", "4dgs", str(ckpt), "--out", str(tmp_path / "x.bin"), "--quiet"]) == 1
    assert "a .4dgs file name" in capsys.readouterr().err
    good = four_dgs_bytes(synthetic_model(20, seed=1))
    (tmp_path / "cut.4dgs").write_bytes(good[:40])
    assert main(["info", str(tmp_path / "cut.4dgs")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cut.4dgs" in err
