"""The distribution installs as one package `splatreel` with its subpackages and shaders, and every subcommand
has --help."""

import subprocess
import sys
from pathlib import Path

import pytest

from splatreel.cli import main, subcommands

ROOT = Path(__file__).resolve().parents[1]


def test_non_editable_install_layout(tmp_path):
    """`pip install .` (into a target folder) yields splatreel.{train,viewer,export,samples,shaders} and GLSL data,
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
    assert "splatreel" in top and not {"train", "export", "viewer", "samples", "shaders"} & set(top), top
    for sub in ("train", "viewer", "export", "samples", "shaders", "cli"):
        assert (target / "splatreel" / sub / "__init__.py").exists(), sub
    # every subpackage of the core is installed too
    for init in (ROOT / "splatreel").glob("*/__init__.py"):
        assert (target / "splatreel" / init.parent.name / "__init__.py").exists(), init.parent.name
    shaders = {p.name for p in (target / "splatreel" / "shaders").glob("*.glsl")}
    assert shaders == {p.name for p in (ROOT / "shaders").glob("*.glsl")}
    code = ("import splatreel, splatreel.train, splatreel.viewer, splatreel.export; "
            "from splatreel.gl import shader_source; from splatreel.samples import trained_checkpoint; "
            "print(splatreel.__file__); print(trained_checkpoint())")
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
    assert "usage: splatreel " + name in capsys.readouterr().out


def test_console_script_help():
    exe = Path(sys.executable).with_name("splatreel")
    out = subprocess.run([str(exe), "--help"], capture_output=True, text=True, check=True).stdout
    for name in subcommands():
        assert name in out


def test_the_format_registry_imports_its_formats_only_when_used():
    """`splatreel.formats` lists every reader and writer by dotted path: importing it imports no importer or
    exporter, and every path it names resolves (to a function, or a module with add_args and run)."""
    code = ("import sys, splatreel.formats as f; "
            "print(sorted(m for m in sys.modules if m.startswith(('splatreel.importers', 'splatreel.export'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    from splatreel.export import exporters
    from splatreel.formats import readers, resolve, writers

    assert [r.name for r in readers()] == ["4dgs-checkpoint", "deformation-folder", "ply", "ply-sequence",
                                           "splatv", "4dgs", "splatreel"]
    for r in readers():
        assert callable(resolve(r.sniff)) and callable(resolve(r.read)), r.name
    assert list(exporters()) == [w.name for w in writers()] == ["usd", "mesh", "ply", "gltf", "splatv", "4dgs",
                                                                "web"]
    for w in writers():
        assert callable(resolve(f"{w.module}:add_args")) and callable(resolve(f"{w.module}:run")), w.name
