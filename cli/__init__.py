"""``blender --command shapespace …``: ShapeSpace on the command line.

The handler is registered with ``bpy.utils.register_cli_command`` when the
extension is enabled; ``tools/run_cli.py`` calls the same :func:`main` with
the ``bpy`` module.  Output goes to stdout as JSON; errors are one line on
stderr and a non-zero exit code.
"""
from __future__ import annotations

import argparse
import json
import sys

import bpy

from ..core.result import ShapeSpaceError

COMMAND = "shapespace"

_registered = []  # the handle returned by register_cli_command, for unregister


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise ShapeSpaceError(f"{self.prog}: {message}", "usage")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=f"blender --command {COMMAND}",
                     description="ShapeSpace example-based deformation tools.")
    sub = parser.add_subparsers(dest="command", required=True)
    info = sub.add_parser("info", help="list the rigs (shape-key meshes, armatures, skins, actions) as JSON")
    info.add_argument("files", nargs="*", help=".blend/.glb/.gltf/.fbx/.bvh files; default: the open file")
    info.add_argument("--out", help="write the JSON here instead of stdout")
    return parser


def _cmd_info(args) -> int:
    from ..bridge import assets, inventory
    reports = []
    if args.files:
        for path in args.files:
            assets.load(path)
            rep = inventory.describe_file()
            rep["file"] = path
            reports.append(rep)
    else:
        reports.append(inventory.describe_file())
    for rep in reports:
        inventory.require_rigs(rep)
    payload = reports[0] if len(reports) == 1 else reports
    text = json.dumps(payload, indent=2)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(text + "\n")
    else:
        print(text)
    return 0


COMMANDS = {"info": _cmd_info}


def main(argv) -> int:
    """Run one ShapeSpace command; return the process exit code."""
    try:
        args = build_parser().parse_args(list(argv))
        return COMMANDS[args.command](args)
    except ShapeSpaceError as exc:
        print(f"shapespace: error: {exc}", file=sys.stderr)
        return 2 if exc.code == "usage" else 1


def register():
    if hasattr(bpy.utils, "register_cli_command"):
        _registered.append(bpy.utils.register_cli_command(COMMAND, main))


def unregister():
    while _registered:
        bpy.utils.unregister_cli_command(_registered.pop())
