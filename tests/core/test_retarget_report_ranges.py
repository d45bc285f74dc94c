"""core.retarget.report: clipped frames as runs of scene frames, and the report's JSON keys (#12 Build 3)."""
import numpy as np
import pytest

from core.blendshape import BlendshapeModel
from core.retarget.metrics import clipping_frames
from core.retarget.performance import retarget_weights
from core.retarget.report import RetargetReport, clipped_mask, format_ranges, frame_ranges


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


def test_clipped_mask_counts_what_metrics_counts():
    rng = np.random.default_rng(1)
    W = rng.uniform(-0.3, 1.3, size=(50, 4))
    lo, hi = np.zeros(4), np.ones(4)
    mask = clipped_mask(W, lo, hi)
    assert mask.sum() == clipping_frames(W, lo, hi)
    assert np.array_equal(mask, ((W < 0) | (W > 1)).any(axis=1))


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
