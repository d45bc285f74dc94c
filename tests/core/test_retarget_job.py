"""core.retarget.job: the middle step of a retarget job, from a plan read out of Blender to the curves to write (#23).

References are independent of the code under test: exact geometry gives back the weights it was made from
(analytic), a bounded per-frame fit is checked against ``scipy.optimize.lsq_linear`` (BVLS), linear keys are
re-evaluated with ``np.interp`` and smooth keys with ``scipy.interpolate.CubicHermiteSpline`` at every frame.
"""
import numpy as np
import pytest
from scipy.interpolate import CubicHermiteSpline
from scipy.optimize import lsq_linear

from core.blendshape import BlendshapeModel
from core.headpose import BoneSpec
from core.progress import Cancelled
from core.result import ShapeSpaceError, Status
from core.retarget import RetargetReport, performance, split_mapping
from core.retarget.job import (
    LANDMARK_PREFIX,
    RetargetPlan,
    check_landmark_pairs,
    check_settings,
    compute_retarget,
    dense_positions,
    plan_curves,
    written_range,
)
from core.retarget.performance import normalised_basis


def _model(n=4, p=12, seed=0, lo=0.0, hi=1.0):
    rng = np.random.default_rng(seed)
    return BlendshapeModel(neutral=rng.normal(size=(p, 3)), deltas=rng.normal(size=(n, p, 3)),
                           names=[f"K{k}" for k in range(n)], slider_min=np.full(n, lo), slider_max=np.full(n, hi),
                           values=np.zeros(n))


def _take(F=40, n=4, centre=0.5, amplitude=0.3, seed=1):
    t = np.linspace(0, 1, F)[:, None]
    phase = np.random.default_rng(seed).uniform(0, 1, n)
    return centre + amplitude * np.sin(2 * np.pi * (1.5 * t + phase))


def _plan(model, method, frames, *, source=None, mapping=None, raw=None, dense=None, key_tolerance=0.0,
          key_shape="BEZIER", lam=1e-7, bones=None, rotations=None, bone_paths=None):
    report = RetargetReport(source="take", method=method, frames=int(len(frames)))
    plan = RetargetPlan("Face", method, lam, key_tolerance, key_shape, "Face_take", True, model,
                        [f'key_blocks["{n}"].value' for n in model.names], np.asarray(frames, dtype=np.float64),
                        report, ("OBJECT", model.n_vertices, ()), raw=raw, dense=dense, bones=bones,
                        rotations=rotations, bone_paths=bone_paths)
    if source is not None:
        plan.pairs, plan.gain, plan.offset = split_mapping(mapping, model.n_targets)
        plan.source_weights = source
    return plan


# --------------------------------------------------------------------------- the fit
def test_perframe_on_exact_geometry_gives_back_the_copied_weights():
    model = _model()
    W = _take()
    source = W[:, ::-1] * 2.0                    # source channels reversed, at half the target's scale
    mapping = [(3 - j, j, 0.5, 0.0) for j in range(4)]
    frames = np.arange(101.0, 141.0)
    out = compute_retarget(_plan(model, "perframe", frames, source=source, mapping=mapping))
    np.testing.assert_allclose(out.weights, W, atol=1e-5)              # inside the ranges: exact (but the 1e-6 ridge)
    rep = out.report
    assert rep.clipping_frames == 0 and rep.frame_range == [101, 140] and rep.position_error_rms < 1e-5
    assert rep.status is Status.OK and rep.solver_message is None
    for (path, x, y, slopes), name, j in zip(out.curves, model.names, range(4)):
        assert path == f'key_blocks["{name}"].value' and slopes is None
        np.testing.assert_array_equal(x, frames)
        np.testing.assert_array_equal(y, out.weights[:, j])


def test_bounded_perframe_fit_matches_scipy_bvls_frame_by_frame():
    model = _model(seed=4)
    raw = _take(F=25, amplitude=0.9, seed=5)                            # swings beyond [0, 1]
    out = compute_retarget(_plan(model, "perframe", np.arange(25.0), raw=raw))
    B, b0, _ = normalised_basis(model)
    a = 1e-6 * np.trace(B.T @ B) / B.shape[1]                           # fit_frames' documented ridge
    A = np.vstack([B, np.sqrt(a) * np.eye(B.shape[1])])
    for f in range(25):
        rhs = np.concatenate([B @ raw[f], np.zeros(B.shape[1])])
        ref = lsq_linear(A, rhs, bounds=(0.0, 1.0), method="bvls", tol=1e-14).x
        np.testing.assert_allclose(out.weights[f], ref, atol=1e-8)
    assert out.report.clipping_frames == int(np.any((raw < 0) | (raw > 1), axis=1).sum()) > 0
    assert out.report.status is Status.WARNING                          # clipped frames are flagged


def test_spacetime_within_the_ranges_follows_exact_geometry_and_converges():
    model = _model(seed=2)
    W = _take(seed=3)
    out = compute_retarget(_plan(model, "spacetime", np.arange(40.0), raw=W, lam=1e-9))
    np.testing.assert_allclose(out.weights, W, atol=1e-4)
    assert out.report.converged is True and out.report.status is Status.OK


def test_spacetime_stopped_at_its_iteration_limit_is_not_converged(monkeypatch):
    solve = performance.spacetime
    monkeypatch.setattr(performance, "spacetime", lambda *a, **kw: solve(*a, **{**kw, "max_iter": 1}))
    model = _model(seed=2)
    out = compute_retarget(_plan(model, "spacetime", np.arange(40.0), raw=_take(amplitude=0.9, seed=3)))
    rep = out.report
    assert rep.converged is False and rep.solver_message == "iteration limit reached"
    assert rep.status is Status.NOT_CONVERGED and rep.exit_code() == 1
    assert np.all(out.weights >= -1e-12) and np.all(out.weights <= 1 + 1e-12)    # the last iterate, in range


