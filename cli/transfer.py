"""``shapespace transfer``: give a head a source rig's shape keys by model transfer (thesis 3.4.1).

    blender -b target.blend --command shapespace transfer --source-rig template.blend:Object --object Head \\
        --out rigged.blend [--naming source|arkit|suffix|pascal] [--existing refuse|skip|overwrite]
        [--landmarks auto|stored|shapes|geometry|named|FILE.json] [--unmatched-parts move|keep|refuse]
        [--parts-collection COLLECTION] [--examples stored|none|FILE.json] [--report FILE] [--dry-run]

The source rig is appended from its .blend, used, and removed again: the saved file holds the target with its
new keys only (plus the landmark pairs used, stored on the target for the next run).  stdout carries only the
JSON report; progress goes to stderr.  Exit codes (:func:`core.result.exit_code`, one rule for every subcommand):
0 done; 1 bad input, a registration that stopped at its iteration limit or a key that failed its checks (the
result is saved all the same and the report says so); 2 usage.
"""
from __future__ import annotations

import json
import os
import sys

import bpy

from ..core.authoring.named import load_landmark_file
from ..core.errors import ErrorCode
from ..core.result import ShapeSpaceError, exit_code
from .outputs import check_outputs, same_file

HELP = "give a head a source rig's shape keys by model transfer (landmarks, registration, deformation transfer)"
EPILOG = """\
--source-rig FILE.blend:OBJECT appends OBJECT from FILE.blend for the transfer and removes it again (the saved
file holds only the target's new keys); a bare OBJECT names a mesh of the opened file.
Landmarks: 'auto' (default) uses the pairs stored on the target when it has at least 5 for this source,
else proposes them (from shared shapes, else from the heads' geometry) and stores them on the target.
--landmarks FILE.json: named landmarks of both heads, {"version": 1, "source": {"eye_inner_L": 123, ...},
"target": {"eye_inner_L": 456, ...}} (vertex indices; names: eye_inner/eye_outer/lid_upper/lid_lower/brow_inner/
brow_mid/brow_outer/mouth_corner/nostril/jaw_angle + _L/_R, lip_upper_outer, lip_lower_outer, lip_upper_inner,
lip_lower_inner, nose_tip, chin); the names on both sides are used (at least 5).
--examples: target shape keys that show how some source shapes should look on this head; every transferred key
is refined so they are reproduced, and they are kept as they are.  'stored' (default) uses the list of the panel
(Transfer Shapes > Examples), 'none' ignores it; FILE.json: {"version": 1, "examples": [{"key": "jawOpen"},
{"key": "SmileScan", "weights": {"mouthSmileLeft": 1, "mouthSmileRight": 1}}]} (a key named after a source shape
needs no weights: that shape at 1).
Existing keys of the same names are refused unless --existing skip|overwrite says otherwise.
Saving: --out never overwrites an input (the opened .blend, the source .blend); --overwrite allows saving into
the opened .blend (Blender keeps the old one as .blend1) or replacing a file of another kind."""


