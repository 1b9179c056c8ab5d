"""``splatreel --help``, ``--version`` and ``info CKPT`` start without torch: `info` verifies a checkpoint and prints
the summary its metadata stores (`splatreel.summary`, written with the model), and reads anything else, or an
older checkpoint without a summary, through the full loader."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from splatreel.checkpoint import load_checkpoint, save_checkpoint
from splatreel.cli import info as info_cli
from splatreel.summary import model_summary

from test_checkpoint import write_raw
from test_model import keyframed, random_model

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "moderngl", "numba", "cv2")


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["train", "--help"],
                                  ["info", str(ROOT / "samples" / "spinner.safetensors")],
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
def test_the_stored_summary_is_the_models_and_info_prints_the_same_without_it(tmp_path, make):
    model = make()
    path = save_checkpoint(tmp_path / "m.safetensors", model, background=(1.0, 0.5, 0.0), provenance={"tool": "t"})
    ckpt = load_checkpoint(path)
    fast = info_cli.summarize(path)  # from the metadata
    assert fast["count"] == len(model) and fast["kind"] == model.kind
    assert {k: fast[k] for k in model_summary(ckpt.model)} == model_summary(ckpt.model)
    # a checkpoint written before summaries were stored: the same facts, from the model
    meta = json.loads(__import__("safetensors").safe_open(str(path), "np").metadata()["splatreel"])
    old = tmp_path / "old.safetensors"
    write_raw(old, {k: v.contiguous() for k, v in ckpt.model.tensors().items()},
              {k: v for k, v in meta.items() if k not in ("summary", "shapes")})
    slow = info_cli.summarize(old)
    assert {k: v for k, v in slow.items() if k not in ("path", "size_bytes")} == \
        {k: v for k, v in fast.items() if k not in ("path", "size_bytes")}
