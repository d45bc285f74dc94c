"""The pure middle steps of the face-space verbs (core.facespace.job), checked against independent references:
NumPy SVD / covariance, SciPy's SLSQP and χ² distribution, and analytic answers."""
import numpy as np
import pytest
from scipy import stats
from scipy.optimize import minimize

from core.blendshape import BlendshapeModel
from core.errors import ErrorCode
from core.facespace import coherence_image, coherence_matrix
from core.facespace.job import (
    coherence_problem,
    coherence_step,
    compression_step,
    convex_step,
    inpaint_step,
    meter_step,
    neutral_key_names,
    pca_copy,
    prior_step,
    whole_face_plan,
)
from core.facespace.report import (
    CoherenceReport,
    CompressionReport,
    ConvexReport,
    InpaintReport,
    MeterReport,
    PriorReport,
)
from core.result import ShapeSpaceError, Status


def _rig(n=5, p=40, seed=0, lo=0.0, hi=1.0, names=None):
    rng = np.random.default_rng(seed)
    neutral = rng.normal(size=(p, 3))
    deltas = rng.normal(size=(n, p, 3)) * 0.1
    return BlendshapeModel(neutral, deltas, names or [f"k{i}" for i in range(n)],
                           slider_min=np.full(n, lo), slider_max=np.full(n, hi))


def _progress():
    seen = []
    return seen, seen.append


# ------------------------------------------------------------------ whole-face copy (3.7.3)
def test_whole_face_plan_reproduces_every_face_within_the_key_limit():
    model = _rig(n=12, lo=0.0, hi=1.0)                     # Σw up to 12: |1 − Σw| = 11 needs K = 2 keys of ±10
    plan = whole_face_plan(model, convex=True, limit=10.0)
    assert plan.neutral_names == ["Neutral", "Neutral 2"] == neutral_key_names(2)
    assert sorted(np.concatenate(plan.runs).tolist()) == list(range(12)) and len(plan.runs) == 2
    rng = np.random.default_rng(1)
    for w in [np.ones(12), np.zeros(12), rng.uniform(0, 1, 12)]:
        c0 = (1.0 - w.sum()) / len(plan.neutral_names)
        assert abs(c0) <= 10.0
        face = len(plan.neutral_names) * c0 * plan.neutral + np.tensordot(w, plan.targets, axes=1)
        np.testing.assert_allclose(face, model.neutral + np.tensordot(w, model.deltas, axes=1), atol=1e-12)


def test_whole_face_plan_without_convex_has_one_neutral_and_refuses_reserved_names():
    assert whole_face_plan(_rig(n=12), convex=False, limit=10.0).neutral_names == ["Neutral"]
    for reserved in ("Neutral", "Zero"):
        with pytest.raises(ShapeSpaceError, match=f"shape key '{reserved}' of 'Face'") as exc:
            whole_face_plan(_rig(n=3, names=["a", reserved, "b"]), True, 10.0, owner="'Face'")
        assert exc.value.code == ErrorCode.RESERVED_NAME


# ------------------------------------------------------------------ PCA copy (3.4.6, 3.7.5)
def test_pca_copy_of_the_rig_spans_every_face():
    model = _rig(n=4)
    basis, sliders = pca_copy(model, None, 1e-3, 10.0)
    assert basis.n_components == 4
    rng = np.random.default_rng(2)
    W = rng.uniform(0, 1, size=(7, 4))
    S = sliders.slider_values(W)
    faces = sliders.rest + np.tensordot(S, sliders.keys - sliders.rest, axes=1)
    np.testing.assert_allclose(faces, model.evaluate(W), atol=1e-10)


def test_pca_copy_of_an_animation_keeps_it_within_tol_and_blenders_limit():
    model = _rig(n=6, p=60, seed=3)
    rng = np.random.default_rng(4)
    W = rng.uniform(0, 1, size=(200, 2)) @ rng.uniform(0, 0.5, size=(2, 6))    # a rank-2 animation
    W[7] = 0.999                                                               # one rare extreme frame
    tol = 1e-3 * model.scale
    basis, sliders = pca_copy(model, W, tol, 10.0)
    S = sliders.slider_values(W)
    faces = sliders.rest + np.tensordot(S, sliders.keys - sliders.rest, axes=1)
    assert np.linalg.norm(faces - model.evaluate(W), axis=-1).max() <= tol
    assert np.abs(S).max() <= 10.0 + 1e-9 and basis.n_components <= 3


def test_pca_copy_of_targets_that_move_nothing_is_refused():
    model = BlendshapeModel(np.ones((5, 3)), np.zeros((2, 5, 3)), ["a", "b"])
    with pytest.raises(ShapeSpaceError, match="action 'Take' moves no vertex") as exc:
        pca_copy(model, np.zeros((4, 2)), 1e-3, 10.0, what="action 'Take' moves")
    assert exc.value.code == ErrorCode.EMPTY


