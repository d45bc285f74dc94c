"""``blender --command shapespace …``: ShapeSpace on the command line.

The handler is registered with ``bpy.utils.register_cli_command`` when the
extension is enabled; ``tools/run_cli.py`` calls the same :func:`main` with
the ``bpy`` module.  Output goes to stdout as JSON; errors are one line on
stderr and a non-zero exit code.
"""
from __future__ import annotations

import argparse
import json
import os
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
    rt = sub.add_parser("retarget", help="retarget capture files or actions onto a shape-key rig, one action each")
    rt.add_argument("--source", action="append", required=True,
                    help="Live Link Face CSV, action name, or an animated mesh object (repeat for a batch)")
    rt.add_argument("--object", help="target mesh (default: the only mesh with shape keys)")
    rt.add_argument("--method", choices=("copy", "learned", "perframe", "spacetime"), default="spacetime")
    rt.add_argument("--key-poses", help="learned method: the action keying the target at its key poses")
    rt.add_argument("--lam", type=float, default=1e-7,
                    help="space-time regulariser λ, relative to the data (small: the motion is kept)")
    rt.add_argument("--key-tolerance", type=float, default=0.0,
                    help="reduce keys to this max slider error (0 keeps every frame)")
    rt.add_argument("--key-shape", choices=("BEZIER", "LINEAR"), default="BEZIER",
                    help="reduced keys: smooth Bezier (fewest keys) or linear")
    rt.add_argument("--target", help="target .blend to open first (default: the open file)")
    rt.add_argument("--out", help="save the result as this .blend")
    rt.add_argument("--report", help="write a JSON report here")
    return parser


def _cmd_info(args) -> int:
    from ..bridge import assets, inventory
    reports = []
    if args.files:
        for path in args.files:
            assets.load(path)
            rep = inventory.describe_file()
            rep.file = path
            reports.append(rep)
    else:
        reports.append(inventory.describe_file())
    for rep in reports:
        rep.require_rigs()
    payload = reports[0].to_json() if len(reports) == 1 else [rep.to_json() for rep in reports]
    text = json.dumps(payload, indent=2)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(text + "\n")
    else:
        print(text)
    return 0


def _target_object(name):
    meshes = [ob for ob in bpy.data.objects if ob.type == "MESH" and ob.data.shape_keys is not None
              and len(ob.data.shape_keys.key_blocks) > 1]
    if name:
        ob = bpy.data.objects.get(name)
        if ob is None or ob not in meshes:
            raise ShapeSpaceError(f"no mesh with shape keys named {name!r}", "missing_object")
        return ob
    if len(meshes) != 1:
        raise ShapeSpaceError(f"{len(meshes)} meshes have shape keys; choose one with --object", "ambiguous_object")
    return meshes[0]


def _cmd_retarget(args) -> int:
    from ..bridge import assets, retarget
    if args.target:
        assets.load(args.target)
    obj = _target_object(args.object)
    results, failed = [], 0
    for k, src in enumerate(args.source, start=1):
        print(f"shapespace: [{k}/{len(args.source)}] {src} → {obj.name} ({args.method})", file=sys.stderr)
        try:
            name = f"{obj.name}_{os.path.splitext(os.path.basename(src))[0]}"
            source_obj = bpy.data.objects.get(src)
            if source_obj is not None and source_obj.type == "MESH":   # a mesh performance
                rep = retarget.retarget_dense(obj, source_obj, args.method, lam=args.lam,
                                              key_tolerance=args.key_tolerance, action_name=name,
                                              key_shape=args.key_shape)
            else:
                rep = retarget.retarget(obj, src, args.method, lam=args.lam, key_tolerance=args.key_tolerance,
                                        action_name=name, key_shape=args.key_shape, key_pose_action=args.key_poses)
            rep = {**rep.to_json(), "ok": True}
        except ShapeSpaceError as exc:
            print(f"shapespace: error: {src}: {exc}", file=sys.stderr)
            rep = {"source": src, "ok": False, "error": str(exc)}
            failed += 1
        results.append(rep)
    if args.out:
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(args.out), check_existing=False)
    payload = {"target": obj.name, "method": args.method, "results": results}
    if args.report:
        with open(args.report, "w", encoding="utf-8") as fh:
            json.dump(payload, fh, indent=2)
    else:
        print(json.dumps(payload, indent=2))
    return 1 if failed else 0


COMMANDS = {"info": _cmd_info, "retarget": _cmd_retarget}


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
