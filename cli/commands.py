"""The command-line commands: ``info`` and ``retarget``.

Each takes the parsed arguments and the files already opened for it (``tools/run_cli.py FILE``), checks
every output before any work (:mod:`.outputs`), and returns ``(exit code, JSON text for stdout or None)``,
the exit code by the one rule of :mod:`core.result` (``exit_code`` of its reports).
"""
from __future__ import annotations

import json
import os
import sys
import time

import bpy

from ..core.errors import ErrorCode
from ..core.inventory import CaptureInfo, FileInventory
from ..core.result import ShapeSpaceError, Status, exit_code
from .outputs import check_outputs

__all__ = ["info", "retarget", "COMMANDS"]


def _say(text: str) -> None:
    print(f"shapespace: {text}", file=sys.stderr, flush=True)


def _capture_info(path: str) -> CaptureInfo:
    """A capture recording described: kind, channels, rate, duration, head / eye channels present."""
    from ..core.retarget import describe_stream, read_capture
    return CaptureInfo.of(path, describe_stream(read_capture(path)))


def info(args, inputs: list) -> tuple:
    """``info``: describe the rigs of the open file or of each file given (capture recordings: their take)."""
    from ..bridge import assets, inventory
    from ..bridge.retarget import CAPTURE_EXTENSIONS
    (out,) = check_outputs([("--out", args.out, "json")], [*args.files, *inputs, bpy.data.filepath], args.overwrite)
    reports = []
    if args.files:
        for path in args.files:
            if path.lower().endswith(CAPTURE_EXTENSIONS):
                reports.append(_capture_info(path))
                continue
            assets.load(path)
            rep = inventory.describe_file()
            rep.file = path
            reports.append(rep)
    else:
        reports.append(inventory.describe_file())
    for rep in reports:
        if isinstance(rep, FileInventory):
            rep.require_rigs()
    payload = [rep.to_json() for rep in reports]
    payload = payload[0] if len(payload) == 1 else payload
    text = json.dumps(payload, indent=2)
    if out is None:
        return exit_code(reports), text
    out.stage_text(text + "\n")
    out.commit()
    return exit_code(reports), None


def _target_object(name, where: str):
    meshes = [ob for ob in bpy.data.objects if ob.type == "MESH" and ob.data.shape_keys is not None
              and len(ob.data.shape_keys.key_blocks) > 1]
    if name:
        ob = bpy.data.objects.get(name)
        if ob is None or ob not in meshes:
            raise ShapeSpaceError(f"no mesh with shape keys named {name!r}", ErrorCode.MISSING_OBJECT)
        return ob
    if not meshes:
        raise ShapeSpaceError(f"no mesh with shape keys in {where or 'the open file'}: nothing to retarget onto",
                              ErrorCode.NO_SHAPE_KEYS)
    if len(meshes) > 1:
        names = ", ".join(ob.name for ob in meshes[:6]) + (" …" if len(meshes) > 6 else "")
        raise ShapeSpaceError(f"{len(meshes)} meshes have shape keys ({names}); choose one with --object",
                              ErrorCode.AMBIGUOUS_OBJECT)
    return meshes[0]


def _one_source(obj, src: str, args, bones=None) -> tuple:
    """Retarget one source: ``(its report, JSON)`` — the report's JSON with ``ok`` true, or, when it failed, a
    ``FAILED`` report and its one-line error (``ok`` false)."""
    from ..bridge import retarget as bridge
    from ..core.retarget import RetargetReport

    def work():
        name = f"{obj.name}_{os.path.splitext(os.path.basename(src))[0]}"
        source_obj = bpy.data.objects.get(src)
        settings = dict(lam=args.lam, key_tolerance=args.key_tolerance, action_name=name, key_shape=args.key_shape,
                        extend_scene_range=not args.keep_scene_range, progress=_ProgressLines(src))
        if source_obj is not None and source_obj.type == "MESH":   # a mesh performance
            rep = bridge.retarget_dense(obj, source_obj, args.method, **settings)
        else:
            rep = bridge.retarget(obj, src, args.method, key_pose_action=args.key_poses, bones=bones, **settings)
        if rep.status == Status.NOT_CONVERGED:
            _say(f"warning: {src}: the space-time solver did not converge ({rep.solver_message}); "
                 "the result is its last iterate")
        return rep

    return _batch_item(src, work, RetargetReport(source=src, method=args.method, status=Status.FAILED),
                       "not enough memory for this source (split the take, or use --method copy)")


