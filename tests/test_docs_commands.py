"""Every ``trase-bench COMMAND --option`` the README and docs/ show exists: the command is one of
the CLI's and each option is one its ``--help`` lists (old spellings, hidden, do not count)."""

import re
from pathlib import Path

import click

from benchmark.cli import COMMANDS

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]  # user pages; docs/notes/ keeps history
# code: fenced blocks and inline code spans; in it a command, then its words up to the line's end
CODE = re.compile(r"```.*?```|`[^`\n]+`", re.DOTALL)
INVOCATION = re.compile(r"(?:^|[\s$/])trase-bench ([a-z][a-z-]*)([^\n|]*)", re.MULTILINE)


def _options(command: click.Command) -> set[str]:
    """The options ``--help`` shows, of the command and, for a group, of its subcommands."""
    commands = [command, *(command.commands.values() if isinstance(command, click.Group) else [])]
    return {o for c in commands for p in c.params if isinstance(p, click.Option) and not p.hidden
            for o in (*p.opts, *p.secondary_opts)} | {"--help", "-h"}


def _invocations():
    for page in PAGES:
        code = "\n".join(m.strip("`") for m in CODE.findall(page.read_text()))
        for name, rest in INVOCATION.findall(code):
            yield page.relative_to(ROOT), name, re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", rest)


def test_documented_commands_and_options_exist():
    unknown = []
    seen = 0
    for page, name, options in _invocations():
        if name not in COMMANDS:
            unknown.append(f"{page}: trase-bench {name} (no such command)")
            continue
        allowed = _options(COMMANDS.load(name))
        unknown += [f"{page}: trase-bench {name} {o}" for o in options if o not in allowed]
        seen += 1
    assert seen > 50, f"only {seen} documented commands found: the pattern no longer matches the pages"
    assert not unknown, unknown
