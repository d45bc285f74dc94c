"""Farm jobs: splitting a batch into tasks and merging the per-take reports into one.

A farm (Deadline Cloud through Open Job Description, Flamenco) runs ``shapespace retarget`` once per take
(or per chunk of takes), each writing ``<stem>.json`` (the command's ``--report``) and ``<stem>.blend``;
a final task merges the reports.  A take whose task failed before writing its report — or whose report is
unreadable — is reported as failed, so the merged report always names every take.
"""
from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field

from ..errors import ErrorCode
from ..result import Report, ShapeSpaceError, Status

__all__ = ["FarmSummary", "batch_status", "check_stems", "chunk", "did_not_converge", "load_take_report",
           "merge_take_reports",
           "read_take_report", "take_outputs", "take_stem"]


def take_stem(take: str) -> str:
    """The name a take's outputs are written under: its file name without the extension (``take1.csv`` →
    ``take1``), or an action name as it is."""
    stem = os.path.splitext(os.path.basename(str(take)))[0]
    if not stem:
        raise ShapeSpaceError(f"take {take!r} has no file name", ErrorCode.USAGE)
    return stem


def check_stems(takes: Sequence[str]) -> list[str]:
    """The stem of every take; two takes with one stem are refused (their outputs would overwrite each other,
    and a merge would read one report for both)."""
    seen = {}
    for t in takes:
        stem = take_stem(t)
        if stem in seen:
            raise ShapeSpaceError(f"takes {seen[stem]!r} and {t!r} would both write {stem}.json: rename one",
                                  ErrorCode.USAGE)
        seen[stem] = t
    return list(seen)


def take_outputs(takes: Sequence[str], report_dir: str) -> list[str]:
    """Every file the per-take tasks write in ``report_dir`` (``<stem>.json`` and ``<stem>.blend``): the
    inputs of a merge."""
    return [os.path.join(report_dir, f"{stem}{ext}") for stem in check_stems(takes) for ext in (".json", ".blend")]


def chunk(takes: Sequence[str], size: int) -> list[list[str]]:
    """``takes`` in chunks of at most ``size`` (one task each), order kept; duplicate stems refused
    (:func:`check_stems`)."""
    if int(size) < 1:
        raise ShapeSpaceError(f"chunk size must be at least 1, got {size}", ErrorCode.RANGE)
    check_stems(takes)
    items = list(takes)
    return [items[i:i + int(size)] for i in range(0, len(items), int(size))]


def load_take_report(path: str) -> tuple[dict | None, str]:
    """A per-take report (the retarget command's ``--report`` JSON) and ``""``, or ``None`` and why it cannot be
    used: ``"missing"`` when there is no file, else the damage in a few words (not JSON, no results list, a
    result without a boolean ``ok``)."""
    if not os.path.lexists(path):
        return None, "missing"
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except UnicodeDecodeError:
        return None, "not UTF-8 text"
    except ValueError as exc:
        return None, f"not JSON ({getattr(exc, 'msg', exc)} at line {getattr(exc, 'lineno', '?')})"
    except OSError as exc:
        return None, f"unreadable ({exc.strerror or exc})"
    if not isinstance(data, dict):
        return None, f"a JSON {type(data).__name__}, not an object"
    results = data.get("results")
    if not isinstance(results, list):
        return None, "no results list"
    for k, res in enumerate(results):
        if not isinstance(res, dict) or not isinstance(res.get("ok"), bool):
            return None, f"result {k} has no ok true/false"
    return data, ""


def read_take_report(path: str) -> dict | None:
    """A per-take report, or None when missing or damaged (:func:`load_take_report` says why)."""
    return load_take_report(path)[0]


@dataclass
class FarmSummary(Report):
    """The merged report of a farm batch.

    Attributes
    ----------
    takes : int
        Takes in the batch.
    succeeded : list of str
        Takes retargeted (their ``results`` entries are in ``results``).
    failed : list of dict
        ``{"take", "error"}`` for each take that failed or left no report.
    results : list of dict
        Every per-take result, ``take`` and ``blend`` (the task's output file) added.
    target, method : str
        From the first report that names them.
    status : Status
        ``FAILED`` when a take failed or left no report; else ``NOT_CONVERGED`` when a take's fit stopped
        before converging, ``WARNING`` when a take's result carries a warning, ``OK`` otherwise
        (:func:`batch_status`).
    """

    takes: int = 0
    succeeded: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    results: list = field(default_factory=list)
    target: str = ""
    method: str = ""

    @property
    def ok(self) -> bool:
        """Every take succeeded."""
        return not self.failed

    @property
    def unconverged(self) -> list:
        """The ``results`` whose fit stopped before converging (:func:`did_not_converge`)."""
        return [r for r in self.results if did_not_converge(r)]


def merge_take_reports(takes: Sequence[str], report_dir: str) -> FarmSummary:
    """Merge ``<report_dir>/<stem>.json`` of every take into one :class:`FarmSummary`.

    Parameters
    ----------
    takes : sequence of str
        The batch's takes, as given to the job (paths or action names).
    report_dir : str
        Where the per-take tasks wrote ``<stem>.json`` and ``<stem>.blend``.
    """
    check_stems(takes)
    summary = FarmSummary(takes=len(takes))
    for take in takes:
        stem = take_stem(take)
        path = os.path.join(report_dir, f"{stem}.json")
        rep, problem = load_take_report(path)
        if rep is None:
            error = (f"no report: the task for {stem} did not finish" if problem == "missing" else
                     f"report {path} is damaged: {problem}")
            summary.failed.append({"take": take, "error": error})
            continue
        summary.target = summary.target or str(rep.get("target", ""))
        summary.method = summary.method or str(rep.get("method", ""))
        blend = os.path.join(report_dir, f"{stem}.blend")
        for res in rep["results"]:
            entry = {**res, "take": take, "blend": blend if os.path.isfile(blend) else None}
            summary.results.append(entry)
            if not res["ok"]:
                summary.failed.append({"take": take, "error": str(res.get("error", "failed"))})
        if all(r["ok"] for r in rep["results"]) and rep["results"]:
            summary.succeeded.append(take)
        elif not rep["results"]:
            summary.failed.append({"take": take, "error": "the report lists no result"})
    summary.status = batch_status(summary.failed, summary.results)
    return summary


def batch_status(failed: Sequence, results: Sequence[dict]) -> Status:
    """The status of a batch: the worst of its takes'.

    Parameters
    ----------
    failed : sequence
        The takes that failed (any entry: ``FAILED``).
    results : sequence of dict
        Every per-take result as its report wrote it (``status`` a lower-case :class:`Status` name; a result
        with ``converged`` false did not converge either).
    """
    if failed:
        return Status.FAILED
    if any(did_not_converge(r) for r in results):
        return Status.NOT_CONVERGED
    return Status.WARNING if any(str(r.get("status") or "").lower() == "warning" for r in results) else Status.OK


def did_not_converge(result: dict) -> bool:
    """Whether a per-take result (as its report wrote it) stopped before converging: status ``not_converged``,
    or ``converged`` false."""
    return str(result.get("status") or "").lower() == "not_converged" or result.get("converged") is False
