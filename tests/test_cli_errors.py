"""What the command line prints when something is wrong: one line, never a traceback (splatreel.cli.main)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from splatreel.cli import EXIT_USAGE, main
from splatreel.samples import trained_checkpoint


@pytest.mark.parametrize("argv, names", [
    (["view", "--size", "12"], "--size"),
    (["render", "--out", "x.mp4", "--fps", "fast"], "--fps"),
    (["export", "usd", "m.safetensors", "--out", "x.usdc", "--bogus"], "--bogus"),
    (["train"], "DATA"),
    (["nonsense"], "nonsense"),
])
def test_a_usage_error_is_one_line_that_points_to_help(argv, names, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == EXIT_USAGE
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "usage:" not in err, err
    assert names in err and "--help)" in err and err.startswith("splatreel")


def test_a_reader_that_goes_away_ends_the_command_quietly():
    """``splatreel info M --json | head -c 1``: the closed pipe is not a BrokenPipeError traceback."""
    proc = subprocess.Popen([sys.executable, "-m", "splatreel", "info", str(trained_checkpoint("spinner")), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # before the command writes anything
    err = proc.stderr.read().decode()
    assert proc.wait() == 1 and "Traceback" not in err and "BrokenPipe" not in err, err


@pytest.mark.parametrize("argv, option", [
    (["render", "--out", "x.mp4", "--seconds", "0"], "--seconds"),
    (["render", "--out", "x.mp4", "--seconds", "-1"], "--seconds"),
    (["render", "--out", "x.mp4", "--loop-seconds", "nan"], "--loop-seconds"),
    (["view", "--exit-after", "0"], "--exit-after"),
    (["export", "usd", "m", "--out", "x.usdc", "--fps", "0"], "--fps"),
    (["sample", "spinner", "--out", "d", "--views", "0"], "--views"),
    (["train", "d", "--out", "m", "--iters", "-5"], "--iters"),
    (["train", "d", "--out", "m", "--smooth-weight", "-1"], "--smooth-weight"),
    (["eval", "m", "d", "--downscale", "0"], "--downscale"),
])
def test_meaningless_numbers_are_refused_by_name(argv, option, capsys):
    with pytest.raises(SystemExit):
        main(argv)
    err = capsys.readouterr().err
    assert f"argument {option}" in err and err.count("\n") == 1, err


def test_a_time_outside_the_models_range_is_drawn_with_a_warning(tmp_path):
    out = tmp_path / "late.png"
    proc = subprocess.run([sys.executable, "-m", "splatreel", "render", str(trained_checkpoint("spinner")), "--out",
                           str(out), "--size", "32x24", "--time", "5", "--quiet"], capture_output=True, text=True)
    assert proc.returncode == 0 and out.exists(), proc.stderr
    assert proc.stderr.strip() == ("splatreel render: warning: --time 5 lies outside the model's time range [0, 1]: "
                                   "little or nothing may be visible there")
