"""Weighted PSD at memory speed (float32 layout vs the float64 evaluation) and the blended distance (#16)."""
import numpy as np
import pytest

from core.errors import ErrorCode
from core.posespace.psd import loo_errors_wpsd, train_psd
from core.result import ShapeSpaceError

COLUMNS = [np.arange(0, 3), np.arange(3, 6), np.arange(6, 9)]


@pytest.fixture
def rng():
    return np.random.default_rng(3)


def setup(rng, K=9, p=40, smooth=True):
    X = rng.normal(size=(K, 9)) * 0.5
    gi = np.stack([rng.permutation(3)[:2] for _ in range(p)])
    gw = rng.uniform(0.1, 1.0, size=(p, 2))
    if smooth:   # correctives that are smooth functions of the pose
        dirs = rng.normal(size=(p, 3))
        D = np.stack([np.sin(x[:3].sum()) * np.cos(x[3:6].sum() + x[6]) * dirs for x in X]) * 0.05
    else:
        D = rng.normal(size=(K, p, 3)) * 0.05
    return X, D, gi, gw


def normalised_rbf(X, D, eps, d2_fn, x):
    """A normalised Gaussian RBF interpolant computed directly (reference)."""
    K = len(X)

    def row(pose):
        phi = np.exp(-(eps ** 2) * np.array([d2_fn(pose, X[k]) for k in range(K)]))
        return phi / phi.sum()

    A = np.array([row(X[i]) for i in range(K)])
    return row(x) @ np.linalg.solve(A, D.reshape(K, -1))


@pytest.mark.parametrize("smooth", [True, False])
def test_fast_float32_within_1e6_of_the_size(rng, smooth):
    X, D, gi, gw = setup(rng, smooth=smooth)
    m = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)
    size = 1.0                                     # a mesh 20× the largest corrective coordinate or more
    m.prepare_fast(size)
    for _ in range(10):
        x = rng.normal(size=9) * 0.6
        fast = m.evaluate_fast(x)
        assert fast.dtype == np.float32
        assert np.abs(fast - m.evaluate(x)).max() <= 1e-6 * size


def test_fast_default_size_is_the_corrective_and_cancelling_vertices_stay_float64(rng):
    X, D, gi, gw = setup(rng, smooth=False)
    m = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)
    m.prepare_fast()
    fast = m._fast
    assert fast.idx32.size + fast.idx64.size == D.shape[1]
    big = np.abs(m.folded).max(axis=(1, 2))
    assert (big[fast.idx64] > big[fast.idx32].max()).all() if fast.idx32.size and fast.idx64.size else True
    for _ in range(5):
        x = rng.normal(size=9) * 0.6
        assert np.abs(m.evaluate_fast(x) - m.evaluate(x)).max() <= 1e-6 * np.abs(D).max()


def test_fast_skips_vertices_without_correctives_and_survives_far_poses(rng):
    X, D, gi, gw = setup(rng)
    D[:, :10] = 0.0
    m = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)
    m.prepare_fast(1.0)
    assert not np.isin(np.arange(10), np.concatenate([m._fast.idx32, m._fast.idx64])).any()
    far = X[0] + 40.0                                  # float32 exp would underflow without the shift/fallback
    out = m.evaluate_fast(far)
    with np.errstate(all="ignore"):
        ref = m.evaluate(far)
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(out[:10], 0.0)
    if np.isfinite(ref).all():
        assert np.abs(out - ref).max() <= 1e-6


def test_blend_zero_is_todays_weighted_psd_exactly(rng):
    X, D, gi, gw = setup(rng)
    kw = dict(vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)
    today = train_psd(X, D, "wpsd", **kw)
    for blend in (0.0, np.zeros(D.shape[1])):
        m = train_psd(X, D, "wpsd", blend=blend, **kw)
        assert m.blend is None
        np.testing.assert_array_equal(m.folded, today.folded)
        x = rng.normal(size=9)
        np.testing.assert_array_equal(m.evaluate(x), today.evaluate(x))


