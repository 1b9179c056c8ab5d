"""Import options shared by every command that takes a model file, and the record of what an importer assumed.

Other tools' files leave out facts splatreel needs (the 4D rotation convention, the time range, the background
colour, how many frames to bake). Commands expose them through one argparse helper::

    from splatreel.importers import add_import_args, import_options

    def add_args(p):
        p.add_argument("checkpoint")
        add_import_args(p)

    def run(args):
        ckpt = read_checkpoint(args.checkpoint, **import_options(args))

Every value an importer had to assume is written as one line to stderr (logger ``splatreel.importers``) and
recorded in ``provenance["assumed"]`` so that ``splatreel info`` shows it. This module imports nothing heavy: it
runs while the CLI builds its parser.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..constants import ROTATION_CONVENTIONS
from ..errors import CheckpointError

log = logging.getLogger("splatreel.importers")

#: Option name -> (flags, help). The argparse destination is ``import_<name>`` so that it never collides with a
#: command's own options (``render --background`` stays the renderer's).
_FLAGS: dict[str, tuple[tuple[str, ...], dict]] = {
    "convention": (("--convention",), dict(
        type=str.lower, choices=ROTATION_CONVENTIONS,
        help="4D rotation convention of an official 4DGS checkpoint: 'current' (official main since "
             "2024-09-15; default for files with an iteration number) or 'legacy' (older main and "
             "Efficient4D; default for bare model.pth tuples)")),
    "time_range": (("--time-range",), dict(
        nargs=2, type=float, metavar=("T0", "T1"),
        help="time range of the imported model (official checkpoints: default 0 1, Efficient4D 0 15; "
             "4DGaussians 0 1; 4DGen 0 0.9375; PLY sequences 0 1, frames evenly spaced)")),
    "background": (("--background",), dict(
        nargs=3, type=float, metavar=("R", "G", "B"),
        help="background colour recorded with the imported model, 0..1 (default: from cfg_args when "
             "present, else black for official 4DGS checkpoints and PLY files, white for Efficient4D, "
             "4DGaussians and 4DGen)")),
    "frames": (("--bake-frames",), dict(
        type=int, metavar="N",
        help="4DGaussians/4DGen folders: number of times at which the deformation is baked into keyframes "
             "(default 30 for 4DGaussians, 16 for 4DGen), evenly spaced over the time range")),
    "sh_degree": (("--sh-degree",), dict(
        type=int, choices=range(4), metavar="D",
        help="spatial SH degree to import, 0..3 (default: the degree the file's renderer uses); lower "
             "values drop the higher coefficients")),
    "iteration": (("--iteration",), dict(
        type=int, metavar="N",
        help="4DGaussians/4DGen folders: which point_cloud/iteration_N to import (default: the latest)")),
}

IMPORT_OPTIONS: tuple[str, ...] = tuple(_FLAGS)


def add_import_args(parser: argparse.ArgumentParser) -> argparse._ArgumentGroup:
    """Add the import options to `parser` (in their own help group) and return the group.

    A flag the parser already defines is left to the command (for example ``export --frames`` keeps its own
    meaning; the bake count is then still reachable as ``--bake-frames``). Read the values back with
    `import_options`.
    """
    group = parser.add_argument_group(
        "import options", "Facts that official 4DGS / Efficient4D checkpoints, 4DGaussians / 4DGen folders and 3DGS\n"
                          "PLY files do not store (ignored for splatreel checkpoints). Every value assumed instead is\n"
                          "printed and recorded in the model's provenance (splatreel info).")
    taken = set(parser._option_string_actions)  # argparse has no public query for this
    for name, (flags, kwargs) in _FLAGS.items():
        free = [f for f in flags if f not in taken]
        if free:
            group.add_argument(*free, dest=f"import_{name}", default=None, **kwargs)
    return group


def import_options(args: argparse.Namespace) -> dict[str, Any]:
    """The import options the user gave on the command line, as keyword arguments for `read_checkpoint`."""
    out = {}
    for name in IMPORT_OPTIONS:
        value = getattr(args, f"import_{name}", None)
        if value is not None:
            out[name] = tuple(value) if isinstance(value, list) else value
    return out


def check_options(options: dict[str, Any]) -> dict[str, Any]:
    """Validate import options given through the library API; raises CheckpointError naming the bad one."""
    unknown = sorted(set(options) - set(IMPORT_OPTIONS) - {"progress"})
    if unknown:
        raise CheckpointError(f"unknown import option(s) {', '.join(unknown)} "
                              f"(expected {', '.join(IMPORT_OPTIONS)})")
    opts = {k: v for k, v in options.items() if v is not None}
    if "convention" in opts and str(opts["convention"]).lower() not in ("current", "legacy", "flipped"):
        raise CheckpointError(f"convention must be 'current' or 'legacy', got {opts['convention']!r}")
    for name, size in (("time_range", 2), ("background", 3)):
        if name in opts:
            v = opts[name]
            try:
                v = tuple(float(x) for x in v)
            except (TypeError, ValueError):
                raise CheckpointError(f"{name} must be {size} numbers, got {v!r}") from None
            if len(v) != size or not all(math.isfinite(x) for x in v):
                raise CheckpointError(f"{name} must be {size} finite numbers, got {opts[name]!r}")
            opts[name] = v
    if "time_range" in opts and not opts["time_range"][0] < opts["time_range"][1]:
        raise CheckpointError(f"time range must satisfy T0 < T1, got {opts['time_range']}")
    if "frames" in opts and (not isinstance(opts["frames"], int) or opts["frames"] < 1):
        raise CheckpointError(f"frames must be a positive integer, got {opts['frames']!r}")
    if "sh_degree" in opts and opts["sh_degree"] not in (0, 1, 2, 3):
        raise CheckpointError(f"sh_degree must be 0..3, got {opts['sh_degree']!r}")
    return opts


@dataclass
class ImportRecord:
    """What an importer read, chose and assumed; becomes the checkpoint's ``provenance``.

    Attributes:
        source: the file or folder imported.
        reader: name of the reader (``4dgs-checkpoint``, ``deformation-folder``, ``ply``, ``ply-sequence``).
        options: the import options the caller gave (validated).
        facts: JSON-able details (tool, iteration, SH degrees, ...).
        assumed: one human-readable line per value that was not given and not in the file.
    """

    source: Path
    reader: str
    options: dict[str, Any]
    facts: dict[str, Any] = field(default_factory=dict)
    assumed: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    _used: set = field(default_factory=set)
    _short: list[str] = field(default_factory=list)

    def option(self, name: str, default: Any, why: str, describe=None) -> Any:
        """The caller's value for `name`, or `default` (recorded as assumed, with the reason `why`)."""
        self._used.add(name)
        if name in self.options:
            return self.options[name]
        shown = describe(default) if describe else _describe(default)
        flag = "--" + name.replace("_", "-")
        self.assumed.append(f"{flag} {shown} ({why})")
        self._short.append(f"{flag} {shown}")
        return default

    def assume(self, text: str, short: str) -> None:
        """Record an assumption that is not an import option (`short` goes into the stderr line)."""
        self.assumed.append(text)
        self._short.append(short)

    def warn(self, text: str) -> None:
        """Print one warning line now (stderr, logger ``splatreel.importers``) and keep it in the provenance."""
        log.warning("%s: %s", self.source.name or str(self.source), text)
        self.warnings.append(text)

    def given(self, name: str) -> Any:
        """The caller's value for `name` or None, without assuming anything."""
        self._used.add(name)
        return self.options.get(name)

    def provenance(self) -> dict[str, Any]:
        from .. import __version__

        out = {"source": os.path.abspath(self.source), "reader": self.reader, "imported_by": f"splatreel {__version__}"}
        out.update(self.facts)
        if self.options:
            out["options"] = {k: list(v) if isinstance(v, tuple) else v for k, v in self.options.items()
                              if k != "progress"}
        out["assumed"] = list(self.assumed)
        if self.warnings:
            out["warnings"] = list(self.warnings)
        return out

    def finish(self) -> None:
        """Log the assumptions (one line) and the options that had no effect on this file (one line)."""
        name = self.source.name or str(self.source)
        if self.assumed:
            log.warning("%s: assumed %s (give these options to choose otherwise; `splatreel info` lists why each "
                        "was assumed)", name, ", ".join(self._short))
        unused = sorted(set(self.options) - self._used - {"progress"})
        if unused:
            flags = ", ".join("--" + u.replace("_", "-") for u in unused)
            log.warning("%s: ignored %s (not used for %s files)", name, flags, self.reader)
            self.facts["ignored_options"] = unused


def _describe(value: Any) -> str:
    if isinstance(value, (tuple, list)):
        return " ".join(f"{float(v):g}" for v in value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)
