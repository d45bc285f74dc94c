"""Result objects shared by every ShapeSpace solver and reader.

Every public entry point in :mod:`core` returns (or raises with) plain data:
arrays in, small dataclasses out.  :class:`Result` carries a value together
with a machine-readable ``status``, a one-line human ``message`` and a
``diagnostics`` dictionary, in the spirit of ``scipy.optimize.OptimizeResult``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


class ShapeSpaceError(ValueError):
    """Bad input detected by core validation.

    The message is a single line meant for the artist (operator report or the
    command line).  ``code`` is a short stable identifier tests can match.
    """

    def __init__(self, message: str, code: str = "invalid"):
        super().__init__(message)
        self.code = code


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
    """Outcome of a core computation.

    Attributes
    ----------
    value : Any
        The computed value (array, dataclass, ...).  ``None`` on failure.
    status : int
        ``0`` success, ``1`` success with warnings, negative on failure.
    message : str
        One-line summary.
    diagnostics : dict
        Extra numbers (iterations, residuals, timings) for reports and tests.
    issues : list of Issue
        Findings of validation, most severe first.
    """

    value: Any = None
    status: int = 0
    message: str = "ok"
    diagnostics: dict = field(default_factory=dict)
    issues: list = field(default_factory=list)

    @property
    def success(self) -> bool:
        return self.status >= 0

    def errors(self) -> list:
        return [i for i in self.issues if i.severity == "error"]

    def warnings(self) -> list:
        return [i for i in self.issues if i.severity == "warning"]
