"""The per-source retarget report: what the command line prints, the panel shows and the file keeps."""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

from ..result import Report, Status

if TYPE_CHECKING:
    from .performance import PerformanceFit

__all__ = ["RetargetReport"]


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
    issues : list of str
        What reading the source repaired or noticed.
    mapped_channels : int or None
        Source channels used (weights sources).
    key_poses : int or None
        Learned method: pose pairs the map was learned from.
    learned_fit_rms : float or None
        Learned method: RMS misfit of the map at the key poses (slider units).
    solver_iterations : int or None
        Space-time: outer iterations of the bounded solver.
    status : str or None
        Space-time: the solver's message.
    converged : bool or None
        Space-time: the solver met its tolerance.
    position_error_rms, velocity_error_rms : float or None
        See :mod:`.metrics`.
    clipping_frames : int or None
        Frames whose ideal weights leave the slider ranges.
    keys_kept_frac : float or None
        With key reduction: fraction of the dense keys kept.
    action : str
        The action written.
    previous_action : str
        The action the rig played before ('' for none).
    previous_fake_user : bool or None
        Whether that action had a fake user before the retarget gave it one (``None``: no previous action,
        or a report written by ShapeSpace 0.1.0).
    """

    source: str = ""
    method: str = ""
    frames: int = 0
    issues: list = field(default_factory=list)
    mapped_channels: int | None = None
    key_poses: int | None = None
    learned_fit_rms: float | None = None
    solver_iterations: int | None = None
    status: str | None = None
    converged: bool | None = None
    position_error_rms: float | None = None
    velocity_error_rms: float | None = None
    clipping_frames: int | None = None
    keys_kept_frac: float | None = None
    action: str = ""
    previous_action: str = ""
    previous_fake_user: bool | None = None

    def record(self, fit: PerformanceFit) -> None:
        """Take the errors, clipping and (space-time) solver outcome of a :class:`~.performance.PerformanceFit`."""
        self.position_error_rms = fit.position_error_rms
        self.velocity_error_rms = fit.velocity_error_rms
        self.clipping_frames = fit.clipping_frames
        if fit.solver is not None:
            self.solver_iterations = fit.solver.iterations
            self.status = fit.solver.message
            self.converged = fit.solver.status == Status.OK

    def to_json(self) -> dict:
        """JSON-ready dict of the fields that apply (``None`` fields left out; NaN → ``null``)."""
        data = super().to_json()
        return {k: v for k, v in data.items() if getattr(self, k) is not None}

    @classmethod
    def from_json(cls, data: dict) -> RetargetReport:
        """A report from a (possibly partial) dict of its JSON keys; unknown keys are ignored."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in names})

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
