"""Propose a face's controls (issue #25 item 5): the channels whose change deforms the evaluated face.

Candidates: every axis of the rotation (in the bone's rotation mode) and location of the armature's visible
pose bones (not hidden, in a visible bone collection; a connected bone's location is left out: Blender ignores
it), the face's shape-key sliders, and every float custom property a driver of the rig reads (on the armature,
its pose bones, the face or a control object).  Locked axes and channels their bounds hold still are skipped
without a probe; the rest are probed through Blender's evaluation (:meth:`RigEvaluator.probe`, measuring
:func:`core.rig.proposal.deformation`) and ranked by :func:`core.rig.proposal.rank_channels`.  The rig is left
exactly as it was.
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from ...core.rig.controls import ChannelKind, ControlSet
from ...core.rig.proposal import deformation, rank_channels
from ...core.rig.stored import StoredChannel
from . import stored
from .channels import bone_channel, shape_key_channel
from .evaluate import RigEvaluator, check_editable

__all__ = ["candidates", "propose", "propose_and_store"]


def _visible(bone) -> bool:
    if bone.hide:
        return False
    cols = list(bone.collections)
    return not cols or any(c.is_visible for c in cols)


def _driver_properties(ids) -> list:
    """``(object, data path)`` of every custom property a driver on ``ids`` reads (each once, in order)."""
    found = []
    for idb in ids:
        ad = getattr(idb, "animation_data", None)
        if ad is None:
            continue
        for fc in ad.drivers:
            for var in fc.driver.variables:
                if var.type != "SINGLE_PROP":
                    continue
                t = var.targets[0]
                if isinstance(t.id, bpy.types.Object) and t.data_path.endswith('"]') and \
                        (t.data_path.startswith('["') or t.data_path.startswith("pose.bones[")):
                    item = (t.id, t.data_path)
                    if item not in found:
                        found.append(item)
    return found


def _property_channel(ob, path: str):
    """The channel of a driver-read custom property, or None when it is not a float property of ``ob``."""
    try:
        return stored.to_channel(StoredChannel(ChannelKind.PROPERTY, ob.name, "", path))
    except ShapeSpaceError:
        return None


def candidates(face, arm) -> tuple:
    """The channels a proposal probes, and those it skips without a probe.

    Returns
    -------
    (list of Channel, list of str, list of str)
        Candidates; names of locked channels; names of channels their bounds hold still.
    """
    chans = []
    if arm is not None:
        for pb in arm.pose.bones:
            if not _visible(pb.bone):
                continue
            chans += [bone_channel(arm, pb.name, "rotation", a) for a in range(3)]
            if not pb.bone.use_connect:
                chans += [bone_channel(arm, pb.name, "location", a) for a in range(3)]
    keys = face.data.shape_keys
    if keys is not None:
        chans += [shape_key_channel(face, kb.name) for kb in keys.key_blocks if kb != keys.reference_key]
    ids = [face, face.data, keys] + ([arm, arm.data] if arm is not None else [])
    for ob, path in _driver_properties([i for i in ids if i is not None]):
        ch = _property_channel(ob, path)
        if ch is not None and all(ch.key != c.key for c in chans):
            chans.append(ch)
    locked = [ch.name for ch in chans if ch.locked]
    held = [ch.name for ch in chans if not ch.locked and ch.lo == ch.hi]
    return [ch for ch in chans if not ch.locked and ch.lo < ch.hi], locked, held


def probe_candidates(face, arm) -> tuple:
    """:func:`candidates` and their :class:`ControlSet`: ``(channels, locked, held, controls)``; refused, naming the
    face, when there is nothing to probe."""
    chans, locked, held = candidates(face, arm)
    if not chans:
        raise ShapeSpaceError(f"{face.name!r} has no channels to probe (no visible bones, shape keys or driven "
                              "properties)", ErrorCode.NO_CHANNELS)
    return chans, locked, held, ControlSet(tuple(chans))


def checked_rest(face, ev) -> np.ndarray:
    """The evaluator's rest evaluation (:meth:`RigEvaluator.check_rig`), refused naming the first vertex that is not
    finite."""
    rest = ev.check_rig()
    bad = np.flatnonzero(~np.isfinite(rest).all(1))
    if bad.size:
        raise ShapeSpaceError(f"{face.name!r}: evaluated vertex {int(bad[0])} is not finite (NaN or infinite "
                              "coordinates, shape keys or drivers)", ErrorCode.NON_FINITE)
    return rest


def propose(face, arm=None, progress=None) -> tuple:
    """Probe the candidates of ``face`` (and the armature ``arm``) through Blender's evaluation (``progress``:
    :mod:`core.progress`, per channel probed).

    Returns
    -------
    (ProposalReport, list of Channel)
        The report and the proposed channels in rank order.
    """
    if face is None or face.type != "MESH":
        raise ShapeSpaceError(f"{getattr(face, 'name', face)!r} is not a mesh object", ErrorCode.NOT_MESH)
    chans, locked, held, controls = probe_candidates(face, arm)
    with RigEvaluator(face, controls, [0], check=False) as ev:
        rest = checked_rest(face, ev)
        lo, hi = controls.solve_bounds(ev.c0)
        amounts, _ = ev.probe(rest, lo, hi, measure=deformation, progress=progress, either_side=True)
        report = rank_channels(controls.names, amounts, ev.diagonal, locked=locked, held=held)
    by_name = {ch.name: ch for ch in chans}
    return report, [by_name[n] for n in report.proposed]


def propose_and_store(face, arm=None, progress=None) -> tuple:
    """:func:`propose`, then add the proposed channels not stored yet to the face's control set (stored ones keep
    their bounds and enabled flags).  Nothing is written when nothing deforms the face (the report is FAILED).

    Returns
    -------
    (ProposalReport, list of StoredChannel)
        The report and the entries added.
    """
    stored_arm, _ = stored.read(face)
    if arm is not None and stored_arm and stored_arm != arm.name:
        raise ShapeSpaceError(f"the control set of {face.name!r} belongs to armature {stored_arm!r}, not "
                              f"{arm.name!r}: clear it first", ErrorCode.INVALID)
    check_editable([face] + ([arm] if arm is not None else []))
    report, chans = propose(face, arm, progress)
    added = stored.add_entries_of(face, arm.name if arm is not None else "", chans) if chans else []
    return report, added
