"""Checkpoint round trip and the one-line failures of bad files, from the library and the CLI."""

import json
import os
import subprocess
import sys

import pytest
import torch
from safetensors.torch import save_file

from splatreel.checkpoint import FORMAT_VERSION, checkpoint_bytes, load_checkpoint, save_checkpoint
from splatreel.cli import main
from splatreel.errors import CheckpointError, OutputExistsError
from test_model import accelerated, keyframed, random_model


@pytest.mark.parametrize("dtype, accelerations", [(torch.float32, False), (torch.float64, False),
                                                  (torch.float32, True)])
def test_roundtrip_is_exact(tmp_path, dtype, accelerations):
    model = random_model(100, "legacy", dtype=dtype, sh_degree=3, sh_degree_t=2)
    if accelerations:
        model = accelerated(model)
    path = save_checkpoint(tmp_path / "m.safetensors", model, background=(1, 1, 1),
                           provenance={"tool": "test"}, training={"iters": 5})
    ck = load_checkpoint(path)
    for k, v in model.tensors().items():
        assert torch.equal(getattr(ck.model, k), v), k
    assert (ck.model.accelerations is None) == (not accelerations)
    assert (ck.model.sh_degree, ck.model.sh_degree_t, ck.model.time_range, ck.model.rotation_convention) == \
        (3, 2, (0.0, 1.0), "legacy")
    assert ck.background == (1.0, 1.0, 1.0) and ck.provenance == {"tool": "test"} and ck.training == {"iters": 5}
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())  # no temp files left behind


def test_keyframed_roundtrip(tmp_path):
    k = keyframed()
    ck = load_checkpoint(save_checkpoint(tmp_path / "k.safetensors", k))
    assert ck.model.kind == "keyframed"
    for name, v in k.tensors().items():
        assert torch.equal(getattr(ck.model, name), v)


def test_checkpoints_written_before_the_rename_still_open(tmp_path):
    """Files from before the project was renamed carry the old metadata key and format name."""
    from safetensors import safe_open
    from safetensors.torch import save

    model = random_model(50, "legacy", sh_degree=1, sh_degree_t=0)
    new = tmp_path / "new.safetensors"
    save_checkpoint(new, model, provenance={"tool": "test"})
    with safe_open(str(new), "pt") as f:
        meta = json.loads(f.metadata()["splatreel"])
    assert meta["format"] == "splatreel"
    meta["format"] = "splat4d"
    old = tmp_path / "old.safetensors"
    old.write_bytes(save({k: v.contiguous() for k, v in model.tensors().items()},
                         metadata={"splat4d": json.dumps(meta)}))
    ck = load_checkpoint(old)
    assert ck.provenance == {"tool": "test"}
    for k, v in model.tensors().items():
        assert torch.equal(getattr(ck.model, k), v), k


def test_existing_output_is_not_clobbered(tmp_path):
    path = tmp_path / "m.safetensors"
    path.write_bytes(b"precious")
    with pytest.raises(OutputExistsError):
        save_checkpoint(path, random_model(3, "current"))
    assert path.read_bytes() == b"precious"
    save_checkpoint(path, random_model(3, "current"), force=True)
    assert len(load_checkpoint(path).model) == 3


def test_atomic_outputs_get_the_usual_permissions(tmp_path):
    """Temp files are created private (0600 / 0700); once renamed into place an output must be as readable as a
    plainly written file, or the user's other tools and users cannot open it."""
    from splatreel.fileio import atomic_dir

    for umask in (0o022, 0o077):
        previous = os.umask(umask)
        try:
            path = save_checkpoint(tmp_path / f"m{umask:o}.safetensors", random_model(3, "current"))
            with atomic_dir(tmp_path / f"folder{umask:o}") as d:
                (d / "a.txt").write_text("a")
        finally:
            os.umask(previous)
        assert path.stat().st_mode & 0o777 == 0o666 & ~umask
        assert (tmp_path / f"folder{umask:o}").stat().st_mode & 0o777 == 0o777 & ~umask


