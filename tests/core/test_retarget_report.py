"""core.retarget.report: clipped frames as runs of scene frames, the report's JSON keys (#12 Build 3), and the one
report contract of core.result.Report (#23): status, issues, exit code."""
import json

import numpy as np
import pytest

from core.blendshape import BlendshapeModel
from core.result import Issue, Report, Status, exit_code
from core.retarget import performance
from core.retarget.metrics import clipped_mask
from core.retarget.performance import retarget_weights
from core.retarget.report import RetargetReport, format_ranges, frame_ranges


def test_frame_ranges_compress_runs():
    frames = np.arange(10, 21)
    mask = np.isin(frames, [12, 13, 14, 17])
    assert frame_ranges(frames, mask) == [[12, 14], [17, 17]]
    assert frame_ranges(frames, np.zeros(11, bool)) == []
    assert frame_ranges(frames, np.ones(11, bool)) == [[10, 20]]
    edges = np.isin(frames, [10, 20])
    assert frame_ranges(frames, edges) == [[10, 10], [20, 20]]
    assert all(isinstance(v, int) for run in frame_ranges(frames, mask) for v in run)


def test_frame_ranges_against_a_brute_force_reference():
    rng = np.random.default_rng(3)
    for _ in range(200):
        n = int(rng.integers(1, 40))
        frames = np.arange(n) + int(rng.integers(-5, 100))
        mask = rng.random(n) < rng.random()
        runs = frame_ranges(frames, mask)
        # expand the runs back: exactly the masked frames, runs separated by at least one unmasked frame
        expanded = [f for a, b in runs for f in range(a, b + 1)]
        assert expanded == [int(f) for f in frames[mask]]
        assert all(b2 > b1 + 1 for (_, b1), (b2, _) in zip(runs, runs[1:]))


def test_fractional_frames_stay_fractional():
    assert frame_ranges([1.5, 2.5, 3.5], [True, True, False]) == [[1.5, 2.5]]


def test_frame_ranges_refuses_mismatched_shapes():
    with pytest.raises(ValueError, match="3 frames for a mask of 2"):
        frame_ranges([1, 2, 3], [True, False])


def test_format_ranges():
    assert format_ranges([[12, 40], [97, 97]]) == "12–40, 97"
    assert format_ranges([[k, k] for k in range(10)], limit=2) == "0, 1, … (10 runs)"


def _model(n=3, p=5, seed=0):
    rng = np.random.default_rng(seed)
    deltas = rng.normal(size=(n, p, 3))
    return BlendshapeModel(neutral=rng.normal(size=(p, 3)), deltas=deltas, names=[f"K{k}" for k in range(n)],
                           slider_min=np.zeros(n), slider_max=np.ones(n), values=np.zeros(n))


def test_clipped_mask_is_the_one_clipping_count():
    rng = np.random.default_rng(1)
    W = rng.uniform(-0.3, 1.3, size=(50, 4))
    lo, hi = np.zeros(4), np.ones(4)
    mask = clipped_mask(W, lo, hi)
    brute = [any(w < 0 or w > 1 for w in row) for row in W]              # frame by frame, slider by slider
    assert mask.tolist() == brute
    assert np.array_equal(mask, ((W < 0) | (W > 1)).any(axis=1))
    fit = retarget_weights(_model(n=4), W, "copy")                        # the fit's count is the mask's
    assert fit.clipping_frames == sum(brute) and np.array_equal(fit.clipped, mask)


def test_report_lists_clipped_runs_and_range_for_copy():
    model = _model()
    frames = np.arange(5.0, 15.0)
    ideal = np.full((10, 3), 0.5)
    ideal[2:5, 0] = 1.4         # frames 7–9 beyond the top
    ideal[8, 2] = -0.2          # frame 13 below the bottom
    fit = retarget_weights(model, ideal, "copy")
    rep = RetargetReport(source="s", method="copy", frames=10)
    rep.record(fit, frames)
    data = rep.to_json()
    assert data["clipped_frames"] == [[7, 9], [13, 13]]
    assert data["frame_range"] == [5, 14]
    assert data["clipping_frames"] == 4
    assert RetargetReport.from_json(data).clipped_frames == [[7, 9], [13, 13]]


# --------------------------------------------------------------------------- the one report contract (#23)
def _clipping_take(n=4, F=40):
    """A weight take that swings beyond [0, 1] on every slider (the bounded space-time solve has work to do)."""
    t = np.linspace(0, 1, F)[:, None]
    return 0.5 + 0.9 * np.sin(2 * np.pi * (2 * t + np.arange(n) / n))


