"""The report of a transfer (core/authoring/report.py) follows the one report contract of core.result.Report.

A key that fails its check (core.authoring.quality.check_keys on a key ten times the source's size, relative to
the head) is an error issue: status WARNING, exit code 1; a registration that stopped at its iteration limit exits
1 too; the JSON carries both statuses as lower-case names and the issues as plain dicts.
"""
import json

import numpy as np

from core.authoring import quality
from core.authoring.report import TransferReport
from core.result import Report, Status, exit_code
from test_authoring import _head, _shapes


def test_a_key_failing_its_check_is_an_error_issue_and_exits_one():
    V, _ = _head()
    D = _shapes(V)
    names = ["a", "b", "c"]
    big = D.copy()
    big[0] *= 10.0
    keys, issues, status = quality.check_keys(V, D, names, V, big)
    assert [k["failed"] for k in keys] == [["size"], [], []]
    assert [(i.severity, i.code, i.items) for i in issues] == [("error", "transfer_size", ("a",))]
    rep = TransferReport(source="S", target="T", keys=keys, issues=issues, status=status)
    assert isinstance(rep, Report) and rep.status == Status.WARNING
    assert rep.exit_code() == 1 and exit_code([rep]) == 1
    data = json.loads(json.dumps(rep.to_json()))
    assert data["status"] == "warning" and data["registration_status"] == "ok"
    assert data["issues"] == [{"severity": "error", "code": "transfer_size", "message": issues[0].message,
                               "items": ["a"]}]
    _, issues, status = quality.check_keys(V, D, names, V, D)
    assert not issues and status == Status.OK
    assert TransferReport(source="S", target="T", issues=issues, status=status).exit_code() == 0


def test_registration_status_is_a_status_and_not_converged_exits_one():
    ok = TransferReport(source="S", target="T")
    capped = TransferReport(source="S", target="T", registration_status=Status.NOT_CONVERGED,
                            registration_residual_mm=float("nan"))
    assert ok.exit_code() == 0 and capped.exit_code() == 1 and exit_code([ok, capped]) == 1
    data = capped.to_json()
    assert data["status"] == "ok" and data["registration_status"] == "not_converged"
    assert data["registration_residual_mm"] is None                 # NaN → null: the JSON stays valid
    assert TransferReport(source="S", target="T", registration_status=1).registration_status == Status.WARNING
    assert np.isnan(capped.registration_residual_mm)
