"""core.rig.take: per-frame retarget of a take onto a nonlinear toy rig's controls.

References: the controls that generated the take (the rig's own smooth curves), an independent per-frame
``scipy.optimize.least_squares`` on the regularised objective, and ``core.retarget.perframe.fit_frames`` on a
linear rig (the shape-key per-frame retarget the rig take generalises).
"""
import numpy as np
import pytest
from scipy.optimize import least_squares

from core.progress import Cancelled
from core.result import Status
from core.retarget.perframe import fit_frames
from core.rig import finite_difference_jacobian, solve_controls, solve_take, take_report
from test_rig_solve import DriverCurveRig, TwoBoneChain


def _smooth_curves(rng, frames, lo, hi):
    """Random smooth control curves (sums of a few low-frequency sines) inside [lo, hi]."""
    t = np.linspace(0.0, 1.0, frames)[:, None]
    n = lo.size
    u = sum(np.sin(2 * np.pi * (k + 1) * t * rng.uniform(0.3, 1.0, n) + rng.uniform(0, 6, n)) / (k + 1)
            for k in range(3))
    u = 0.5 + 0.45 * u / np.abs(u).max(0)
    return lo + u * (hi - lo)


class Counting:
    def __init__(self, rig):
        self.rig, self.calls = rig, 0

    def __call__(self, c):
        self.calls += 1
        return self.rig(c)


def test_take_made_by_the_rig_is_recovered_with_few_evaluations_per_frame():
    rig = Counting(TwoBoneChain())
    lo, hi = np.array([-0.6, -0.8, 0.8]), np.array([0.6, 0.8, 1.2])
    truth = _smooth_curves(np.random.default_rng(4), 40, lo, hi)
    targets = np.stack([rig.rig(c) for c in truth])
    res = solve_take(rig, np.array([0.0, 0.0, 1.0]), targets, lo=lo, hi=hi, reg=0.0, pin_tol=1e-9, max_iter=30)
    assert res.status == Status.OK, res.message
    np.testing.assert_allclose(res.controls, truth, atol=1e-6)
    assert res.rms.max() <= 1e-9
    assert res.jacobians < 40 / 4                    # the Jacobian is carried over and Broyden-updated
    assert rig.calls == res.evaluations and res.evaluations < 40 * 8


def test_each_frame_matches_an_independent_regularised_least_squares():
    rig = DriverCurveRig()
    lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    rng = np.random.default_rng(2)
    truth = _smooth_curves(rng, 12, lo, hi)
    targets = np.stack([rig(c) for c in truth]) + rng.normal(scale=0.05, size=(12,) + rig.base.shape)
    s = np.array([2.0, 0.5])
    reg, smooth = 1e-2, 0.5
    res = solve_take(rig, np.zeros(2), targets, lo=lo, hi=hi, scale=s, reg=reg, smooth=smooth, max_iter=200,
                     steps=np.full(2, 1e-7))
    assert res.status == Status.OK, res.message
    unit = res.diagnostics["ridge_unit"]
    prev = np.zeros(2)
    for f in range(12):
        wr, ws = reg * unit * s * s, (smooth * unit * s * s if f else 0.0)

        def resid(c, f=f, wr=wr, ws=ws, prev=prev):
            return np.concatenate([(rig(c) - targets[f]).ravel(), np.sqrt(wr) * c, np.sqrt(ws) * (c - prev)])

        ref = least_squares(resid, res.controls[f], bounds=(lo, hi), xtol=1e-15, ftol=1e-15, gtol=1e-15)
        np.testing.assert_allclose(res.controls[f], ref.x, atol=2e-5)
        prev = res.controls[f]


def test_ridge_has_the_shape_key_per_frame_semantics_on_a_linear_rig():
    """On a linear rig with equal natural scales the take is exactly fit_frames (same ridge, same bounds)."""
    rng = np.random.default_rng(5)
    B = rng.normal(size=(60, 4))
    b0 = rng.normal(size=60)
    W = rng.uniform(-0.2, 1.2, size=(15, 4))
    frames = W @ B.T + b0 + rng.normal(scale=0.1, size=(15, 60))
    reg = 1e-2
    ref = fit_frames(B, b0, frames, 0.0, 1.0, reg)

    def evaluate(c):
        return (B @ c + b0).reshape(-1, 3)

    res = solve_take(evaluate, np.zeros(4), frames.reshape(15, -1, 3), lo=np.zeros(4), hi=np.ones(4), reg=reg,
                     jacobian=lambda c, p: B, max_iter=50)
    np.testing.assert_allclose(res.controls, ref, atol=1e-7)