def _one_rig_source(obj, controls, src: str, args) -> tuple:
    """Retarget one source onto the rig ``controls`` (``--controls``): ``(its report, JSON)`` as
    :func:`_one_source` (a ``FAILED`` report and its one-line error when it failed; the batch goes on)."""
    from ..bridge import rig as brig
    from ..core.rig import RigTakeReport

    def work():
        source_obj = bpy.data.objects.get(src)
        if source_obj is not None and source_obj.type == "MESH":
            raise ShapeSpaceError(f"{src!r} is a mesh performance: onto --controls only capture recordings and "
                                  "shape-key actions are retargeted", ErrorCode.METHOD)
        name = f"{obj.name}_{os.path.splitext(os.path.basename(src))[0]}"
        return brig.retarget_capture_onto_rig(obj, controls, src, key_tolerance=args.key_tolerance,
                                              action_name=name, method=args.method, lam=args.lam,
                                              progress=_ProgressLines(src))

    return _batch_item(src, work, RigTakeReport(status=Status.FAILED, source=src),
                       "not enough memory for this source (split the take)")


def _batch_item(src: str, work, failed, memory_message: str) -> tuple:
    """Run one source of a batch: ``(report, JSON)`` — ``work()``'s report (its issues said on stderr) and its JSON
    with ``ok`` true, or, when it raised, the ``failed`` report and the one-line error (``ok`` false): one bad
    source never aborts the batch (``SHAPESPACE_TRACEBACK=1`` shows an unexpected error's traceback)."""
    try:
        rep = work()
        for issue in rep.issues:
            _say(f"warning: {src}: {issue.message}")
        return rep, {**rep.to_json(), "ok": True}
    except MemoryError:
        message = memory_message
    except ShapeSpaceError as exc:
        message = str(exc)
    except Exception as exc:
        if os.environ.get("SHAPESPACE_TRACEBACK"):
            raise
        message = f"unexpected {type(exc).__name__}: {(str(exc).strip().splitlines() or [''])[-1]}"
    if not message.startswith(src):
        message = f"{src}: {message}"
    print(f"shapespace: error: {message}", file=sys.stderr, flush=True)
    return failed, {"source": src, "ok": False, "error": message}


#: ``--method`` values with ``--controls`` (None: the default, per frame).
RIG_METHODS = (None, "perframe", "spacetime", "cloning")


def _rig_specs(args) -> list | None:
    """``--controls`` parsed (syntax only, before any work) and the options it excludes refused: usage errors."""
    from .controls import parse_specs
    if not args.controls:
        if args.method == "cloning":
            raise ShapeSpaceError("--method cloning is the rig route's: give the rig's --controls", ErrorCode.USAGE)
        args.method = args.method or "spacetime"
        return None
    if args.method not in RIG_METHODS:
        raise ShapeSpaceError(f"--controls retargets by {', '.join(RIG_METHODS[1:])}: --method {args.method} is not "
                              "available with it", ErrorCode.USAGE)
    excluded = [flag for flag, given in (("--key-poses", args.key_poses), ("--head-bone", args.head_bone),
                                         ("--neck-bone", args.neck_bone), ("--eye-bones", args.eye_bones),
                                         ("--mirror", args.mirror),
                                         ("--calibrate-frame", args.calibrate_frame is not None),
                                         ("--key-shape LINEAR", args.key_shape != "BEZIER"))
                if given]
    if excluded:
        raise ShapeSpaceError(f"{excluded[0]} is not available with --controls", ErrorCode.USAGE)
    args.method = args.method or "perframe"
    return parse_specs(args.controls)


def _head_eye_bones(args, obj):
    """The ``--head-bone/--neck-bone/--eye-bones/--armature/--mirror/--calibrate-frame`` choice; without a bone
    named there, the choice stored on the target mesh (Retarget panel ▸ Head & Eyes); ``None`` when neither
    names a bone."""
    from ..bridge.retarget import HeadEyeBones
    stored = getattr(obj, "shapespace_retarget", None)
    arm = stored.armature if stored is not None and stored.armature is not None and \
        stored.armature.type == "ARMATURE" else None
    if not (args.head_bone or args.neck_bone or args.eye_bones):
        if arm is None or not any((stored.head_bone, stored.neck_bone, stored.eye_left_bone, stored.eye_right_bone)):
            return None
        _say(f"head / neck / eye bones stored on {obj.name!r}: {arm.name} "
             + ", ".join(b for b in (stored.head_bone, stored.neck_bone, stored.eye_left_bone, stored.eye_right_bone)
                         if b))
        rest = args.calibrate_frame if args.calibrate_frame is not None else \
            float(stored.rest_frame) if stored.calibrate else None
        return HeadEyeBones(arm.name, stored.head_bone, stored.neck_bone, stored.eye_left_bone,
                            stored.eye_right_bone, stored.neck_share, stored.mirror or args.mirror, rest)
    eyes = args.eye_bones or ("", "")
    if args.neck_share > 1:
        raise ShapeSpaceError(f"--neck-share must lie in [0, 1], got {args.neck_share:g}", ErrorCode.USAGE)
    arms = [ob.name for ob in bpy.data.objects if ob.type == "ARMATURE"]
    name = args.armature or (arms[0] if len(arms) == 1 else arm.name if arm is not None else "")
    if not name:
        raise ShapeSpaceError(f"{len(arms)} armatures in the file: choose the bones' one with --armature",
                              ErrorCode.NO_ARMATURE if not arms else ErrorCode.AMBIGUOUS_OBJECT)
    return HeadEyeBones(name, args.head_bone or "", args.neck_bone or "", eyes[0], eyes[1], args.neck_share,
                        args.mirror, args.calibrate_frame)


