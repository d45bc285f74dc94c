"""Whole-face / delta / convex forms of a rig (core.facespace.forms, thesis 3.7.3): round trips, the
convex projection against SciPy's SLSQP and a KKT check, and how many Neutral keys a whole-face rig needs under
a per-key weight limit."""
import numpy as np
import pytest
from scipy.optimize import minimize

from core import facespace as fs
from core.result import ShapeSpaceError
from facespace_models import random_model


# ------------------------------------------------------------ whole-face form
@pytest.mark.parametrize("seed", [0, 1])
def test_delta_whole_delta_round_trip(seed):
    model = random_model(seed)
    targets, neutral = fs.to_whole_face(model)
    assert targets.shape == (6, 30, 3) and neutral.shape == (30, 3)
    for k in range(6):
        np.testing.assert_array_equal(targets[k], model.neutral + model.deltas[k])
    back = fs.from_whole_face(neutral, targets, model.names)
    assert back.names == model.names
    np.testing.assert_allclose(back.deltas, model.deltas, rtol=0, atol=1e-12 * np.abs(model.deltas).max())
    again, _ = fs.to_whole_face(back)
    np.testing.assert_allclose(again, targets, rtol=0, atol=1e-12 * np.abs(targets).max())


def test_whole_face_weights_reproduce_faces():
    model = random_model(2)
    targets, b0 = fs.to_whole_face(model)
    w = np.random.default_rng(3).uniform(0, 1, size=(4, 6))
    c = fs.whole_face_weights(w)
    assert c.shape == (4, 7)
    np.testing.assert_allclose(c.sum(axis=1), 1.0, atol=1e-15)
    faces = c[:, 0, None, None] * b0 + np.einsum("fk,kpc->fpc", c[:, 1:], targets)
    np.testing.assert_allclose(faces, model.evaluate(w), atol=1e-12)
    back, scale = fs.delta_weights(c)
    np.testing.assert_allclose(back, w, atol=1e-15)
    np.testing.assert_allclose(scale, 1.0, atol=1e-15)
    assert fs.whole_face_weights(w[0]).shape == (7,)


def test_nonconvex_whole_face_weights_scale_the_neutral():
    model = random_model(4)
    targets, b0 = fs.to_whole_face(model)
    c = np.array([0.7, 0.5, -0.2, 0.9, 0.0, 0.3, 0.1])  # sums to 2.3
    w, scale = fs.delta_weights(c)
    assert scale == pytest.approx(2.3)
    face = c[0] * b0 + np.einsum("k,kpc->pc", c[1:], targets)
    np.testing.assert_allclose(face, scale * b0 + np.einsum("k,kpc->pc", w, model.deltas), atol=1e-12)


# ----------------------------------------------------------- convex projection
def qp_projection(w, lo, hi):
    """Reference: quadprog on min ½|x − w|² s.t. lo ≤ x ≤ hi, Σx ≤ 1."""
    quadprog = pytest.importorskip("quadprog")
    n = w.size
    rows, rhs = [np.eye(n), -np.ones((1, n))], [lo, [-1.0]]
    fin = np.isfinite(hi)
    rows.insert(1, -np.eye(n)[fin])
    rhs.insert(1, -hi[fin])
    return quadprog.solve_qp(np.eye(n), w, np.vstack(rows).T, np.concatenate(rhs), 0)[0]


@pytest.mark.parametrize("seed", range(8))
def test_projection_matches_quadprog_and_kkt(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 12))
    lo = rng.uniform(-0.3, 0.0, n) if seed % 2 else np.zeros(n)
    hi = np.where(rng.uniform(size=n) < 0.3, np.inf, rng.uniform(0.2, 1.0, n))
    w = rng.uniform(-0.5, 1.5, size=(5, n))
    x = fs.project_convex(w, lo, hi)
    for t in range(5):
        np.testing.assert_allclose(x[t], qp_projection(w[t], lo, hi), atol=1e-9)
        np.testing.assert_allclose(fs.project_convex(w[t], lo, hi), x[t], atol=0)  # vectorised = per row
        # KKT: x = clip(w − λ), λ ≥ 0, complementary slackness
        assert np.all(x[t] >= lo - 1e-15) and np.all(x[t] <= hi + 1e-15) and x[t].sum() <= 1 + 1e-12
        free = (x[t] > lo + 1e-12) & (x[t] < hi - 1e-12)
        lam = float(np.mean((w[t] - x[t])[free])) if free.any() else max(0.0, float(np.min(w[t] - x[t])))
        assert lam >= -1e-12
        np.testing.assert_allclose(x[t], np.clip(w[t] - lam, lo, hi), atol=1e-10)
        if lam > 1e-10:
            assert x[t].sum() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(fs.project_convex(x, lo, hi), x, atol=1e-14)  # idempotent


def test_projection_matches_slsqp():
    rng = np.random.default_rng(11)
    w = rng.uniform(0, 1, 7)
    x = fs.project_convex(w)
    ref = minimize(lambda z: 0.5 * np.sum((z - w) ** 2), np.zeros(7), jac=lambda z: z - w, method="SLSQP",
                   bounds=[(0, 1)] * 7, constraints=[{"type": "ineq", "fun": lambda z: 1 - z.sum()}],
                   options={"ftol": 1e-14, "maxiter": 500})
    np.testing.assert_allclose(x, ref.x, atol=1e-7)
    assert x.sum() == pytest.approx(1.0, abs=1e-14)


def test_projection_keeps_feasible_points_and_rejects_empty_set():
    w = np.array([0.2, 0.3, 0.1])
    np.testing.assert_array_equal(fs.project_convex(w), w)
    with pytest.raises(ShapeSpaceError, match="lo"):
        fs.project_convex(w, lo=0.5)
    with pytest.raises(ShapeSpaceError, match="w must have shape"):
        fs.project_convex(np.zeros((2, 2, 2)))


@pytest.mark.parametrize("lo,hi,want", [
    (np.zeros(51), np.ones(51), 5),            # FBHead: 1 − Σw down to −50 → five shares of ≥ −10
    (np.zeros(10), np.ones(10), 1),            # 1 − Σw ∈ [−9, 1]
    (np.zeros(11), np.ones(11), 1),            # −10 exactly: still one key
    (np.zeros(12), np.ones(12), 2),
    (np.full(3, -10.0), np.full(3, 10.0), 4),  # 1 − Σw ∈ [−29, 31]
    (np.zeros(0), np.zeros(0), 1),
])
def test_neutral_key_count_keeps_every_share_within_the_limit(lo, hi, want):
    k = fs.neutral_key_count(lo, hi)
    assert k == want
    for w in (lo, hi):                               # the extremes of 1 − Σw over the slider box
        assert abs(1.0 - np.sum(w)) / k <= 10.0
    if k > 1:
        assert max(abs(1.0 - lo.sum()), abs(1.0 - hi.sum())) / (k - 1) > 10.0      # and no key to spare


def test_neutral_key_count_bad_input():
    with pytest.raises(ShapeSpaceError, match="slider_min must not exceed"):
        fs.neutral_key_count([1.0], [0.0])
    with pytest.raises(ShapeSpaceError, match="slider_max must have shape"):
        fs.neutral_key_count([0.0, 0.0], [1.0])
    with pytest.raises(ShapeSpaceError, match="limit must be positive"):
        fs.neutral_key_count([0.0], [1.0], limit=0.0)
