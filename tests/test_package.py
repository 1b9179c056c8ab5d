"""The distribution installs as one package `splat4d` with its subpackages and shaders, and every subcommand
has --help."""

import subprocess
import sys
from pathlib import Path

import pytest

from splat4d.cli import main, subcommands

ROOT = Path(__file__).resolve().parents[1]


def test_non_editable_install_layout(tmp_path):
    """`pip install .` (into a target folder) yields splat4d.{train,viewer,export,samples,shaders} and GLSL data,
    and no bare top-level `train`/`export` modules."""
    import shutil

    # build from a clean copy of the tracked sources: a stale build/ folder must not leak old files in
    src = tmp_path / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".venv", "build", "*.egg-info", ".git", "out",
                                                             "__pycache__", ".pytest_cache"))
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--quiet",
                    "--target", str(target), str(src)], check=True, capture_output=True)
    top = sorted(p.name for p in target.iterdir() if not p.name.endswith((".dist-info", ".egg-info")))
    assert "splat4d" in top and not {"train", "export", "viewer", "samples", "shaders"} & set(top), top
    for sub in ("train", "viewer", "export", "samples", "shaders", "cli"):
        assert (target / "splat4d" / sub / "__init__.py").exists(), sub
    # every subpackage of the core is installed too
    for init in (ROOT / "splat4d").glob("*/__init__.py"):
        assert (target / "splat4d" / init.parent.name / "__init__.py").exists(), init.parent.name
    shaders = {p.name for p in (target / "splat4d" / "shaders").glob("*.glsl")}
    assert shaders == {p.name for p in (ROOT / "shaders").glob("*.glsl")}
    code = ("import splat4d, splat4d.train, splat4d.viewer, splat4d.export; "
            "from splat4d.gl import shader_source; from splat4d.samples import trained_checkpoint; "
            "print(splat4d.__file__); print(trained_checkpoint())")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env={"PYTHONPATH": str(target)},
                         capture_output=True, text=True, check=True).stdout.splitlines()
    assert str(target) in out[0]
    bundled = Path(out[1])  # the trained sample is package data
    assert bundled.is_relative_to(target) and bundled.read_bytes() == (ROOT / "samples" / bundled.name).read_bytes()


@pytest.mark.parametrize("name", list(subcommands()))
def test_every_subcommand_has_help(name, capsys):
    with pytest.raises(SystemExit) as exc:
        main([name, "--help"])
    assert exc.value.code == 0
    assert "usage: splat4d " + name in capsys.readouterr().out


def test_console_script_help():
    exe = Path(sys.executable).with_name("splat4d")
    out = subprocess.run([str(exe), "--help"], capture_output=True, text=True, check=True).stdout
    for name in subcommands():
        assert name in out
