"""Write docs/cli.md, the command-line reference, from the parsers the ``shapespace`` command runs.

    python tools/gen_cli_docs.py            # (re)write docs/cli.md
    python tools/gen_cli_docs.py --check    # exit 1 when docs/cli.md differs from what the parsers give

The page is generated from ``cli.build_parser()`` (every subcommand, its help, usage, options with their
choices, defaults and whether they are required or repeatable, and the epilog), so it cannot drift from the
code: ``tests/bridge/test_cli_docs.py`` regenerates it in memory and fails when the file is stale.  Only the
actions' own attributes are read (never argparse's help formatter), so the page is the same on every Python
and terminal width.  Needs ``bpy`` (the ``cli`` package imports it): without it this script re-runs itself
in ``.venv/bpy50`` (created on first use).
"""
from __future__ import annotations

import argparse
import os
import re
import sys

TOOLS = os.path.dirname(os.path.abspath(__file__))
if TOOLS not in sys.path:
    sys.path.insert(0, TOOLS)
import env  # noqa: E402  (tools/env.py)
import package  # noqa: E402  (tools/package.py)

OUT = os.path.join(env.ROOT, "docs", "cli.md")
BLENDER = "blender [-b FILE.blend]"
_MD_SPECIAL = re.compile(r"([\\`*_\[\]<>])")


def escape(text: str) -> str:
    """``text`` as literal Markdown (no emphasis, links or HTML from the characters help strings use)."""
    return _MD_SPECIAL.sub(r"\\\1", text)


def _metavar(action: argparse.Action) -> str:
    if action.metavar is not None:
        return action.metavar if isinstance(action.metavar, str) else " ".join(action.metavar)
    if action.choices is not None:
        return "{" + ",".join(str(c) for c in action.choices) + "}"
    return action.dest.upper() if action.option_strings else action.dest


def _arguments(action: argparse.Action) -> str:
    """What follows the option on the command line (``M``, ``[M]``, ``M [M ...]``, …)."""
    if action.nargs == 0:
        return ""
    m = _metavar(action)
    if action.nargs is None:
        return m
    if action.nargs == "?":
        return f"[{m}]"
    if action.nargs == "*":
        return f"[{m} ...]"
    if action.nargs == "+":
        return f"{m} [{m} ...]"
    if isinstance(action.nargs, int):
        return m if isinstance(action.metavar, tuple) else " ".join([m] * action.nargs)
    return m


def _visible(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in parser._actions
            if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)) and a.help != argparse.SUPPRESS]


def usage(parser: argparse.ArgumentParser, command: str) -> str:
    """One synopsis line: required options and positionals as they are, the others in brackets."""
    parts = [BLENDER, "--command", parser.prog.split(" --command ", 1)[1] if " --command " in parser.prog else command]
    for action in _visible(parser):
        if isinstance(action, argparse._VersionAction):
            continue
        if action.option_strings:
            word = f"{action.option_strings[-1]} {_arguments(action)}".strip()
            parts.append(word if action.required else f"[{word}]")
        else:
            parts.append(_arguments(action))
    return " ".join(parts)


def _help(action: argparse.Action) -> str:
    text = action.help or ""
    if "%(" in text:
        text = text % {**vars(action), "default": action.default}
    return text


def option_line(action: argparse.Action) -> str:
    """One Markdown list item for an option or positional: names, help, default, required, repeatable."""
    args = _arguments(action)
    names = action.option_strings or [action.dest]
    shown = ", ".join(f"`{n}`" for n in names[:-1])
    shown += (", " if shown else "") + f"`{(names[-1] + ' ' + args).strip() if action.option_strings else args}`"
    notes = []
    if action.required and action.option_strings:
        notes.append("required")
    if isinstance(action, argparse._AppendAction):
        notes.append("repeatable")
    if (action.option_strings and action.nargs != 0 and action.default not in (None, argparse.SUPPRESS)
            and not isinstance(action, argparse._VersionAction)):
        notes.append(f"default: `{action.default}`")
    help_text = escape(_help(action))
    tail = f" ({'; '.join(notes)})" if notes else ""
    return f"- {shown}{' — ' + help_text if help_text else ''}{tail}"


def _text(parser: argparse.ArgumentParser, text: str | None) -> list[str]:
    """A description or epilog: pre-formatted (Raw…HelpFormatter) as a text block, else a paragraph."""
    if not text:
        return []
    if issubclass(parser.formatter_class, argparse.RawDescriptionHelpFormatter):
        return ["```text", text.rstrip(), "```", ""]
    return [escape(" ".join(text.split())), ""]


def subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """``(name, help, parser)`` of every subcommand, in the order they were added."""
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            found += [(name, helps.get(name, ""), sub) for name, sub in action.choices.items()]
    return found


def render(parser: argparse.ArgumentParser) -> str:
    """The whole page for the top-level ``shapespace`` parser."""
    subs = subcommands(parser)
    lines = ["# Command-line reference", "",
             "<!-- Generated by tools/gen_cli_docs.py from cli.build_parser(): do not edit by hand; run "
             "`python tools/gen_cli_docs.py`. -->", "",
             "ShapeSpace registers the command `shapespace` with Blender when the extension is enabled; "
             "`python tools/run_cli.py` runs the same handler with the `bpy` module (see "
             "[Command line](user/command-line.md), which also gives the exit codes). "
             "Every subcommand takes `-h`/`--help`.", "",
             f"    {BLENDER} --command shapespace [--version] COMMAND [options]", ""]
    lines += _text(parser, parser.description)
    lines += [option_line(a) for a in _visible(parser)] + [""]
    lines += ["| command | what it does |", "|---|---|"]
    lines += [f"| [`{name}`](#{name}) | {escape(help_).replace('|', '&#124;')} |" for name, help_, _ in subs]
    lines.append("")
    for name, help_, sub in subs:
        lines += [f"## {name}", ""]
        if help_:
            lines += [escape(help_[:1].upper() + help_[1:]) + ("" if help_.endswith(".") else "."), ""]
        lines += [f"    {usage(sub, name)}", ""]
        lines += _text(sub, sub.description)
        options = [option_line(a) for a in _visible(sub)]
        if options:
            lines += options + [""]
        lines += _text(sub, sub.epilog)
    return "\n".join(lines).rstrip("\n") + "\n"


def build_page() -> str:
    """docs/cli.md as the code gives it now (loads the repository as the ``shapespace`` package)."""
    return render(package.load().cli.build_parser())


def main(argv) -> int:
    ap = argparse.ArgumentParser(description="Write docs/cli.md from the shapespace command's parsers.")
    ap.add_argument("--check", action="store_true", help="exit 1 if docs/cli.md is stale; write nothing")
    args = ap.parse_args(argv)
    env.reexec_in("bpy50", os.path.abspath(__file__), argv)
    page = build_page()
    old = open(OUT, encoding="utf-8").read() if os.path.isfile(OUT) else None
    if args.check:
        if old != page:
            print("gen_cli_docs: docs/cli.md is stale; run `python tools/gen_cli_docs.py`", file=sys.stderr)
            return 1
        return 0
    if old != page:
        with open(OUT, "w", encoding="utf-8") as fh:
            fh.write(page)
    print(f"gen_cli_docs: {os.path.relpath(OUT, env.ROOT)} {'written' if old != page else 'up to date'}",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
