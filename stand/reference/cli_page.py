"""``docs/reference/cli.md``: every command and sub-command of ``stand``, read from the parsers
that ``stand COMMAND --help`` prints (:func:`stand.cli.build_parser`): its summary, description,
usage, and every option with its default and help. Nothing is written by hand, so the page is
what ``--help`` says; a command or an option added anywhere appears once the page is
regenerated (``python -m stand.reference docs/reference``).

The help is formatted at a fixed width, never the terminal's, so the page depends on the code
alone."""
from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Iterator

from . import markdown as md

#: the width usage lines are wrapped at (the terminal's is not used: the page is the code's)
WIDTH = 100


@dataclass
class Command:
    """One command of the tree: ``path`` (``("stand", "test", "start")``), its parser and the
    one-line summary its parent lists it with."""

    path: tuple[str, ...]
    parser: argparse.ArgumentParser
    summary: str

    @property
    def name(self) -> str:
        return " ".join(self.path)


def commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ("stand",),
             summary: str = "") -> Iterator[Command]:
    """``parser`` and every sub-command below it, depth first, in the order they were added."""
    yield Command(path, parser, summary)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            for name, sub in action.choices.items():
                yield from commands(sub, path + (name,), helps.get(name, ""))


def _formatter(parser: argparse.ArgumentParser) -> argparse.HelpFormatter:
    return parser.formatter_class(prog=parser.prog, width=WIDTH)


def usage(parser: argparse.ArgumentParser) -> str:
    """The usage lines ``--help`` starts with, at :data:`WIDTH`."""
    f = _formatter(parser)
    f.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups)
    return f.format_help().strip()


def help_text(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """An option's help as ``--help`` prints it (``%(default)s`` and the like filled in)."""
    if not action.help:
        return ""
    return _formatter(parser)._expand_help(action)


def invocation(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """How the option is written: ``--bus SPEC``, ``-o, --out RUN``, ``DATA [DATA ...]``."""
    if action.option_strings:
        return _formatter(parser)._format_action_invocation(action)
    f = _formatter(parser)
    return f._format_args(action, f._get_default_metavar_for_positional(action))


def default(action: argparse.Action) -> str:
    """The option's default as the reference shows it: ``required``, ``off`` for a flag, the
    value, or nothing where there is none (the help then says what happens without it)."""
    if action.required and action.option_strings:
        return "required"
    if isinstance(action, argparse._StoreTrueAction):
        return "off"
    if isinstance(action, argparse._StoreFalseAction):
        return "on"
    if not action.option_strings or isinstance(action, argparse._StoreConstAction):
        return ""
    value = action.default
    if value is None or value == [] or value is argparse.SUPPRESS:
        return ""
    return md.code(value)


def _description(parser: argparse.ArgumentParser) -> str:
    """The description as paragraphs (a raw description keeps its blank lines)."""
    desc = parser.description or ""
    if issubclass(parser.formatter_class, argparse.RawDescriptionHelpFormatter):
        return "\n\n".join(md.text(p) for p in desc.split("\n\n") if p.strip())
    return md.text(desc)


def _options(cmd: Command) -> list[str]:
    """A table per argument group (positionals, options, the command's own groups)."""
    out = []
    for group in cmd.parser._action_groups:
        rows = []
        for action in group._group_actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)) \
                    or action.help == argparse.SUPPRESS:
                continue
            rows.append([md.code(invocation(cmd.parser, action)), default(action),
                         md.text(help_text(cmd.parser, action))])
        if not rows:
            continue
        title = group.title or "options"
        parts = [f"**{md.text(title[:1].upper() + title[1:])}**"]
        if group.description:
            parts.append(md.text(group.description))
        parts.append(md.table(["option", "default", "what it does"], rows))
        out.append("\n\n".join(parts))
    return out


def _subcommands(cmd: Command, children: list[Command]) -> str:
    if not children:
        return ""
    rows = [[f"[{md.code(c.path[-1])}](#{md.anchor(c.name)})", md.text(c.summary)] for c in children]
    return md.table(["command", "what it does"], rows)


def _section(cmd: Command, children: list[Command]) -> str:
    parts = [f"## {cmd.name}"]
    if cmd.summary and not (cmd.parser.description or "").startswith(cmd.summary):
        parts.append(f"*{md.text(cmd.summary)}*")
    if cmd.parser.description:
        parts.append(_description(cmd.parser))
    parts.append(md.fenced(usage(cmd.parser)))
    parts.append(_subcommands(cmd, children))
    parts += _options(cmd)
    return "\n\n".join(p for p in parts if p)


def cli_page(parser: argparse.ArgumentParser | None = None) -> str:
    """The page (module docstring); ``parser``: :func:`stand.cli.build_parser`'s by default."""
    if parser is None:
        from stand.cli import build_parser
        parser = build_parser()
    tree = list(commands(parser))
    children = {c.path: [d for d in tree if d.path[:-1] == c.path] for c in tree}
    top = tree[0]
    intro = ("Every command of `stand`, as `stand COMMAND --help` prints it: what it does, its "
             "usage, and every option with its default. `-h`/`--help` works on every command; "
             "a blank default means the option is off unless given (its help says what happens "
             "without it). The file formats the commands read and write: [the reference's "
             "index](README.md).")
    parts = [intro, md.text(top.parser.description or ""), md.fenced(usage(top.parser)),
             _subcommands(top, children[top.path]), *_options(top)]
    parts += [_section(c, children[c.path]) for c in tree[1:]]
    return md.page("The command line: `stand`", *parts)
