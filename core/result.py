"""The one result family of ShapeSpace's core, and its error type.

Every public computation in :mod:`core` either raises :class:`ShapeSpaceError`
(bad input, detected before any work) or returns a :class:`Result` (or one of
its subclasses).  A result always carries

- ``value`` — what was computed (an array, a dataclass, …), ``None`` on failure;
- ``status`` — a :class:`Status`, with one convention everywhere;
- ``message`` — one line for the artist or the command line;
- ``iterations`` — solver iterations (0 for direct methods);
- ``diagnostics`` — extra numbers for reports and tests;
- ``issues`` — findings of validation (:class:`Issue`), most severe first.

Solvers that have a natural name for their value expose it as a read-only
alias (``BoxQPResult.x``, ``SpacetimeResult.weights`` …), in the spirit of
``scipy.optimize.OptimizeResult``.

Status convention (:data:`STATUS_MESSAGES` is the table)::

     0  OK             the value is exact to the solver's tolerance
     1  WARNING        the value is usable; ``issues``/``message`` say what to look at
     2  NOT_CONVERGED  the solver stopped at its iteration limit (or stalled); the value is the
                       best iterate — never reported as "ok" (the CLI exits non-zero)
    -1  FAILED         no usable value

Error codes (:class:`ErrorCode`) are listed in one place, :mod:`core.errors`.
"""
from __future__ import annotations

import enum
import math
from dataclasses import KW_ONLY, asdict, dataclass, field, fields, is_dataclass
from typing import Any

import numpy as np

from .errors import ErrorCode

__all__ = ["ErrorCode", "Issue", "Report", "Result", "STATUS_MESSAGES", "ShapeSpaceError", "Status",
           "exit_code", "to_jsonable"]


class Status(enum.IntEnum):
    """Outcome of a core computation (the same meaning in every result type)."""

    FAILED = -1
    OK = 0
    WARNING = 1
    NOT_CONVERGED = 2


#: Default one-line message of each status.
STATUS_MESSAGES = {
    Status.FAILED: "failed",
    Status.OK: "ok",
    Status.WARNING: "ok, with warnings",
    Status.NOT_CONVERGED: "stopped at the iteration limit before converging",
}


class ShapeSpaceError(ValueError):
    """Bad input detected by core (or bridge) validation.

    The message is a single line meant for the artist (operator report or the
    command line) and names the culprit (argument and shape, key, vertex, flag,
    line).  ``code`` is an :class:`ErrorCode` (a ``str`` enum, so tests can
    compare it with the plain string).
    """

    def __init__(self, message: str, code: ErrorCode | str = ErrorCode.INVALID):
        super().__init__(message)
        self.code = ErrorCode(code)


@dataclass
class Issue:
    """One finding of a validation pass.

    Attributes
    ----------
    severity : {"error", "warning", "info"}
        ``error`` means the data cannot be used as it is.
    code : str
        Stable identifier, e.g. ``"empty_target"``.
    message : str
        One line for the artist, naming the offending item.
    items : tuple of str
        Names of the shape keys, bones or groups concerned.
    """

    severity: str
    code: str
    message: str
    items: tuple = ()


@dataclass
class Result:
    """Outcome of a core computation (base of every result type).

    Attributes
    ----------
    value : Any
        The computed value (the only positional field).  ``None`` on failure.
    status : Status
        See the module docstring.
    message : str
        One-line summary.
    iterations : int
        Solver iterations (0 for a direct method).
    diagnostics : dict
        Extra numbers (residuals, timings, routes taken) for reports and tests.
    issues : list of Issue
        Findings of validation, most severe first.
    """

    value: Any = None
    _: KW_ONLY
    status: Status = Status.OK
    message: str = ""
    iterations: int = 0
    diagnostics: dict = field(default_factory=dict)
    issues: list = field(default_factory=list)

    def __post_init__(self):
        self.status = Status(int(self.status))
        if not self.message:
            self.message = STATUS_MESSAGES[self.status]

    @property
    def success(self) -> bool:
        """True when the value is usable as it is (``OK`` or ``WARNING``)."""
        return self.status in (Status.OK, Status.WARNING)

    @property
    def converged(self) -> bool:
        """True unless the computation failed or stopped at its iteration limit."""
        return self.status != Status.NOT_CONVERGED and self.status != Status.FAILED

    def errors(self) -> list:
        return [i for i in self.issues if i.severity == "error"]

    def warnings(self) -> list:
        return [i for i in self.issues if i.severity == "warning"]


def to_jsonable(obj: Any) -> Any:
    """Convert dataclasses, numpy values, enums and non-finite floats into plain JSON values.

    Non-finite floats become ``None`` (JSON has no NaN); enums their value;
    arrays lists.
    """
    if is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in fields(obj)}
    if isinstance(obj, enum.Enum):
        return to_jsonable(obj.value)
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    return obj


@dataclass
class Report:
    """Base of every report the command line prints and the panels show (one contract for all capabilities).

    Each capability owns its report type in core, a dataclass deriving from this one. Every report carries

    - ``status`` — a :class:`Status`, with the same meaning as in :class:`Result`;
    - ``issues`` — findings (:class:`Issue`), most severe first; an ``error`` issue is a refused quality check
      (the data was written, but it failed a check the user must look at);
    - :meth:`to_json` — the JSON-ready dict (NaN → ``null``, ``status`` as its lower-case name: ``"ok"``,
      ``"warning"``, ``"not_converged"``, ``"failed"``);
    - :meth:`exit_code` — the one command-line exit rule.

    Command-line exit rule (every subcommand)::

        0  every report OK or WARNING, and no error issue
        1  any report FAILED or NOT_CONVERGED, or any error issue (a refused quality check)
        2  usage (bad arguments; raised before any report exists)
    """

    _: KW_ONLY
    status: Status = Status.OK
    issues: list = field(default_factory=list)

    def __post_init__(self):
        if isinstance(self.status, int):
            self.status = Status(int(self.status))

    def to_json(self) -> dict:
        out = to_jsonable(self)
        if isinstance(self.status, Status):
            out["status"] = self.status.name.lower()
        return out

    def as_dict(self) -> dict:
        return asdict(self)

    def error_issues(self) -> list:
        """The issues of severity ``error`` (refused quality checks)."""
        return [i for i in self.issues if getattr(i, "severity", None) == "error"]

    def exit_code(self) -> int:
        """The command-line exit code this report asks for (see the class docstring)."""
        if self.status in (Status.FAILED, Status.NOT_CONVERGED) or self.error_issues():
            return 1
        return 0


def exit_code(reports: Report | list) -> int:
    """The exit code of a command that produced ``reports`` (one or many): the worst of theirs."""
    if isinstance(reports, Report):
        reports = [reports]
    return max((r.exit_code() for r in reports), default=0)
