"""The trained checkpoint shipped in ``samples/``: small, loadable, trained (it reproduces held-out views of its
sample), and reachable from ``splatreel sample --trained`` and ``splatreel view`` with no model."""

from __future__ import annotations


import numpy as np
import pytest
import torch

from splatreel.checkpoint import load_checkpoint
from splatreel.cli import main
from splatreel.errors import SplatreelError
from splatreel.samples import TRAINED, DatasetConfig, MeshRenderer, get_sample, trained_checkpoint
from splatreel.samples import dataset as sample_dataset
from splatreel.skinned import SkinnedGaussians
from splatreel.train import losses
from splatreel.viewer.renderer import RenderSettings, render_image

#: Worst held-out view of the bundled model, scored on black (the model carries its alpha, so it can be composited
#: on any backdrop; on its training white a dark silhouette costs ~6 dB more, bench/train.py); a broken checkpoint,
#: a broken loader or a renderer drifting from the trainer would fall far below this.
MIN_HELD_OUT_PSNR = 26.0


@pytest.fixture(scope="module")
def bundled():
    return load_checkpoint(trained_checkpoint("spinner"))


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """`splatreel.train.losses.psnr` (the project's one PSNR) on numpy images."""
    return losses.psnr(torch.from_numpy(np.asarray(a, np.float64)), torch.from_numpy(np.asarray(b, np.float64)))


def test_bundled_checkpoint_is_small_and_says_how_it_was_made(bundled):
    path = trained_checkpoint()
    assert path.stat().st_size <= 10 * 2 ** 20
    assert TRAINED == ("spinner",)
    # the default recipe on a rigid object: one set of Gaussians for the clip, carried by rigidly moving nodes
    assert isinstance(bundled.model, SkinnedGaussians) and 10_000 < len(bundled.model) <= 60_000  # densified, capped
    assert bundled.training["nodes"]["template"] and bundled.model.num_keys == 16
    assert bundled.provenance["tool"] == "splatreel train"
    assert bundled.provenance["preset"] == "auto" and bundled.training["iteration"] == 600
    assert bundled.views and bundled.background == (1.0, 1.0, 1.0)  # its cameras and the D-NeRF white


def test_bundled_checkpoint_reproduces_held_out_views_of_its_sample(bundled):
    """GL render of the bundled model vs the sample mesh rendered at the dataset's test cameras and times (other
    azimuths and elevations, times between the training frames)."""
    config = DatasetConfig()
    views = sample_dataset.test_views(config)[1::4]
    obj = get_sample("spinner")
    renderer = MeshRenderer()
    try:
        truths = [next(renderer.render(obj.mesh(v.time), [v.camera])).astype(np.float64) / 255 for v in views]
    finally:
        renderer.release()
    scores = []
    for view, truth in zip(views, truths):
        expected = truth[..., :3] * truth[..., 3:]  # on black
        img = render_image(bundled.model, view.camera, view.time, RenderSettings(background=(0.0, 0.0, 0.0)))
        scores.append(psnr(np.clip(img[..., :3], 0, 1), expected))
    assert min(scores) >= MIN_HELD_OUT_PSNR, scores


def test_sample_cli_copies_the_bundled_checkpoint(tmp_path, capsys):
    out = tmp_path / "spinner.safetensors"
    assert main(["sample", "spinner", "--trained", str(out)]) == 0
    assert out.read_bytes() == trained_checkpoint().read_bytes()
    assert main(["sample", "spinner", "--trained", str(out)]) == 1  # never overwrites without --force
    err = capsys.readouterr().err
    assert "already exists" in err and "Traceback" not in err
    assert main(["sample", "wave", "--trained", str(tmp_path / "wave.safetensors")]) == 1
    assert "no trained checkpoint is bundled for sample 'wave'" in capsys.readouterr().err
    assert not (tmp_path / "wave.safetensors").exists()
    assert main(["sample", "--list"]) == 0
    listing = capsys.readouterr().out.splitlines()
    assert [line for line in listing if "trained checkpoint bundled" in line][0].startswith("spinner")


def test_unknown_bundled_name_is_a_clear_error():
    with pytest.raises(SplatreelError, match="bundled: spinner"):
        trained_checkpoint("nope")
