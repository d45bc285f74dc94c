"""Shared reporting for operators: one place that turns core errors and findings into reports."""
from ..core.result import ShapeSpaceError

FAILED = object()


def attempt(op, fn, *args, **kwargs):
    """Call ``fn``; on a ShapeSpaceError report it as an error and return :data:`FAILED`."""
    try:
        return fn(*args, **kwargs)
    except ShapeSpaceError as exc:
        op.report({"ERROR"}, str(exc))
        return FAILED


def report_issues(op, issues) -> None:
    """Report core findings (duplicate, conflicting, outlier examples, …) as warnings."""
    for issue in issues:
        op.report({"WARNING"}, issue.message)
