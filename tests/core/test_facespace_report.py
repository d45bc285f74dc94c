"""The face-space reports (core.facespace.report): one contract (core.result.Report), the same JSON keys the
face-space verbs returned before, plus ``status`` and ``issues``."""
import json
import math
from dataclasses import fields

import pytest

from core.facespace.report import (
    CoherenceReport,
    CompressionReport,
    ConvexReport,
    FaceSpaceReport,
    FillReport,
    InpaintReport,
    MeterReport,
    PriorReport,
)
from core.result import Issue, Report, Status, exit_code

#: The keys each verb's plain dict had (bridge/facespace.py before the reports), and the report that replaces it.
OLD_KEYS = {
    ConvexReport: {"sum_before", "sum_after", "moved"},
    CompressionReport: {"components", "targets", "frames", "tol", "ratio", "animation_rank", "rig_rank", "message"},
    CoherenceReport: {"targets", "mutual_coherence", "similar_pairs", "empty_targets", "png", "image"},
    PriorReport: {"frames", "dimension", "regularised", "message"},
    MeterReport: {"norm", "shell_radius", "percentile", "plausibility"},
    FillReport: {"frames", "start", "end"},
    InpaintReport: {"frames", "channels", "method", "message"},
}


@pytest.mark.parametrize("cls", sorted(OLD_KEYS, key=lambda c: c.__name__))
def test_every_report_keeps_its_keys_and_adds_status_and_issues(cls):
    rep = cls()
    assert isinstance(rep, Report) and isinstance(rep, FaceSpaceReport)
    out = rep.to_json()
    assert set(out) == OLD_KEYS[cls] | {"status", "issues"} and out["status"] == "ok" and out["issues"] == []
    assert set(rep.payload()) == OLD_KEYS[cls]
    json.dumps(out, allow_nan=False)                      # plain JSON
    assert {f.name for f in fields(cls) if f.kw_only} == {"status", "issues"}      # keyword-only, from the base


def test_coherence_report_lists_sparsity_only_when_measured():
    rep = CoherenceReport(targets=3, mutual_coherence=0.5, similar_pairs=[["a", "b", 0.99]], empty_targets=["c"])
    assert "sparsity" not in rep.to_json() and "sparsity_message" not in rep.payload()
    rep.sparsity = {"blendshape": {"hoyer": 0.9}, "pca": {"hoyer": float("nan")}}
    rep.sparsity_message = "blendshape weights are sparser"
    out = rep.to_json()
    assert out["sparsity"] == {"blendshape": {"hoyer": 0.9}, "pca": {"hoyer": None}}   # NaN → null
    assert out["sparsity_message"] == "blendshape weights are sparser"


def test_statuses_and_exit_codes_follow_the_one_rule():
    failed = CompressionReport(components=None, ratio=math.nan, status=Status.FAILED,
                               issues=[Issue("error", "tolerance_not_met", "no m reaches tol")])
    assert failed.to_json()["status"] == "failed" and failed.to_json()["ratio"] is None
    assert failed.exit_code() == 1
    warned = PriorReport(regularised=True, status=Status.WARNING, issues=[Issue("warning", "regularised", "ridge")])
    assert warned.to_json()["status"] == "warning" and warned.exit_code() == 0
    assert MeterReport(plausibility="too_extreme", status=Status.WARNING).to_json()["plausibility"] == "too_extreme"
    assert exit_code([FillReport(), warned]) == 0 and exit_code([FillReport(), warned, failed]) == 1
