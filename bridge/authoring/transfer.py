"""Transfer Shapes: a source rig's shape keys written onto the target in one step (thesis 3.4.1).

Three steps: :func:`read_transfer` (main thread: validate and read everything, write nothing),
:func:`core.authoring.job.compute_transfer` (any thread, touches no Blender data — the operator runs it in a
:class:`core.jobs.BackgroundJob`, cancellable) and :func:`write_transfer` (main thread: everything in one step;
on any failure the file is as before).  :func:`transfer_shapes` runs the three.

Deltas are transferred *unmasked*; a source key's vertex-group mask becomes a vertex group of the target
(weights mapped through the correspondence) named on the new key, so Blender applies it exactly as on the
source.  In-betweens and combination shapes are transferred as full sculpts and rebuilt on the target with
:func:`bridge.driven.add_inbetween` / :func:`~bridge.driven.add_combination` (native drivers: they play
back without the add-on).  The last transfer's verdict (the per-key checks) is kept on the target's keys for
the panel (:func:`last_verdict`).
"""
from __future__ import annotations

import time

import bpy
import numpy as np

from ...core import blobs
from ...core.authoring.job import SourceRig, TargetMesh, TransferOutcome, TransferPlan, compute_transfer
from ...core.authoring.report import TransferReport
from ...core.authoring.transfer import convert_name
from ...core.errors import ErrorCode
from ...core.jobs import BackgroundJob
from ...core.result import ShapeSpaceError
from .. import driven, part_objects, storage
from ..arrays import read_float, write_float
from .examples import example_keys, read_examples
from .landmarks import landmarks_for, openings
from .parts import part_kinds, part_owner, show_parts
from .reading import read_source_rig, read_target, target_signature, with_part_objects
from .registration import clear_preview

__all__ = ["NAMINGS", "EXISTING", "LAST_PROP", "LAST_SCHEMA", "TransferReport", "TransferPlan", "TransferOutcome",
           "read_transfer", "compute_transfer", "write_transfer", "start_transfer_job", "finish_transfer_job",
           "transfer_shapes", "last_verdict", "verdict_status"]

NAMINGS = ("source", "arkit", "suffix", "pascal")
EXISTING = ("refuse", "skip", "overwrite")
_TMP = "__shapespace_transfer_tmp"
_WEIGHT_STEP = 1e-4        # mapped mask weights are written rounded to this (one vertex-group call per value)


def _new_names(rig: SourceRig, naming: str) -> dict:
    """Source key name → target key name in the chosen convention (driven keys follow their primaries)."""
    if naming not in NAMINGS:
        raise ShapeSpaceError(f"unknown naming {naming!r}: {', '.join(NAMINGS)}", ErrorCode.METHOD)
    out = {}
    for n in rig.names:
        if n not in rig.inbetweens and n not in rig.combinations:
            out[n] = n if naming == "source" else convert_name(n, naming)
    for n, v in rig.inbetweens.items():
        default = f"{v['primary']}@{v['at']:g}"
        out[n] = f"{out[v['primary']]}@{v['at']:g}" if n == default else (
            n if naming == "source" else convert_name(n, naming))
    for n, v in rig.combinations.items():
        out[n] = "+".join(out[i] for i in v["inputs"]) if n == "+".join(v["inputs"]) else (
            n if naming == "source" else convert_name(n, naming))
    by_new = {}
    for old, new in out.items():
        if len(new.encode("utf-8")) > 63:
            raise ShapeSpaceError(f"the new name of {old!r} is longer than Blender's 63 bytes: {new!r}",
                                  ErrorCode.RESERVED_NAME)
        if new in by_new:
            raise ShapeSpaceError(f"source keys {by_new[new]!r} and {old!r} both become {new!r} in this naming "
                                  f"convention: rename one, or keep the source names", ErrorCode.DUPLICATE_NAME)
        by_new[new] = old
    return out


