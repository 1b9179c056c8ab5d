"""``splatreel convert`` and ``splatreel info`` on imported files; the shared import-options helper."""

from __future__ import annotations

import argparse
import json
import os
import pickle

import torch
from test_import_helpers import capture_tuple, random_splats, write_splat_ply

from splatreel.checkpoint import load_checkpoint
from splatreel.cli import main
from splatreel.importers import add_import_args, import_options


def test_convert_official_checkpoint_round_trip(tmp_path, capsys):
    src = tmp_path / "chkpnt30000.pth"
    torch.save((capture_tuple(n=8), 30000), src)
    out = tmp_path / "lego.safetensors"
    assert main(["convert", str(src), "--out", str(out), "--convention", "legacy", "--time-range", "0", "2"]) == 0
    assert "wrote" in capsys.readouterr().out
    ckpt = load_checkpoint(out)
    model = ckpt.model
    assert (model.rotation_convention, model.time_range, len(model)) == ("legacy", (0.0, 2.0), 8)
    cap = capture_tuple(n=8)
    torch.testing.assert_close(model.means, cap[1].detach())
    torch.testing.assert_close(model.quats_r, cap[15].detach())
    prov = ckpt.provenance
    assert prov["reader"] == "4dgs-checkpoint" and prov["options"]["convention"] == "legacy"
    assert prov["assumed"] == ["--background 0 0 0 (official D-NeRF/N3V configs use black; no cfg_args found)"]

    # never overwrite without --force; one-line error, exit 1
    assert main(["convert", str(src), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "already exists" in err and err.count("\n") == 1
    assert main(["convert", str(src), "--out", str(out), "--force"]) == 0


def test_info_reports_provenance_and_assumptions(tmp_path, capsys):
    src = write_splat_ply(tmp_path / "scene.ply", **random_splats(6, 2))
    assert main(["info", str(src), "--time-range", "0", "5"]) == 0
    out = capsys.readouterr().out
    assert "provenance.reader" in out and "ply" in out
    assert "provenance.assumed" in out and "--background 0 0 0" in out
    assert main(["info", str(src), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["count"] == 6 and info["sh_degree"] == 2 and info["provenance"]["assumed"]


def test_convert_ply_sequence_glob_then_info(tmp_path, capsys):
    for i in range(3):
        write_splat_ply(tmp_path / f"frame_{i}.ply", **random_splats(4, 0, seed=i))
    out = tmp_path / "seq.safetensors"
    assert main(["convert", str(tmp_path / "frame_*.ply"), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "keyframes" in text and "ply-sequence" in text


def test_cli_errors_are_one_line(tmp_path, capsys):
    marker = tmp_path / "PWNED"

    class Payload:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    evil = tmp_path / "chkpnt1.pth"
    evil.write_bytes(pickle.dumps(Payload(), protocol=2))
    cases = [
        ["convert", str(evil), "--out", str(tmp_path / "x.safetensors")],
        ["convert", str(tmp_path / "missing.pth"), "--out", str(tmp_path / "y.safetensors")],
        ["convert", str(evil), "--out", str(tmp_path / "z.ply")],
        ["info", str(tmp_path / "nothing_*.ply")],
    ]
    for argv in cases:
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert err.startswith(f"splatreel {argv[0]}: error: ") and err.count("\n") == 1, err
    assert not marker.exists()
    assert not list(tmp_path.glob("*.safetensors"))


def test_import_options_helper_leaves_existing_flags_alone():
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=48)  # e.g. `export --frames`: the command's own meaning
    p.add_argument("--background", nargs=3, type=float)
    add_import_args(p)
    args = p.parse_args(["--frames", "10", "--bake-frames", "7", "--convention", "LEGACY", "--time-range", "0", "3"])
    assert args.frames == 10
    assert import_options(args) == {"convention": "legacy", "time_range": (0.0, 3.0), "frames": 7}
    assert import_options(p.parse_args([])) == {}


def test_convert_crop_keeps_the_box_and_records_it(tmp_path, capsys):
    """``convert --crop`` writes only the Gaussians anchored in the box (negative corners parse as numbers) and
    records the box in the provenance; a box that misses the model is a one-line error that writes nothing."""
    from splatreel.checkpoint import save_checkpoint
    from splatreel.model import CropBox, crop
    from splatreel.viewer.synthetic import synthetic_model

    model = synthetic_model(500, seed=3, radius=1.0)
    src = save_checkpoint(tmp_path / "in.safetensors", model, provenance={"tool": "test"})
    out = tmp_path / "out.safetensors"
    box = [-0.5, -0.5, -0.5, 0.4, 0.3, 0.5]
    assert main(["convert", str(src), "--out", str(out), "--crop", *map(str, box)]) == 0
    ckpt = load_checkpoint(out)
    want = crop(model, CropBox.of(box))
    assert 0 < len(ckpt.model) == len(want) < 500
    torch.testing.assert_close(ckpt.model.means, want.means, rtol=0, atol=0)
    assert ckpt.provenance["tool"] == "test"
    assert ckpt.provenance["crop"] == {"box": box, "kept": len(want), "of": 500}
    missed = tmp_path / "none.safetensors"
    assert main(["convert", str(src), "--out", str(missed), "--crop", "5", "5", "5", "6", "6", "6"]) == 1
    err = capsys.readouterr().err
    assert "holds none of the 500 Gaussians" in err and err.count("\n") == 1 and not missed.exists()


def test_convert_up_records_the_up_axis_the_exporters_then_declare(tmp_path, capsys):
    """Other tools' files do not say which way is up: ``convert --up z`` records it, and export declares it."""
    from pxr import Usd, UsdGeom

    from splatreel.checkpoint import load_checkpoint, save_checkpoint
    from splatreel.viewer.synthetic import synthetic_model

    src = save_checkpoint(tmp_path / "src.safetensors", synthetic_model(50, seed=1))
    out = tmp_path / "z.safetensors"
    assert main(["convert", str(src), "--out", str(out), "--up", "z"]) == 0
    assert load_checkpoint(out).provenance["up_axis"] == "z"
    usd = tmp_path / "z.usda"
    assert main(["export", "usd", str(out), "--out", str(usd), "--frame-count", "2", "--quiet"]) == 0
    assert UsdGeom.GetStageUpAxis(Usd.Stage.Open(str(usd))) == "Z"
    capsys.readouterr()