class _ProgressLines:
    """A ``progress(fraction)`` callable that prints ``SOURCE: NN %`` on stderr for a source that takes a while
    (a line per tenth, at most one a second, the first after a second)."""

    def __init__(self, src: str, interval: float = 1.0):
        self.src, self.interval = src, interval
        self.start = self.last = time.perf_counter()
        self.tenth = 0

    def __call__(self, fraction: float) -> None:
        now, tenth = time.perf_counter(), int(10 * fraction)
        if tenth > self.tenth and now - self.last >= self.interval and fraction < 1:
            self.tenth, self.last = tenth, now
            _say(f"{self.src}: {100 * fraction:.0f} % ({now - self.start:.0f} s)")


def _progress_line(src: str, frames, seconds: float) -> str:
    """``SOURCE: F frames in T s (R frames/s)`` after each source of the batch (#11)."""
    if not frames:
        return f"{src}: done in {seconds:.1f} s"
    return f"{src}: {int(frames)} frames in {seconds:.1f} s ({int(frames) / max(seconds, 1e-9):.0f} frames/s)"


def retarget(args, inputs: list) -> tuple:
    """``retarget``: every source onto one rig, each into its own action (kept with a fake user)."""
    from ..bridge import assets
    if bool(args.out) == bool(args.dry_run):
        raise ShapeSpaceError("retarget: give --out FILE.blend to save the results, or --dry-run to only report "
                              "them" if not args.out else "retarget: --out and --dry-run exclude each other",
                              ErrorCode.USAGE)
    specs = _rig_specs(args)
    opened = args.target or bpy.data.filepath or (inputs[0] if inputs else "")
    sources = [s for s in args.source if os.path.isfile(s)]
    read = [p for p in (bpy.data.filepath, args.target, *inputs, *sources) if p]
    out, report = check_outputs([("--out", args.out, "blend"), ("--report", args.report, "json")], read,
                                args.overwrite, opened)
    if args.target:
        assets.load(args.target)
    obj = _target_object(args.object, opened)
    bones = _head_eye_bones(args, obj) if specs is None else None
    controls = None
    if specs is not None:
        from .controls import control_set_of
        controls = control_set_of(specs, obj)
    reports, results = [], []
    for k, src in enumerate(args.source, start=1):
        _say(f"[{k}/{len(args.source)}] {src} → {obj.name} ({args.method})")
        start = time.perf_counter()
        rep, result = (_one_source(obj, src, args, bones) if controls is None
                       else _one_rig_source(obj, controls, src, args))
        reports.append(rep)
        results.append(result)
        if results[-1]["ok"]:
            _say(_progress_line(src, results[-1].get("frames"), time.perf_counter() - start))
    done = sum(r["ok"] for r in results)
    payload = {"target": obj.name, "method": args.method,
               **({"controls": controls.names} if controls is not None else {}), "results": results,
               "saved": out.path if out is not None and done else None}
    text = json.dumps(payload, indent=2)
    if report is not None:
        report.stage_text(text + "\n")
    try:
        if out is not None and done:
            _save(out)
        if report is not None:
            report.commit()
    finally:
        if report is not None:
            report.discard()
    if out is not None and not done:
        _say(f"nothing retargeted: {out.path} not written")
    return exit_code(reports), (text if report is None else None)


def _save(out) -> None:
    """Save the open file as ``out`` (every result action has a fake user, so all of them are kept)."""
    try:
        bpy.ops.wm.save_as_mainfile(filepath=out.abspath, check_existing=False)
    except RuntimeError as exc:
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip() and not ln.startswith("Location:")]
        raise out.fail(f"cannot be saved ({lines[-1] if lines else exc})") from None
    _say(f"saved {out.path}")


COMMANDS = {"info": info, "retarget": retarget}
