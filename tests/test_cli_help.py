"""Every option of every command this package owns says what it does."""
from __future__ import annotations

import argparse

import pytest

from eval.harness_cli import build_parser as tables_parser
from smokeseer.cli import build_parser as trainer_parser


@pytest.mark.parametrize("parser", [trainer_parser(), tables_parser()], ids=["train-and-evaluate", "regenerate-tables"])
def test_every_option_has_help(parser: argparse.ArgumentParser) -> None:
    missing = [", ".join(a.option_strings) or a.dest for a in parser._actions
               if not isinstance(a, argparse._HelpAction) and not (a.help or "").strip()]
    assert not missing, f"{parser.prog}: options without help: {missing}"
