"""``splatreel --help``, ``--version`` and ``info CKPT`` start without torch: `info` reads a splatreel checkpoint with
NumPy (`splatreel.checkpoint_numpy`), whose numbers match the torch model's, and leaves every other file to the
full loader."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from splatreel.checkpoint import save_checkpoint
from splatreel.checkpoint_numpy import KIND_TENSORS, bounds, read_numpy_checkpoint, sizes_and_opacities
from splatreel.cli import info as info_cli
from splatreel.model import Gaussians4D, KeyframedGaussians, model_bounds

from test_checkpoint import EXPECTED, bad_files
from test_model import keyframed, random_model

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "moderngl", "numba", "cv2")


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["info", str(ROOT / "samples" / "spinner.safetensors")],
                                  ["info", str(ROOT / "samples" / "spinner.safetensors"), "--json"]])
def test_help_version_and_info_import_no_torch(argv):
    code = ("import sys\nfrom splatreel.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
            f"print('HEAVY', *[m for m in {HEAVY!r} if m in sys.modules])")
    proc = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "HEAVY", proc.stdout[-300:]


def test_help_lists_every_command():
    from splatreel.cli import subcommands

    out = subprocess.run([sys.executable, "-m", "splatreel", "--help"], capture_output=True, text=True,
                         check=True).stdout
    assert all(name in out for name in subcommands())


@pytest.mark.parametrize("make", [
    lambda: random_model(300, "current", dtype=torch.float32, sh_degree=2, sh_degree_t=1),
    lambda: random_model(300, "legacy", dtype=torch.float64, sh_degree=0, sh_degree_t=0, seed=4),
    keyframed,
], ids=["4d-current-f32", "4d-legacy-f64", "keyframed"])
def test_numpy_reading_matches_the_model(tmp_path, make):
    model = make()
    path = save_checkpoint(tmp_path / "m.safetensors", model, background=(1.0, 0.5, 0.0), provenance={"tool": "t"})
    ckpt = read_numpy_checkpoint(path)
    assert ckpt is not None and ckpt.kind == model.kind and len(ckpt) == len(model)
    assert set(ckpt.arrays) == set({"gaussians4d": Gaussians4D, "keyframed": KeyframedGaussians}[ckpt.kind].TENSORS)
    assert KIND_TENSORS[ckpt.kind] == {"gaussians4d": Gaussians4D, "keyframed": KeyframedGaussians}[ckpt.kind].TENSORS
    lo, hi = bounds(ckpt)
    want_lo, want_hi = model_bounds(model)
    np.testing.assert_allclose(lo, want_lo.numpy(), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(hi, want_hi.numpy(), rtol=1e-5, atol=1e-6)
    std, opacity = sizes_and_opacities(ckpt)
    want_std, want_opacity = info_cli._sizes_and_opacities(model)
    np.testing.assert_allclose(std, want_std, rtol=1e-5)
    np.testing.assert_allclose(opacity, want_opacity, rtol=1e-6)
    # what info prints is the same either way
    fast = info_cli.summarize(path)
    full = info_cli._summary(path, **info_cli._facts_of_model(path, {}))
    assert fast == full


@pytest.mark.parametrize("case", list(EXPECTED))
def test_files_the_loader_refuses_are_left_to_it(tmp_path, case):
    path = tmp_path / f"{case}.safetensors"
    path.write_bytes(bad_files(tmp_path)[case])
    assert read_numpy_checkpoint(path) is None
    assert read_numpy_checkpoint(tmp_path / "missing.safetensors") is None