def test_blend_one_is_global_distance_psd_exactly(rng):
    X, D, gi, gw = setup(rng, K=7, p=6)
    m = train_psd(X, D, "wpsd", blend=1.0, vertex_ridge=0.0, vertex_groups=gi, vertex_weights=gw,
                  group_columns=COLUMNS)
    for _ in range(4):
        x = rng.normal(size=9) * 0.5
        ref = normalised_rbf(X, D, m.epsilon, lambda a, b: 0.25 * np.sum((a - b) ** 2), x).reshape(-1, 3)
        np.testing.assert_allclose(m.evaluate(x), ref, rtol=0, atol=1e-10)
        np.testing.assert_allclose(m.evaluate_fast(x), ref, rtol=0, atol=1e-6 * np.abs(D).max())
    for k in range(len(X)):        # interpolates the examples
        np.testing.assert_allclose(m.evaluate(X[k]), D[k], rtol=0, atol=1e-9)


def test_blend_in_between_is_the_blended_metric(rng):
    X, D, gi, gw = setup(rng, K=6, p=5)
    lam = np.array([0.0, 0.3, 0.5, 0.9, 1.0])
    m = train_psd(X, D, "wpsd", blend=lam, vertex_ridge=0.0, vertex_groups=gi, vertex_weights=gw,
                  group_columns=COLUMNS)
    x = rng.normal(size=9) * 0.5
    for v in range(5):
        w = np.zeros(3)
        np.add.at(w, gi[v], gw[v])
        w /= w.sum()

        def d2(a, b, v=v, w=w):
            skin = sum(w[j] * np.sum((a[c] - b[c]) ** 2) for j, c in enumerate(COLUMNS))
            return (1 - lam[v]) * skin + lam[v] * 0.25 * np.sum((a - b) ** 2)
        ref = normalised_rbf(X, D[:, v:v + 1], m.epsilon, d2, x)
        np.testing.assert_allclose(m.evaluate(x)[v], ref, rtol=0, atol=1e-10)


def test_blend_refuses_out_of_range(rng):
    X, D, gi, gw = setup(rng)
    with pytest.raises(ShapeSpaceError) as e:
        train_psd(X, D, "wpsd", blend=1.5, vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)
    assert e.value.code == ErrorCode.RANGE
    with pytest.raises(ShapeSpaceError):
        train_psd(X, D, "wpsd", blend="sometimes", vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)


def test_loo_closed_form_equals_refitting(rng):
    X, D, gi, gw = setup(rng, K=7, p=3)
    pair = np.stack([((X[:, None, c] - X[None, :, c]) ** 2).sum(-1) for c in COLUMNS])
    W = np.zeros((3, 3))
    for v in range(3):
        np.add.at(W[v], gi[v], gw[v])
        W[v] /= W[v].sum()
    eps = 0.8
    got = loo_errors_wpsd(D[:, :3], W, pair, eps)
    for v in range(3):
        want = 0.0
        for k in range(len(X)):
            keep = np.arange(len(X)) != k
            d2 = lambda a, b, v=v: sum(W[v, j] * np.sum((a[c] - b[c]) ** 2) for j, c in enumerate(COLUMNS))  # noqa
            pred = normalised_rbf(X[keep], D[keep, v], eps, d2, X[k])
            want += np.sum((pred - D[k, v]) ** 2)
        assert got[v] == pytest.approx(want, rel=1e-6)


def test_auto_blend_helps_a_corrective_of_joints_the_vertex_ignores(rng):
    """The two-joint bulge: vertices skinned to joint 0 only, corrective driven by joints 0 and 1."""
    K, p = 16, 30
    X = rng.uniform(-1, 1, size=(K, 9))
    gi = np.zeros((p, 1), dtype=int)
    gw = np.ones((p, 1))
    dirs = rng.normal(size=(p, 3))

    def bulge(x):
        return 0.05 * np.sin(x[0] + x[1]) * np.sin(x[3] + x[4]) * dirs
    D = np.stack([bulge(x) for x in X])
    kw = dict(vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)
    plain = train_psd(X, D, "wpsd", **kw)
    auto = train_psd(X, D, "wpsd", blend="auto", **kw)
    assert auto.diagnostics["blend_regions"][0][0] > 0
    tests = rng.uniform(-1, 1, size=(40, 9))
    err = lambda m: np.mean([np.abs(m.evaluate(x) - bulge(x)).max() for x in tests])  # noqa: E731
    assert err(auto) < 0.7 * err(plain)
