"""``shapespace export`` (bake + glTF/FBX/Alembic) and ``shapespace merge-reports`` (farm batches).

    blender -b shot.blend --command shapespace export --format gltf|fbx|abc --out FILE \\
        [--objects NAME …] [--frame-range A B] [--report FILE]
    blender -b --command shapespace merge-reports --reports-dir DIR --out merged.json --takes TAKE …

Exit codes: the one rule of every subcommand (:mod:`cli`): 0 done (with or without notes); 1 bad input or a
failed export (one ``shapespace: error:`` line on stderr) — for ``merge-reports``: a take failed or did not
converge (the merged report is written all the same); 2 usage.
"""
from __future__ import annotations

import json
import os
import sys

import bpy

from ..core.errors import ErrorCode
from ..core.export.formats import FORMATS, check_format, format_of
from ..core.result import ShapeSpaceError, exit_code
from .outputs import check_outputs

EXPORT_HELP = "bake drivers and pose-space correctives, then write glTF, FBX or Alembic with Blender's exporter"
MERGE_HELP = "merge the per-take reports of a farm batch into one (exit 1 if any take failed or did not converge)"


def add_parsers(sub) -> None:
    """Add the ``export`` and ``merge-reports`` sub-commands to the ``shapespace`` parser."""
    ex = sub.add_parser("export", help=EXPORT_HELP)
    ex.add_argument("--format", choices=tuple(FORMATS), help="default: from the --out extension")
    ex.add_argument("--out", required=True, help="output file: .glb/.gltf, .fbx or .abc")
    ex.add_argument("--objects", nargs="+", metavar="NAME",
                    help="objects to export (default: the selection, else every mesh and armature)")
    ex.add_argument("--frame-range", nargs=2, type=int, metavar=("A", "B"),
                    help="frames to bake (default: the full range of the exported objects' actions)")
    ex.add_argument("--report", help="write the JSON report here instead of stdout")
    mr = sub.add_parser("merge-reports", help=MERGE_HELP)
    mr.add_argument("--takes", nargs="+", required=True, help="the batch's takes, as given to the job")
    mr.add_argument("--reports-dir", required=True, help="where the per-take tasks wrote <take>.json")
    mr.add_argument("--out", required=True, help="the merged JSON report")


def cmd_export(args, inputs: list) -> tuple:
    """``export``: returns (exit code, the JSON report for stdout or None when written to --report)."""
    from ..bridge import export
    fmt = check_format(args.format) if args.format else format_of(args.out)
    if args.format and format_of(args.out).name != fmt.name:
        raise ShapeSpaceError(f"--format {fmt.name} does not match --out {args.out}", ErrorCode.FORMAT)
    read = [p for p in (bpy.data.filepath, *inputs) if p]
    _, report = check_outputs([("--out", args.out, "export"), ("--report", args.report, "json")], read)
    rep = export.export(fmt.name, args.out, names=args.objects, frame_range=args.frame_range, whole_scene=True)
    what = f"frames {rep.frame_start}–{rep.frame_end}" if rep.animated else f"frame {rep.frame_start} (a still)"
    print(f"shapespace: exported {', '.join(rep.objects)}, {what}, to {rep.path}", file=sys.stderr)
    return exit_code(rep), _emit({**rep.to_json(), "frames": rep.frames}, report)


def cmd_merge_reports(args, inputs: list) -> tuple:
    """``merge-reports``: exit 0 when every take succeeded, 1 otherwise (the merged report is written anyway)."""
    from ..core.export.farm import merge_take_reports, take_outputs
    if not os.path.isdir(args.reports_dir):
        raise ShapeSpaceError(f"--reports-dir {args.reports_dir}: no such folder (no take's report can be read)",
                              ErrorCode.MISSING_FILE)
    read = [*inputs, *take_outputs(args.takes, args.reports_dir), *(t for t in args.takes if os.path.isfile(t))]
    (out,) = check_outputs([("--out", args.out, "json")], read)
    summary = merge_take_reports(args.takes, args.reports_dir)
    _emit({**summary.to_json(), "ok": summary.ok}, out)
    for failure in summary.failed:
        print(f"shapespace: error: {failure['take']}: {failure['error']}", file=sys.stderr)
    for res in summary.unconverged:
        print(f"shapespace: error: {res['take']}: {res.get('source', '')}: the fit stopped before converging",
              file=sys.stderr)
    print(f"shapespace: {len(summary.succeeded)} of {summary.takes} takes retargeted; report {args.out}",
          file=sys.stderr)
    return exit_code(summary), None


def _emit(payload: dict, out=None):
    """The JSON text for stdout, or None after writing it to the checked output ``out`` (no half-file)."""
    text = json.dumps(payload, indent=2)
    if out is None:
        return text
    out.stage_text(text + "\n")
    try:
        out.commit()
    finally:
        out.discard()
    return None


COMMANDS = {"export": cmd_export, "merge-reports": cmd_merge_reports}
