"""The last retarget onto a face's rig controls, remembered on the face, and its *Discard Result*.

A retarget onto rig controls (the Retarget panel's *Rig Controls* route, or ``retarget --controls``) keys new actions
on the armature, on objects with custom properties and on shape-key datablocks.  :func:`remember` keeps, on the face
object (blob :data:`core.blobs.RIG_RETARGET_LAST`), what giving them back needs: per keyed datablock the action it
played before (slot, fake-user flag), each channel's value from before, the channel names and the panel's summary.
:func:`discard` gives it all back through :func:`bridge.rig.take.restore_previous` — only ever restoring: refused,
with nothing changed, when a datablock no longer plays the take's action, an action to restore is gone, or the face's
control set is not the one the take was keyed with.
"""
from __future__ import annotations

from ...core import blobs
from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from ...core.rig import RigTakeReport
from .. import storage
from . import stored
from .take import restore_previous

__all__ = ["PROP", "discard", "forget", "has_result", "remember", "remember_or_give_back", "summary", "summary_of"]

PROP = blobs.RIG_RETARGET_LAST.prop
_SCHEMA = blobs.RIG_RETARGET_LAST.schema


def summary(report: RigTakeReport) -> str:
    """One line for the user: the actions written, frames, surface error, keys kept, frames not converged."""
    acts = ", ".join(a["action"] for a in report.actions) or "no action (nothing moved)"
    text = (f"{acts}: {report.frames} frames onto {len(report.channels)} controls ({len(report.keyed_channels)} "
            f"keyed), surface RMS {report.rms:.3g} (worst frame {report.rms_max:.3g}, scene units), "
            f"{100 * report.key_fraction:.0f} % of the keys kept")
    if report.not_converged:
        text += f"; {len(report.not_converged)} frames not converged"
    return text


def remember(face, report: RigTakeReport) -> None:
    """Keep what :func:`discard` needs of ``report`` (a written take) and its :func:`summary` on ``face``; a take that
    keyed nothing leaves the previous one remembered (it still plays, and can still be discarded)."""
    if not report.actions:
        return
    values = [list(v) if isinstance(v, (list, tuple)) else float(v) for v in report.values_before]
    storage.write_id_blob(face, PROP, _SCHEMA, {"channels": list(report.channels), "actions": list(report.actions),
                                                "values_before": values, "summary": summary(report)})


def remember_or_give_back(face, report: RigTakeReport, controls) -> None:
    """:func:`remember` the take just written with ``controls``; when that fails, give back what the take keyed
    (:func:`bridge.rig.take.restore_previous`) before the error goes on, so the file is as before."""
    try:
        remember(face, report)
    except BaseException:
        restore_previous(report, controls)
        raise


def forget(face) -> None:
    """Drop the remembered result (nothing else changes)."""
    if PROP in face:
        del face[PROP]


def has_result(face) -> bool:
    """Whether ``face`` remembers a retarget onto its rig controls."""
    return face is not None and PROP in face


def summary_of(face) -> str:
    """The remembered result's one-line summary ('' when there is none)."""
    return _read(face)["summary"] if has_result(face) else ""


def _read(face) -> dict:
    return storage.read_id_blob(face, PROP, _SCHEMA)


def discard(face) -> list:
    """Give back what the last retarget onto ``face``'s rig controls keyed (module doc); returns, per datablock given
    back, ``(what it plays now: its previous action's name, or its own name when it plays none, previous action
    name or '')``."""
    if not has_result(face):
        raise ShapeSpaceError(f"{face.name!r} has no retarget onto its rig controls to discard", ErrorCode.NO_RESULT)
    data = _read(face)
    controls = stored.control_set(face)
    if list(controls.names) != list(data["channels"]):
        gone = [n for n in data["channels"] if n not in controls.names]
        new = [n for n in controls.names if n not in data["channels"]]
        what = "; ".join(filter(None, (f"no longer enabled: {', '.join(gone[:4])}" if gone else "",
                                       f"enabled since: {', '.join(new[:4])}" if new else ""))) or "their order"
        raise ShapeSpaceError(f"{face.name!r}'s control set changed since the retarget ({what}): nothing was "
                              "discarded; enable the same channels to discard it", ErrorCode.NO_RESULT)
    report = RigTakeReport(channels=list(data["channels"]), actions=list(data["actions"]),
                           values_before=list(data["values_before"]))
    restore_previous(report, controls)
    forget(face)
    return [(entry["previous"] or entry["name"], entry["previous"]) for entry in data["actions"]]
