"""Options that several subcommands take, defined once: ``--up AXIS`` (view, render, export) and
``--crop X0 Y0 Z0 X1 Y1 Z1`` (convert, export, render, view)."""

from __future__ import annotations

import argparse

CROP_HELP = ("keep only the Gaussians inside this world-space box (min corner, then max corner): those whose centre "
             "lies in it when they show most; the viewer's crop panel prints the box it shows")


def add_up_arg(parser: argparse.ArgumentParser | argparse._ArgumentGroup, axes: tuple[str, ...] | None = None,
               default: str | None = "z", help: str = "world up axis", dest: str = "up") -> None:
    """``--up AXIS``: the world's up axis, lowercase as `splatreel.cameras.UP_AXES` spells it. `axes`: the subset
    a command can honour (None: all six)."""
    from ..cameras import UP_AXES

    choices = tuple(UP_AXES) if axes is None else axes
    assert set(choices) <= set(UP_AXES), choices
    shown = f" (default {default})" if default is not None else ""
    parser.add_argument("--up", choices=choices, default=default, dest=dest, help=help + shown)


def add_crop_arg(parser: argparse.ArgumentParser | argparse._ArgumentGroup, what: str = "") -> None:
    parser.add_argument("--crop", type=float, nargs=6, default=None, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                        help=CROP_HELP + what)


def apply_crop(model, values):
    """`model` cropped to the ``--crop`` values (a one-line ModelError if the box misses it), or as it is."""
    from ..model import CropBox, crop

    return model if values is None else crop(model, CropBox.of(values), require_any=True)


def check_crop(model, values) -> None:
    """The one-line ModelError `apply_crop` would raise, without making the cropped copy (the viewer crops later,
    after its window opens)."""
    from ..model import CropBox, crop_mask

    if values is not None:
        crop_mask(model, CropBox.of(values), require_any=True)
