"""The docs site builds with ``mkdocs build --strict``, documents every option of every command, and the README stays
a short front door whose links resolve."""

from __future__ import annotations

import argparse
import html
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from splatreel.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"

#: Options of other programs that the docs name on purpose (the official 4DGS code, bench scripts, pytest, mkdocs).
FOREIGN_OPTIONS = {
    "--loaded_pth",  # official 4DGS: the option that reads a checkpoint dict
    "--json", "--rounds", "--ref-full", "--set",  # bench/*.py
    "--strict",  # mkdocs build
    "--head", "--node-ip-address", "--num-cpus", "--port",  # ray start
}


def commands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()):
    """(command words, parser) for every subcommand, depth first: ("train",), ("export",), ("export", "usd"), ..."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield prefix + (name,), sub
                yield from commands(sub, prefix + (name,))


def documented(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in parser._actions
            if a.help is not argparse.SUPPRESS and not isinstance(a, argparse._SubParsersAction)]


def all_option_strings() -> set[str]:
    found = set(build_parser()._option_string_actions)
    for _, sub in commands(build_parser()):
        found |= set(sub._option_string_actions)
    return found


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")  # mkdocs-material's banner about its successor
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stderr[-4000:]}"
    return out


def test_site_builds_with_api_pages(site):
    assert (site / "index.html").is_file()
    for module in ("model", "checkpoint", "cameras", "formats"):
        page = (site / "api" / module / "index.html").read_text()
        assert f'id="splatreel.{module}"' in page, f"mkdocstrings rendered nothing for splatreel.{module}"


def test_every_command_page_lists_every_option_of_its_parser(site):
    for words, parser in commands(build_parser()):
        page = site / "commands" / words[0] / "index.html"
        assert page.is_file(), f"no docs page for `splatreel {words[0]}`: add docs/commands/{words[0]}.md"
        text = html.unescape(page.read_text())
        for action in documented(parser):
            for spelling in action.option_strings:
                assert re.search(rf"<code>{re.escape(spelling)}[ <]", text), \
                    f"docs/commands/{words[0]}.md: the reference of `{' '.join(words)}` lacks {spelling}"
        assert f"{parser.prog}" in text


def test_docs_and_readme_name_only_options_that_exist():
    """Prose that names an option the parsers do not have is stale (renamed or removed): fix the spelling."""
    known = all_option_strings() | FOREIGN_OPTIONS
    stale = []
    for path in [README, *sorted(DOCS.rglob("*.md"))]:
        for n, line in enumerate(path.read_text().splitlines(), 1):
            for option in re.findall(r"(?<![\w-])--[a-z][a-z0-9_-]*[a-z0-9]", line):
                if option not in known:
                    stale.append(f"{path.relative_to(ROOT)}:{n}: {option}")
    assert not stale, "options no parser defines:\n" + "\n".join(stale)


def test_readme_is_short_and_starts_with_the_two_commands():
    lines = README.read_text().splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines; move detail to docs/"
    body = [line for line in lines[1:] if line.strip()]
    assert lines[0].startswith("# ") and body[0] == "```bash", "README: the set-up commands come first"
    assert body[1].startswith("bash scripts/demo.sh") and body[2].startswith("bash scripts/test.sh")
    assert body[3] == "```"


def test_readme_relative_links_resolve():
    text = README.read_text()
    targets = re.findall(r"\]\(([^)\s]+)\)", text) + re.findall(r'src="([^"]+)"', text)
    relative = [t for t in targets if not re.match(r"[a-z]+:", t) and not t.startswith("#")]
    assert relative, "README links to nothing in the repository"
    missing = [t for t in relative if not (ROOT / t.split("#")[0]).exists()]
    assert not missing, f"README links to missing files: {missing}"


def test_readme_picture_is_small():
    for image in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", README.read_text()):
        assert (ROOT / image).stat().st_size < 200_000, f"{image} is over 200 KB"


def test_reference_generator_walks_nested_parsers_and_escapes_help():
    """docs/hooks.py on a toy parser: groups, nested subcommands, choices behind a metavar, Markdown in help."""
    import importlib.util

    import markdown

    spec = importlib.util.spec_from_file_location("docs_hooks", DOCS / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    root = argparse.ArgumentParser(prog="tool")
    sub = root.add_subparsers(dest="command")
    cmd = sub.add_parser("make", description="Makes things.")
    cmd.add_argument("--level", choices=["a", "b"], metavar="L", default="a", help="a|b, *not* [x]")
    group = cmd.add_argument_group("look")
    group.add_argument("--size", type=int, default=3, help="size in `px|pt` (default %(default)s)")
    inner = cmd.add_subparsers(dest="kind").add_parser("deep")
    inner.add_argument("--depth", help="how deep")
    page = markdown.markdown(hooks.render_markers("<!-- options: make -->", root), extensions=["tables"])
    assert "<code>--level L</code>" in page and "<code>a</code>, <code>b</code>" in page
    assert "<em>" not in page and "a|b, *not* [x]" in html.unescape(page)  # escaped: no emphasis, no link
    assert "<code>px|pt</code>" in page and "default 3" in page and "<h3>Look</h3>" in page
    assert "<code>tool make deep</code>" in page and "<code>--depth DEPTH</code>" in page
    assert 'id="opt-make-deep-depth"' in page
    with pytest.raises(Exception, match="no subcommand 'nope'"):
        hooks.render_markers("<!-- options: make nope -->", root)