def _plan(rig: SourceRig, tgt: TargetMesh, names: dict, existing: str, target_obj, groups: bool = True,
          kept: tuple = ()) -> tuple:
    """Which source keys are written, which target keys are replaced, which are skipped (by policy); masks
    (vertex groups) only where ``groups``.  ``kept``: source keys whose target key is an example (never
    written, whatever the policy)."""
    if existing not in EXISTING:
        raise ShapeSpaceError(f"unknown policy for existing keys {existing!r}: {', '.join(EXISTING)}",
                              ErrorCode.METHOD)
    have = set(tgt.keys) - {names[n] for n in kept}
    reference = tgt.keys[0] if tgt.keys else None
    clash = [n for n in rig.names if names[n] in have]
    if clash and existing == "refuse":
        shown = ", ".join(names[n] for n in clash[:6]) + (f" … ({len(clash)} in all)" if len(clash) > 6 else "")
        raise ShapeSpaceError(f"{tgt.name!r} already has shape keys named {shown}: choose to skip or "
                              f"overwrite existing keys (nothing was changed)", ErrorCode.DUPLICATE_NAME)
    if reference is not None and existing == "overwrite" and any(names[n] == reference for n in clash):
        raise ShapeSpaceError(f"a source key would replace the basis {reference!r} of {tgt.name!r}: rename it or "
                              f"skip existing keys", ErrorCode.RESERVED_NAME)
    skip = (set(clash) if existing == "skip" else set()) | set(kept)
    # driven keys whose primary / inputs were skipped are skipped too (their correction belongs to our primary)
    for n, v in rig.inbetweens.items():
        if v["primary"] in skip:
            skip.add(n)
    for n, v in rig.combinations.items():
        if any(i in skip for i in v["inputs"]):
            skip.add(n)
    write = [n for n in rig.names if n not in skip]
    replace = [names[n] for n in write if names[n] in have]
    skip -= set(kept)                                 # reported as kept examples, not as skipped
    groups_clash = sorted({rig.groups[n] for n in write if n in rig.groups
                           and rig.groups[n] in target_obj.vertex_groups}) if groups else []
    if groups_clash and existing == "refuse":
        raise ShapeSpaceError(f"{tgt.name!r} already has vertex groups named {', '.join(groups_clash)} (masks of "
                              f"the source keys): choose to skip or overwrite existing keys", ErrorCode.DUPLICATE_NAME)
    return write, replace, sorted(skip, key=rig.names.index), groups_clash


def _fill_group(group, weights: np.ndarray) -> None:
    rounded = np.round(weights / _WEIGHT_STEP) * _WEIGHT_STEP
    for w in np.unique(rounded[rounded > 0]):
        group.add(np.flatnonzero(rounded == w).tolist(), float(w), "REPLACE")


def _set_range(kb, lo: float, hi: float) -> None:
    kb.slider_max = 10.0
    kb.slider_min = float(lo)
    kb.slider_max = float(hi)


def _write(target, rig: SourceRig, names: dict, write: list, replace: list, full: np.ndarray, base: np.ndarray,
           masks: dict, replace_groups: bool, report: TransferReport) -> None:
    """Write every new key (plain ones, then in-betweens and combinations through the driven verbs).

    Keys and mask groups that replace existing ones are written under temporary names first; only when
    everything is written are the old ones removed and the new ones renamed (drivers that referred to an
    old key by name then find the new one).  Any failure before that removes everything new and restores
    the driven-key blob, so the file is as before.
    """
    index = {n: i for i, n in enumerate(rig.names)}
    made_key = target.data.shape_keys is None
    old_keys = set() if made_key else {kb.name for kb in target.data.shape_keys.key_blocks}
    old_groups = {g.name for g in target.vertex_groups}
    old_meta = None if made_key else target.data.shape_keys.get(driven.PROP)
    replacing = set(replace)
    live = {n: (f"{_TMP}{i}" if names[n] in replacing else names[n]) for i, n in enumerate(write)}
    new_groups, swap_groups = [], {}
    try:
        if made_key:
            target.shape_key_add(name="Basis", from_mix=False)
        group_names = _write_groups(target, masks, old_groups, replace_groups, new_groups, swap_groups)
        _write_keys(target, rig, names, write, live, [base + full[index[n]] for n in write], report)
        blocks = target.data.shape_keys.key_blocks
        for n in write:
            kb = blocks[live[n]]
            i = index[n]
            _set_range(kb, rig.slider_min[i], rig.slider_max[i])
            kb.mute = bool(rig.mute[i])
            kb.value = 0.0
            if n in rig.groups:
                kb.vertex_group = group_names[rig.groups[n]]
    except Exception:
        _undo_write(target, old_keys, new_groups, made_key, old_meta)
        raise
    _swap_in(target, replace, {live[n]: names[n] for n in write}, swap_groups)
    report.overwritten = list(replace)
    report.created = [names[n] for n in write]
    report.vertex_groups = sorted(group_names.values())
    target.data.update()


def _write_groups(target, masks: dict, old_groups: set, replace_groups: bool, new_groups: list,
                  swap_groups: dict) -> dict:
    """Write the mask vertex groups (those replacing a group under temporary names, listed in ``swap_groups``;
    every new group appended to ``new_groups`` as it is made, for the undo); source group → target group."""
    group_names = {}
    for j, (group, weights) in enumerate(masks.items()):
        if group in old_groups and not replace_groups:
            group_names[group] = group                       # "skip": the target's own group is kept
            continue
        made = target.vertex_groups.new(name=group if group not in old_groups else f"{_TMP}g{j}")
        new_groups.append(made.name)
        _fill_group(made, weights)
        group_names[group] = group
        if group in old_groups:
            swap_groups[made.name] = group
    return group_names


