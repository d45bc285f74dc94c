"""The per-source retarget report: what the command line prints, the panel shows and the file keeps.

:class:`RetargetReport` follows the one report contract of :class:`core.result.Report`: ``status`` is a
:class:`~core.result.Status` (``NOT_CONVERGED`` when the space-time solver stopped before converging,
``WARNING`` when reading the source noticed something or frames clip, else ``OK``), ``issues`` are
:class:`~core.result.Issue` findings, and the command line's exit code follows from them
(:func:`core.result.exit_code`).
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..result import Issue, Report, Status
from .performance import PerformanceFit

__all__ = ["RetargetReport", "frame_ranges", "format_ranges", "ISSUE_CODE"]

#: Code of an issue given as plain text (a report read from the JSON of ShapeSpace 0.1).
ISSUE_CODE = "retarget"


def frame_ranges(frames: ArrayLike, mask: ArrayLike) -> list:
    """The frames where ``mask`` holds, as inclusive runs ``[[first, last], …]``.

    A run is a maximal sequence of masked frames that are consecutive in ``frames``
    (one row apart): ``frames = 10…20``, ``mask`` true at 12, 13, 14 and 17 gives
    ``[[12, 14], [17, 17]]``.  Whole-number frames are given as ``int``.

    Parameters
    ----------
    frames : ndarray (f,)
        Scene frame of each row, increasing.
    mask : ndarray of bool (f,)

    Returns
    -------
    list of [first, last]
        In frame order; empty when nothing is masked.
    """
    frames = np.asarray(frames, dtype=np.float64).ravel()
    mask = np.asarray(mask, dtype=bool).ravel()
    if frames.shape != mask.shape:
        raise ValueError(f"{frames.size} frames for a mask of {mask.size}")
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.diff(padded)
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [[_frame(frames[a]), _frame(frames[b])] for a, b in zip(starts, stops)]


def format_ranges(ranges: list, limit: int = 6) -> str:
    """``[[12, 40], [97, 97]]`` → ``'12–40, 97'`` (the first ``limit`` runs, then ``'… (N runs)'``)."""
    parts = [f"{a:g}" if a == b else f"{a:g}–{b:g}" for a, b in ranges[:limit]]
    if len(ranges) > limit:
        parts.append(f"… ({len(ranges)} runs)")
    return ", ".join(parts)


def _frame(value: float) -> int | float:
    return int(value) if float(value).is_integer() else float(value)


@dataclass
class RetargetReport(Report):
    """One retargeted source.

    Fields left ``None`` did not apply to the method (e.g. ``solver_iterations``
    outside space-time, ``keys_kept_frac`` without key reduction) and are left
    out of :meth:`to_json`, so the JSON keys are exactly those that apply.

    Attributes
    ----------
    source : str
        CSV path, action or mesh name.
    method : str
        ``copy``, ``learned``, ``perframe`` or ``spacetime``.
    frames : int
    status : Status
        ``NOT_CONVERGED`` when the space-time solver stopped before converging; ``WARNING`` when there are
        ``issues`` or clipped frames; else ``OK`` (:meth:`settle_status`).  In JSON its lower-case name.
    issues : list of Issue
        What reading the source repaired or noticed, stale channel mappings, unused head / eye channels
        (``{"severity", "code", "message", "items"}`` in JSON).
    mapped_channels : int or None
        Source channels used (weights sources).
    key_poses : int or None
        Learned method: pose pairs the map was learned from.
    learned_fit_rms : float or None
        Learned method: RMS misfit of the map at the key poses (slider units).
    solver_iterations : int or None
        Space-time: outer iterations of the bounded solver.
    solver_message : str or None
        Space-time: the solver's message (``"converged"``, ``"iteration limit reached"`` …).
    converged : bool or None
        Space-time: the solver met its tolerance (``status`` is ``NOT_CONVERGED`` when false).
    position_error_mm, velocity_error_mm : float or None
        How far the result is from the unlimited source motion: RMS over frames and vertices of one vertex's
        distance (of its frame-to-frame motion), mm with the head scaled to a 30 cm bounding-box diagonal
        (:func:`~.metrics.per_vertex_mm`).
    position_error_rms, velocity_error_rms : float or None
        The same as whole-mesh frame norms over the head size (the space-time objective's unit), see
        :mod:`.metrics`; they grow with the square root of the vertex count.
    clipping_frames : int or None
        Frames whose ideal weights leave the slider ranges.
    clipped_frames : list of [first, last] or None
        Those frames (scene frames) as inclusive runs, :func:`frame_ranges`.
    frame_range : list of [first, last] or None
        The scene frames written (first and last key of the new action).
    scene_range_extended : bool or None
        Whether the scene's frame range was widened to include ``frame_range``.
    scene_range_before : list of [start, end] or None
        The scene's frame range before it was widened (*Discard Result* gives it back).
    keys_kept_frac : float or None
        With key reduction: fraction of the dense keys kept.
    action : str
        The action written.
    previous_action : str
        The action the rig played before ('' for none).
    bones : list of str or None
        Head / neck / eye bones keyed from the source's head and eye channels.
    bones_action : str or None
        The action holding the bone curves (the result action on Blender 4.4+, a second one on 4.2).
    armature : str or None
        The armature whose bones were keyed.
    armature_previous : list or None
        What it played before: ``[action name ('' for none), slot identifier ('' for none), had a fake user]``
        (*Discard Result* gives it back).
    previous_fake_user : bool or None
        Whether that action had a fake user before the retarget gave it one (``None``: no previous action,
        or a report written by ShapeSpace 0.1.0).
    """

    source: str = ""
    method: str = ""
    frames: int = 0
    mapped_channels: int | None = None
    key_poses: int | None = None
    learned_fit_rms: float | None = None
    solver_iterations: int | None = None
    solver_message: str | None = None
    converged: bool | None = None
    position_error_mm: float | None = None
    velocity_error_mm: float | None = None
    position_error_rms: float | None = None
    velocity_error_rms: float | None = None
    clipping_frames: int | None = None
    clipped_frames: list | None = None
    frame_range: list | None = None
    scene_range_extended: bool | None = None
    scene_range_before: list | None = None
    keys_kept_frac: float | None = None
    bones: list | None = None
    bones_action: str | None = None
    armature: str | None = None
    armature_previous: list | None = None
    action: str = ""
    previous_action: str = ""
    previous_fake_user: bool | None = None

    def __post_init__(self):
        self.status = _status(self.status)
        self.issues = [_issue(i) for i in self.issues]

    def settle_status(self) -> Status:
        """Set (and return) :attr:`status` from the outcome: ``NOT_CONVERGED`` when the space-time solver did not
        converge, ``WARNING`` when there are issues or clipped frames, else ``OK``."""
        if self.converged is False:
            self.status = Status.NOT_CONVERGED
        elif self.issues or self.clipping_frames:
            self.status = Status.WARNING
        else:
            self.status = Status.OK
        return self.status

    def record(self, fit: PerformanceFit, frames: ArrayLike | None = None) -> None:
        """Take the errors, clipping and (space-time) solver outcome of a :class:`~.performance.PerformanceFit`;
        with the scene ``frames`` (f,) of its rows, the clipped frames as runs and the frame range too.  Settles
        :attr:`status` (:meth:`settle_status`), so every issue is added before."""
        self.position_error_rms = fit.position_error_rms
        self.velocity_error_rms = fit.velocity_error_rms
        self.position_error_mm = fit.position_error_mm
        self.velocity_error_mm = fit.velocity_error_mm
        self.clipping_frames = fit.clipping_frames
        if frames is not None:
            frames = np.asarray(frames, dtype=np.float64)
            self.clipped_frames = frame_ranges(frames, fit.clipped)
            if frames.size:
                self.frame_range = [_frame(frames[0]), _frame(frames[-1])]
        if fit.solver is not None:
            self.solver_iterations = fit.solver.iterations
            self.solver_message = fit.solver.message
            self.converged = fit.solver.status == Status.OK
        self.settle_status()

    def to_json(self) -> dict:
        """JSON-ready dict of the fields that apply (``None`` fields left out; NaN → ``null``), ``status`` as its
        lower-case name right after ``frames``."""
        data = super().to_json()
        data = {k: v for k, v in data.items() if getattr(self, k) is not None}
        head = ("source", "method", "frames", "status", "issues")
        return {**{k: data[k] for k in head if k in data}, **{k: v for k, v in data.items() if k not in head}}

    @classmethod
    def from_json(cls, data: dict) -> RetargetReport:
        """A report from a (possibly partial) dict of its JSON keys; unknown keys are ignored.  Without a
        ``status`` (the report kept on a Key) it is settled from the fields (:meth:`settle_status`); a ``status``
        that names no :class:`Status` is the solver's message of a ShapeSpace 0.1 report."""
        names = {f.name for f in fields(cls)}
        kw = {k: v for k, v in data.items() if k in names}
        if isinstance(kw.get("status"), str) and kw["status"].upper() not in Status.__members__:
            kw.setdefault("solver_message", kw.pop("status"))
        rep = cls(**kw)
        if "status" not in kw:
            rep.settle_status()
        return rep
    # mapping-style reads of the JSON keys, for scripts written against the dict report
    def __getitem__(self, key: str) -> Any:
        value = getattr(self, key, None) if key in {f.name for f in fields(self)} else None
        if value is None:
            raise KeyError(key)
        return value

    def __contains__(self, key: str) -> bool:
        return key in {f.name for f in fields(self)} and getattr(self, key) is not None

    def get(self, key: str, default: Any = None) -> Any:
        """``report[key]``, or ``default`` when it does not apply."""
        try:
            return self[key]
        except KeyError:
            return default


def _status(value) -> Status:
    """A :class:`Status` from itself, its value or its lower-case JSON name."""
    if isinstance(value, str):
        try:
            return Status[value.upper()]
        except KeyError:
            raise ValueError(f"unknown report status {value!r}") from None
    return Status(int(value))


def _issue(value) -> Issue:
    """An :class:`Issue` from itself, its JSON dict, or plain text (a warning)."""
    if isinstance(value, Issue):
        return value
    if isinstance(value, dict):
        return Issue(str(value.get("severity", "warning")), str(value.get("code", ISSUE_CODE)),
                     str(value.get("message", "")), tuple(value.get("items", ())))
    return Issue("warning", ISSUE_CODE, str(value))
