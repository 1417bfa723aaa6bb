"""Write docs/reference.md from the code: every FilterConfig field and every command.

The fields come from ``FilterConfig`` itself (names, defaults), its docstring's Attributes
section (what each does) and ``FIELD_SPECS`` (what each accepts); the presets from
``PRESETS``; the commands from the command line's own argparse parsers
(``clearsplat.cli.build_parser``: every subcommand, its arguments, defaults and help). Nothing
is written by hand, so the page cannot drift: ``tests/test_reference.py`` fails when the page
differs from what this script writes now.

    python docs/gen_reference.py            # rewrite docs/reference.md
    python docs/gen_reference.py --check    # exit 1 if docs/reference.md is out of date
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import sys
import textwrap
from pathlib import Path

PAGE = Path(__file__).resolve().parent / "reference.md"
WIDTH = 100          # usage lines are wrapped at this width, whatever the terminal

HEADER = """\
# Reference

Every option of the filter (`FilterConfig`, `--set KEY=VALUE`) and every command of
`clearsplat`, with its arguments. This page is generated from the code by `python
docs/gen_reference.py` (from `FilterConfig`'s docstring, `FIELD_SPECS` and the command line's
parsers); do not edit it by hand: `tests/test_reference.py` fails when it differs from what the
script writes. Why each default is what it is: `docs/method.md`; errors: `docs/errors.md`.
"""


# ------------------------------------------------------------------------------------------------
# docstrings
# ------------------------------------------------------------------------------------------------
def _markdown(text: str) -> str:
    """reST inline markup of a docstring as Markdown, on one line."""
    text = " ".join(text.split())
    # :func:`~a.b` and friends -> `a.b` (a role's target may have been wrapped mid-name)
    text = re.sub(r":[a-z]+:`~?([^`]+)`", lambda m: f"`{''.join(m.group(1).split())}`", text)
    text = re.sub(r"``([^`]+)``", r"`\1`", text)
    return text


def docstring_sections(doc: str) -> tuple[str, dict[str, tuple[str, str]]]:
    """``(summary, {name: (type, description)})`` from a numpydoc class docstring.

    ``summary`` is the text before the first section; the entries are those of the
    ``Attributes`` section, an entry naming several fields (``tau1, tau2 : float``) once per
    field.
    """
    first, _, rest = doc.partition("\n")
    lines = textwrap.dedent(rest).splitlines()
    heads = [i for i in range(len(lines) - 1)
             if lines[i].strip() and lines[i + 1].strip() and set(lines[i + 1].strip()) == {"-"}]
    start = next(i for i in heads if lines[i].strip() == "Attributes")
    end = next((i for i in heads if i > start), len(lines))
    summary = "\n".join([first.strip()] + lines[:heads[0]]).strip()
    entries, names, kind, body = {}, [], "", []
    for line in lines[start + 2:end] + ["END"]:
        if line and not line[0].isspace():              # "name : type" starts an entry
            for n in names:
                entries[n] = (kind, _markdown(" ".join(body)))
            head, _, kind = line.partition(" : ")
            names, body = [n.strip() for n in head.split(",")], []
        elif line.strip():
            body.append(line.strip())
    return "\n\n".join(_markdown(p) for p in summary.split("\n\n")), entries


# ------------------------------------------------------------------------------------------------
# FilterConfig
# ------------------------------------------------------------------------------------------------
def _cell(text) -> str:
    return str(text).replace("|", "\\|")


def _value(value) -> str:
    return "`None`" if value is None else f"`{value!r}`"


def filter_config_section() -> list[str]:
    from clearsplat.filter.config import FIELD_SPECS, PRESETS, FilterConfig

    summary, entries = docstring_sections(FilterConfig.__doc__)
    fields = dataclasses.fields(FilterConfig)
    missing = [f.name for f in fields if f.name not in entries]
    unspecified = [f.name for f in fields if f.name not in FIELD_SPECS]
    if missing or unspecified:
        raise SystemExit(f"FilterConfig fields without a docstring entry {missing} or without "
                         f"a FIELD_SPECS entry {unspecified}: document them in "
                         "src/clearsplat/filter/config.py first")
    out = ["## `FilterConfig`", "", summary, "",
           "In Python `FilterConfig(eta=0.4)` or `FilterConfig.preset(\"paper-local\", "
           "eta=0.4)`; on the command line `--preset NAME` and `--set eta=0.4` "
           "(`true`/`false`, `null` for None).", "",
           "| field | type | default | accepts | what it does |", "|---|---|---|---|---|"]
    default = FilterConfig()
    for f in fields:
        kind, text = entries[f.name]
        out.append(f"| `{f.name}` | {_cell(_markdown(kind))} | "
                   f"{_cell(_value(getattr(default, f.name)))} | "
                   f"{_cell(FIELD_SPECS[f.name].allowed())} | {_cell(text)} |")
    names = list(PRESETS)
    differ = [f.name for f in fields
              if len({repr(getattr(PRESETS[n], f.name)) for n in names}) > 1]
    out += ["", "### Presets", "",
            "`FilterConfig.preset(NAME)`, `--preset NAME`: " + ", ".join(
                f"`{n}`" for n in names) + ". The fields where they differ:", "",
            "| field | " + " | ".join(f"`{n}`" for n in names) + " |",
            "|---|" + "---|" * len(names)]
    for name in differ:
        out.append(f"| `{name}` | " + " | ".join(
            _cell(_value(getattr(PRESETS[n], name))) for n in names) + " |")
    return out


# ------------------------------------------------------------------------------------------------
# the command line
# ------------------------------------------------------------------------------------------------
def _metavar(action: argparse.Action) -> str:
    if action.metavar is not None:
        return action.metavar
    if action.choices is not None and not isinstance(action, argparse._SubParsersAction):
        return "{" + ",".join(map(str, action.choices)) + "}"
    return action.dest if not action.option_strings else action.dest.upper()


def _usage(parser: argparse.ArgumentParser) -> str:
    """The usage line, wrapped at WIDTH (written here, not by argparse, whose layout changes
    between Python versions)."""
    optional, positional = [], []
    groups = {id(a): g for g in parser._mutually_exclusive_groups for a in g._group_actions}
    done = set()
    for action in parser._actions:
        if action.help is argparse.SUPPRESS or id(action) in done:
            continue
        if not action.option_strings:
            m = _metavar(action)
            positional.append({"+": f"{m} [{m} ...]", "*": f"[{m} ...]", "?": f"[{m}]"}.get(
                action.nargs, f"{m} ..." if action.nargs == argparse.PARSER else m))
            continue
        group = groups.get(id(action))
        members = group._group_actions if group is not None else [action]
        done.update(id(a) for a in members)
        words = []
        for a in members:
            word = a.option_strings[0]
            if a.nargs != 0:
                word += f" {_metavar(a)}"
            words.append(word)
        required = group.required if group is not None else action.required
        text = " | ".join(words)
        optional.append(f"({text})" if required and len(words) > 1 else
                        text if required else f"[{text}]")
    head = f"usage: {parser.prog} "
    lines, line = [], head
    for part in optional + positional:
        if len(line) + len(part) > WIDTH and line.strip() != head.strip():
            lines.append(line.rstrip())
            line = " " * len(head)
        line += part + " "
    lines.append(line.rstrip())
    return "\n".join(lines)


def _argument(action: argparse.Action) -> str:
    if not action.option_strings:
        return f"`{action.metavar or action.dest}`" + (
            f" (one of {', '.join(map(str, action.choices))})"
            if action.choices and action.metavar is None else "")
    if action.nargs == 0:
        return ", ".join(f"`{o}`" for o in action.option_strings)
    return ", ".join(f"`{o} {_metavar(action)}`" for o in action.option_strings)


def _help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """The help text with ``%(default)s`` and the like filled in, as ``--help`` shows it,
    plus what ``--help`` shows elsewhere: required, the default, the choices."""
    text = ""
    if action.help:
        params = {k: v for k, v in vars(action).items() if v is not argparse.SUPPRESS}
        params["prog"] = parser.prog
        if params.get("choices") is not None:
            params["choices"] = ", ".join(map(str, params["choices"]))
        text = " ".join((action.help % params).split())
    extra = []
    if action.required and action.option_strings:
        extra.append("required")
    if action.option_strings and action.nargs != 0 and action.default is not None \
            and action.default is not argparse.SUPPRESS \
            and "%(default)" not in (action.help or ""):
        extra.append(f"default: {action.default!r}")
    if action.option_strings and action.choices is not None and action.metavar is not None:
        extra.append("one of " + ", ".join(map(str, action.choices)))
    return (text + (f" ({'; '.join(extra)})" if extra else "")).strip()


def _subparsers(parser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action
    return None


def command_sections(parser: argparse.ArgumentParser, level: int = 2,
                     epilogs: dict | None = None) -> list[str]:
    """A section per command: description, usage, arguments, epilog; then its subcommands.
    An epilog already written under an earlier command (``--set``'s field list) is named, not
    repeated."""
    epilogs = {} if epilogs is None else epilogs
    out = [f"{'#' * level} `{parser.prog}`", ""]
    if parser.description:
        out += [" ".join(parser.description.split()), ""]
    out += ["```text", _usage(parser), "```", ""]
    rows = [a for a in parser._actions
            if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))
            and a.help is not argparse.SUPPRESS]
    if rows:
        out += ["| argument | what it does |", "|---|---|"]
        out += [f"| {_cell(_argument(a))} | {_cell(_help(parser, a))} |" for a in rows]
        out.append("")
    if parser.epilog and parser.epilog in epilogs:
        first = epilogs[parser.epilog]
        out += [f"After the arguments, `--help` lists what `{first} --help` lists "
                f"([`{first}`](#{first.replace(' ', '-')})).", ""]
    elif parser.epilog:
        epilogs[parser.epilog] = parser.prog
        if parser.formatter_class is argparse.RawDescriptionHelpFormatter:
            out += ["```text", parser.epilog.rstrip(), "```", ""]
        else:
            out += [" ".join(parser.epilog.split()), ""]
    sub = _subparsers(parser)
    if sub is not None:
        helps = {a.dest: a.help for a in sub._choices_actions}
        out += ["| command | what it does |", "|---|---|"]
        out += [f"| `{name}` | {_cell(' '.join((helps.get(name) or '').split()))} |"
                for name in sub.choices]
        out.append("")
        for child in sub.choices.values():
            out += command_sections(child, level + 1, epilogs)
    return out


# ------------------------------------------------------------------------------------------------
def generate() -> str:
    """The text of docs/reference.md as the code stands now."""
    from clearsplat.cli import build_parser

    lines = [HEADER, *filter_config_section(), "", "## Command line", "",
             "Each command's `--help` prints the same; exit codes and messages: "
             "`docs/errors.md`.", "", *command_sections(build_parser(), level=3)]
    text = "\n".join(lines)
    text = re.sub(r"\n{3,}", "\n\n", text)
    return "\n".join(line.rstrip() for line in text.splitlines()).rstrip("\n") + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Write docs/reference.md from the code.")
    p.add_argument("--check", action="store_true",
                   help="write nothing; exit 1 if docs/reference.md differs from the code")
    args = p.parse_args(argv)
    text = generate()
    if args.check:
        current = PAGE.read_text() if PAGE.exists() else ""
        if current != text:
            print(f"{PAGE} is out of date: run python docs/gen_reference.py", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(text)
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
