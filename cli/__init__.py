"""``blender --command shapespace …``: ShapeSpace on the command line.

The handler is registered with ``bpy.utils.register_cli_command`` when the
extension is enabled; ``tools/run_cli.py`` calls the same :func:`main` with
the ``bpy`` module.  stdout carries only the JSON (Blender's and the importers'
log lines go to stderr while a command runs); errors are one
``shapespace: error: …`` line on stderr.

Exit rule — the same for every subcommand (:data:`EXIT_RULE`, printed by ``--help``;
each command returns :func:`core.result.exit_code` of the reports it made)::

    0  done: every report OK or WARNING
    1  any report FAILED or NOT_CONVERGED, or a refused quality check (an error
       issue); bad input or a failed write (one ``shapespace: error:`` line)
    2  usage: bad or missing arguments (before any work)

- :mod:`.commands` — ``info`` and ``retarget``;
- :mod:`.export` — ``export`` and ``merge-reports``;
- :mod:`.transfer` — ``transfer``;
- :mod:`.outputs` — output checks (before any work) and safe writing.
"""
from __future__ import annotations

import argparse
import math
import os
import sys

import bpy

from ..core.result import ShapeSpaceError
from ..core.version import version

COMMAND = "shapespace"

_registered = []  # the handle returned by register_cli_command, for unregister

EXIT_RULE = """\
Exit code (every subcommand): 0 done (every report ok or with warnings); 1 any report failed or did not
converge, a refused quality check, bad input or a failed write (one "shapespace: error:" line on stderr);
2 usage (bad or missing arguments)."""