def add_parser(sub) -> None:
    import argparse
    tr = sub.add_parser("transfer", help=HELP, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    tr.add_argument("--source-rig", required=True, metavar="FILE.blend:OBJECT",
                    help="the rig whose shape keys are transferred (an object of another .blend, or of this one)")
    tr.add_argument("--object", help="target mesh (default: the only mesh of the file without the source)")
    tr.add_argument("--naming", choices=("source", "arkit", "suffix", "pascal"), default="source",
                    help="naming convention of the new keys (default: the source's names)")
    tr.add_argument("--existing", choices=("refuse", "skip", "overwrite"), default="refuse",
                    help="target keys that already have a new name: refuse (default), keep them, or replace them")
    tr.add_argument("--landmarks", type=_landmark_choice, default="auto",
                    metavar="auto|stored|shapes|geometry|named|FILE.json",
                    help="landmark pairs: stored on the target, proposed from shared shapes or geometry, auto, the "
                         "named landmarks proposed (unsure ones left out), or a file of named source and target "
                         "vertices")
    tr.add_argument("--unmatched-parts", choices=("move", "keep", "refuse"), default="move",
                    help="target parts the source does not move (eyes, teeth, lashes): move them as rigged "
                         "(default), keep them still, or refuse")
    tr.add_argument("--parts-collection", metavar="COLLECTION",
                    help="meshes of this collection (eyes, teeth as objects of their own) are transferred with the "
                         "target as its parts and get shape keys of the same names")
    tr.add_argument("--examples", type=_example_choice, default="stored", metavar="stored|none|FILE.json",
                    help="target shape keys given as examples of the source's shapes: the panel's list (default), "
                         "none, or a file")
    tr.add_argument("--target", help="target .blend to open first (default: the open file)")
    tr.add_argument("--out", help="save the result as this .blend")
    tr.add_argument("--dry-run", action="store_true", help="compute and report only; save nothing")
    tr.add_argument("--report", help="write the JSON report here instead of stdout")
    tr.add_argument("--overwrite", action="store_true",
                    help="allow --out onto the opened .blend, and replacing a file of another kind")


def _landmark_choice(value: str) -> str:
    import argparse
    if value in ("auto", "stored", "shapes", "geometry", "named") or value.lower().endswith(".json"):
        return value
    raise argparse.ArgumentTypeError(f"{value!r}: auto, stored, shapes, geometry, named or a FILE.json of named "
                                     f"landmarks")


def _example_choice(value: str) -> str:
    import argparse
    if value in ("stored", "none") or value.lower().endswith(".json"):
        return value
    raise argparse.ArgumentTypeError(f"{value!r}: stored, none or a FILE.json of examples")


def _examples(bridge, target, how: str) -> list:
    """The examples' ``[(key, weights or None)]``: the panel's list, none, or a file."""
    if how == "none":
        return []
    specs = bridge.stored_examples(target) if how == "stored" else bridge.load_example_file(how)
    if specs:
        _say(f"{len(specs)} examples ({'the panel' if how == 'stored' else how}): "
             f"{', '.join(key for key, _ in specs[:6])}{' …' if len(specs) > 6 else ''}")
    return specs


def _say(text: str) -> None:
    print(f"shapespace: {text}", file=sys.stderr, flush=True)


#: Files that are never a source rig (takes, exports, reports): ``take.csv:FBHead`` is a mistake, not an object name.
_OTHER_FILES = (".csv", ".json", ".fbx", ".glb", ".gltf", ".bvh", ".abc", ".obj", ".usd", ".usda", ".usdc",
                ".blend1", ".txt", ".pc2")


def _split_source(spec: str) -> tuple:
    """``FILE.blend:OBJECT`` → (file, object); a bare ``OBJECT`` → ("", object)."""
    low = spec.lower()
    cut = low.rfind(".blend:")
    if cut >= 0:
        path, name = spec[:cut + len(".blend")], spec[cut + len(".blend:"):]
        if not name:
            raise ShapeSpaceError(f"--source-rig {spec}: name the object after the colon (FILE.blend:OBJECT)",
                                  ErrorCode.USAGE)
        return path, name
    if low.endswith(".blend"):
        raise ShapeSpaceError(f"--source-rig {spec}: name the rig object too (FILE.blend:OBJECT)", ErrorCode.USAGE)
    path = spec.rpartition(":")[0]
    if path and (os.path.isfile(path) or os.path.splitext(path)[1].lower() in _OTHER_FILES):
        raise ShapeSpaceError(f"--source-rig {spec}: {path} is not a rig file; give the .blend holding the rig "
                              f"(FILE.blend:OBJECT)", ErrorCode.USAGE)
    return "", spec


def _target(name, exclude):
    meshes = [ob for ob in bpy.data.objects if ob.type == "MESH" and ob not in exclude
              and ob.get("shapespace_registration_preview") is None]
    if name:
        ob = bpy.data.objects.get(name)
        if ob is None or ob.type != "MESH":
            raise ShapeSpaceError(f"no mesh named {name!r} to transfer onto", ErrorCode.MISSING_OBJECT)
        return ob
    if not meshes and exclude:
        only = ", ".join(repr(ob.name) for ob in exclude)
        raise ShapeSpaceError(f"no mesh to transfer onto: the only mesh is the source rig {only}; open the target's "
                              f".blend (or --target) or add the target mesh", ErrorCode.MISSING_OBJECT)
    if len(meshes) != 1:
        shown = ", ".join(ob.name for ob in meshes[:6]) + (" …" if len(meshes) > 6 else "")
        raise ShapeSpaceError(f"{len(meshes)} meshes ({shown or 'none'}): choose the target with --object",
                              ErrorCode.AMBIGUOUS_OBJECT)
    return meshes[0]


def _parts(target, name) -> list:
    """The part objects of ``--parts-collection`` (refused by name when the collection does not exist)."""
    from ..bridge import part_objects
    if name is None:
        return []
    coll = bpy.data.collections.get(name)
    if coll is None:
        have = ", ".join(sorted(c.name for c in bpy.data.collections)) or "none"
        raise ShapeSpaceError(f"--parts-collection: no collection named {name!r} in this file (it has: {have})",
                              ErrorCode.MISSING_OBJECT)
    return part_objects.meshes_of(coll, target)


def _landmark_file(bridge, source, target, path: str) -> str:
    """Named landmarks from a file (validated against both meshes' vertex counts) stored as the target's pairs."""
    if not os.path.isfile(path):
        raise ShapeSpaceError(f"--landmarks {path}: file not found", ErrorCode.MISSING_FILE)
    src, dst, ignored = load_landmark_file(path, len(source.data.vertices), len(target.data.vertices))
    if ignored:
        _say(f"warning: landmarks named on one side only (not used): {', '.join(ignored)}")
    bridge.set_landmarks(target, source, list(src.values()), list(dst.values()))
    _say(f"{len(src)} named landmark pairs from {path}")
    return "file"


def _landmarks(bridge, source, target, how: str) -> str:
    if how.lower().endswith(".json"):
        return _landmark_file(bridge, source, target, how)
    if how == "stored":
        return "stored"                      # the transfer refuses fewer than 5, stale or damaged pairs
    if how == "auto" and bridge.landmark_count(target)[0] >= bridge.MIN_LANDMARKS:
        try:
            bridge.landmark_pairs(target, source)
            return "stored"
        except ShapeSpaceError as exc:       # stale: propose new ones (said on stderr)
            _say(f"stored landmarks not used: {exc}")
    result = bridge.propose_landmarks(source, target, "auto" if how == "auto" else how)
    if result.message and result.status != 0:
        _say(f"warning: landmarks: {result.message}")
    _say(f"{result.value} landmark pairs proposed ({how})")
    return "proposed"


def transfer(args, inputs: list) -> tuple:
    """``transfer``: returns (exit code, JSON text for stdout or None)."""
    from ..bridge import assets
    from ..bridge import authoring as bridge
    if bool(args.out) == bool(args.dry_run):
        raise ShapeSpaceError("transfer: give --out FILE.blend to save the result, or --dry-run to only report it"
                              if not args.out else "transfer: --out and --dry-run exclude each other", ErrorCode.USAGE)
    src_file, src_name = _split_source(args.source_rig)
    opened = args.target or bpy.data.filepath or (inputs[0] if inputs else "")
    lm_file = args.landmarks if args.landmarks.lower().endswith(".json") else ""
    ex_file = args.examples if args.examples.lower().endswith(".json") else ""
    read = [p for p in (bpy.data.filepath, args.target, *inputs, src_file, lm_file, ex_file) if p]
    out, report_out = check_outputs([("--out", args.out, "blend"), ("--report", args.report, "json")], read,
                                    args.overwrite, opened)
    if src_file and not os.path.isfile(src_file):
        raise ShapeSpaceError(f"--source-rig: file not found: {src_file}", ErrorCode.MISSING_FILE)
    if args.target:
        assets.load(args.target)
    if src_file and bpy.data.filepath and same_file(src_file, bpy.data.filepath):
        src_file = ""                            # the rig is in the opened file itself: nothing to append
    appended = []
    try:
        if src_file:
            source, appended = bridge.append_object(src_file, src_name)
        else:
            source = bpy.data.objects.get(src_name)
            if source is None:
                raise ShapeSpaceError(f"--source-rig: no object named {src_name!r} in {opened or 'the open file'}",
                                      ErrorCode.MISSING_OBJECT)
        target = _target(args.object, {source})
        if target == source:
            raise ShapeSpaceError("--source-rig and --object name the same mesh", ErrorCode.SAME_KEY)
        _say(f"transfer {source.name} → {target.name}")
        parts = _parts(target, args.parts_collection)
        examples = _examples(bridge, target, args.examples)
        landmarks = _landmarks(bridge, source, target, args.landmarks)
        step = {"last": -1}

        def progress(fraction: float) -> None:
            tenth = int(fraction * 10)
            if tenth > step["last"]:
                step["last"] = tenth
                _say(f"{tenth * 10}%")

        rep = bridge.transfer_shapes(source, target, naming=args.naming, existing=args.existing,
                                     unmatched_parts=args.unmatched_parts, progress=progress, parts=parts,
                                     examples=examples)
    finally:
        bridge.remove_appended(appended)
    for warning in rep.warnings:
        _say(f"warning: {warning}")
    _say(f"{len(rep.created)} shape keys onto {target.name} in {rep.seconds:.1f} s "
         f"(registration residual {rep.registration_residual_mm:.2f} mm)")
    code = exit_code(rep)
    payload = {**rep.to_json(), "source_file": src_file or None, "landmarks_from": landmarks,
               "saved": out.path if out is not None else None, "ok": code == 0}
    text = json.dumps(payload, indent=2)
    if report_out is not None:
        report_out.stage_text(text + "\n")
    try:
        if out is not None:
            _save(out)
        if report_out is not None:
            report_out.commit()
    finally:
        if report_out is not None:
            report_out.discard()
    return code, (text if report_out is None else None)


def _save(out) -> None:
    try:
        bpy.ops.wm.save_as_mainfile(filepath=out.abspath, check_existing=False)
    except RuntimeError as exc:
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip() and not ln.startswith("Location:")]
        raise out.fail(f"cannot be saved ({lines[-1] if lines else exc})") from None
    _say(f"saved {out.path}")


COMMANDS = {"transfer": transfer}
