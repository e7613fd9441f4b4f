"""The command-line and config reference pages are generated: the committed pages must equal a fresh
generation, and the generation must follow the parsers."""

from __future__ import annotations

import argparse
import importlib.util
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _gen():
    spec = importlib.util.spec_from_file_location("gen_reference", ROOT / "docs" / "scripts" / "gen_reference.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["gen_reference"] = module
    spec.loader.exec_module(module)
    return module


def test_committed_reference_pages_are_a_fresh_generation():
    gen = _gen()
    for path, make in gen.PAGES.items():
        assert path.read_text(encoding="utf-8") == make(), \
            f"{path.relative_to(ROOT)} is stale: regenerate with `{gen.REGENERATE}`"


def _builder(gen, prog: str):
    """The parser builder of ``prog`` where the generator finds it (its one list of locations)."""
    return gen._first(next(c for p, sub, c in gen.PARSERS if p == prog and not sub))


def test_every_subcommand_and_option_of_the_parsers_is_on_the_page():
    gen = _gen()
    page = gen.cli_page()
    for prog in ("gonio", "simulate", "compare"):
        parser = _builder(gen, prog)()
        for name, (_, sub) in gen._subparsers(parser).items():
            assert f"### `{prog} {name}`" in page
            if not sub._actions[1:]:            # a placeholder for a parser of its own (gonio mock)
                continue
            for action in sub._actions:
                if isinstance(action, argparse._HelpAction) or action.help == argparse.SUPPRESS:
                    continue                    # -h, and old spellings kept for one release
                for option in action.option_strings:
                    assert f"`{option}`" in page, f"{prog} {name} {option} missing"
    assert "### `gonio mock`" in page and "`--faults`" in page           # from gonio.mock.cli's own parser
    assert "### `gonio bench-driver`" in page and "`--repeats`" in page


def test_a_changed_parser_shows_as_a_stale_page(monkeypatch):
    gen = _gen()
    original = _builder(gen, "simulate")
    module = sys.modules[original.__module__]

    def with_new_option():
        parser = original()
        gen._subparsers(parser)["fabric"][1].add_argument("--brand-new", help="a new option")
        return parser

    monkeypatch.setattr(module, original.__name__, with_new_option)
    page = gen.cli_page()
    assert "`--brand-new`" in page
    assert page != gen.CLI_PAGE.read_text(encoding="utf-8")


def test_the_config_page_holds_every_known_key():
    import simulate.config as config

    page = _gen().config_page()
    for table, keys in config._FIELDS.items():
        for key in keys:
            assert f"`{key}`" in page, f"[{table}] {key}"
    assert "## `[structure]`" in page and "felt_spread_deg" in page


def test_a_missing_builder_names_the_list_to_update():
    gen = _gen()
    try:
        gen._first(("no_such_package.cli:build_parser",))
    except SystemExit as exc:
        assert "PARSERS" in str(exc) and "no_such_package.cli:build_parser" in str(exc)
    else:
        raise AssertionError("an unknown builder location was accepted")


def test_the_option_help_reads_as_sentences():
    """No option's help repeats a word, as a help string formed from two parts that both say it
    would ("replace replace"), and --force's common tail is not a second parenthesis."""
    page = _gen().cli_page()
    assert not re.findall(r"\b([a-z]+) \1\b", page)
    assert ") (without it" not in page
