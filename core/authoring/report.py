"""The report of a transfer (*Transfer Shapes*, ``shapespace transfer``): what it wrote and how it went.

:class:`TransferReport` follows the one report contract (:class:`core.result.Report`):

- ``status`` — ``OK``, or ``WARNING`` when a transferred key failed one of its checks
  (:func:`core.authoring.quality.check_keys`: the keys were written, the panel and the report name them);
- ``issues`` — one ``error`` :class:`~core.result.Issue` per failed check (a refused quality check, naming the
  key), so :meth:`~TransferReport.exit_code` is 1;
- ``registration_status`` — the :class:`~core.result.Status` of the registration; ``NOT_CONVERGED`` (the
  registration stopped at its iteration limit; the result is written all the same) makes the exit code 1 too.

In JSON both statuses are lower-case names (``"ok"``, ``"warning"``, ``"not_converged"``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from ..result import Report, Status

__all__ = ["TransferReport"]


@dataclass
class TransferReport(Report):
    """What a transfer did (the command line prints it as JSON; see the module docstring for the statuses)."""

    source: str
    target: str
    created: list = field(default_factory=list)          # new key names, in order
    overwritten: list = field(default_factory=list)
    skipped: list = field(default_factory=list)          # existing names kept ("skip") and their dependents
    empty: list = field(default_factory=list)            # source shapes that move nothing (created all the same)
    inbetweens: list = field(default_factory=list)
    combinations: list = field(default_factory=list)
    vertex_groups: list = field(default_factory=list)
    landmarks: int = 0
    registration_residual_mm: float = 0.0
    registration_status: Status = Status.OK
    seconds: float = 0.0
    warnings: list = field(default_factory=list)         # one line each, for stderr and the operator report
    keys: list = field(default_factory=list)             # per-key checks (core.authoring.quality.check_keys)
    parts: list = field(default_factory=list)            # per-part kind, size, confidence, reason
    part_objects: list = field(default_factory=list)     # per part object: keys created / overwritten / skipped
    openings: list = field(default_factory=list)         # eye / mouth openings whose closure was carried
    examples: list = field(default_factory=list)         # per example: key, weights, relative residual before/after
    examples_gain: bool = False                          # the examples taught a gain carried to the other keys
    examples_changed: list = field(default_factory=list)  # keys the examples changed (written names)
    kept: list = field(default_factory=list)             # target keys kept because they are examples

    def __post_init__(self):
        super().__post_init__()
        self.registration_status = Status(int(self.registration_status))

    def to_json(self) -> dict:
        """JSON-ready dict: NaN → ``null``; ``status`` and ``registration_status`` as lower-case names."""
        out = super().to_json()
        out["registration_status"] = self.registration_status.name.lower()
        return out

    def exit_code(self) -> int:
        """1 when a key failed a check (an error issue) or the registration did not converge, else 0."""
        if self.registration_status in (Status.FAILED, Status.NOT_CONVERGED):
            return 1
        return super().exit_code()

