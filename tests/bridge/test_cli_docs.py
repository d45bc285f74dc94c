"""docs/cli.md is what tools/gen_cli_docs.py makes from the parsers the ``shapespace`` command runs (real bpy)."""
import argparse
import os

import gen_cli_docs  # tools/gen_cli_docs.py
import package  # tools/package.py
from support import ROOT


def test_cli_reference_is_current():
    """Regenerate the page in memory from ``cli.build_parser()``: a help string, option or subcommand changed
    without `python tools/gen_cli_docs.py` fails here."""
    with open(os.path.join(ROOT, "docs", "cli.md"), encoding="utf-8") as fh:
        on_disk = fh.read()
    assert gen_cli_docs.build_page() == on_disk, \
        "docs/cli.md is stale: run `python tools/gen_cli_docs.py` and commit the result"


def test_cli_reference_names_every_subcommand_and_option():
    """The page lists every subcommand under its own heading and every option of it, from the parser itself."""
    parser = package.load().cli.build_parser()
    page = gen_cli_docs.render(parser)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert len(sub.choices) >= 5
    for name, sub_parser in sub.choices.items():
        section = page.split(f"\n## {name}\n", 1)[1].split("\n## ", 1)[0]
        for action in sub_parser._actions:
            for flag in action.option_strings:
                if flag not in ("-h", "--help"):
                    assert f"`{flag}" in section, f"{name} {flag} missing from docs/cli.md"
