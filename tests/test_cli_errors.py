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