def _write_keys(target, rig: SourceRig, names: dict, write: list, live: dict, coords: list,
                report: TransferReport) -> None:
    """Add the keys of ``write`` under their ``live`` names with ``coords`` (one array per key, in ``write``'s
    order): plain keys first, then in-betweens and combinations through the driven verbs."""
    co = dict(zip(write, coords))
    for n in write:
        if n in rig.inbetweens or n in rig.combinations:
            continue
        kb = target.shape_key_add(name=live[n], from_mix=False)
        write_float(kb.data, "co", co[n])
    for n in [n for n in write if n in rig.inbetweens] + [n for n in write if n in rig.combinations]:
        tmp = target.shape_key_add(name=_TMP, from_mix=False)
        write_float(tmp.data, "co", co[n])
        if n in rig.inbetweens:
            v = rig.inbetweens[n]
            driven.add_inbetween(target, live.get(v["primary"], names[v["primary"]]), tmp.name,
                                 float(v["at"]), name=live[n])
            report.inbetweens.append(names[n])
        else:
            inputs = [live.get(i, names[i]) for i in rig.combinations[n]["inputs"]]
            driven.add_combination(target, inputs, tmp.name, name=live[n])
            report.combinations.append(names[n])


def _swap_in(target, replace: list, renames: dict, swap_groups: dict) -> None:
    """Everything is written: replace the old keys and groups (plain renames and removals; drivers referring to
    a renamed key follow it)."""
    blocks = target.data.shape_keys.key_blocks
    for name in replace:                                         # validated: never the reference key
        old = blocks[name]
        old.driver_remove("value")
        target.shape_key_remove(old)
    for tmp_name, final in renames.items():
        if tmp_name != final:
            blocks[tmp_name].name = final
    for tmp_name, final in swap_groups.items():
        target.vertex_groups.remove(target.vertex_groups[final])
        target.vertex_groups[tmp_name].name = final
    if replace:
        key = target.data.shape_keys
        storage.write_id_blob(key, driven.PROP, driven.SCHEMA, driven.prune(key))


def _undo_write(target, old_keys: set, groups: list, made_key: bool, old_meta) -> None:
    """Remove what :func:`_write` made (every key not there before, with its driver; new groups) and restore
    the driven-key blob."""
    key = target.data.shape_keys
    if key is not None and not made_key:
        if old_meta is None:
            key.pop(driven.PROP, None)
        else:
            key[driven.PROP] = old_meta
    if key is not None:
        for kb in [kb for kb in key.key_blocks if kb.name not in old_keys and kb != key.reference_key]:
            target.shape_key_remove(kb)
        if made_key and target.data.shape_keys is not None:
            target.shape_key_clear()
    for name in groups:
        g = target.vertex_groups.get(name)
        if g is not None:
            target.vertex_groups.remove(g)


def _part_plans(rig, tgt: TargetMesh, names: dict, existing: str, kept: tuple = ()) -> list:
    """Each part object's keys to write / replace / skip under the same policy (no masks on part objects); the
    examples' keys are kept on them too."""
    out = []
    for p in tgt.objects:
        ob = bpy.data.objects[p.name]
        mesh = TargetMesh(name=p.name, neutral=np.zeros((0, 3)), triangles=np.zeros((0, 3), int), keys=p.keys,
                          parts=0)
        write, replace, skipped, _ = _plan(rig, mesh, names, existing, ob, groups=False,
                                           kept=tuple(n for n in kept if names[n] in p.keys))
        out.append((p, write, replace, skipped))
    return out


def _signature(target, parts, examples) -> tuple:
    """:func:`target_signature` and the examples' coordinates as read (an example sculpted further while the
    transfer computes makes the result stale)."""
    blocks = target.data.shape_keys.key_blocks if target.data.shape_keys is not None else {}
    shapes = tuple(read_float(blocks[ex.key].points, "co", 3).tobytes() if ex.key in blocks else None
                   for ex in examples)
    return target_signature(target, parts), shapes


