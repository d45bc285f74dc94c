"""``shapespace export`` (bake + glTF/FBX/Alembic) and ``shapespace merge-reports`` (farm batches).

    blender -b shot.blend --command shapespace export --format gltf|fbx|abc --out FILE \\
        [--objects NAME …] [--frame-range A B] [--report FILE]
    blender -b --command shapespace merge-reports --reports-dir DIR --out merged.json --takes TAKE …

Exit codes: 0 done; 1 bad input or a failed export (one ``shapespace: error:`` line on stderr) — for
``merge-reports``: at least one take failed (the merged report is written all the same); 2 usage.
"""
from __future__ import annotations

import json
import os
import sys

from ..core.errors import ErrorCode
from ..core.export.formats import FORMATS, check_format, check_output_path, format_of
from ..core.result import ShapeSpaceError

EXPORT_HELP = "bake drivers and pose-space correctives, then write glTF, FBX or Alembic with Blender's exporter"
MERGE_HELP = "merge the per-take reports of a farm batch into one (exit 1 if any take failed)"


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
    check_output_path(args.out, fmt, inputs=tuple(inputs))
    if args.report:
        _check_report(args.report, [*inputs, args.out])
    rep = export.export(fmt.name, args.out, names=args.objects, frame_range=args.frame_range, whole_scene=True)
    what = f"frames {rep.frame_start}–{rep.frame_end}" if rep.animated else f"frame {rep.frame_start} (a still)"
    print(f"shapespace: exported {', '.join(rep.objects)}, {what}, to {rep.path}", file=sys.stderr)
    return 0, _emit({**rep.to_json(), "frames": rep.frames}, args.report)


def cmd_merge_reports(args, inputs: list) -> tuple:
    """``merge-reports``: exit 0 when every take succeeded, 1 otherwise (the merged report is written anyway)."""
    from ..core.export.farm import merge_take_reports
    _check_report(args.out, inputs)
    summary = merge_take_reports(args.takes, args.reports_dir)
    _emit({**summary.to_json(), "ok": summary.ok}, args.out)
    for failure in summary.failed:
        print(f"shapespace: error: {failure['take']}: {failure['error']}", file=sys.stderr)
    print(f"shapespace: {len(summary.succeeded)} of {summary.takes} takes retargeted; report {args.out}",
          file=sys.stderr)
    return (0 if summary.ok else 1), None


def _check_report(path: str, inputs: list) -> None:
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise ShapeSpaceError(f"cannot write {path}: the folder {folder} does not exist", ErrorCode.UNWRITABLE)
    for other in inputs:
        if other and os.path.exists(other) and os.path.exists(path) and os.path.samefile(other, path):
            raise ShapeSpaceError(f"{path} is an input of this command; choose another file", ErrorCode.OVERWRITE)


def _emit(payload: dict, path: str = None):
    """The JSON text for stdout, or None after writing it to ``path``."""
    text = json.dumps(payload, indent=2)
    if not path:
        return text
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text + "\n")
    return None


COMMANDS = {"export": cmd_export, "merge-reports": cmd_merge_reports}
