"""MkDocs hook: the option reference of each command page, generated from the argparse parsers at build time.

A page asks for a command's reference with a marker on a line of its own::

    <!-- options: train -->
    <!-- options: export usd -->

The marker is replaced by the usage line, the command's description and one table per argument group, read from
``splatreel.cli.build_parser()``; nested subcommands (``export usd``, ...) follow their parent. Nothing here knows
an option's name, so renaming an option in the CLI renames it in the docs. An unknown command in a marker fails
the build. Hook API: https://www.mkdocs.org/user-guide/configuration/#hooks
"""

from __future__ import annotations

import argparse
import re

from mkdocs.exceptions import PluginError

USAGE_WIDTH = 100
MARKER = re.compile(r"^<!--\s*options:\s*(?P<command>[\w\- ]+?)\s*-->\s*$", re.MULTILINE)


def subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Subcommand name -> parser, in the order ``--help`` lists them (empty for a leaf command)."""
    found: dict[str, argparse.ArgumentParser] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            found.update(action.choices)
    return found


def find_parser(root: argparse.ArgumentParser, command: str) -> argparse.ArgumentParser:
    """The parser of ``command`` ("train", "export usd"), walking down from the root."""
    parser = root
    for word in command.split():
        children = subparsers(parser)
        if word not in children:
            raise KeyError(f"{parser.prog} has no subcommand {word!r} (it has: {', '.join(children) or 'none'})")
        parser = children[word]
    return parser


def documented_actions(parser: argparse.ArgumentParser) -> list[tuple[str, list[argparse.Action]]]:
    """(group title, its actions) for every group with something to show; subcommand lists are left out."""
    groups = []
    for group in parser._action_groups:
        actions = [a for a in group._group_actions
                   if a.help is not argparse.SUPPRESS and not isinstance(a, argparse._SubParsersAction)]
        if actions:
            groups.append((group.title or "options", actions))
    return groups


def _escape(text: str) -> str:
    """Markdown-safe table-cell text: code spans (backticks) kept as they are, the rest escaped.

    Python-Markdown's tables do not split cells at a ``|`` inside a code span, so only the text outside them needs
    escaping."""
    parts = text.replace("\n", " ").split("`")
    for i in range(0, len(parts), 2):  # even parts lie outside code spans
        parts[i] = (parts[i].replace("\\", "\\\\").replace("*", "\\*").replace("_", "\\_")
                    .replace("[", "\\[").replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;"))
    return "`".join(parts)


def _invocation(formatter: argparse.HelpFormatter, action: argparse.Action) -> str:
    # "-h, --help", "--minutes M", "CKPT": what --help prints in its left column, one code span per spelling
    return ", ".join(f"`{part}`" for part in formatter._format_action_invocation(action).split(", "))


def _description(formatter: argparse.HelpFormatter, action: argparse.Action) -> str:
    text = formatter._expand_help(action) if action.help else ""
    default = action.default
    shown = default not in (None, False, argparse.SUPPRESS) and not isinstance(
        action, (argparse._HelpAction, argparse._VersionAction))
    if shown and "default" not in text.lower():
        text += f" (default: `{default}`)"
    if action.choices is not None and action.metavar is not None:  # choices hidden behind a metavar
        text += " One of: " + ", ".join(f"`{c}`" for c in action.choices) + "."
    return _escape(text.strip())


def anchor(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """A stable HTML id for an option row: ``opt-<command words>-<longest spelling>``."""
    spelling = max(action.option_strings, key=len) if action.option_strings else action.dest
    words = parser.prog.split()[1:] + [spelling.lstrip("-")]
    return "opt-" + "-".join(re.sub(r"[^\w-]", "", w) for w in words)


def parser_reference(parser: argparse.ArgumentParser, level: int = 3) -> str:
    """Markdown for one parser and its subcommands: usage, description, one table per argument group."""
    # a fixed width, so that the page does not depend on the terminal that builds it
    usage = parser.formatter_class(prog=parser.prog, width=USAGE_WIDTH)
    usage.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups)
    out = ["```text", usage.format_help().strip(), "```", ""]
    formatter = parser.formatter_class(prog=parser.prog, width=USAGE_WIDTH)  # for the table cells
    if parser.description:
        out += ["```text", parser.description.strip("\n"), "```", ""]
    for title, actions in documented_actions(parser):
        out += [f"{'#' * level} {title[:1].upper()}{title[1:]}", "", "| argument | meaning |", "|---|---|"]
        for action in actions:
            out.append(f"| <a id=\"{anchor(parser, action)}\"></a>{_invocation(formatter, action)} "
                       f"| {_description(formatter, action)} |")
        out.append("")
    for child in subparsers(parser).values():
        out += [f"{'#' * level} `{child.prog}`", ""]
        out.append(parser_reference(child, level + 1))
    return "\n".join(out)


def render_markers(markdown: str, root: argparse.ArgumentParser) -> str:
    """Every ``<!-- options: CMD -->`` marker replaced by that command's reference."""
    def replace(match: re.Match) -> str:
        try:
            return parser_reference(find_parser(root, match["command"]))
        except KeyError as exc:
            raise PluginError(f"options marker {match[0].strip()!r}: {exc.args[0]}") from None
    return MARKER.sub(replace, markdown)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if not MARKER.search(markdown):
        return markdown
    from splatreel.cli import build_parser  # the installed (editable) package: the parsers as they are now

    return render_markers(markdown, build_parser())