def test_dense_performance_of_the_same_topology_gives_back_its_weights():
    model = _model(seed=6, p=15)
    W = _take(F=20, seed=7)
    seq = (model.neutral + np.einsum("fn,npc->fpc", W, model.deltas)).copy()
    dense = {"seq": seq, "rest": model.neutral.copy(), "stable": np.zeros(0, dtype=int),
             "src_lm": np.zeros(0, dtype=int), "dst_lm": np.zeros(0, dtype=int)}
    out = compute_retarget(_plan(model, "perframe", np.arange(1.0, 21.0), dense=dense))
    np.testing.assert_allclose(out.weights, W, atol=1e-5)                # exact (but the 1e-6 ridge)
    assert out.report.status is Status.OK


def test_dense_positions_refuses_other_topology_without_three_landmarks():
    model = _model(p=15)
    dense = {"seq": np.zeros((3, 9, 3)), "rest": np.zeros((9, 3)), "stable": np.zeros(0, dtype=int),
             "src_lm": np.array([0, 1]), "dst_lm": np.array([0, 1])}
    with pytest.raises(ShapeSpaceError, match=f"at least 3 landmark pairs .*'{LANDMARK_PREFIX}…'.*found 2"):
        dense_positions(dense, model)
    check_landmark_pairs(15, 15, 0)                                     # same topology: vertex to vertex
    check_landmark_pairs(9, 15, 3)
    with pytest.raises(ShapeSpaceError, match="found 0"):
        check_landmark_pairs(9, 15, 0)


# --------------------------------------------------------------------------- the curves
@pytest.mark.parametrize("key_shape", ["LINEAR", "BEZIER"])
def test_reduced_curves_reproduce_the_weights_within_the_tolerance(key_shape):
    model = _model(seed=8)
    W = _take(F=120, seed=9)
    frames = np.arange(1.0, 121.0)
    tol = 0.01
    out = compute_retarget(_plan(model, "copy", frames, raw=W, key_tolerance=tol, key_shape=key_shape))
    keys = 0
    for j, (_, x, y, slopes) in enumerate(out.curves):
        if key_shape == "LINEAR":
            assert slopes is None
            back = np.interp(frames, x, y)
        else:
            back = CubicHermiteSpline(x, y, slopes)(frames)
        assert np.max(np.abs(back - out.weights[:, j])) <= tol * (1 + 1e-9)
        assert x[0] == frames[0] and x[-1] == frames[-1]
        keys += len(x)
    assert out.report.keys_kept_frac == pytest.approx(keys / W.size) and keys < W.size / 3
    assert written_range(out.curves) == (1.0, 120.0)


def test_plan_curves_refuses_non_finite_keys_naming_the_curve():
    W = np.zeros((5, 2))
    W[3, 1] = np.nan
    with pytest.raises(ShapeSpaceError, match="the keys of 'B' came out NaN"):
        plan_curves(["A", "B"], ["a", "b"], np.arange(5.0), W, 0.0, "LINEAR")
    with pytest.raises(ShapeSpaceError, match="key shape must be one of"):
        plan_curves(["A"], ["a"], np.arange(5.0), np.zeros((5, 1)), 0.0, "STEP")


def test_written_range_of_nothing_is_none():
    assert written_range([]) is None and written_range([("a", np.zeros(0), np.zeros(0), None)]) is None


def test_settings_are_checked():
    assert check_settings(1e-7, 0.0, "LINEAR") == (1e-7, 0.0)
    for bad in [(0.0, 0.0, "BEZIER"), (1e-7, -1.0, "BEZIER"), (1e-7, float("nan"), "BEZIER"), (1e-7, 0.0, "x")]:
        with pytest.raises(ShapeSpaceError):
            check_settings(*bad)


# --------------------------------------------------------------------------- progress and bones
def test_progress_rises_to_one_and_cancel_stops_the_job():
    model = _model()
    seen = []
    compute_retarget(_plan(model, "spacetime", np.arange(60.0), raw=_take(F=60), key_tolerance=0.01), seen.append)
    assert seen[-1] == 1.0 and all(b >= a - 1e-12 for a, b in zip(seen, seen[1:])) and len(seen) > 3

    def cancel(fraction):
        if fraction > 0.5:
            raise Cancelled()
    with pytest.raises(Cancelled):
        compute_retarget(_plan(model, "spacetime", np.arange(60.0), raw=_take(F=60), key_tolerance=0.01), cancel)


def test_bone_curves_follow_the_plans_paths_and_a_mismatch_is_refused():
    model = _model()
    bone = BoneSpec("head", "head", 1.0, np.eye(3), "XYZ")
    rotations = np.zeros((10, 9))
    rotations[:, 0] = np.linspace(0.0, 0.3, 10)                        # head yaw
    paths = [('pose.bones["head"].rotation_euler', i, "head") for i in range(3)]
    out = compute_retarget(_plan(model, "copy", np.arange(10.0), raw=np.full((10, 4), 0.5), bones=[bone],
                                 rotations=rotations, bone_paths=paths))
    assert [(p, i, b) for p, i, b, *_ in out.bone_curves] == paths
    assert all(np.array_equal(x, np.arange(10.0)) for _, _, _, x, _, _ in out.bone_curves)
    turned = [np.ptp(y) for *_, y, _ in out.bone_curves]
    assert max(turned) > 0.1                                            # the head turns about one axis
    with pytest.raises(ShapeSpaceError, match="2 bone curves for 3 bone channels"):
        compute_retarget(_plan(model, "copy", np.arange(10.0), raw=np.full((10, 4), 0.5), bones=[bone],
                               rotations=rotations, bone_paths=paths[:2]))
