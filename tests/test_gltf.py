"""``export gltf``: KHR_gaussian_splatting .glb files that hold each frame's slice exactly and that the Khronos
glTF-Validator (npm ``gltf-validator``, installed into ``.tools/`` on first use) passes with zero errors and zero
warnings."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from splatreel.checkpoint import save_checkpoint
from splatreel.cli import main
from splatreel.colorspace import srgb_to_linear
from splatreel.export import ExportError, frame_times, iter_frames
from splatreel.export.gltf import EXTENSION, glb_bytes, sh_attribute_names, write_gltf
from splatreel.sh import SH_C0
from splatreel.viewer.synthetic import synthetic_model

ROOT = Path(__file__).resolve().parents[1]
VALIDATOR = "gltf-validator@2.0.0-dev.3.10"
TOOLS = ROOT / ".tools" / "gltf-validator"


@pytest.fixture(scope="module")
def validate():
    """`validate(*files) -> [report]`: the Khronos glTF-Validator's report of each file (tests/gltf_validate.js)."""
    stamp = TOOLS / ".installed"
    if not (stamp.exists() and stamp.read_text() == VALIDATOR):
        subprocess.run([shutil.which("npm") or "npm", "install", "--silent", "--prefix", str(TOOLS), VALIDATOR],
                       check=True, timeout=600)
        stamp.write_text(VALIDATOR)

    def run(*files):
        out = subprocess.run(["node", str(ROOT / "tests" / "gltf_validate.js"), str(TOOLS), *map(str, files)],
                             capture_output=True, text=True, check=True, timeout=300).stdout
        return [r["issues"] for r in json.loads(out)]

    return run


def read_glb(path):
    """(semantic -> array, the document) of a splat .glb, read with pygltflib."""
    import pygltflib as gl

    doc = gl.GLTF2().load(str(path))
    blob = doc.binary_blob()
    prim = doc.meshes[0].primitives[0]
    widths = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}
    arrays = {}
    for semantic, index in vars(prim.attributes).items():
        if index is None:
            continue
        acc = doc.accessors[index]
        view = doc.bufferViews[acc.bufferView]
        data = np.frombuffer(blob, np.float32, acc.count * widths[acc.type], view.byteOffset + (acc.byteOffset or 0))
        arrays[semantic] = data.reshape(acc.count, widths[acc.type])
    return arrays, doc


@pytest.fixture(scope="module")
def model():
    return synthetic_model(300, seed=3, lifetime=0.3, sh_degree=3, sh_degree_t=1)  # SH in time; Gaussians come and go


def test_a_glb_holds_the_slice_exactly_and_validates(model, tmp_path, validate):
    t = 0.4
    path = write_gltf(model, tmp_path / "one.glb", [t], up_axis="Z")[0]
    arrays, doc = read_glb(path)
    frame = next(iter_frames(model, [t]))
    np.testing.assert_array_equal(arrays["POSITION"], frame.means.astype(np.float32))
    quat_xyzw = arrays[f"{EXTENSION}:ROTATION"]
    np.testing.assert_allclose(np.linalg.norm(quat_xyzw, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(quat_xyzw, np.roll(frame.quats, -1, axis=1), atol=1e-6)
    np.testing.assert_array_equal(arrays[f"{EXTENSION}:SCALE"], frame.scales.astype(np.float32))
    np.testing.assert_array_equal(arrays[f"{EXTENSION}:OPACITY"][:, 0], frame.opacities.astype(np.float32))
    assert (arrays[f"{EXTENSION}:OPACITY"][~frame.visible] == 0).all() and (~frame.visible).any()
    names = sh_attribute_names(3)
    assert len(names) == 16 and all(n in arrays for n in names)
    for k, name in enumerate(names):
        np.testing.assert_array_equal(arrays[name], frame.sh[:, k].astype(np.float32))
    colour = srgb_to_linear(np.clip(0.5 + SH_C0 * frame.sh[:, 0], 0, 1))
    np.testing.assert_allclose(arrays["COLOR_0"][:, :3], colour, atol=1e-6)
    prim = doc.meshes[0].primitives[0]
    assert prim.mode == 0 and prim.extensions[EXTENSION]["kernel"] == "ellipse"
    assert prim.extensions[EXTENSION]["colorSpace"] == "srgb_rec709_display" and doc.extensionsUsed == [EXTENSION]
    np.testing.assert_allclose(doc.nodes[0].rotation, [-math.sqrt(0.5), 0, 0, math.sqrt(0.5)])  # +Z up stood up
    report = validate(path)[0]
    assert report["numErrors"] == 0 and report["numWarnings"] == 0, report["messages"][:5]


def test_the_validator_catches_a_broken_file(model, tmp_path, validate):
    """The validation is real: a splat file without POSITION's required min/max fails it."""
    import pygltflib as gl

    good = tmp_path / "good.glb"
    good.write_bytes(glb_bytes(next(iter_frames(model, [0.5]))))
    doc = gl.GLTF2().load(str(good))
    doc.accessors[0].min = doc.accessors[0].max = None
    bad = tmp_path / "bad.glb"
    doc.save(str(bad))
    assert validate(bad)[0]["numErrors"] > 0


def test_a_sequence_is_a_folder_of_valid_frames_and_the_cli_names_its_limits(model, tmp_path, validate, capsys):
    ckpt = save_checkpoint(tmp_path / "m.safetensors", model, provenance={"up_axis": "z"})
    out = tmp_path / "seq"
    assert main(["export", "gltf", str(ckpt), "--out", str(out), "--frame-count", "3", "--quiet"]) == 0
    files = sorted(out.glob("*.glb"))
    assert [f.name for f in files] == [f"splats_{i:06d}.glb" for i in range(3)]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["up_axis"] == "Z" and [f["time"] for f in manifest["frames"]] == [0.0, 0.5, 1.0]
    for path, t in zip(files, frame_times(model.time_range, 3)):
        arrays, _ = read_glb(path)
        np.testing.assert_array_equal(arrays["POSITION"], next(iter_frames(model, [t])).means.astype(np.float32))
    assert all(r["numErrors"] == 0 and r["numWarnings"] == 0 for r in validate(*files))
    capsys.readouterr()
    for bad, message in ((tmp_path / "many.glb", "one .glb holds one time"), (tmp_path / "x.gltf", "writes NAME.glb")):
        assert main(["export", "gltf", str(ckpt), "--out", str(bad), "--frame-count", "3", "--quiet"]) == 1
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1 and not bad.exists()
    with pytest.raises(ExportError):
        write_gltf(model, tmp_path / "two.glb", [0.0, 1.0])


def test_a_keyframed_model_exports_too(tmp_path, validate):
    from test_model import keyframed

    keyed = keyframed()
    path = write_gltf(keyed, tmp_path / "k.glb", [float(keyed.time_range[0])])[0]
    arrays, _ = read_glb(path)
    assert len(arrays["POSITION"]) == len(keyed)
    assert validate(path)[0]["numErrors"] == 0