def read_transfer(source, target, naming: str = "source", existing: str = "refuse",
                  unmatched_parts: str = "keep", parts=None, examples=None) -> TransferPlan:
    """Step 1 of :func:`transfer_shapes` (main thread): validate and read everything; writes nothing.
    ``parts``: part objects transferred with the target (:func:`bridge.part_objects.meshes_of`); ``examples``:
    ``[(target key, weights or None)]`` (:mod:`.examples`)."""
    start = time.perf_counter()
    if source is not None and target is not None and source == target:
        raise ShapeSpaceError("the source rig and the target are the same object", ErrorCode.SAME_KEY)
    if unmatched_parts not in ("move", "keep", "refuse"):
        raise ShapeSpaceError(f"unknown unmatched-parts policy {unmatched_parts!r}: move, keep or refuse",
                              ErrorCode.METHOD)
    rig = read_source_rig(source)
    tgt = read_target(target)
    if target.library is not None or target.data.library is not None:
        raise ShapeSpaceError(f"{target.name!r} is linked from a library: make it local first", ErrorCode.LINKED)
    parts = list(parts or ())
    tgt = with_part_objects(target, source, tgt, parts)
    names = _new_names(rig, naming)
    specs = list(examples or ())
    read = read_examples(target, specs, rig, tgt, names)
    kept = example_keys(specs, rig, names)
    write, replace, skipped, groups_clash = _plan(rig, tgt, names, existing, target, kept=tuple(kept))
    part_plans = _part_plans(rig, tgt, names, existing, tuple(kept))
    carried = openings(source, target, rig, tgt)
    if not write:
        raise ShapeSpaceError(f"{target.name!r} already has every shape of {source.name!r}: nothing to transfer",
                              ErrorCode.NO_TARGETS)
    pairs = landmarks_for(source, target, rig, tgt)
    kinds = part_kinds(target, tgt)
    return TransferPlan(source=source.name, target=target.name, rig=rig, tgt=tgt, pairs=pairs, names=names,
                        write=write, replace=replace, skipped=skipped, groups_clash=groups_clash, existing=existing,
                        unmatched_parts=unmatched_parts, signature=_signature(target, parts, read), started=start,
                        part_plans=part_plans, openings=carried, examples=read, kept=kept, part_kinds=kinds)


def _write_part_objects(outcome: TransferOutcome, report: TransferReport) -> None:
    """Each part object gets its keys (its rows of the result, in its own object space), after the head."""
    plan = outcome.plan
    for p, write, replace, skipped in plan.part_plans:
        ob = bpy.data.objects[p.name]
        own = TransferReport(source=plan.source, target=p.name)
        local = part_objects.to_part_space(p, outcome.full[:, p.start:p.start + p.count])
        _write(ob, plan.rig, plan.names, write, replace, local, part_objects.own_neutral(ob), {},
               plan.existing == "overwrite", own)
        report.part_objects.append({"object": p.name, "created": own.created, "overwritten": own.overwritten,
                                    "skipped": [plan.names[n] for n in skipped]})


#: Shape-key custom property of a transfer target: the last transfer's verdict for the panel.
LAST_PROP = "shapespace_last_transfer"
LAST_SCHEMA = blobs.TRANSFER_LAST.schema


def _store_verdict(target, report: TransferReport) -> None:
    """Keep the last transfer's verdict on the target's keys (what the panel shows): status, the failed checks
    per key, the parts' kinds, the openings carried."""
    failed = [[k["name"], list(k["failed"])] for k in report.keys if k["failed"]]
    parts = [[p["part"], p["kind"], p["vertices"], bool(p["unsure"])] for p in report.parts]
    storage.write_id_blob(target.data.shape_keys, LAST_PROP, LAST_SCHEMA,
                          {"source": report.source, "status": report.status.name.lower(), "failed": failed,
                           "parts": parts, "openings": list(report.openings)})


def last_verdict(target) -> dict | None:
    """The last transfer's stored verdict on ``target`` (see :func:`_store_verdict`), or None."""
    key = target.data.shape_keys if target is not None and target.type == "MESH" else None
    if key is None or LAST_PROP not in key:
        return None
    return storage.read_id_blob(key, LAST_PROP, LAST_SCHEMA)


def verdict_status(target) -> tuple:
    """``(verdict or None, problem)`` for panels: never raises (``problem`` is '' or one line)."""
    try:
        return last_verdict(target), ""
    except ShapeSpaceError as exc:
        return None, str(exc)


