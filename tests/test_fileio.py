"""Atomic outputs (`splatreel.fileio`): an OS error on any output path is one `OutputWriteError` naming the
user's path (never the hidden temporary file), and nothing is left behind."""

from __future__ import annotations

import errno
import os
import tempfile

import pytest

from splatreel.errors import OutputWriteError
from splatreel.fileio import atomic_dir, atomic_path, atomic_write_bytes


def _leftovers(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_a_file_where_a_folder_should_be_is_named(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    for out in (tmp_path / "notes.txt" / "model.safetensors", tmp_path / "notes.txt" / "deeper" / "m.bin"):
        with pytest.raises(OutputWriteError, match=r"notes\.txt is a file, not a folder") as info:
            atomic_write_bytes(out, b"data")
        assert str(out) in str(info.value)
    with pytest.raises(OutputWriteError, match="is a file, not a folder"):
        with atomic_dir(tmp_path / "notes.txt" / "frames"):
            pass
    assert _leftovers(tmp_path) == ["notes.txt"] and (tmp_path / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize("code", [errno.EROFS, errno.EACCES, errno.ENOSPC])
def test_an_unwritable_folder_names_the_users_path_not_the_temp_file(tmp_path, monkeypatch, code):
    """A read-only disk (EROFS), no permission (EACCES) or a full disk (ENOSPC), raised where the OS raises it:
    creating the temporary file, or writing into it (a library writing the temp name)."""
    out = tmp_path / "clip.mp4"
    real_mkstemp = tempfile.mkstemp

    def refuse(*args, **kwargs):
        raise OSError(code, os.strerror(code), str(tmp_path / ".clip.mp4.tmp.abc.mp4"))

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(OutputWriteError) as info:
        atomic_write_bytes(out, b"x")
    assert str(info.value) == f"{out}: cannot write: {os.strerror(code)}"
    monkeypatch.setattr(tempfile, "mkstemp", real_mkstemp)

    with pytest.raises(OutputWriteError) as info:
        with atomic_path(out) as tmp:
            raise OSError(code, os.strerror(code), str(tmp))  # e.g. the encoder opening its temp output
    assert ".tmp" not in str(info.value) and str(out) in str(info.value)
    assert _leftovers(tmp_path) == []  # the temp file is gone, nothing was renamed into place

    with pytest.raises(OutputWriteError):
        with atomic_dir(tmp_path / "frames") as tmp:
            raise OSError(code, os.strerror(code), str(tmp / "frame_00000.png"))
    assert _leftovers(tmp_path) == []


def test_errors_about_other_files_pass_through(tmp_path):
    """A missing *input* read while an output is open is not reported as a write failure."""
    with pytest.raises(FileNotFoundError):
        with atomic_path(tmp_path / "out.bin"):
            open(tmp_path / "no-such-input.json")
    assert _leftovers(tmp_path) == []


def test_cli_reports_an_output_under_a_file_in_one_line(tmp_path, capsys):
    from splatreel.cli import main

    blocker = tmp_path / "taken"
    blocker.write_text("x")
    assert main(["render", "--out", str(blocker / "still.png"), "--size", "32x24", "--quiet"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"splatreel render: error: {blocker / 'still.png'}: cannot write: {blocker} is a file, not a folder"


def test_a_folder_that_refuses_new_files_is_named_not_the_temp_file(tmp_path, monkeypatch):
    """E.g. /proc, where creating the temp file fails with ENOENT: still the user's path in one line."""
    out = tmp_path / "x.splatv"

    def refuse(*args, **kwargs):
        raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), str(tmp_path / ".x.splatv.tmp.abc.splatv"))

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(OutputWriteError) as info:
        atomic_write_bytes(out, b"x")
    assert str(info.value) == f"{out}: cannot write: {os.strerror(errno.ENOENT)}"
