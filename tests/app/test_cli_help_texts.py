"""Every command's help reads as written: argparse formats only the options' help strings with %, not a
description, so a "%%" written for one of them shows doubled in the other."""

from __future__ import annotations

import argparse

from app.cli.main import build_parser


def _parsers(parser: argparse.ArgumentParser, path: str = "sensnake"):
    yield path, parser
    for action in parser._actions:  # argparse keeps its sub-commands here; there is no public way to walk them
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, f"{path} {name}")


def test_no_command_help_shows_a_doubled_percent_sign():
    seen = 0
    for path, parser in _parsers(build_parser()):
        text = parser.format_help()
        assert "%%" not in text, f"`{path} --help` shows '%%'"
        seen += 1
    assert seen > 20  # every sub-command was reached