def write_transfer(outcome: TransferOutcome) -> TransferReport:
    """Step 3 (main thread): write the new keys (and mask groups) in one step; returns the report.

    Refused, with nothing written, when the target is gone or changed (mode, vertices, shape keys, vertex
    groups, part objects, the kinds set for its parts) since :func:`read_transfer`.
    """
    plan, report = outcome.plan, outcome.report
    target = bpy.data.objects.get(plan.target)
    parts = [bpy.data.objects.get(p.name) for p in plan.tgt.objects]
    if target is None or target.type != "MESH" or _signature(target, parts, plan.examples) != plan.signature:
        raise ShapeSpaceError(f"{plan.target!r} changed while the transfer computed (mode, mesh, shape keys, "
                              "examples, vertex groups or part objects): nothing was written; transfer again",
                              ErrorCode.RIG_CHANGED)
    if part_kinds(target, plan.tgt) != plan.part_kinds:
        raise ShapeSpaceError(f"the kinds of the parts of {plan.target!r} changed while the transfer computed (Parts "
                              "list or the rig of a part object): nothing was written; transfer again",
                              ErrorCode.RIG_CHANGED)
    own = plan.tgt.own if plan.tgt.own >= 0 else len(plan.tgt.neutral)
    _write(target, plan.rig, plan.names, plan.write, plan.replace, outcome.full[:, :own], plan.tgt.neutral[:own],
           {g: w[:own] for g, w in outcome.masks.items()}, plan.existing == "overwrite", report)
    _write_part_objects(outcome, report)
    for entry in report.parts:
        name, entry["vertex"] = part_owner(plan.tgt, entry["first"])
        entry["object"] = name or plan.target
    if report.parts:
        show_parts(target, plan.tgt, report.parts)
    _store_verdict(target, report)
    clear_preview(target)                       # it served its purpose; the result file does not keep it
    shown = {ex.key for ex in plan.examples}
    report.kept = [plan.names[n] if plan.names[n] in shown else n for n in plan.kept]
    report.skipped = [plan.names[n] for n in plan.skipped] + (
        [f"vertex group {g} (kept)" for g in plan.groups_clash] if plan.existing == "skip" else [])
    report.seconds = time.perf_counter() - plan.started
    return report


def start_transfer_job(plan: TransferPlan) -> BackgroundJob:
    """Start :func:`compute_transfer` of ``plan`` in a worker thread (a modal operator polls the job and
    cancels it on Esc); :func:`finish_transfer_job` writes its outcome once it is done."""
    return BackgroundJob(lambda progress: compute_transfer(plan, progress), name="ShapeSpace transfer").start()


def finish_transfer_job(job: BackgroundJob) -> TransferReport:
    """Write a finished job's outcome (main thread, one step) and return its report.

    Re-raises what stopped the job (:class:`~core.progress.Cancelled` when it was cancelled, its
    :class:`ShapeSpaceError`); nothing is written then."""
    try:
        outcome = job.result()
    except MemoryError:
        raise ShapeSpaceError("not enough memory for this transfer (decimate the target, or transfer fewer "
                              "shapes)", ErrorCode.TOO_LARGE) from None
    return write_transfer(outcome)


def transfer_shapes(source, target, naming: str = "source", existing: str = "refuse", unmatched_parts: str = "keep",
                    progress=None, parts=None, examples=None) -> TransferReport:
    """Transfer every shape key of ``source`` onto ``target``: :func:`read_transfer` → :func:`compute_transfer`
    → :func:`write_transfer` (validate → compute → write).

    Parameters
    ----------
    source, target : bpy.types.Object
        Meshes; the target may have any topology and vertex count and needs ≥ 5 landmark pairs.
    naming : {"source", "arkit", "suffix", "pascal"}
    existing : {"refuse", "skip", "overwrite"}
        Target keys (and mask vertex groups) that already have a new name: refuse naming them (default),
        keep them (their in-betweens/combinations are skipped too), or replace them.
    unmatched_parts : {"move", "keep", "refuse"}
        Separate parts of the target the source does not have (eyes, teeth, lashes): they move as rigged
        (:mod:`core.authoring.parts`; the panel's and the command line's default), stay still (this
        function's default, as before 0.2), or refuse.
    progress : callable(fraction) or None
        :mod:`core.progress` protocol; raising :class:`~core.progress.Cancelled` from it stops the transfer
        with nothing written.
    parts : sequence of bpy.types.Object, optional
        Part objects (eyes, teeth as meshes of their own) transferred with the target; each gets shape keys
        of the same names (:mod:`bridge.part_objects`).
    examples : sequence of (str, dict or None), optional
        Target shape keys given as examples, each with its weights of the source's shapes (None: the source
        shape of its name at 1; :mod:`bridge.authoring.examples`): every key is refined so they are reproduced,
        and the example keys are kept as they are.

    Raises
    ------
    core.ShapeSpaceError
        Before anything is written; the file is unchanged.
    """
    plan = read_transfer(source, target, naming, existing, unmatched_parts, parts, examples)
    return write_transfer(compute_transfer(plan, progress))
