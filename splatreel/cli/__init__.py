"""The ``splatreel`` command: thin subcommand modules over the library.

Each subcommand is a module in this package, found automatically, exposing ``HELP`` (one line),
``add_args(parser)``, ``run(args) -> int`` and optionally ``ORDER`` (its place in ``--help``; default 100) and
``DESCRIPTION``. The subcommand's name is the module's name (``_`` becomes ``-``). Heavy imports happen inside
``run``, and `main` adds the options of the chosen subcommand only, so that ``splatreel --help`` and ``--version``
import no torch (some ``add_args`` read a registry that does). Library code raises typed
errors (`splatreel.errors`); only `main` turns them into ``splatreel: error: <one line>`` and an exit code.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from typing import Collection, Sequence

from .. import __version__
from ..errors import SplatreelError


def subcommands() -> dict[str, object]:
    """Subcommand name -> module, in --help order."""
    mods = []
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(mod, "HELP") and hasattr(mod, "run"):
            mods.append((getattr(mod, "ORDER", 100), info.name.replace("_", "-"), mod))
    return {name: mod for _, name, mod in sorted(mods, key=lambda m: (m[0], m[1]))}


#: exit codes: a library error (bad input file, unwritable output ...), a usage error (bad option), Ctrl-C
EXIT_ERROR, EXIT_USAGE, EXIT_INTERRUPTED = 1, 2, 130


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line naming the command and pointing to its ``--help``
    (argparse prints the whole usage block first), exit code `EXIT_USAGE`, argparse's convention."""

    def error(self, message: str):  # noqa: D102  (argparse's hook)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser(options_of: Collection[str] | None = None) -> argparse.ArgumentParser:
    """The ``splatreel`` parser. `options_of`: the subcommands whose options are added (None: all, as the docs'
    option reference needs); the others are listed in ``--help`` with their one line and take no options."""
    parser = OneLineParser(
        prog="splatreel", description="Toolkit for 4D Gaussian assets: train, view, render, export.")
    parser.add_argument("--version", action="version", version=f"splatreel {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=OneLineParser)
    for name, mod in subcommands().items():
        p = sub.add_parser(name, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        if options_of is None or name in options_of:
            mod.add_args(p)
        p.set_defaults(_run=mod.run)
    return parser


def chosen_command(argv: Sequence[str]) -> set[str]:
    """The subcommand named in `argv` (as a one-element set), or an empty set for ``--help``, ``--version`` or none.
    The top-level parser has no option that takes a value, so the first word that is not an option is the command."""
    words = [a for a in argv if not a.startswith("-")]
    return set(words[:1])


def main(argv: list[str] | None = None) -> int:
    import warnings

    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(options_of=chosen_command(argv))
    args = parser.parse_args(argv)
    # a warning is one line that names the command, like an error, not a source location and a code line; the
    # library's logged warnings (the importers' assumptions) print the same way
    import logging

    prefix = f"splatreel {args.command}: warning: "
    previous = warnings.formatwarning
    warnings.formatwarning = lambda message, *_, **__: f"{prefix}{message}\n"
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter(prefix + "%(message)s"))
    logger = logging.getLogger("splatreel")
    logger.addHandler(handler)
    try:
        code = int(args._run(args) or 0)
        sys.stdout.flush()  # inside the try: a reader that went away is a BrokenPipeError here, not at exit
        return code
    except SplatreelError as exc:
        print(f"splatreel {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"splatreel {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # the reader went away (`splatreel info M --json | head`): stop quietly, as cat and grep do; the
        # interpreter's own flush at exit would fail again, so stdout goes to /dev/null first
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_ERROR
    except OSError as exc:  # any other OS error: one line naming the file, not a traceback
        where = f": {exc.filename}" if exc.filename else ""
        print(f"splatreel {args.command}: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return EXIT_ERROR
    finally:
        warnings.formatwarning = previous
        logger.removeHandler(handler)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