# ------------------------------------------------------------------ Make Convex (3.7.3)
def test_convex_step_matches_slsqp_and_reports_the_move():
    rng = np.random.default_rng(5)
    lo, hi = np.array([-1.0, 0.0, 0.0, 0.2]), np.array([1.0, 2.0, 0.5, 1.0])
    w = rng.normal(size=4) + 0.6
    values, rep = convex_step(w, lo, hi)
    ref = minimize(lambda x: np.sum((x - w) ** 2), np.clip(w, 0.2, 0.25), method="SLSQP",
                   bounds=list(zip(np.maximum(lo, 0), np.minimum(hi, 1))),
                   constraints=[{"type": "ineq", "fun": lambda x: 1 - x.sum()}], options={"ftol": 1e-14})
    np.testing.assert_allclose(values, ref.x, atol=1e-6)
    assert isinstance(rep, ConvexReport) and rep.status == Status.OK
    assert rep.sum_before == pytest.approx(w.sum()) and rep.sum_after == pytest.approx(ref.x.sum(), abs=1e-6)
    assert rep.moved == pytest.approx(np.linalg.norm(values - w))


# ------------------------------------------------------------------ compression (3.7.8)
def _brute_components(frames, tol):
    """Smallest m whose rank-m PCA reconstruction keeps every vertex within tol (NumPy SVD)."""
    f = frames.shape[0]
    Xc = frames.reshape(f, -1) - frames.reshape(f, -1).mean(axis=0)
    U, s, vt = np.linalg.svd(Xc, full_matrices=False)
    for m in range(s.size + 1):
        err = np.linalg.norm((Xc - (U[:, :m] * s[:m]) @ vt[:m]).reshape(f, -1, 3), axis=2).max()
        if err <= tol:
            return m
    return None


def test_compression_step_matches_a_brute_force_svd():
    model = _rig(n=6, p=50, seed=6)
    rng = np.random.default_rng(7)
    W = rng.uniform(0, 1, size=(80, 6)) * np.array([1, 0.5, 0.2, 0.05, 0.01, 0.001])
    seen, progress = _progress()
    found = []
    for tol in (1e-1, 1e-2, 1e-3, 1e-4):
        tol = tol * model.scale
        rep = compression_step(model, W, tol, progress)
        assert isinstance(rep, CompressionReport) and rep.status == Status.OK and rep.exit_code() == 0
        assert rep.components == _brute_components(model.evaluate(W), tol)
        assert rep.targets == 6 and rep.frames == 80 and rep.tol == tol
        if rep.components:
            assert rep.ratio == pytest.approx(6 / rep.components)
        found.append(rep.components)
    assert len(set(found)) >= 3 and seen[-1] == 0.95


# ------------------------------------------------------------------ rig analysis (3.7.1, 3.7.6)
def _diagnostic_rig():
    rng = np.random.default_rng(8)
    d = rng.normal(size=(3, 20, 3))
    deltas = np.stack([d[0], 2.0 * d[0], np.zeros((20, 3)), d[1], d[2]])      # b = 2a, c empty
    return BlendshapeModel(rng.normal(size=(20, 3)), deltas, ["a", "b", "c", "d", "e"])


def test_coherence_step_finds_duplicates_and_empty_targets_like_the_cosines():
    model = _diagnostic_rig()
    seen, progress = _progress()
    rep, image = coherence_step(model, None, 0.95, "/tmp/x.png", progress)
    assert isinstance(rep, CoherenceReport) and rep.status == Status.OK
    assert rep.empty_targets == ["c"] and rep.png == "/tmp/x.png" and rep.image == ""
    assert [p[:2] for p in rep.similar_pairs] == [["a", "b"]] and rep.similar_pairs[0][2] == pytest.approx(1.0)
    D = model.deltas.reshape(5, -1)[[0, 1, 3, 4]]
    cos = np.abs(D @ D.T) / np.outer(np.linalg.norm(D, axis=1), np.linalg.norm(D, axis=1))
    assert rep.mutual_coherence == pytest.approx(cos[~np.eye(4, dtype=bool)].max())
    np.testing.assert_array_equal(image, coherence_image(coherence_matrix(model)))
    assert rep.sparsity is None and "sparsity" not in rep.to_json() and "sparsity_message" not in rep.to_json()
    assert seen == [0.4, 0.9]


def test_coherence_step_with_an_animation_compares_sparsity():
    model = _diagnostic_rig()
    W = np.zeros((10, 5))
    W[np.arange(10), np.arange(10) % 5] = 1.0                 # one active target per frame
    rep, _ = coherence_step(model, W)
    assert set(rep.sparsity) == {"blendshape", "pca"} and rep.sparsity_message
    assert rep.sparsity["blendshape"]["hoyer"] == pytest.approx(1.0)       # maximally sparse
    assert coherence_step(model, W[:1])[0].sparsity is None                # one frame: no sparsity over time


