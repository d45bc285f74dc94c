"""Result / Issue / ShapeSpaceError plumbing."""
import pytest

from core.result import Issue, Result, ShapeSpaceError


def test_result_success_and_issue_filters():
    issues = [Issue("error", "non_finite", "bad"), Issue("warning", "empty_target", "empty", ("a",)),
              Issue("info", "note", "fyi")]
    r = Result(value=None, status=-1, message="bad", diagnostics={}, issues=issues)
    assert not r.success
    assert [i.code for i in r.errors()] == ["non_finite"]
    assert [i.code for i in r.warnings()] == ["empty_target"]
    ok = Result(3)
    assert ok.success and ok.status == 0 and ok.message == "ok" and ok.issues == [] and ok.diagnostics == {}
    assert Result(1, status=1).success
    # default containers are per-instance
    ok.issues.append(1)
    assert Result().issues == []


def test_shapespace_error_is_value_error_with_code():
    with pytest.raises(ValueError) as exc:
        raise ShapeSpaceError("neutral must have shape (p, 3)", "shape")
    assert exc.value.code == "shape" and str(exc.value) == "neutral must have shape (p, 3)"
    assert ShapeSpaceError("x").code == "invalid"
