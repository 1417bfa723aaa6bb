"""docs/reference.md is what docs/gen_reference.py writes from the code now: a FilterConfig
field or a command argument added without regenerating the page fails here."""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
from pathlib import Path

import pytest

from clearsplat.cli import COMMANDS, build_parser
from clearsplat.filter.config import FIELD_SPECS, FilterConfig

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "reference.md"


@pytest.fixture(scope="module")
def gen():
    spec = importlib.util.spec_from_file_location("gen_reference",
                                                  ROOT / "docs" / "gen_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def page():
    return PAGE.read_text()


def test_reference_is_what_the_script_writes_now(gen, page):
    assert page == gen.generate(), \
        "docs/reference.md is out of date: run python docs/gen_reference.py"
    assert gen.main(["--check"]) == 0


def test_every_filter_config_field_is_documented(page):
    section = page.split("## Command line")[0]
    default = FilterConfig()
    for f in dataclasses.fields(FilterConfig):
        rows = [line for line in section.splitlines() if line.startswith(f"| `{f.name}` | ")]
        assert rows, f.name
        row = rows[0]
        assert repr(getattr(default, f.name)).replace("|", "\\|") in row, f.name
        assert FIELD_SPECS[f.name].allowed().replace("|", "\\|") in row, f.name
        assert len(row.split(" | ")[-1]) > 20, f"{f.name}: no description"


def test_every_command_and_argument_is_documented(page):
    sub = next(a for a in build_parser()._actions
               if isinstance(a, argparse._SubParsersAction))
    assert list(sub.choices) == list(COMMANDS)
    for name, parser in sub.choices.items():
        assert f"#### `clearsplat {name}`" in page, name
        section = page.split(f"#### `clearsplat {name}`")[1].split("\n#### ")[0]
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            for option in action.option_strings:
                assert f"`{option}" in section, (name, option)
            if not action.option_strings:
                assert f"| `{action.metavar or action.dest}`" in section, (name, action.dest)


def test_a_field_without_a_docstring_entry_stops_the_script(gen, monkeypatch):
    doc = FilterConfig.__doc__
    start = doc.index("    eta : float")
    end = doc.index("    num_verify_views : int")
    monkeypatch.setattr(FilterConfig, "__doc__", doc[:start] + doc[end:])
    with pytest.raises(SystemExit, match=r"without a docstring entry \['eta'\]"):
        gen.generate()


def test_docstring_entries_markup_and_shared_entries(gen):
    doc = '''Options.

    Summary with ``code``.

    Attributes
    ----------
    a, b : float or None
        Two at once, see :func:`x.y.
        z` and :attr:`~p.q`.
    c : {"u", "v"}
        One of them.

        Second paragraph.

    Notes
    -----
    d : int
        Not an attribute.
    '''
    summary, entries = gen.docstring_sections(doc)
    assert summary == "Options.\n\nSummary with `code`."
    assert entries == {"a": ("float or None", "Two at once, see `x.y.z` and `p.q`."),
                       "b": ("float or None", "Two at once, see `x.y.z` and `p.q`."),
                       "c": ('{"u", "v"}', "One of them. Second paragraph.")}


def test_usage_lines_fit_and_name_every_option(gen):
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, p in sub.choices.items():
        usage = gen._usage(p)
        assert usage.startswith(f"usage: clearsplat {name} [-h]")
        assert max(len(line) for line in usage.splitlines()) <= gen.WIDTH
        for action in p._actions:
            if action.option_strings:
                assert action.option_strings[0] in usage, (name, action.dest)