RETARGET_EPILOG = """\
Saving: every retargeted action gets a fake user, so a batch keeps all of them in --out; an action a
result displaces from the rig gets one too. retarget needs --out (the .blend to save) or --dry-run (compute
and report only, nothing saved).
Safety: outputs are checked before any work. --out/--report never overwrite an input (the opened or --target
.blend, a --source file) and replace an existing file only if it is of the same kind (a .blend, a JSON
report); --overwrite allows replacing a file of another kind and saving into the opened .blend (Blender keeps
the old one as .blend1). A source that fails is reported (one line) and the batch goes on; exit code 1.
Exit code: 0 when every source is retargeted (status "ok" or "warning"), 1 when any failed or its space-time
fit did not converge (status "not_converged": the result is written, its last iterate), 2 for bad arguments.
Scene range: the scene's frame range is widened to include every frame a result keys (saved with --out), so
playback and exporters see the whole take; --keep-scene-range leaves it as it is. Each report gives the
frame_range written and the clipped_frames (scene frames where the source leaves the slider ranges) as
[first, last] runs.
Rig controls (--controls): each source's weights are played on the --object mesh's own shape keys (ARKit
names, mapped as for the sliders) and the rig's channels are solved to reproduce that surface — frame by frame
(--method perframe, the default), then over the whole take with the space-time smoothing (spacetime, --lam as
for the sliders), or through a cloning matrix of the source's expressions refined per frame (cloning) — then
keyed (only the channels that move) in new actions on their owners (armature/object, the mesh's Key);
each result is the take's report (method, rms, pin_error_max in scene units, keyed_channels, actions). A malformed
SPEC is a usage error (exit 2); a SPEC naming an object, bone, property or key the file lacks is refused by
name before any work (exit 1). Not with --key-poses, --head-bone/--neck-bone/--eye-bones or --key-shape
LINEAR; the scene's frame range is left as it is.
stdout carries only the JSON (without --report); progress and log lines go to stderr."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise ShapeSpaceError(f"{self.prog}: {message}", "usage")


def _number(positive: bool):
    """An argparse type: a finite float, > 0 (``positive``) or ≥ 0."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
        if not math.isfinite(value) or value < 0 or (positive and value == 0):
            raise argparse.ArgumentTypeError(f"must be a {'positive' if positive else 'non-negative'} finite "
                                             f"number, got {text!r}")
        return value
    return parse


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=f"blender --command {COMMAND}",
                     description="ShapeSpace example-based deformation tools.", epilog=EXIT_RULE,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"ShapeSpace {version()}",
                        help="print ShapeSpace's version (from its blender_manifest.toml) and exit")
    sub = parser.add_subparsers(dest="command", required=True)
    info = sub.add_parser("info", help="list the rigs (shape-key meshes, armatures, skins, actions) as JSON; "
                          "describe capture recordings")
    info.add_argument("files", nargs="*", help=".blend/.glb/.gltf/.fbx/.bvh files, or capture recordings "
                      "(.csv/.txt/.json: kind, channels, rate, duration, head/eye channels); default: the open file")
    info.add_argument("--out", help="write the JSON here instead of stdout (never onto an input)")
    info.add_argument("--overwrite", action="store_true", help="replace an existing --out that is not JSON")
    rt = sub.add_parser("retarget", help="retarget capture files or actions onto a shape-key rig, one action each",
                        epilog=RETARGET_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    rt.add_argument("--source", action="append", required=True,
                    help="capture recording (Live Link Face CSV, Face Cap TXT, iFacialMocap, Audio2Face JSON, "
                    "MediaPipe JSON/CSV), action name, or an animated mesh object (repeat for a batch)")
    rt.add_argument("--object", help="target mesh (default: the only mesh with shape keys)")
    rt.add_argument("--method", choices=("copy", "learned", "perframe", "spacetime", "cloning"),
                    help="copy, learned, perframe or spacetime (default: spacetime); with --controls perframe "
                         "(default), spacetime or cloning")
    rt.add_argument("--controls", nargs="+", metavar="SPEC",
                    help="retarget onto these rig channels instead of the sliders (any face rig: bones, custom "
                    "properties, sliders; per-frame, through the --object mesh's own ARKit shape keys): "
                    "ARMATURE:BONE:rotation[:AXES], ARMATURE:BONE:location[:AXES], ARMATURE:BONE:scale[:AXES], "
                    "OBJECT:[\"prop\"], ARMATURE:BONE:[\"prop\"], key:NAME (AXES: e.g. xz; default every "
                    "unlocked axis), or `stored` alone: the control set stored on the --object mesh (Rig ▸ "
                    "Controls); capture recordings and shape-key actions only")
    rt.add_argument("--key-poses", help="learned method: the action keying the target at its key poses")
    rt.add_argument("--lam", type=_number(positive=True), default=1e-7,
                    help="space-time regulariser λ > 0, relative to the data (small: the motion is kept)")
    rt.add_argument("--key-tolerance", type=_number(positive=False), default=0.0,
                    help="reduce keys to this max slider error ≥ 0 (0 keeps every frame; with --controls: max "
                    "surface error, in scene units)")
    rt.add_argument("--key-shape", choices=("BEZIER", "LINEAR"), default="BEZIER",
                    help="reduced keys: smooth Bezier (fewest keys) or linear")
    rt.add_argument("--head-bone", help="bone keyed from the recording's head rotation (HeadYaw/Pitch/Roll); "
                    "without --head-bone, --neck-bone or --eye-bones: the bones stored on the --object mesh "
                    "(Retarget panel ▸ Head & Eyes), if any")
    rt.add_argument("--neck-bone", help="bone taking --neck-share of the head rotation (the head bone the rest)")
    rt.add_argument("--neck-share", type=_number(positive=False), default=0.3,
                    help="the neck bone's share of the head rotation, 0…1 (as live capture)")
    rt.add_argument("--eye-bones", nargs=2, metavar=("LEFT", "RIGHT"), help="the character's left and right eye bones")
    rt.add_argument("--armature", help="the armature of those bones (default: the only armature in the file)")
    rt.add_argument("--calibrate-frame", type=_number(positive=False), metavar="FRAME",
                    help="scene frame whose head and eye pose becomes the rest pose (as live capture's Calibrate)")
    rt.add_argument("--mirror", action="store_true",
                    help="swap left and right head / eye channels (a mirrored, selfie-view capture)")
    rt.add_argument("--target", help="target .blend to open first (default: the open file)")
    rt.add_argument("--out", help="save the result as this .blend (every result action is kept: fake user)")
    rt.add_argument("--dry-run", action="store_true", help="compute and report only; save nothing (instead of --out)")
    rt.add_argument("--report", help="write the JSON report here instead of stdout")
    rt.add_argument("--keep-scene-range", action="store_true",
                    help="leave the scene's frame range as it is (default: widen it to every frame written)")
    rt.add_argument("--overwrite", action="store_true",
                    help="allow --out onto the opened .blend, and replacing a file of another kind")
    from .export import add_parsers
    add_parsers(sub)
    from .transfer import add_parser as add_transfer_parser
    add_transfer_parser(sub)
    return parser


def main(argv, inputs=()) -> int:
    """Run one ShapeSpace command; return the process exit code.

    ``inputs``: files already opened for the command (``tools/run_cli.py FILE``), never written.
    """
    from ..bridge.assets import redirected_fd
    from .commands import COMMANDS as BASE_COMMANDS
    from .export import COMMANDS as EXPORT_COMMANDS
    from .transfer import COMMANDS as TRANSFER_COMMANDS
    COMMANDS = {**BASE_COMMANDS, **EXPORT_COMMANDS, **TRANSFER_COMMANDS}
    try:
        args = build_parser().parse_args(list(argv))
    except ShapeSpaceError as exc:
        print(f"shapespace: error: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:       # --help
        return exc.code if isinstance(exc.code, int) else 0
    try:
        with redirected_fd(1, 2):  # Blender's and the importers' log lines: stderr; the JSON is printed after
            code, text = COMMANDS[args.command](args, [p for p in inputs if p])
    except ShapeSpaceError as exc:
        print(f"shapespace: error: {exc}", file=sys.stderr)
        return 2 if exc.code == "usage" else 1
    except Exception as exc:
        if os.environ.get("SHAPESPACE_TRACEBACK"):
            raise
        last = (str(exc).strip().splitlines() or [""])[-1]
        print(f"shapespace: error: unexpected {type(exc).__name__}: {last} (SHAPESPACE_TRACEBACK=1 shows where)",
              file=sys.stderr)
        return 1
    if text is not None:
        print(text, flush=True)
    return code


def register():
    if hasattr(bpy.utils, "register_cli_command"):
        _registered.append(bpy.utils.register_cli_command(COMMAND, main))


def unregister():
    while _registered:
        bpy.utils.unregister_cli_command(_registered.pop())
