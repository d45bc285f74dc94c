"""The face-space Gaussian (core.facespace.prior, thesis 3.7.9, ch. 6): covariances and Mahalanobis distances
with plain NumPy, chi-square tails with scipy.stats, and stored prior arrays checked against each other."""
import numpy as np
import pytest
from scipy import stats

from core import facespace as fs
from core.facespace import FaceGaussian, fit_face_gaussian
from core.result import Result, ShapeSpaceError
from facespace_models import correlated_faces


# ------------------------------------------------------------------ face Gaussian
def test_fit_matches_numpy_covariance_and_whitening_round_trips():
    rng = np.random.default_rng(0)
    W, _ = correlated_faces(rng)
    g = fit_face_gaussian(W)
    assert isinstance(g, FaceGaussian) and not g.regularised and g.ridge == 0.0
    C = np.cov(W, rowvar=False)
    np.testing.assert_allclose(g.mean, W.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose((g.eigvecs * g.eigvals) @ g.eigvecs.T, C, rtol=1e-10, atol=1e-10)
    Z = g.whiten(W)
    np.testing.assert_allclose(np.cov(Z, rowvar=False), np.eye(6), atol=1e-9)
    np.testing.assert_allclose(g.unwhiten(Z), W, atol=1e-9)
    assert g.dimension == 6.0 and g.shell_radius == pytest.approx(np.sqrt(5.0))


def test_face_norm_and_percentile_match_direct_formulas():
    rng = np.random.default_rng(1)
    W, _ = correlated_faces(rng, n=4)
    g = fit_face_gaussian(W)
    C = np.cov(W, rowvar=False)
    w = rng.normal(size=(3, 5, 4)) * 3
    diff = w - W.mean(axis=0)
    maha = np.sqrt(np.einsum("...i,ij,...j->...", diff, np.linalg.inv(C), diff))
    np.testing.assert_allclose(g.face_norm(w), maha, rtol=1e-10)
    np.testing.assert_allclose(g.percentile(w), stats.chi2.cdf(maha ** 2, 4), rtol=1e-10)
    assert g.face_norm(g.mean) == 0.0 and g.percentile(g.mean) == 0.0


def test_high_dimensional_mass_sits_in_a_shell_and_the_mean_face_is_atypical():
    rng = np.random.default_rng(2)
    n = 50
    W = rng.normal(size=(5000, n)) * rng.uniform(0.5, 2.0, n)
    g = fit_face_gaussian(W)
    norms = g.face_norm(W)
    assert abs(np.median(norms) - np.sqrt(n)) < 0.5
    assert np.std(norms) < 1.0                       # thin shell: width O(1) at radius ≈ 7
    assert np.mean(norms < 0.5 * np.sqrt(n)) == 0.0  # nothing near the mean
    test = np.vstack([g.mean, W[:200], g.mean + 3 * (W[0] - g.mean)])
    res = g.plausibility(test, alpha=0.01)
    assert isinstance(res, Result) and res.status == 1
    assert res.value[0] == "too_average" and res.value[-1] == "too_extreme"
    assert np.mean(res.value[1:-1] == "typical") > 0.97
    np.testing.assert_allclose(res.diagnostics["norm"], g.face_norm(test))
    codes = {i.code for i in res.issues}
    assert {"too_average", "too_extreme"} <= codes
    # about alpha of the training frames are flagged
    idx, reasons = g.implausible_frames(W, alpha=0.05)
    assert 0.02 < idx.size / W.shape[0] < 0.08
    assert set(reasons) <= {"too_average", "too_extreme"} and len(reasons) == idx.size
    ok = g.plausibility(W[5], alpha=0.01)
    assert ok.value.shape == () and (ok.status == 0) == (ok.value == "typical")


def test_too_few_frames_regularise_and_say_so():
    rng = np.random.default_rng(3)
    W = rng.normal(size=(4, 10))
    g = fit_face_gaussian(W)
    assert g.regularised and "ridge" in g.message and "4 frames for 10 channels" in g.message
    assert g.ridge == pytest.approx(1e-3 * np.mean(np.var(W, axis=0, ddof=1)))
    assert 2.9 < g.dimension <= 3.0                  # rank of 4 centred frames
    assert np.isfinite(g.whiten(rng.normal(size=10))).all()
    np.testing.assert_allclose(g.unwhiten(g.whiten(W)), W, atol=1e-10)


def test_constant_channels_are_listed_and_whitened_with_the_ridge():
    rng = np.random.default_rng(4)
    W = rng.normal(size=(500, 4))
    W[:, 2] = 0.25
    g = fit_face_gaussian(W)
    assert g.regularised and g.diagnostics["constant_channels"] == [2] and "constant" in g.message
    w = g.mean.copy()
    w[2] += np.sqrt(g.ridge)                           # one ridge standard deviation on the flat channel
    assert g.face_norm(w) == pytest.approx(1.0, rel=1e-6)
    allflat = fit_face_gaussian(np.ones((10, 3)))
    assert allflat.ridge == 1e-6 and "every channel is constant" in allflat.message
    explicit = fit_face_gaussian(rng.normal(size=(100, 3)), ridge=0.5)
    assert explicit.regularised and explicit.ridge == 0.5 and explicit.dimension < 3


def test_face_gaussian_bad_input_names_the_argument():
    with pytest.raises(ShapeSpaceError, match="weights must have shape"):
        fit_face_gaussian(np.zeros(5))
    with pytest.raises(ShapeSpaceError, match="weights contains NaN"):
        fit_face_gaussian(np.array([[0.0, np.nan], [1.0, 2.0], [0.0, 1.0]]))
    with pytest.raises(ShapeSpaceError, match="ridge"):
        fit_face_gaussian(np.eye(3), ridge=-1.0)
    g = fit_face_gaussian(np.random.default_rng(5).normal(size=(50, 3)))
    with pytest.raises(ShapeSpaceError, match=r"w must have shape \(\.\.\., 3\)"):
        g.face_norm(np.zeros(4))
    with pytest.raises(ShapeSpaceError, match="alpha"):
        g.plausibility(g.mean, alpha=1.5)
    with pytest.raises(ShapeSpaceError, match="frames_weights"):
        g.implausible_frames(g.mean)


def test_face_gaussian_from_arrays_round_trips_a_fit():
    W = np.random.default_rng(3).normal(size=(40, 5))
    g = fs.fit_face_gaussian(W)
    names = list("abcde")
    h = fs.face_gaussian_from_arrays(names, g.mean.tolist(), g.eigvecs.tolist(), g.eigvals.tolist(), g.dimension,
                                     g.ridge, g.regularised, g.message)
    np.testing.assert_allclose(h.whiten(W), g.whiten(W))


@pytest.mark.parametrize("change,match", [
    ({"names": ["a", "b", "c"]}, r"mean must have shape \(3,\), got \(5,\)"),
    ({"names": ["a", "a", "b", "c", "d"]}, "names repeats 'a'"),
    ({"names": "abcde"}, "names must be a non-empty list"),
    ({"mean": [0.0] * 4}, r"mean must have shape \(5,\)"),
    ({"mean": [None] * 5}, "mean contains NaN"),
    ({"eigvecs": np.eye(5)[:, :4]}, r"eigvecs must have shape \(5, 5\)"),
    ({"eigvecs": 2 * np.eye(5)}, "orthonormal"),
    ({"eigvals": np.zeros(5)}, "eigvals must be positive"),
    ({"dimension": 0.0}, "dimension must be positive"),
    ({"dimension": 9.0}, "at most the 5 sliders"),
    ({"ridge": -1.0}, "ridge must be ≥ 0"),
])
def test_face_gaussian_from_arrays_names_what_does_not_fit(change, match):
    args = dict(names=list("abcde"), mean=np.zeros(5), eigvecs=np.eye(5), eigvals=np.ones(5), dimension=5.0)
    args.update(change)
    with pytest.raises(ShapeSpaceError, match=match):
        fs.face_gaussian_from_arrays(**args)
