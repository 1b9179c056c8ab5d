"""Options that several commands share are defined once (`splatreel.viewer.options.add_look_args`), with one
spelling and the registry's choices."""

from __future__ import annotations

import argparse

import pytest

from splatreel.cli import build_parser, main
from splatreel.viewer.options import OptionError, add_look_args, look_settings
from splatreel.viewer.render_settings import COMPOSITE_ORDERS, RENDER_MODES


def options_of(command: str) -> dict[str, argparse.Action]:
    parser = build_parser({command})
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    return {flag: action for action in sub._actions for flag in action.option_strings}


@pytest.mark.parametrize("command", ["view", "render"])
def test_view_and_render_share_the_look_options(command):
    found = options_of(command)
    assert tuple(found["--composite"].choices) == COMPOSITE_ORDERS
    assert all(mode in found["--mode"].help for mode in RENDER_MODES)
    for flag in ("--background", "--splat-scale", "--sh-degree", "--near-plane", "--temporal-fade",
                 "--max-std-dev", "--max-screen-radius"):
        assert flag in found
    assert ("transparent" in found["--background"].help) == (command == "render")


def test_look_settings_from_the_options():
    parser = argparse.ArgumentParser()
    add_look_args(parser)
    args = parser.parse_args(["--mode", "colour", "--splat-scale", "0.5", "--composite", "back-to-front"])
    settings = look_settings(args, (1.0, 1.0, 1.0))
    assert (settings.mode, settings.splat_scale, settings.composite) == ("color", 0.5, "back-to-front")
    assert settings.background == (1.0, 1.0, 1.0) and not settings.transparent  # the checkpoint's
    args = parser.parse_args(["--background", "transparent", "--mode", "depth"])
    settings = look_settings(args, (1.0, 1.0, 1.0), value_range=(1.0, 2.0))
    assert settings.transparent and settings.value_range == (1.0, 2.0)
    with pytest.raises(OptionError, match="background must be"):
        look_settings(parser.parse_args(["--background", "purple"]), (0.0, 0.0, 0.0))


def test_view_refuses_a_transparent_background(capsys):
    assert main(["view", "--background", "transparent"]) == 1
    assert "cannot show a transparent background" in capsys.readouterr().err


def every_parser(parser: argparse.ArgumentParser, words: tuple[str, ...] = ()):
    """(command words, parser) of every subcommand, nested ones (``export usd``) included."""
    yield words, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from every_parser(sub, (*words, name))


def test_one_option_one_spelling():
    """--up is lowercase everywhere, outputs are --out, and --frames means no command's frame count."""
    from splatreel.cameras import UP_AXES

    ups, outs = {}, []
    for words, parser in every_parser(build_parser()):
        flags = {flag: action for action in parser._actions for flag in action.option_strings}
        assert "--up-axis" not in flags, words
        if "--up" in flags:
            ups[" ".join(words)] = flags["--up"].choices
        if "--out" in flags:
            outs.append(words[0])
            assert "-o" in flags and flags["-o"] is flags["--out"], words
        assert "--frames" not in flags, words  # frame counts are --frame-count, the bake count --bake-frames
        assert not any(a.metavar in ("OUT", "OUT.usd", "OUTDIR") for a in parser._actions if not a.option_strings)
    assert set(ups) == {"view", "render", "export usd", "export mesh", "export ply", "export gltf", "export splatv",
                        "export 4dgs", "export web", "convert"}
    assert all(set(choices) <= set(UP_AXES) for choices in ups.values())
    assert set(outs) >= {"convert", "sample", "train", "eval", "render", "export"}


def test_export_takes_the_up_axis_usd_can_declare(capsys):
    with pytest.raises(SystemExit):
        main(["export", "usd", "model.safetensors", "--out", "a.usd", "--up", "x"])
    assert "invalid choice: 'x'" in capsys.readouterr().err
