"""Command-line values checked where they are parsed: one rule per kind of number, the same in every command.

Each ``*_number`` / ``count`` function is an argparse ``type=``: a value it refuses is a one-line usage error
naming the option (``argument --seconds: expected a positive number, got '0'``). `OptionError` is the error of a
value that parses but cannot be used (checked later, across options). Nothing heavy is imported here: option
definitions must load without torch (``splatreel --help``).
"""

from __future__ import annotations

import argparse
import math
import warnings

from .errors import SplatreelError


class OptionError(SplatreelError):
    """A command-line value that cannot be parsed or used."""


def argtype(parse):
    """Wrap a parser raising `OptionError` for argparse, so that its errors print as usage errors."""

    def convert(text):
        try:
            return parse(text)
        except OptionError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    convert.__name__ = parse.__name__.replace("parse_", "")
    return convert


def _number(text: str, ok, expected: str, kind=float):
    """`text` as a `kind` that passes `ok`, else OptionError "expected <expected>, got '<text>'"."""
    try:
        value = kind(text)
    except ValueError:
        value = None
    if value is None or not math.isfinite(value) or not ok(value):
        raise OptionError(f"expected {expected}, got {text!r}")
    return value


def parse_positive(text: str) -> float:
    """'2.5' -> 2.5; a positive finite number."""
    return _number(text, lambda v: v > 0, "a positive number")


def parse_far_clip(text: str) -> str | float:
    """'auto' / 'none' as they are, '6.95' -> 6.95 (a positive camera depth): the --far-clip of train and eval."""
    if text in ("auto", "none"):
        return text
    return _number(text, lambda v: v > 0, "auto, none or a positive camera depth")


def parse_non_negative(text: str) -> float:
    """'0' -> 0.0; a finite number >= 0."""
    return _number(text, lambda v: v >= 0, "a number >= 0")


def parse_finite(text: str) -> float:
    """'-1.5' -> -1.5; any finite number (not nan or inf)."""
    return _number(text, lambda v: True, "a finite number")


def parse_count(text: str) -> int:
    """'3' -> 3; a whole number >= 1."""
    return _number(text, lambda v: v >= 1, "a whole number >= 1", int)


def parse_non_negative_count(text: str) -> int:
    """'0' -> 0; a whole number >= 0."""
    return _number(text, lambda v: v >= 0, "a whole number >= 0", int)


def parse_fraction(text: str) -> float:
    """'0.3' -> 0.3; a number from 0 to 1."""
    return _number(text, lambda v: 0 <= v <= 1, "a number from 0 to 1")


positive_number = argtype(parse_positive)
fraction = argtype(parse_fraction)
non_negative_number = argtype(parse_non_negative)
finite_number = argtype(parse_finite)
count = argtype(parse_count)
non_negative_count = argtype(parse_non_negative_count)


def warn_outside_time_range(t: float, time_range, option: str) -> None:
    """One warning line when model time `t` (given as `option`) lies outside the model's time range: it is
    drawn as asked, but little or nothing may be visible there."""
    t0, t1 = float(time_range[0]), float(time_range[1])
    tol = 1e-9 * max(1.0, abs(t0), abs(t1))  # a range typed back from a printout is not "outside"
    if not t0 - tol <= t <= t1 + tol:
        warnings.warn(f"{option} {t:g} lies outside the model's time range [{t0:g}, {t1:g}]: little or nothing "
                      "may be visible there", stacklevel=2)