def _early_stop(monkeypatch, max_iter=1):
    """The real space-time solver, stopped after ``max_iter`` outer iterations (a fit that does not converge)."""
    solve = performance.spacetime
    monkeypatch.setattr(performance, "spacetime", lambda *a, **kw: solve(*a, **{**kw, "max_iter": max_iter}))


def test_report_is_a_core_report_with_a_status_enum_and_issue_objects():
    rep = RetargetReport(source="s", method="copy", frames=3)
    assert isinstance(rep, Report) and rep.status is Status.OK and rep.issues == []
    rep = RetargetReport(source="s", method="copy", frames=3, status=1,
                         issues=[Issue("warning", "filled_nan", "filled 2 NaN values")])
    assert rep.status is Status.WARNING and rep.issues[0].code == "filled_nan"


def test_status_ok_warning_from_issues_and_clipping():
    model = _model(n=4)
    inside = np.full((12, 4), 0.5)
    rep = RetargetReport(source="s", method="copy", frames=12)
    rep.record(retarget_weights(model, inside, "copy"), np.arange(12.0))
    assert rep.status is Status.OK and rep.exit_code() == 0 and rep.to_json()["status"] == "ok"
    rep = RetargetReport(source="s", method="copy", frames=12, issues=[Issue("info", "extra_columns", "ignored 2")])
    rep.record(retarget_weights(model, inside, "copy"), np.arange(12.0))
    assert rep.status is Status.WARNING and rep.exit_code() == 0          # flagged, still usable
    rep = RetargetReport(source="s", method="copy", frames=40)
    rep.record(retarget_weights(model, _clipping_take(), "copy"), np.arange(40.0))
    assert rep.clipping_frames > 0 and rep.status is Status.WARNING and rep.exit_code() == 0


def test_a_converged_spacetime_fit_is_ok():
    rep = RetargetReport(source="s", method="spacetime", frames=40)
    rep.record(retarget_weights(_model(n=4), _clipping_take() * 0.4 + 0.3, "spacetime"), np.arange(40.0))
    assert rep.converged is True and rep.solver_message.startswith("converged")
    assert rep.status is Status.OK and exit_code([rep]) == 0


def test_a_spacetime_fit_that_did_not_converge_is_not_converged_and_exits_1(monkeypatch):
    _early_stop(monkeypatch)
    fit = retarget_weights(_model(n=4), _clipping_take(), "spacetime")
    assert fit.solver.status == Status.NOT_CONVERGED                      # the real solver, stopped early
    rep = RetargetReport(source="s", method="spacetime", frames=40)
    rep.record(fit, np.arange(40.0))
    assert rep.status is Status.NOT_CONVERGED and rep.converged is False
    assert rep.solver_message == fit.solver.message == "iteration limit reached"
    assert rep.exit_code() == 1
    ok = RetargetReport(source="t", method="copy", frames=3)
    assert exit_code([ok, rep]) == 1 and exit_code([ok]) == 0


def test_json_is_readable_and_reads_back():
    rep = RetargetReport(source="a.csv", method="spacetime", frames=10, solver_iterations=4,
                         solver_message="iteration limit reached", converged=False, clipping_frames=2,
                         issues=[Issue("warning", "timecode_gap", "2 gaps in the timecode", ("a.csv",))])
    rep.settle_status()
    data = json.loads(json.dumps(rep.to_json()))
    assert list(data)[:5] == ["source", "method", "frames", "status", "issues"]
    assert data["status"] == "not_converged" and data["solver_message"] == "iteration limit reached"
    assert data["issues"] == [{"severity": "warning", "code": "timecode_gap", "message": "2 gaps in the timecode",
                               "items": ["a.csv"]}]
    back = RetargetReport.from_json(data)
    assert back.status is Status.NOT_CONVERGED and back.issues == rep.issues and back.converged is False


def test_reports_without_a_status_settle_it_from_their_fields():
    # the report kept on a Key has no status and no issues: settled from converged / clipping
    assert RetargetReport.from_json({"source": "s", "converged": False}).status is Status.NOT_CONVERGED
    assert RetargetReport.from_json({"source": "s", "clipping_frames": 3}).status is Status.WARNING
    assert RetargetReport.from_json({"source": "s", "clipping_frames": 0, "converged": True}).status is Status.OK
    # a ShapeSpace 0.1 report: "status" was the solver's message, issues plain text
    old = RetargetReport.from_json({"source": "s", "status": "converged", "converged": True, "issues": ["x"]})
    assert old.solver_message == "converged" and old.status is Status.WARNING
    assert old.issues == [Issue("warning", "retarget", "x")]
