"""core.rig: control sets and the bounded regularised LM solve on smooth nonlinear toy rigs.

References: the analytic answers of the toy rigs (targets made by the rig itself at known controls) and
``scipy.optimize.least_squares`` (trf, with bounds) on the same objective, written here independently.
"""
import numpy as np
import pytest
from scipy.optimize import least_squares, lsq_linear

from core.result import ShapeSpaceError, Status
from core.rig import (
    Channel,
    ChannelKind,
    ControlSet,
    broyden_update,
    finite_difference_jacobian,
    quaternion_from_rotation_vector,
    rotation_vector_from_quaternion,
    solve_controls,
)
from core.rig.solve import box_qp_primal


# --------------------------------------------------------------------------- toy rigs
def _rot(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class TwoBoneChain:
    """A planar two-bone chain (lengths 1 and 0.8, joints at the origin and x = 1) skinning a ribbon of points
    with linear blend skinning; controls: the two bone angles (radians) and the root bone's length scale."""

    def __init__(self, n_points=24):
        x = np.linspace(0.05, 1.75, n_points)
        y = np.where(np.arange(n_points) % 2 == 0, 0.05, -0.05)
        self.rest = np.stack([x, y, np.zeros(n_points)], 1)
        w2 = 1.0 / (1.0 + np.exp(-(x - 1.0) / 0.08))           # smooth blend around the elbow
        self.w = np.stack([1.0 - w2, w2], 1)

    def __call__(self, c):
        a1, a2, s1 = c
        R1 = _rot(a1)
        S1 = np.diag([s1, 1.0, 1.0])
        p1 = self.rest @ (R1 @ S1).T                             # bone 1: scale along it, rotate about the root
        elbow = R1 @ np.array([s1, 0.0, 0.0])
        p2 = (self.rest - [1.0, 0.0, 0.0]) @ (R1 @ _rot(a2)).T + elbow
        return self.w[:, :1] * p1 + self.w[:, 1:] * p2


class DriverCurveRig:
    """Two shape keys driven through nonlinear driver curves of one control each, plus an in-between-like
    smooth bump on the first: w0 = sin(1.3 c0) + 0.3 c0², w1 = tanh(2 c1) (a linear blendshape model behind)."""

    def __init__(self, p=30, seed=1):
        rng = np.random.default_rng(seed)
        self.base = rng.normal(size=(p, 3))
        self.d = rng.normal(size=(3, p, 3))

    def __call__(self, c):
        w0 = np.sin(1.3 * c[0]) + 0.3 * c[0] ** 2
        w1 = np.tanh(2.0 * c[1])
        bump = np.exp(-((c[0] - 0.5) / 0.2) ** 2)
        return self.base + w0 * self.d[0] + w1 * self.d[1] + bump * self.d[2]


def _scipy_reference(rig, c0, t, lo, hi, mu, s, ref):
    def res(c):
        return np.concatenate([(rig(c) - t).ravel(), np.sqrt(mu) * s * (c - ref)])
    out = least_squares(res, c0, bounds=(lo, hi), method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                        max_nfev=2000)
    return out.x, float(2.0 * out.cost)


# --------------------------------------------------------------------------- control sets
def test_control_set_holds_locked_channels_and_widens_bounds_to_the_current_value():
    cs = ControlSet((Channel("a", ChannelKind.ROTATION, "Arm", 'pose.bones["a"].rotation_euler', 0, -1.0, 1.0),
                     Channel("b", "location", "Arm", 'pose.bones["a"].location', 1, locked=True),
                     Channel("k", "shape_key", "Face", 'data.shape_keys.key_blocks["k"].value', -1, 0.0, 1.0)))
    lo, hi = cs.solve_bounds([1.5, 0.25, 0.5])
    np.testing.assert_array_equal(lo, [-1.0, 0.25, 0.0])
    np.testing.assert_array_equal(hi, [1.5, 0.25, 1.0])
    assert cs.out_of_bounds([1.5, 0.25, 0.5]) == ["a"]
    np.testing.assert_allclose(cs.steps(), [2e-3, 1e-3, 1e-3])
    assert cs.index("k") == 2
    assert cs.with_scales([1.0, 2.0, 3.0]).scale.tolist() == [1.0, 2.0, 3.0]


def test_control_set_refuses_duplicates_bad_bounds_and_non_finite_values_by_name():
    ch = Channel("jaw X", "rotation", "Arm", 'pose.bones["jaw"].rotation_euler', 0)
    with pytest.raises(ShapeSpaceError, match="jaw X") as e:
        ControlSet((ch, Channel("again", "rotation", "Arm", 'pose.bones["jaw"].rotation_euler', 0)))
    assert e.value.code == "duplicate_name"
    with pytest.raises(ShapeSpaceError, match="'bad'") as e:
        Channel("bad", "location", "Arm", "location", 0, 1.0, -1.0)
    assert e.value.code == "range"
    with pytest.raises(ShapeSpaceError, match="jaw X") as e:
        ControlSet((ch,)).vector([np.nan])
    assert e.value.code == "non_finite"
    with pytest.raises(ShapeSpaceError) as e:
        ControlSet(())
    assert e.value.code == "no_channels"


@pytest.mark.parametrize("v", [[0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [1e-9, 0.0, 0.0], [0.0, 3.0, 0.0]])
def test_rotation_vector_round_trips_through_the_quaternion(v):
    q = quaternion_from_rotation_vector(v)
    assert np.isclose(np.linalg.norm(q), 1.0)
    np.testing.assert_allclose(rotation_vector_from_quaternion(q), v, atol=1e-12)
    np.testing.assert_allclose(rotation_vector_from_quaternion(-2.0 * q), v, atol=1e-12)   # sign, norm free
    angle = np.linalg.norm(v)
    assert np.isclose(q[0], np.cos(angle / 2))                                              # analytic


# --------------------------------------------------------------------------- building blocks
def test_finite_difference_jacobian_matches_the_analytic_one_and_steps_into_the_box():
    rig = DriverCurveRig()
    c = np.array([0.2, 1.0])
    J = finite_difference_jacobian(rig, c, [1e-6, 1e-6], [-1.0, -1.0], [1.0, 1.0])      # c1 at its upper bound
    dw0 = 1.3 * np.cos(1.3 * c[0]) + 0.6 * c[0]
    dbump = -2.0 * (c[0] - 0.5) / 0.04 * np.exp(-((c[0] - 0.5) / 0.2) ** 2)
    dw1 = 2.0 / np.cosh(2.0 * c[1]) ** 2
    np.testing.assert_allclose(J[:, 0], (dw0 * rig.d[0] + dbump * rig.d[2]).ravel(), rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(J[:, 1], (dw1 * rig.d[1]).ravel(), rtol=1e-4, atol=1e-6)
    held = finite_difference_jacobian(rig, c, [1e-6, 1e-6], [-1.0, 1.0], [1.0, 1.0])
    assert not held[:, 1].any()                                                          # lo == hi: cannot move


def test_broyden_update_satisfies_the_secant_equation():
    rng = np.random.default_rng(3)
    J = rng.normal(size=(6, 3))
    d, dp = rng.normal(size=3), rng.normal(size=6)
    J2 = broyden_update(J.copy(), d, dp)
    np.testing.assert_allclose(J2 @ d, dp, atol=1e-12)
    orth = np.cross(d, rng.normal(size=3))
    np.testing.assert_allclose(J2 @ orth, J @ orth, atol=1e-12)                          # unchanged off d


# --------------------------------------------------------------------------- solves
@pytest.mark.parametrize("seed", range(5))
def test_two_bone_chain_recovers_random_poses_from_rest(seed):
    rig = TwoBoneChain()
    rng = np.random.default_rng(seed)
    truth = np.array([rng.uniform(-1.0, 1.0), rng.uniform(-1.2, 1.2), rng.uniform(0.8, 1.2)])
    pins = rng.choice(len(rig.rest), 8, replace=False)
    t = rig(truth)[pins]
    res = solve_controls(lambda c: rig(c)[pins], [0.0, 0.0, 1.0], t, lo=[-np.pi, -np.pi, 0.5],
                         hi=[np.pi, np.pi, 1.5], mu=0.0, pin_tol=1e-10)
    assert res.status == Status.OK, res.message
    assert res.pin_error_max <= 1e-10
    np.testing.assert_allclose(rig(res.x)[pins], t, atol=1e-10)                          # the rig, not the model
    np.testing.assert_allclose(res.x, truth, atol=1e-7)                                  # 8 pins fix 3 controls


def test_regularised_solve_matches_scipy_least_squares_on_the_driver_curve_rig():
    rig = DriverCurveRig()
    truth = np.array([0.7, -0.4])
    rng = np.random.default_rng(0)
    t = rig(truth) + rng.normal(scale=0.05, size=rig.base.shape)                        # not reachable exactly
    lo, hi, s, mu = np.array([-1.0, -1.0]), np.array([1.0, 1.0]), np.array([2.0, 3.0]), 1e-2
    res = solve_controls(rig, [0.0, 0.0], t, lo=lo, hi=hi, scale=s, mu=mu, reference=[0.0, 0.0], ftol=1e-14,
                         steps=[1e-7, 1e-7])
    starts = [np.array([a, b]) for a in np.linspace(-0.9, 0.9, 5) for b in np.linspace(-0.9, 0.9, 5)]
    ref_x, ref_f = min((_scipy_reference(rig, x0, t, lo, hi, mu, s, np.zeros(2)) for x0 in starts),
                       key=lambda r: r[1])                                               # the global optimum
    assert res.status == Status.OK, res.message
    assert res.objective <= ref_f * (1 + 1e-9)
    np.testing.assert_allclose(res.x, ref_x, atol=1e-6)
    hist = res.diagnostics["objective_history"]
    assert all(b <= a for a, b in zip(hist, hist[1:]))                                   # never increases
    assert np.isclose(res.objective, hist[-1]) and np.isclose(res.objective_start, hist[0])


def test_bounds_are_active_and_the_solution_is_the_bounded_optimum():
    rig = TwoBoneChain()
    pins = np.arange(0, 24, 3)
    t = rig(np.array([1.2, 0.9, 1.0]))[pins]                                             # a1 beyond its bound
    lo, hi = np.array([-0.5, -2.0, 0.9]), np.array([0.5, 2.0, 1.1])
    res = solve_controls(lambda c: rig(c)[pins], [0.0, 0.0, 1.0], t, lo=lo, hi=hi, mu=1e-8, ftol=1e-14,
                         steps=[1e-7] * 3, max_iter=200)
    ref_x, ref_f = _scipy_reference(lambda c: rig(c)[pins], np.array([0.0, 0.0, 1.0]), t, lo, hi, 1e-8,
                                    np.ones(3), np.array([0.0, 0.0, 1.0]))
    assert res.status == Status.OK, res.message
    assert res.x[0] == 0.5                                                               # exactly on the bound
    assert np.all(res.x >= lo) and np.all(res.x <= hi)
    assert res.objective <= ref_f * (1 + 1e-12)
    np.testing.assert_allclose(res.x, ref_x, atol=1e-5)


def test_locked_channel_stays_put():
    rig = TwoBoneChain()
    pins = np.arange(0, 24, 2)
    t = rig(np.array([0.4, 0.6, 1.1]))[pins]
    res = solve_controls(lambda c: rig(c)[pins], [0.0, 0.0, 1.0], t, lo=[-3.0, -3.0, 1.0], hi=[3.0, 3.0, 1.0],
                         mu=0.0)
    assert res.x[2] == 1.0
    assert res.objective < res.objective_start


def test_supplied_jacobian_is_used_and_cached_jacobian_is_refreshed_before_stopping():
    rig = DriverCurveRig()
    truth = np.array([0.3, 0.5])
    t = rig(truth)
    calls = []

    def jac(c, p):
        calls.append(c.copy())
        return finite_difference_jacobian(rig, c, [1e-7, 1e-7], [-2.0, -2.0], [2.0, 2.0], base=p)

    res = solve_controls(rig, [0.0, 0.0], t, jacobian=jac, mu=0.0, pin_tol=1e-9)
    assert res.status == Status.OK and res.pin_error_max <= 1e-9
    assert res.jacobians == len(calls) >= 1
    stale = np.zeros((t.size, 2))                                                        # a useless cache
    res2 = solve_controls(rig, [0.0, 0.0], t, first_jacobian=stale, mu=0.0, pin_tol=1e-9)
    assert res2.status == Status.OK and res2.jacobians >= 1                              # refreshed, then solved


def test_iteration_limit_is_reported_as_not_converged_with_the_best_iterate():
    rig = TwoBoneChain()
    pins = np.arange(24)
    t = rig(np.array([2.5, -2.0, 1.3]))[pins]
    res = solve_controls(lambda c: rig(c)[pins], [0.0, 0.0, 1.0], t, mu=0.0, max_iter=2, pin_tol=1e-10)
    assert res.status == Status.NOT_CONVERGED
    assert not res.converged and res.iterations == 2
    assert res.objective < res.objective_start
    np.testing.assert_allclose(np.linalg.norm(rig(res.x)[pins] - t, axis=1), res.pin_errors, atol=1e-12)


def test_unreachable_targets_converge_to_a_stationary_point_with_the_residual_reported():
    rig = DriverCurveRig()
    t = rig(np.array([0.2, 0.1])) + 10.0                                                 # far off the rig
    res = solve_controls(rig, [0.0, 0.0], t, lo=[-1.0, -1.0], hi=[1.0, 1.0], mu=0.0, ftol=1e-12)
    ref_x, ref_f = _scipy_reference(rig, np.zeros(2), t, np.array([-1.0, -1.0]), np.array([1.0, 1.0]), 0.0,
                                    np.ones(2), np.zeros(2))
    assert res.status == Status.OK and res.message == "stationary on the bounds"
    assert res.objective <= ref_f * (1 + 1e-9)
    assert res.pin_error_max > 5.0


def test_bad_inputs_are_refused_by_name():
    rig = DriverCurveRig()
    t = rig(np.zeros(2))
    with pytest.raises(ShapeSpaceError, match="outside") as e:
        solve_controls(rig, [2.0, 0.0], t, lo=[-1.0, -1.0], hi=[1.0, 1.0])
    assert e.value.code == "range"
    with pytest.raises(ShapeSpaceError) as e:
        solve_controls(rig, [0.0, 0.0], t[:, :2])
    assert e.value.code == "no_pins"
    with pytest.raises(ShapeSpaceError, match="steps") as e:
        solve_controls(rig, [0.0, 0.0], t, steps=[1e-3, 0.0])
    assert e.value.code == "range"
    with pytest.raises(ShapeSpaceError, match="non-finite") as e:
        solve_controls(lambda c: rig(c) * np.nan, [0.0, 0.0], t)
    assert e.value.code == "non_finite"


def test_rounded_evaluation_stops_at_the_jacobians_resolution_not_at_the_iteration_limit():
    """A rig evaluated in float32-like rounding (quantised to 1e-7): the solve reaches the rounding floor and
    reports OK (stationary to the Jacobian's resolution) well before ``max_iter``."""
    rig = TwoBoneChain()
    pins = np.arange(0, 24, 3)
    t = rig(np.array([0.7, -0.5, 1.05]))[pins]
    res = solve_controls(lambda c: np.round(rig(c)[pins], 7), [0.0, 0.0, 1.0], t, mu=0.0, ftol=1e-300,
                         steps=[1e-4] * 3, max_iter=200)
    assert res.status == Status.OK, res.message
    assert res.iterations < 200
    assert res.pin_error_max <= 1e-5


def test_a_deferred_refresh_stops_on_the_stale_jacobian_and_computes_none():
    """``defer_refresh``: a solve started from a cached Jacobian never recomputes one; where it would (here a
    useless cache: the first step predicts no decrease, or a step is refused or stalls) it stops with the last
    verified controls, says so, and the objective never increased."""
    rig = TwoBoneChain()
    pins = np.arange(24)
    t = rig(np.array([0.9, -0.7, 1.2]))[pins]
    calls = []

    def ev(c):
        calls.append(c.copy())
        return rig(c)[pins]

    good = finite_difference_jacobian(ev, [0.0, 0.0, 1.0], [1e-7] * 3, [-3.0] * 3, [3.0] * 3)
    calls.clear()
    res = solve_controls(ev, [0.0, 0.0, 1.0], t, first_jacobian=good, mu=0.0, pin_tol=1e-9, defer_refresh=True,
                         max_iter=50)
    assert res.jacobians == 0 and res.evaluations == len(calls)          # every evaluation a verified step
    assert res.status == Status.NOT_CONVERGED and res.diagnostics["jacobian_stale"]
    assert "deferred" in res.message
    hist = res.diagnostics["objective_history"]
    assert all(b <= a for a, b in zip(hist, hist[1:])) and res.objective < res.objective_start
    np.testing.assert_allclose(rig(res.x)[pins], res.points, atol=1e-12)
    again = solve_controls(ev, [0.0, 0.0, 1.0], t, first_jacobian=good, mu=0.0, pin_tol=1e-9, max_iter=50)
    assert again.status == Status.OK and again.jacobians >= 1 and not again.diagnostics["jacobian_stale"]
    stale = np.zeros((t.size, 3))
    res2 = solve_controls(ev, [0.0, 0.0, 1.0], t, first_jacobian=stale, mu=0.0, defer_refresh=True)
    assert res2.jacobians == 0 and res2.diagnostics["jacobian_stale"] and res2.iterations == 1
    np.testing.assert_array_equal(res2.x, [0.0, 0.0, 1.0])


@pytest.mark.parametrize("seed", range(6))
def test_the_primal_active_set_box_qp_matches_scipys_bounded_least_squares(seed):
    """Many channels on their bounds (a face at rest: sliders at 0, the gradient pushing about half of them out):
    the primal active-set step equals SciPy's BVLS on the same bounded least-squares problem and satisfies the
    KKT conditions; a channel held still (lo = hi) stays put."""
    rng = np.random.default_rng(seed)
    m, n = 60, 59
    J = rng.normal(size=(m, n)) @ np.diag(rng.uniform(0.05, 2.0, n))
    e = rng.normal(size=m)
    reg = np.full(n, 1e-6)
    lo = np.where(rng.random(n) < 0.7, 0.0, -rng.uniform(0.1, 1.0, n))
    hi = np.where(rng.random(n) < 0.1, 0.0, rng.uniform(0.1, 1.0, n))
    hi[lo == hi] = 0.5
    H, g = J.T @ J + np.diag(reg), -J.T @ e
    x = box_qp_primal(H, g, lo, hi)
    ref = lsq_linear(np.vstack([J, np.diag(np.sqrt(reg))]), np.concatenate([-e, np.zeros(n)]), bounds=(lo, hi),
                     method="bvls", tol=1e-14).x
    assert x is not None and np.all(x >= lo) and np.all(x <= hi)
    np.testing.assert_allclose(x, ref, atol=1e-6)
    mult = g - H @ x                                            # KKT: no free entry, no held entry pushing in
    tol = 1e-8 * np.abs(g).max()
    free = (x > lo + 1e-12) & (x < hi - 1e-12)
    np.testing.assert_allclose(mult[free], 0.0, atol=tol)
    assert np.all(mult[x <= lo + 1e-12] <= tol) and np.all(mult[x >= hi - 1e-12] >= -tol)
    lo[0] = hi[0] = 0.0
    held = box_qp_primal(H, g, lo, hi)
    assert held[0] == 0.0 and np.all(held >= lo) and np.all(held <= hi)


def test_a_deferring_move_takes_the_gauss_newton_step_its_stopping_test_computed():
    """A deferring solve on a cached Jacobian stops at the first refused step, so its λ never grows: its one
    verified step (a mouse move) is the bounded Gauss–Newton step the ``xtol`` test computed.  On a linear rig
    with its exact Jacobian that step lands on the bounded least-squares optimum (SciPy's) in one evaluation."""
    rng = np.random.default_rng(5)
    A = rng.normal(size=(18, 7)) * np.array([1.0, 1e-2, 3.0, 0.5, 1e-3, 2.0, 1.0])      # ill-conditioned columns
    b = rng.normal(size=18)
    t = rng.normal(size=(6, 3)) * 2.0
    lo, hi = -np.full(7, 0.4), np.full(7, 0.4)
    calls = []

    def ev(c):
        calls.append(c.copy())
        return (A @ c + b).reshape(6, 3)

    p0 = ev(np.zeros(7))
    calls.clear()
    res = solve_controls(ev, np.zeros(7), t, lo=lo, hi=hi, first_jacobian=A, first_points=p0, mu=0.0,
                         defer_refresh=True, max_iter=1, xtol=1e-12)
    best = lsq_linear(A, t.reshape(-1) - b, bounds=(lo, hi), method="bvls", tol=1e-14)
    assert res.evaluations == len(calls) == 1 and res.jacobians == 0
    assert np.any(np.isclose(np.abs(best.x), 0.4))                      # some bounds active
    np.testing.assert_allclose(res.x, best.x, atol=1e-7)
    assert res.objective <= 2 * best.cost * (1 + 1e-9)
