"""core.retarget beyond the solvers' end results: the space-time system's parts, whole-performance fits,
metrics, the report, dense transfer and learned cloning (thesis 3.5, ch. 5).

References are built here independently: the explicit Kronecker operator of the whitened space-time
problem (dense numpy), explicit per-frame loops for the metrics, known similarities and linear maps.
"""
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from core.blendshape import BlendshapeModel, normalised_unit
from core.result import Result, ShapeSpaceError, Status
from core.retarget import (
    RetargetReport,
    SpacetimeResult,
    SpacetimeSystem,
    clipped_mask,
    fit_frames,
    learned_cloning,
    position_error_rms,
    retarget_positions,
    retarget_weights,
    slider_scales,
    spacetime,
    stabilise,
    suggest_key_frames,
    transfer_motion,
    velocity_error_rms,
)
from core.retarget.spacetime_solver import banded_step, capacitance_step, cg_step


def _system_problem(seed=3, F=14, n=3, m3=9, lam=1e-2):
    rng = np.random.default_rng(seed)
    B = rng.standard_normal((m3, n))
    sigma = rng.uniform(0.5, 2.0, n)
    return rng, B, sigma, lam, SpacetimeSystem(B, sigma, lam, F)


def _dense_operator(B, sigma, lam, F):
    """Σ K_II Σ with K_II = (DᵀD ⊗ BᵀB + λ I ⊗ diag(1/σ²)) on the interior frames, row-major (t·n + k)."""
    D = sp.diags([-np.ones(F - 1), np.ones(F - 1)], [0, 1], shape=(F - 1, F)).toarray()
    DtD = (D.T @ D)[1:-1, 1:-1]
    K = np.kron(DtD, B.T @ B) + lam * np.kron(np.eye(F - 2), np.diag(1.0 / sigma ** 2))
    S = np.kron(np.eye(F - 2), np.diag(sigma))
    return S @ K @ S