@pytest.mark.parametrize("change,message", [
    ({"empty_targets": [1]}, "every empty target must be a shape-key name"),
    ({"similar_pairs": [["a", "b"]]}, "must be [name, name, number]"),
    ({"similar_pairs": [["a", "b", True]]}, "must be [name, name, number]"),
    ({"sparsity": {"blendshape": {"curve_small_fraction": "x"}, "pca": {}}}, "blendshape.curve_small_fraction"),
    ({"sparsity": {"blendshape": {"curve_small_fraction": 0.5}, "pca": 3}}, "pca.curve_small_fraction"),
])
def test_coherence_problem_names_what_does_not_fit(change, message):
    good = {"empty_targets": ["c"], "similar_pairs": [["a", "b", 0.99]],
            "sparsity": {"blendshape": {"curve_small_fraction": 0.5}, "pca": {"curve_small_fraction": None}}}
    assert coherence_problem(good) is None
    assert message in coherence_problem(dict(good, **change))


# ------------------------------------------------------------------ face prior (ch. 6)
def test_prior_step_stores_numpys_covariance():
    rng = np.random.default_rng(9)
    W = rng.normal(size=(500, 4)) @ rng.normal(size=(4, 4))
    g, blob, rep = prior_step(["a", "b", "c", "d"], W)
    np.testing.assert_allclose(blob["mean"], W.mean(axis=0), atol=1e-12)
    V, lam = np.array(blob["eigvecs"]), np.array(blob["eigvals"])
    np.testing.assert_allclose((V * lam) @ V.T, np.cov(W, rowvar=False), rtol=1e-10, atol=1e-10)
    assert blob["names"] == ["a", "b", "c", "d"] and blob["frames"] == 500 and blob["ridge"] == 0.0
    assert isinstance(rep, PriorReport) and rep.status == Status.OK and not rep.regularised and rep.frames == 500
    assert rep.dimension == 4.0 and rep.issues == []


def test_prior_step_of_a_short_animation_is_regularised_and_warns():
    W = np.random.default_rng(10).normal(size=(5, 8))            # 5 frames ≪ 8 sliders: singular covariance
    _, blob, rep = prior_step([f"k{i}" for i in range(8)], W)
    assert rep.regularised and blob["regularised"] and blob["ridge"] > 0
    assert rep.status == Status.WARNING and rep.to_json()["status"] == "warning" and rep.exit_code() == 0
    assert [i.code for i in rep.issues] == ["regularised"] and "regularised" in rep.message


def test_meter_step_matches_the_mahalanobis_norm_and_chi2():
    rng = np.random.default_rng(11)
    W = rng.normal(size=(4000, 30)) @ rng.normal(size=(30, 30)) * 0.1
    g, _, _ = prior_step([f"k{i}" for i in range(30)], W)
    S = np.cov(W, rowvar=False)
    w = W[17]
    d = w - W.mean(axis=0)
    rep = meter_step(g, [f"k{i}" for i in range(30)], w)
    norm = np.sqrt(d @ np.linalg.solve(S, d))
    assert isinstance(rep, MeterReport) and rep.norm == pytest.approx(norm, rel=1e-8)
    assert rep.percentile == pytest.approx(stats.chi2.cdf(norm ** 2, 30), rel=1e-8)
    assert rep.shell_radius == pytest.approx(np.sqrt(29))
    mean = meter_step(g, [f"k{i}" for i in range(30)], W.mean(axis=0))   # atypical in 30 dimensions
    assert mean.plausibility == "too_average" and mean.status == Status.WARNING and mean.norm == pytest.approx(0)


def test_meter_step_refuses_a_non_finite_slider_naming_it():
    g, _, _ = prior_step(["a", "b"], np.random.default_rng(12).normal(size=(50, 2)))
    with pytest.raises(ShapeSpaceError, match="shape key 'b' of 'Face' has value nan") as exc:
        meter_step(g, ["a", "b"], [0.1, np.nan], "'Face'")
    assert exc.value.code == ErrorCode.NON_FINITE


# ------------------------------------------------------------------ inpainting (9.3)
def _ar2_sine(rng, T, period):
    e = np.zeros(T)
    for i in range(2, T):
        e[i] = 1.6 * e[i - 1] - 0.8 * e[i - 2] + 0.3 * rng.normal()
    return np.sin(2 * np.pi * np.arange(T) / period) + 0.3 * e


def test_inpaint_step_recovers_a_channel_that_is_a_linear_combination():
    rng = np.random.default_rng(13)
    a, b = _ar2_sine(rng, 1500, 40.0), _ar2_sine(rng, 1500, 65.0)
    X = np.column_stack([0.7 * a - 1.3 * b + 0.2, a, b])
    gap = np.zeros(1500, bool)
    gap[700:725] = True
    values, rep = inpaint_step(X, gap)
    assert values.shape == (25,)
    assert np.sqrt(np.mean((values - X[gap, 0]) ** 2)) < 1e-3 * np.std(X[:, 0])
    assert isinstance(rep, InpaintReport) and rep.frames == 25 and rep.channels == 3 and rep.status == Status.OK
    assert rep.method and rep.message