def test_smoothness_pulls_toward_the_previous_frame():
    rig = DriverCurveRig()
    lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    rng = np.random.default_rng(8)
    truth = _smooth_curves(rng, 20, lo, hi)
    targets = np.stack([rig(c) for c in truth]) + rng.normal(scale=0.3, size=(20,) + rig.base.shape)
    rough = solve_take(rig, np.zeros(2), targets, lo=lo, hi=hi, max_iter=100).controls
    smooth = solve_take(rig, np.zeros(2), targets, lo=lo, hi=hi, smooth=5.0, max_iter=100).controls
    assert np.abs(np.diff(smooth, axis=0)).sum() < 0.8 * np.abs(np.diff(rough, axis=0)).sum()


def test_frames_at_the_iteration_limit_make_the_take_not_converged_and_are_listed():
    rig = TwoBoneChain()
    lo, hi = np.array([-0.6, -0.8, 0.8]), np.array([0.6, 0.8, 1.2])
    truth = _smooth_curves(np.random.default_rng(1), 6, lo, hi)
    targets = np.stack([rig(c) for c in truth])
    res = solve_take(rig, np.array([0.0, 0.0, 1.0]), targets, lo=lo, hi=hi, pin_tol=1e-14, max_iter=1)
    assert res.status == Status.NOT_CONVERGED
    bad = np.flatnonzero(res.frame_status != Status.OK)
    assert bad.size
    report = take_report(res, np.arange(101, 107), ["a1", "a2", "s1"])
    assert report.status == Status.NOT_CONVERGED and report.exit_code() == 1
    assert report.not_converged == [int(101 + i) for i in bad]
    assert report.issues[0].items == tuple(str(101 + i) for i in bad)
    assert report.to_json()["status"] == "not_converged"


def test_progress_is_reported_per_frame_and_cancel_stops_the_take():
    rig = TwoBoneChain()
    targets = np.stack([rig(np.array([0.1 * k, 0.0, 1.0])) for k in range(5)])
    seen = []
    solve_take(rig, np.array([0.0, 0.0, 1.0]), targets, progress=seen.append)
    assert seen[0] == 0.0 and seen[-1] == 1.0 and len(seen) >= 6

    def cancel(fraction):
        if fraction >= 0.4:
            raise Cancelled()

    with pytest.raises(Cancelled):
        solve_take(rig, np.array([0.0, 0.0, 1.0]), targets, progress=cancel)


def test_bad_targets_are_refused_by_name():
    rig = TwoBoneChain()
    t = np.stack([rig(np.array([0.0, 0.0, 1.0]))] * 3)
    t[2, 5, 1] = np.nan
    with pytest.raises(ValueError, match="frame 2 point 5"):
        solve_take(rig, np.array([0.0, 0.0, 1.0]), t)
    with pytest.raises(ValueError, match="smooth"):
        solve_take(rig, np.array([0.0, 0.0, 1.0]), t[:2], smooth=-1.0)


def test_solve_returns_its_last_jacobian_and_xtol_stops_without_a_refresh():
    rig = TwoBoneChain()
    lo, hi = np.array([-0.6, -0.8, 0.8]), np.array([0.6, 0.8, 1.2])
    c0 = np.array([0.0, 0.0, 1.0])
    t = rig(np.array([0.3, -0.2, 1.1]))
    res = solve_controls(rig, c0, t, lo=lo, hi=hi, mu=0.0, steps=np.full(3, 1e-7))
    assert res.status == Status.OK
    exact = finite_difference_jacobian(rig, res.x, np.full(3, 1e-7), lo, hi)
    np.testing.assert_allclose(res.jacobian, exact, atol=1e-4 * np.abs(exact).max())
    t2 = rig(np.array([0.31, -0.21, 1.1]))
    near = solve_controls(rig, res.x, t2, lo=lo, hi=hi, mu=0.0, first_jacobian=res.jacobian,
                          first_points=res.points, xtol=1e-8)
    assert near.status == Status.OK and near.jacobians == 0          # the carried Jacobian sufficed
    assert near.pin_error_max <= 1e-6
