"""Geometric retargeting of a weight performance in the rig's own coordinates (#11, 36,000-frame takes).

``retarget_weights`` fits ``R`` (the QR factor of the rig's normalised deltas) to ``raw Rᵀ`` instead of the
per-vertex positions ``b0 + raw Bᵀ``. The references here are independent: the per-vertex formulation solved
by the same solvers, scipy's bounded least squares (per frame) and the KKT conditions of the space-time problem.
"""
import numpy as np
import pytest
from scipy.optimize import lsq_linear

from core.blendshape import BlendshapeModel
from core.retarget.metrics import slider_scales
from core.retarget.performance import empty_keys, normalised_basis, retarget_weights
from core.retarget.perframe import fit_frames
from core.retarget.spacetime_solver import spacetime


def _rig(seed=3, p=60, n=9, empty=(4,), duplicate=(1, 7)):
    rng = np.random.default_rng(seed)
    neutral = rng.normal(size=(p, 3)) * 10.0
    deltas = rng.normal(size=(n, p, 3)) * (rng.random((n, p, 1)) > 0.6)
    for k in empty:
        deltas[k] = 0.0
    deltas[duplicate[1]] = deltas[duplicate[0]]            # an exact duplicate: rank below the key count
    return BlendshapeModel(neutral, deltas, [f"k{i}" for i in range(n)])


def _take(n, frames=80, seed=5):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 4 * np.pi, frames)[:, None]
    return 0.5 + 0.8 * np.sin(t * rng.uniform(0.3, 1.5, n) + rng.uniform(0, 6, n))   # leaves [0, 1]: clipping


def test_perframe_equals_the_per_vertex_formulation_and_scipy():
    model = _rig()
    raw = _take(model.n_targets)
    got = retarget_weights(model, raw, "perframe").weights
    live = ~empty_keys(model)
    B, b0, _ = normalised_basis(model)
    Bl = B[:, live]
    dense = fit_frames(Bl, b0, b0 + raw[:, live] @ Bl.T, model.slider_min[live], model.slider_max[live])
    np.testing.assert_allclose(got[:, live], dense, atol=1e-7)
    # geometric optimality against scipy (ties among duplicates differ; the fitted geometry may not)
    reg = 1e-6 * np.trace(Bl.T @ Bl) / Bl.shape[1]
    for f in (0, 17, 55):
        A = np.vstack([Bl, np.sqrt(reg) * np.eye(Bl.shape[1])])
        rhs = np.concatenate([raw[f, live] @ Bl.T, np.zeros(Bl.shape[1])])
        ref = lsq_linear(A, rhs, bounds=(0, 1), tol=1e-13, lsmr_tol="auto").x
        cost = lambda w, A=A, rhs=rhs: np.sum((A @ w - rhs) ** 2)    # noqa: E731
        assert cost(got[f, live]) <= cost(ref) * (1 + 1e-7) + 1e-12
    assert np.all(got[:, ~live] == np.clip(raw[:, ~live], 0, 1))


@pytest.mark.parametrize("p", [60, 2])     # 3p ≥ n and 3p < n (a wide R)
def test_spacetime_equals_the_per_vertex_formulation(p):
    model = _rig(p=p)
    raw = _take(model.n_targets, frames=50)
    fit = retarget_weights(model, raw, "spacetime")
    assert fit.solver is not None and fit.solver.converged
    live = ~empty_keys(model)
    B, b0, _ = normalised_basis(model)
    Bl = B[:, live]
    ref = spacetime(Bl, b0, b0 + raw[:, live] @ Bl.T, slider_scales(raw[:, live], model.slider_min[live],
                    model.slider_max[live]), 1e-7, lo=model.slider_min[live], hi=model.slider_max[live],
                    relative=True, anchor=True)
    assert ref.converged
    # same problem: the same geometry and velocities (ties between duplicates may split differently)
    E_got, E_ref = (fit.weights[:, live] - raw[:, live]) @ Bl.T, (ref.weights - raw[:, live]) @ Bl.T
    scale = np.abs(raw[:, live] @ Bl.T).max()
    assert np.abs(E_got - E_ref).max() <= 1e-6 * scale
    assert fit.weights.min() >= 0.0 and fit.weights.max() <= 1.0