# --------------------------------------------------------------------------- the factored system
def test_system_apply_and_solve_match_the_dense_kronecker_operator():
    rng, B, sigma, lam, system = _system_problem()
    F, n = 14, 3
    H = _dense_operator(B, sigma, lam, F)
    Y = rng.standard_normal((F - 2, n))
    np.testing.assert_allclose(system.apply(Y).ravel(), H @ Y.ravel(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(system.solve(Y).ravel(), np.linalg.solve(H, Y.ravel()), rtol=1e-10, atol=1e-12)


def test_system_capacitance_is_the_inverse_restricted_to_the_active_entries():
    rng, B, sigma, lam, system = _system_problem(seed=4, F=11, n=4)
    H_inv = np.linalg.inv(_dense_operator(B, sigma, lam, 11))
    active = np.sort(rng.choice(9 * 4, size=7, replace=False))
    np.testing.assert_allclose(system.capacitance(active), H_inv[np.ix_(active, active)], rtol=1e-9, atol=1e-12)
    assert system.green is not None                                  # the tables are kept for the next call
    again = system.capacitance(active[:3])
    np.testing.assert_allclose(again, H_inv[np.ix_(active[:3], active[:3])], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("route", ["capacitance", "banded", "cg"])
def test_every_step_route_solves_the_reduced_newton_system(route):
    rng, B, sigma, lam, system = _system_problem(seed=5, F=12, n=3)
    H = _dense_operator(B, sigma, lam, 12)
    r = rng.standard_normal((10, 3))
    act = rng.uniform(size=(10, 3)) < 0.3
    free = ~act.ravel()
    want = np.zeros(30)
    want[free] = np.linalg.solve(H[np.ix_(free, free)], r.ravel()[free])
    if route == "capacitance":
        d = capacitance_step(system, np.flatnonzero(act), r)
    elif route == "banded":
        d = banded_step(system, ~act, r, 1.0)
    else:
        d = cg_step(system, ~act, np.where(act, 0.0, r), 0.0, 1.0)
    np.testing.assert_array_equal(d[act], 0.0)
    np.testing.assert_allclose(d.ravel(), want, rtol=1e-8, atol=1e-10)


def test_spacetime_result_is_a_result_and_reports_the_iteration_limit():
    rng = np.random.default_rng(7)
    F, n, m3 = 60, 5, 15
    B = rng.standard_normal((m3, n))
    b0 = rng.standard_normal(m3)
    t = np.linspace(0, 1, F)[:, None]
    W = 2.5 * (0.5 + 0.4 * np.sin(2 * np.pi * rng.uniform(0.5, 2, n) * t + rng.uniform(0, 6, n)))
    S = b0 + W @ B.T + 0.05 * rng.standard_normal((F, m3))
    sigma = rng.uniform(0.3, 2.0, n)
    lo, hi = np.full(n, -0.2), np.full(n, 0.6)
    full = spacetime(B, b0, S, sigma, 1e-3, lo=lo, hi=hi)
    assert isinstance(full, (SpacetimeResult, Result)) and full.status == Status.OK and full.converged
    assert full.weights is full.value and full.weights.shape == (F, n)
    short = spacetime(B, b0, S, sigma, 1e-3, lo=lo, hi=hi, max_iter=1)
    assert short.status == Status.NOT_CONVERGED and not short.converged
    assert np.all(short.weights >= lo) and np.all(short.weights <= hi)       # still within the bounds


@pytest.mark.parametrize("kwargs, code", [
    ({"lo": np.ones(2), "hi": np.zeros(2)}, "infeasible"),
    ({"frames": np.zeros((5, 7))}, "shape"),
    ({"frames": np.full((5, 6), np.nan)}, "non_finite"),
    ({"sigma": np.ones(3)}, "shape"),
    ({"tol": 0.0, "lo": np.zeros(2)}, "range"),
])
def test_spacetime_bad_input(kwargs, code):
    rng = np.random.default_rng(8)
    args = {"B": rng.standard_normal((6, 2)), "neutral": np.zeros(6), "frames": rng.standard_normal((5, 6)),
            "sigma": np.ones(2)}
    args.update(kwargs)
    with pytest.raises(ShapeSpaceError) as exc:
        spacetime(**args)
    assert exc.value.code == code


# --------------------------------------------------------------------------- metrics and the report
def test_metrics_are_per_frame_whole_mesh_norms():
    rng = np.random.default_rng(9)
    R = rng.standard_normal((12, 5, 3))
    size = 2.5
    pos = np.sqrt(np.mean([np.sum(R[f] ** 2) for f in range(12)])) / size
    vel = np.sqrt(np.mean([np.sum((R[f + 1] - R[f]) ** 2) for f in range(11)])) / size
    assert position_error_rms(R, size) == pytest.approx(pos, rel=1e-14)
    assert position_error_rms(R.reshape(12, -1), size) == pytest.approx(pos, rel=1e-14)
    assert velocity_error_rms(R, size) == pytest.approx(vel, rel=1e-14)
    W = np.array([[0.5, 0.5], [1.2, 0.0], [0.5, -1e-10], [0.5, -1e-8]])
    assert clipped_mask(W, np.zeros(2), np.ones(2)).sum() == 2
    assert clipped_mask(W, np.zeros(2), np.ones(2), tol=1e-6).sum() == 1
    flat = np.column_stack([W[:, 0], np.full(4, 0.3)])                 # a still slider: σ at the floor
    np.testing.assert_allclose(slider_scales(flat, np.zeros(2), np.full(2, 2.0)), [W[:, 0].std(), 0.1], rtol=1e-14)


def test_report_json_keeps_only_the_fields_that_apply():
    rep = RetargetReport(source="a.csv", method="copy", frames=10, issues=["x"], mapped_channels=3,
                         position_error_rms=float("nan"), velocity_error_rms=0.1, clipping_frames=0, action="A")
    data = rep.to_json()
    assert set(data) == {"source", "method", "frames", "status", "issues", "mapped_channels", "position_error_rms",
                         "velocity_error_rms", "clipping_frames", "action", "previous_action"}
    assert data["position_error_rms"] is None                              # NaN → null
    assert rep["action"] == "A" and rep.get("converged") is None and "converged" not in rep
    with pytest.raises(KeyError):
        rep["solver_iterations"]
    back = RetargetReport.from_json({**data, "schema_version": 1})
    assert back.action == "A" and back.mapped_channels == 3 and back.converged is None


# --------------------------------------------------------------------------- whole performances
def _tiny_model(rng, p=20, n=3):
    neutral = rng.standard_normal((p, 3))
    deltas = rng.standard_normal((n, p, 3)) * 0.2
    return BlendshapeModel(neutral, deltas, [f"k{i}" for i in range(n)])


def test_retarget_weights_copy_clips_and_fits_follow_representable_motion():
    rng = np.random.default_rng(10)
    model = _tiny_model(rng)
    F = 30
    t = np.linspace(0, 1, F)[:, None]
    inside = 0.5 + 0.3 * np.sin(2 * np.pi * t + np.arange(3))
    copy = retarget_weights(model, inside + 0.5, "copy")
    np.testing.assert_array_equal(copy.weights, np.clip(inside + 0.5, 0, 1))
    assert copy.clipping_frames > 0 and copy.solver is None
    residual = (copy.weights - (inside + 0.5)) @ model.delta_matrix.T
    assert copy.position_error_rms == pytest.approx(position_error_rms(residual, model.scale), rel=1e-14)
    for method in ("perframe", "spacetime"):
        fit = retarget_weights(model, inside, method, lam=1e-9)
        np.testing.assert_allclose(fit.weights, inside, rtol=0, atol=1e-5)
        assert fit.clipping_frames == 0 and fit.position_error_rms < 1e-5
    assert fit.solver is not None and fit.solver.status == Status.OK


def test_retarget_positions_matches_the_weights_path_on_exact_geometry():
    rng = np.random.default_rng(11)
    model = _tiny_model(rng)
    W = 0.5 + 0.3 * np.sin(np.linspace(0, 3, 25)[:, None] + np.arange(3))
    positions = model.neutral.ravel() + W @ model.delta_matrix.T
    fit = retarget_positions(model, positions, "perframe")
    unit = normalised_unit(model)
    B, b0 = model.delta_matrix / unit, model.neutral.ravel() / unit
    np.testing.assert_allclose(fit.weights, fit_frames(B, b0, positions / unit, model.slider_min, model.slider_max),
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(fit.weights, W, rtol=0, atol=1e-5)
    with pytest.raises(ShapeSpaceError) as exc:
        retarget_positions(model, positions, "copy")
    assert exc.value.code == "method"


# --------------------------------------------------------------------------- dense transfer
def test_transfer_same_topology_carries_motion_by_the_rests_similarity():
    rng = np.random.default_rng(12)
    rest = rng.standard_normal((15, 3))
    R = Rotation.random(random_state=12).as_matrix()
    neutral = 2.0 * rest @ R.T + np.array([1.0, 0.0, -3.0])         # the target: the source rest, moved
    motion = 0.1 * rng.standard_normal((4, 15, 3))
    out = transfer_motion(rest + motion, rest, neutral, np.ones((1, 15, 3)), 1.0, [], [])
    np.testing.assert_allclose(out.reshape(4, 15, 3), neutral + 2.0 * motion @ R.T, rtol=0, atol=1e-12)


def test_transfer_needs_landmarks_on_moving_vertices():
    rng = np.random.default_rng(13)
    rest, neutral = rng.standard_normal((10, 3)), rng.standard_normal((12, 3))
    deltas = np.zeros((2, 12, 3))
    deltas[0, 11] = 1.0
    with pytest.raises(ShapeSpaceError) as exc:
        transfer_motion(rest[None], rest, neutral, deltas, 1.0, [0, 1], [0, 1])
    assert exc.value.code == "too_few_landmarks"
    with pytest.raises(ShapeSpaceError) as exc:
        transfer_motion(rest[None], rest, neutral, deltas, 1.0, [0, 1, 2, 3], [0, 1, 2, 3])
    assert exc.value.code == "static_landmarks"


def test_stabilise_removes_rigid_head_motion():
    rng = np.random.default_rng(14)
    rest = rng.standard_normal((30, 3))
    seq = np.stack([rest @ Rotation.random(random_state=i).as_matrix().T + i for i in range(5)])
    stabilise(seq, rest, np.arange(30))
    np.testing.assert_allclose(seq[1:], np.broadcast_to(rest, (4, 30, 3)), rtol=0, atol=1e-10)


# --------------------------------------------------------------------------- learned cloning, key frames
def test_learned_cloning_recovers_a_linear_map_from_suggested_key_frames():
    rng = np.random.default_rng(15)
    F, ns, nt = 120, 4, 3
    frames = np.arange(1.0, F + 1)
    src = np.column_stack([0.5 + 0.4 * np.sin(frames / (5 + 3 * k) + k) for k in range(ns)] + [np.full(F, 0.3)])
    keys = suggest_key_frames(frames, src)
    assert keys.size >= ns + 2 and np.all(np.diff(keys) > 0)
    E = rng.standard_normal((ns, nt))
    idx = np.searchsorted(frames, keys)
    learned = learned_cloning(frames, src, keys, src[idx, :ns] @ E)
    assert learned.mapped_channels == ns and learned.key_poses == keys.size     # the constant channel is left out
    # the cloning matrix's ridge ε = 1e-8·tr(A)/n (A = WsᵀWs) biases E by at most ε/λ_min(A)·‖E‖
    A = src[idx, :ns].T @ src[idx, :ns]
    bound = 1e-8 * np.trace(A) / ns / np.linalg.eigvalsh(A)[0] * np.linalg.norm(E, 2)
    assert np.linalg.norm(learned.matrix - E, 2) <= 1.01 * bound + 1e-12
    np.testing.assert_allclose(learned.weights, src[:, :ns] @ learned.matrix, rtol=0, atol=1e-12)
    # RMS of Ws (Ê − E) ≤ max row norm of Ws (≤ √ns here: entries in [0, 1]) × ‖Ê − E‖₂
    assert learned.fit_rms <= np.sqrt(ns) * (1.01 * bound + 1e-12)


# --------------------------------------------------------------------------- hardening (#10)
def _model_with_empty_key(rng, p=20):
    neutral = rng.standard_normal((p, 3))
    deltas = rng.standard_normal((3, p, 3)) * 0.2
    deltas[1] = 0.0                                             # k1 moves nothing (like facecap's tongueOut)
    return BlendshapeModel(neutral, deltas, ["k0", "k1", "k2"])


@pytest.mark.parametrize("method", ["perframe", "spacetime"])
def test_sliders_of_empty_keys_keep_the_copied_value(method):
    rng = np.random.default_rng(21)
    model = _model_with_empty_key(rng)
    ideal = 0.5 + 0.4 * np.sin(np.linspace(0, 4, 40)[:, None] + np.arange(3))
    ideal[5, 1] = 1.7                                           # beyond the range: clipped, as copy keys it
    fit = retarget_weights(model, ideal, method, lam=1e-9)
    np.testing.assert_array_equal(fit.weights[:, 1], np.clip(ideal[:, 1], 0, 1))
    np.testing.assert_allclose(fit.weights[:, [0, 2]], np.clip(ideal[:, [0, 2]], 0, 1), atol=1e-4)
    dense = retarget_positions(model, model.neutral.ravel() + ideal @ model.delta_matrix.T, method)
    np.testing.assert_array_equal(dense.weights[:, 1], 0.0)     # a mesh performance: at rest


def test_copy_errors_need_no_dense_residual_and_match_it():
    from core.retarget.metrics import weight_errors
    rng = np.random.default_rng(22)
    model = _tiny_model(rng, p=50)
    dW = rng.standard_normal((3000, 3))
    R = dW @ model.delta_matrix.T
    pos, vel = weight_errors(dW, model.delta_matrix, model.scale)
    assert pos == pytest.approx(position_error_rms(R, model.scale), rel=1e-13)
    assert vel == pytest.approx(velocity_error_rms(R, model.scale), rel=1e-13)


def test_dense_performance_beyond_the_memory_budget_is_refused_but_weight_fits_build_nothing_dense(monkeypatch):
    import core.retarget.performance as performance
    rng = np.random.default_rng(23)
    model = _tiny_model(rng)
    ideal = np.full((100, 3), 0.5)
    expected = retarget_weights(model, ideal, "spacetime").weights
    monkeypatch.setattr(performance, "MAX_DENSE_BYTES", 100 * 3 * 20 * 8 - 1)
    with pytest.raises(ShapeSpaceError) as exc:            # a mesh performance: (f, 3p) positions
        performance.check_dense_budget(100, 20, "a mesh performance")
    assert exc.value.code == "too_large" and "100 frames on 20 vertices" in str(exc.value)
    # a weight performance is fitted in the rig's own coordinates (reduced_geometry): nothing per vertex
    np.testing.assert_array_equal(retarget_weights(model, ideal, "spacetime").weights, expected)
    assert retarget_weights(model, ideal, "copy").weights.shape == (100, 3)    # copy builds nothing dense


@pytest.mark.parametrize("lam", [float("nan"), 0.0, -1.0, float("inf")])
def test_bad_lambda_is_refused_naming_it(lam):
    model = _tiny_model(np.random.default_rng(24))
    with pytest.raises(ShapeSpaceError, match="^lam must be"):
        retarget_weights(model, np.full((10, 3), 0.5), "spacetime", lam=lam)


def test_non_finite_fit_is_refused_naming_the_slider():
    from core.retarget.performance import check_finite_weights
    W = np.zeros((5, 3))
    W[3, 2] = np.nan
    with pytest.raises(ShapeSpaceError, match="slider 'eyeLookUp_R' \\(first at frame index 3"):
        check_finite_weights(W, ["jawOpen", "eyeLookUp_L", "eyeLookUp_R"])


def test_spacetime_messages_name_the_sliders():
    rng = np.random.default_rng(25)
    B = rng.standard_normal((9, 3))
    S = rng.standard_normal((6, 9))
    with pytest.raises(ShapeSpaceError, match="lo exceeds hi for sliders eyeLookUp_L, eyeLookUp_R"):
        spacetime(B, np.zeros(9), S, np.ones(3), 1e-3, lo=[0, 1, 1], hi=[1, 0, 0],
                  names=["jawOpen", "eyeLookUp_L", "eyeLookUp_R"])