def write_raw(path, tensors, meta):
    save_file(tensors, str(path), metadata={"splatreel": json.dumps(meta)})


def good(tmp_path):
    path = save_checkpoint(tmp_path / "good.safetensors", random_model(10, "current", dtype=torch.float32))
    return path, path.read_bytes()


def bad_files(tmp_path):
    path, data = good(tmp_path)
    files = {}
    files["truncated"] = data[: len(data) // 2]
    corrupt = bytearray(data)
    corrupt[-7] ^= 0x40  # a bit flip inside the tensor data
    files["corrupted"] = bytes(corrupt)
    files["garbage"] = b"this is not a checkpoint at all"
    ck = load_checkpoint(path)
    meta = json.loads(__import__("safetensors").safe_open(str(path), "pt").metadata()["splatreel"])
    tensors = {k: v.contiguous() for k, v in ck.model.tensors().items()}
    write_raw(tmp_path / "v.safetensors", tensors, {**meta, "format_version": FORMAT_VERSION + 1})
    files["version"] = (tmp_path / "v.safetensors").read_bytes()
    nan = dict(tensors)
    nan["means"] = nan["means"].clone()
    nan["means"][3, 1] = float("nan")
    write_raw(tmp_path / "n.safetensors", nan, {k: v for k, v in meta.items() if k != "checksums"})
    files["nan"] = (tmp_path / "n.safetensors").read_bytes()
    shape = dict(tensors)
    shape["quats_l"] = shape["quats_l"][:, :3].contiguous()
    write_raw(tmp_path / "s.safetensors", shape, {k: v for k, v in meta.items() if k != "checksums"})
    files["shape"] = (tmp_path / "s.safetensors").read_bytes()
    return files


EXPECTED = {"truncated": "truncated", "corrupted": "corrupted", "garbage": "truncated, corrupted or another format",
            "version": "newer", "nan": "NaN", "shape": "quats_l"}


@pytest.mark.parametrize("case", list(EXPECTED))
def test_bad_files_fail_with_one_clear_line(tmp_path, case, capsys):
    data = bad_files(tmp_path)[case]
    path = tmp_path / f"{case}.safetensors"
    path.write_bytes(data)
    with pytest.raises(CheckpointError, match=EXPECTED[case]):
        load_checkpoint(path)
    assert main(["info", str(path)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err and EXPECTED[case] in err


def test_missing_file_and_cli_exit_code(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "splatreel", "info", str(tmp_path / "nope.safetensors")],
                          capture_output=True, text=True)
    assert proc.returncode == 1
    assert proc.stderr.strip().count("\n") == 0 and "no such file" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_info_reports_the_model(tmp_path, capsys):
    model = random_model(42, "current", dtype=torch.float32, sh_degree=2, sh_degree_t=1)
    path = save_checkpoint(tmp_path / "m.safetensors", model, provenance={"tool": "t"})
    assert main(["info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["count"] == 42 and info["sh_degree"] == 2 and info["sh_degree_t"] == 1
    assert info["time_range"] == [0.0, 1.0] and info["size_bytes"] == os.path.getsize(path)
    assert all(lo <= hi for lo, hi in zip(info["bounds_min"], info["bounds_max"]))
    assert main(["info", str(path)]) == 0
    assert "42" in capsys.readouterr().out
    # sizes and opacities; one Gaussian blown up to a std-dev of e^3 ~ 20 is counted as large and named in the table
    sd = info["std_dev"]
    assert 0 < sd["median"] <= sd["p99"] <= sd["max"] and 0 < info["opacity"]["median"] <= info["opacity"]["p99"] < 1
    with torch.no_grad():
        model.log_scales[0] = 3.0
    save_checkpoint(path, model, force=True)
    assert main(["info", str(path), "--json"]) == 0
    grown = json.loads(capsys.readouterr().out)
    assert grown["large"] == info["large"] + 1 and grown["std_dev"]["max"] > 19.0
    assert main(["info", str(path)]) == 0
    assert "Gaussians with a std-dev over 10% of the bounds' diagonal" in capsys.readouterr().out
    # the motion: linear (native), quadratic with accelerations
    assert info["motion"] == "linear"
    save_checkpoint(path, accelerated(model), force=True)
    assert main(["info", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["motion"] == "quadratic"
    assert main(["info", str(path)]) == 0
    assert "quadratic (each Gaussian has an acceleration)" in capsys.readouterr().out


def test_training_cameras_are_recorded_once_per_camera_and_read_back(tmp_path, capsys):
    """A multi-view video repeats each camera per frame: the checkpoint keeps each camera once and each view as
    (camera index, time, name); the views read back exactly; a checkpoint without them has none; a malformed
    record is a one-line error."""
    import numpy as np

    from splatreel.cameras import DatasetView, orbit, views_from_json, views_to_json

    cams = [orbit(20, a, 3.0, fov_deg=40, width=64, height=48) for a in (0, 90)]
    views = [DatasetView(f"v{v}/f{f}", cams[v], f / 2) for f in range(3) for v in range(2)]
    record = views_to_json(views)
    assert len(record["cameras"]) == 2 and len(record["views"]) == 6
    model = random_model(5, "current")
    path = save_checkpoint(tmp_path / "m.safetensors", model, views=views)
    back = load_checkpoint(path).views
    assert [(v.name, v.time) for v in back] == [(v.name, v.time) for v in views]
    for got, want in zip(back, views):
        np.testing.assert_array_equal(got.camera.c2w, want.camera.c2w)
        assert (got.camera.fx, got.camera.fy, got.camera.cx, got.camera.cy, got.camera.width, got.camera.height) == \
            (want.camera.fx, want.camera.fy, want.camera.cx, want.camera.cy, want.camera.width, want.camera.height)
    assert load_checkpoint(save_checkpoint(tmp_path / "none.safetensors", model)).views == []
    assert main(["info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["training_views"], info["training_cameras"]) == (6, 2)
    assert main(["convert", str(path), "--out", str(tmp_path / "converted.safetensors"), "--dtype", "float64"]) == 0
    assert [v.name for v in load_checkpoint(tmp_path / "converted.safetensors").views] == [v.name for v in views]
    bad = tmp_path / "bad.safetensors"
    save_checkpoint(bad, model, views=views)
    data = bad.read_bytes().replace(b'\\"width\\": 64', b'\\"width\\": -1', 1)  # same length: a valid header
    assert data != bad.read_bytes()
    bad.write_bytes(data)
    # the model still loads (the cameras are optional extras), with a warning; asking for them is a one-line error
    with pytest.warns(UserWarning, match="malformed recorded cameras"):
        assert load_checkpoint(bad).views == []
    proc = subprocess.run([sys.executable, "-m", "splatreel", "info", str(bad)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and "gaussians" in proc.stdout
    assert proc.stderr.startswith("splatreel info: warning:") and proc.stderr.count("\n") == 1  # one line
    from splatreel.errors import CameraError
    from splatreel.viewer.camera_path import dataset_views

    with pytest.raises(CameraError, match="malformed recorded cameras") as err:
        dataset_views(bad)
    assert "\n" not in str(err.value)
    with pytest.raises(CameraError, match="not a 'test' split"):
        dataset_views(path, "test")
    for record in ({"cameras": record["cameras"], "views": [[-1, 0.0, "x"]]},
                   {"cameras": record["cameras"], "views": [[1e999, 0.0, "x"]]},
                   {"cameras": [], "views": [[True, 0.0, "x"]]}):
        with pytest.raises(CameraError, match="malformed recorded cameras"):
            views_from_json(record)


def test_bytes_are_deterministic():
    m = random_model(10, "current")
    assert checkpoint_bytes(m) == checkpoint_bytes(m)
