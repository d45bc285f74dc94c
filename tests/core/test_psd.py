"""Pose-space deformation (thesis ch. 7-8): PSD, Shape-by-Example, weighted PSD, example checks, drivers.

References are computed here independently: Gaussian kernel matrices built by hand,
scipy.interpolate.RBFInterpolator, per-vertex loops for weighted PSD, analytic affine data.
"""
import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator
from scipy.spatial.distance import cdist

from core.errors import ErrorCode
from core.posespace import PoseSpaceDeformer, example_issues, train_driver, train_psd
from core.posespace.psd import loo_errors_wpsd
from core.result import ShapeSpaceError


# ------------------------------------------------------------------ helpers
def gaussian_cardinal(X, x, eps, smoothing=0.0):
    """c(x) = phi(x)^T (Phi + lambda I)^-1 with Phi_ij = exp(-(eps d_ij)^2), built by hand."""
    X = np.asarray(X, float)
    x = np.atleast_2d(x)
    K = X.shape[0]
    Phi = np.empty((K, K))
    for i in range(K):
        for j in range(K):
            Phi[i, j] = np.exp(-(eps * np.sqrt(np.sum((X[i] - X[j]) ** 2))) ** 2)
    phi = np.exp(-(eps ** 2) * np.sum((x[:, None, :] - X[None, :, :]) ** 2, axis=2))   # (m, K)
    return np.linalg.solve((Phi + smoothing * np.eye(K)).T, phi.T).T


def smooth_family(rng, K=9, d=3, p=15):
    """Examples whose correctives vary smoothly with the pose."""
    X = rng.uniform(-1.0, 1.0, size=(K, d))
    A = rng.normal(size=(p, 3, d))
    B = rng.normal(size=(p, 3))
    D = np.einsum("pcd,kd->kpc", A, np.sin(X)) + np.cos(X[:, :1])[:, :, None] * B[None]
    return X, D


def example_errors(model, X, D):
    return max(np.abs(model.evaluate(X[k]) - D[k]).max() for k in range(len(X)))


@pytest.fixture
def rng():
    return np.random.default_rng(7)


# ------------------------------------------------------------------ PSD / SbE exactness
@pytest.mark.parametrize("method", ["psd", "sbe"])
@pytest.mark.parametrize("family", ["random", "smooth"])
def test_exact_at_examples_and_one_hot_weights(rng, method, family):
    if family == "random":
        X, D = rng.normal(size=(8, 3)), rng.normal(size=(8, 12, 3))
    else:
        X, D = smooth_family(rng)
    m = train_psd(X, D, method)
    assert m.method == method and m.n_examples == len(X)
    assert m.diagnostics["smoothing"] == 0.0
    for k in range(len(X)):
        np.testing.assert_allclose(m.evaluate(X[k]), D[k], rtol=0, atol=1e-9)
        np.testing.assert_allclose(m.weights(X[k]), np.eye(len(X))[k], rtol=0, atol=1e-9)


@pytest.mark.parametrize("given_eps", [None, 1.3])
def test_psd_weights_equal_independent_gaussian_cardinal(rng, given_eps):
    X, D = smooth_family(rng, K=10, d=2)
    m = train_psd(X, D, "psd", epsilon=given_eps)
    if given_eps is not None:
        assert m.epsilon == given_eps
    x = rng.uniform(-1.2, 1.2, size=(20, 2))
    ref = gaussian_cardinal(X, x, m.epsilon)
    got = np.array([m.weights(xi) for xi in x])
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9 * max(1.0, np.abs(ref).max()))
    # the deformation is the cardinal combination of whole sculpts
    np.testing.assert_allclose(m.evaluate(x[0]), np.tensordot(ref[0], D, axes=1), atol=1e-9 * np.abs(D).max())


def test_psd_matches_scipy_gaussian_rbf(rng):
    X, D = smooth_family(rng, K=10, d=3, p=6)
    m = train_psd(X, D, "psd")
    ref = RBFInterpolator(X, D.reshape(10, -1), kernel="gaussian", epsilon=m.epsilon, degree=-1)
    x = rng.uniform(-1, 1, size=(15, 3))
    got = np.array([m.evaluate(xi).ravel() for xi in x])
    np.testing.assert_allclose(got, ref(x), rtol=0, atol=1e-8 * np.abs(D).max())


def test_sbe_reproduces_affine_correctives(rng):
    K, d, p = 9, 3, 20
    X = rng.normal(size=(K, d))
    A = rng.normal(size=(p, 3, d))
    b = rng.normal(size=(p, 3))
    D = np.einsum("pcd,kd->kpc", A, X) + b
    m = train_psd(X, D, "sbe")
    assert m.diagnostics["degree"] == 1
    for x in rng.normal(size=(10, d)) * 1.5:
        np.testing.assert_allclose(m.evaluate(x), A @ x + b, rtol=0, atol=1e-9 * (1 + np.abs(A @ x + b).max()))
        # cardinal weights reproduce linear functions: sum to 1 and give x back
        w = m.weights(x)
        assert w.sum() == pytest.approx(1.0, abs=1e-10)
        np.testing.assert_allclose(w @ X, x, atol=1e-9)


def test_sbe_matches_scipy_thin_plate_spline(rng):
    X, D = smooth_family(rng, K=10, d=2, p=5)
    m = train_psd(X, D, "sbe")
    ref = RBFInterpolator(X, D.reshape(10, -1), kernel="thin_plate_spline", epsilon=m.epsilon, degree=1)
    x = rng.uniform(-1.2, 1.2, size=(12, 2))
    got = np.array([m.evaluate(xi).ravel() for xi in x])
    np.testing.assert_allclose(got, ref(x), rtol=0, atol=1e-9 * np.abs(D).max())


def test_sbe_with_few_examples_falls_back_to_degree_zero(rng):
    X, D = rng.normal(size=(4, 3)), rng.normal(size=(4, 6, 3))    # K < d + 2: no linear term
    m = train_psd(X, D, "sbe")
    assert m.diagnostics["degree"] == 0
    assert example_errors(m, X, D) <= 1e-9
    ref = RBFInterpolator(X, D.reshape(4, -1), kernel="multiquadric", epsilon=m.epsilon, degree=0)
    x = rng.normal(size=(5, 3))
    got = np.array([m.evaluate(xi).ravel() for xi in x])
    np.testing.assert_allclose(got, ref(x), rtol=0, atol=1e-9 * np.abs(D).max())


@pytest.mark.parametrize("method", ["sbe", "psd"])
def test_pseudo_pose_moves_where_a_sculpt_is_reproduced(rng, method):
    X, D = smooth_family(rng, K=9, d=3)
    moved = np.array([0.3, -0.4, 0.9])
    m = train_psd(X, D, method, pseudo_poses={4: moved})
    np.testing.assert_array_equal(m.poses[4], moved)
    np.testing.assert_allclose(m.evaluate(moved), D[4], rtol=0, atol=1e-9)
    for k in range(9):
        if k != 4:
            np.testing.assert_allclose(m.evaluate(X[k]), D[k], rtol=0, atol=1e-9)
    # the original sculpt location no longer reproduces example 4 exactly
    assert np.abs(m.evaluate(X[4]) - D[4]).max() > 1e-3
    # the caller's poses are not modified
    assert not np.array_equal(X[4], moved)


def test_pseudo_pose_index_out_of_range(rng):
    X, D = rng.normal(size=(5, 2)), rng.normal(size=(5, 3, 3))
    with pytest.raises(ShapeSpaceError) as e:
        train_psd(X, D, "sbe", pseudo_poses={5: [0.0, 0.0]})
    assert e.value.code == "range"


def test_single_example_is_constant(rng):
    X, D = rng.normal(size=(1, 4)), rng.normal(size=(1, 5, 3))
    m = train_psd(X, D, "psd", epsilon=1.0)
    np.testing.assert_allclose(m.evaluate(X[0]), D[0], atol=1e-12)
    x = X[0] + 0.5
    np.testing.assert_allclose(m.evaluate(x), np.exp(-np.sum(0.25 * 4)) * D[0], atol=1e-12)


# ------------------------------------------------------------------ weighted PSD
GROUP_COLUMNS = [np.array([0, 1]), np.array([2, 3, 4]), np.array([5])]


def wpsd_setup(rng, K=7, p=12):
    X = rng.normal(size=(K, 6))
    D = rng.normal(size=(K, p, 3))
    gi = np.stack([rng.permutation(3)[:2] for _ in range(p)])
    gw = rng.uniform(0.1, 1.0, size=(p, 2))
    gi[0] = [0, -1]          # vertex 0: all weight on joint 0 (padding)
    gw[0] = [0.8, 0.3]
    gi[1] = [1, 2]           # vertex 1: all weight on joint 1 (zero weight on joint 2)
    gw[1] = [0.6, 0.0]
    return X, D, gi, gw


def reference_wpsd(X, D, gi, gw, columns, eps, x, v, smoothing=0.0):
    """Kurihara-Miyata weighted PSD for one vertex, computed directly."""
    G = len(columns)
    w = np.zeros(G)
    for g, wt in zip(gi[v], gw[v]):
        if g >= 0:
            w[g] += wt
    w = w / w.sum() if w.sum() > 1e-12 else np.full(G, 1.0 / G)

    def kernel_row(pose):
        d2 = np.array([sum(w[j] * np.sum((pose[columns[j]] - X[k][columns[j]]) ** 2) for j in range(G))
                       for k in range(len(X))])
        phi = np.exp(-(eps ** 2) * d2)
        return phi / phi.sum()

    A = np.array([kernel_row(X[i]) for i in range(len(X))]) + smoothing * np.eye(len(X))
    a = np.linalg.solve(A, D[:, v, :])
    return kernel_row(x) @ a


def test_wpsd_exact_at_examples(rng):
    X, D, gi, gw = wpsd_setup(rng)
    m = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=GROUP_COLUMNS)
    assert m.method == "wpsd"
    assert m.diagnostics["unweighted_vertices"] == 0
    d = cdist(X, X)
    assert m.epsilon == pytest.approx(2.0 / np.median(d[d > 0]), rel=1e-14)   # documented default
    for k in range(len(X)):
        np.testing.assert_allclose(m.evaluate(X[k]), D[k], rtol=0, atol=1e-8)


def test_wpsd_per_vertex_equals_independent_computation(rng):
    X, D, gi, gw = wpsd_setup(rng)
    # vertex_ridge=0: the exact Kurihara–Miyata interpolant, compared with the independent reference
    m = train_psd(X, D, "wpsd", epsilon=0.45, vertex_ridge=0.0, vertex_groups=gi, vertex_weights=gw,
                  group_columns=GROUP_COLUMNS)
    for x in rng.normal(size=(4, 6)):
        got = m.evaluate(x)
        cw = m.vertex_weights_at(x)
        np.testing.assert_allclose(cw.sum(axis=1), 1.0, atol=1e-14)
        for v in (0, 1, 2, 5, 11):
            ref = reference_wpsd(X, D, gi, gw, GROUP_COLUMNS, 0.45, x, v)
            np.testing.assert_allclose(got[v], ref, rtol=0, atol=1e-9 * max(1.0, np.abs(ref).max()))


def test_wpsd_locality_vs_plain_psd(rng):
    X, D, gi, gw = wpsd_setup(rng)
    m = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=GROUP_COLUMNS)
    plain = train_psd(X, D, "psd", epsilon=m.epsilon)
    x = rng.normal(size=6)
    y = x.copy()
    y[GROUP_COLUMNS[1]] += rng.normal(size=3)    # move joints 1 and 2 only
    y[GROUP_COLUMNS[2]] += 1.0
    a, b = m.evaluate(x), m.evaluate(y)
    # vertex 0 is skinned only to joint 0: its corrective does not see joints 1 and 2
    np.testing.assert_allclose(b[0], a[0], rtol=0, atol=1e-12)
    # other vertices do change
    assert np.abs(b[2:] - a[2:]).max() > 1e-3
    # plain PSD mixes every joint into every vertex
    assert np.abs(plain.evaluate(y)[0] - plain.evaluate(x)[0]).max() > 1e-3
    # vertex 1 is skinned only to joint 1 (zero weight on joint 2): moving joints 0 and 2 leaves it alone
    z = x.copy()
    z[GROUP_COLUMNS[0]] -= 0.7
    z[GROUP_COLUMNS[2]] += 2.0
    np.testing.assert_allclose(m.evaluate(z)[1], a[1], rtol=0, atol=1e-12)
    assert np.abs(m.evaluate(z)[0] - a[0]).max() > 1e-3


def test_wpsd_unweighted_vertices_use_equal_joint_weights(rng):
    X, D, gi, gw = wpsd_setup(rng)
    gw[3] = 0.0                 # no weight at all
    gi[7] = [-1, -1]            # only padding
    gw[7] = [0.5, 0.5]
    # vertex_ridge=0: the exact Kurihara–Miyata interpolant, compared with the independent reference
    m = train_psd(X, D, "wpsd", epsilon=0.5, vertex_ridge=0.0, vertex_groups=gi.copy(), vertex_weights=gw,
                  group_columns=GROUP_COLUMNS)
    assert m.diagnostics["unweighted_vertices"] == 2
    for k in range(len(X)):
        np.testing.assert_allclose(m.evaluate(X[k]), D[k], rtol=0, atol=1e-8)
    x = rng.normal(size=6)
    got = m.evaluate(x)
    for v in (3, 7):
        ref = reference_wpsd(X, D, gi, gw, GROUP_COLUMNS, 0.5, x, v)
        np.testing.assert_allclose(got[v], ref, rtol=0, atol=1e-9 * max(1.0, np.abs(ref).max()))
        # the same as a vertex whose weights are explicitly equal on every joint
        Dv = D[:, v:v + 1]
        equal = reference_wpsd(X, Dv, [[0, 1, 2]], [[1.0, 1.0, 1.0]], GROUP_COLUMNS, 0.5, x, 0)
        np.testing.assert_allclose(got[v], equal, rtol=0, atol=1e-9 * max(1.0, np.abs(equal).max()))


def test_wpsd_unweighted_vertex_with_as_many_influences_as_joints(rng):
    X, D = rng.normal(size=(6, 6)), rng.normal(size=(6, 4, 3))
    gi = np.array([[0, 1, 2], [1, -1, -1], [-1, -1, -1], [1, 0, -1]])
    gw = np.array([[0.2, 0.3, 0.5], [1.0, 0, 0], [0.0, 0, 0], [0.5, 0.5, 0]])
    m = train_psd(X, D, "wpsd", epsilon=0.6, vertex_ridge=0.0, vertex_groups=gi.copy(), vertex_weights=gw,
                  group_columns=GROUP_COLUMNS)
    assert m.diagnostics["unweighted_vertices"] == 1
    x = rng.normal(size=6)
    got = m.evaluate(x)
    for v in range(4):
        ref = reference_wpsd(X, D, gi, gw, GROUP_COLUMNS, 0.6, x, v)
        np.testing.assert_allclose(got[v], ref, rtol=0, atol=1e-9 * max(1.0, np.abs(ref).max()))


def test_wpsd_does_not_modify_callers_vertex_groups(rng):
    X, D = rng.normal(size=(6, 6)), rng.normal(size=(6, 3, 3))
    gi = np.array([[0, 1, 2], [-1, -1, -1], [1, -1, -1]], dtype=np.int64)
    gw = np.array([[0.2, 0.3, 0.5], [0.0, 0, 0], [1.0, 0, 0]])
    before = gi.copy()
    train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=GROUP_COLUMNS)
    np.testing.assert_array_equal(gi, before)


def test_wpsd_has_no_global_weights(rng):
    X, D, gi, gw = wpsd_setup(rng)
    m = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=GROUP_COLUMNS)
    with pytest.raises(ShapeSpaceError) as e:
        m.weights(X[0])
    assert e.value.code == "method"


def test_wpsd_chunking_does_not_change_the_result(rng):
    X, D, gi, gw = wpsd_setup(rng)
    a = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=GROUP_COLUMNS)
    b = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=GROUP_COLUMNS, chunk=5)
    x = rng.normal(size=6)
    np.testing.assert_allclose(b.evaluate(x), a.evaluate(x), rtol=0, atol=1e-12)


@pytest.mark.parametrize("missing", ["vertex_groups", "vertex_weights", "group_columns"])
def test_wpsd_without_skin_inputs(rng, missing):
    X, D, gi, gw = wpsd_setup(rng)
    kwargs = dict(vertex_groups=gi, vertex_weights=gw, group_columns=GROUP_COLUMNS)
    kwargs[missing] = None
    with pytest.raises(ShapeSpaceError) as e:
        train_psd(X, D, "wpsd", **kwargs)
    assert e.value.code == "wpsd_inputs"


def test_wpsd_skin_shape_mismatch(rng):
    X, D, gi, gw = wpsd_setup(rng)
    for bad_gi, bad_gw in ((gi[:-1], gw[:-1]), (gi, gw[:, :1])):
        with pytest.raises(ShapeSpaceError) as e:
            train_psd(X, D, "wpsd", vertex_groups=bad_gi, vertex_weights=bad_gw, group_columns=GROUP_COLUMNS)
        assert e.value.code == "shape"


# ------------------------------------------------------------------ bad examples
def test_duplicate_pose_with_identical_sculpt(rng):
    X, D = smooth_family(rng, K=8, d=3, p=6)
    X[5], D[5] = X[2], D[2]
    names = [f"pose{k}" for k in range(8)]
    issues = example_issues(X, D, names)
    dup = [i for i in issues if i.code == "duplicate_pose"]
    assert len(dup) == 1 and dup[0].severity == "warning"
    assert dup[0].items == ("pose2", "pose5")
    assert "pose2" in dup[0].message and "pose5" in dup[0].message
    assert not any(i.code == "conflicting_examples" for i in issues)

    m = train_psd(X, D, "psd", epsilon=1.2)
    lam = m.diagnostics["smoothing"]
    assert lam > 0
    x = np.vstack([X, rng.uniform(-1, 1, size=(5, 3))])
    ref = gaussian_cardinal(X, x, 1.2, smoothing=lam)
    got = np.array([m.weights(xi) for xi in x])
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-8 * np.abs(ref).max())
    # default epsilon and Shape-by-Example train too
    for method in ("psd", "sbe"):
        mm = train_psd(X, D, method)
        assert mm.diagnostics["smoothing"] > 0
        assert np.isfinite(mm.evaluate(X[2])).all()


def test_conflicting_examples_still_train(rng):
    X, D = smooth_family(rng, K=8, d=3, p=6)
    X[6] = X[1] + 1e-9
    D[6] = D[1] + 0.5
    issues = example_issues(X, D, [f"e{k}" for k in range(8)])
    conf = [i for i in issues if i.code == "conflicting_examples"]
    assert len(conf) == 1 and conf[0].items == ("e1", "e6")
    assert not any(i.code == "duplicate_pose" for i in issues)
    for method in ("psd", "sbe"):
        m = train_psd(X, D, method)
        assert m.diagnostics["smoothing"] > 0
        out = m.evaluate(X[1])
        assert np.isfinite(out).all()
        # two different sculpts at the same pose: the fit lands between them, not on either extreme
        mid = 0.5 * (D[1] + D[6])
        assert np.abs(out - mid).max() <= 0.25
        # far-away examples are still (nearly) reproduced
        assert np.isfinite(m.evaluate(X[3])).all()


def test_example_issues_without_correctives_reports_duplicate():
    X = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    issues = example_issues(X)
    assert [(i.code, i.items) for i in issues] == [("duplicate_pose", ("example 1", "example 3"))]


def test_rest_pose_example(rng):
    X, D = smooth_family(rng, K=8, d=3, p=6)
    X[0] = 0.0
    D[0] = 0.0                    # no corrective needed at rest
    for method in ("psd", "sbe"):
        m = train_psd(X, D, method)
        np.testing.assert_allclose(m.evaluate(np.zeros(3)), 0.0, atol=1e-9)
        assert example_errors(m, X, D) <= 1e-9
    codes = [i.code for i in example_issues(X, D)]
    assert "duplicate_pose" not in codes and "constant_dimension" not in codes


def test_constant_dimension_psd(rng):
    X, D = smooth_family(rng, K=8, d=3, p=6)
    X[:, 1] = 0.25
    issues = example_issues(X, D)
    const = [i for i in issues if i.code == "constant_dimension"]
    assert len(const) == 1 and const[0].severity == "info"
    assert "1 pose-space dimension" in const[0].message
    m = train_psd(X, D, "psd")
    assert example_errors(m, X, D) <= 1e-9
    ref = gaussian_cardinal(X, [0.1, 0.9, -0.2], m.epsilon)[0]
    np.testing.assert_allclose(m.weights([0.1, 0.9, -0.2]), ref, atol=1e-9 * max(1, np.abs(ref).max()))


def test_constant_dimension_sbe_drops_the_undetermined_linear_term(rng):
    X, D = smooth_family(rng, K=8, d=3, p=6)
    X[:, 1] = 0.25
    m = train_psd(X, D, "sbe")
    # the examples span only a plane: no affine function of all 3 features is determined
    assert m.diagnostics["degree"] == 0
    assert example_errors(m, X, D) <= 1e-9


def test_coplanar_examples_sbe(rng):
    # poses on a tilted plane (not axis-aligned): the linear part is undetermined as well
    X, D = smooth_family(rng, K=8, d=3, p=6)
    X[:, 2] = 0.3 * X[:, 0] - 0.7 * X[:, 1] + 0.1
    m = train_psd(X, D, "sbe")
    assert m.diagnostics["degree"] == 0
    assert example_errors(m, X, D) <= 1e-9


def test_constant_dimension_driver(rng):
    X = rng.normal(size=(8, 3))
    X[:, 2] = -1.0
    V = rng.normal(size=(8, 2))
    drv = train_driver(X, V, ["a", "b"])
    for k in range(8):
        out = drv(X[k])
        np.testing.assert_allclose([out["a"], out["b"]], V[k], rtol=0, atol=1e-9)


def outlier_grid(rng):
    g = np.linspace(-1.0, 1.0, 4)
    X = np.array([[a, b] for a in g for b in g])
    b1, b2 = rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    D = np.sin(X[:, 0])[:, None, None] * b1 + np.cos(X[:, 1])[:, None, None] * b2
    return X, D


def angle_family(rng):
    th = np.linspace(0.0, 1.4, 8)
    X = np.stack([np.cos(th) - 1.0, np.sin(th)], axis=1)
    b1, b2 = rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    D = np.sin(th)[:, None, None] * b1 + (1.0 - np.cos(th))[:, None, None] * b2
    return X, D


def test_outlier_flagged_by_name(rng):
    X, D = outlier_grid(rng)
    names = [f"sculpt_{k:02d}" for k in range(16)]
    D[0] *= 50.0
    out = [i for i in example_issues(X, D, names) if i.code == "outlier"]
    assert len(out) == 1
    assert out[0].severity == "warning"
    assert out[0].items == ("sculpt_00",)
    assert "sculpt_00" in out[0].message


def test_outlier_check_skipped_with_duplicates(rng):
    X, D = outlier_grid(rng)
    D[0] *= 50.0
    X[9], D[9] = X[4], D[4]
    codes = [i.code for i in example_issues(X, D)]
    assert "duplicate_pose" in codes and "outlier" not in codes


# (the angle family's example 0 is the rest pose with a zero corrective: ×50 leaves it unchanged, so it is
# not an outlier and is not listed)
@pytest.mark.parametrize("family, k", [("angle", 3), ("angle", 4), ("grid", 5), ("grid", 10)])
def test_interior_outlier_flagged_by_name(rng, family, k):
    X, D = angle_family(rng) if family == "angle" else outlier_grid(rng)
    names = [f"pose_{j}" for j in range(len(X))]
    D[k] *= 50.0
    out = [i for i in example_issues(X, D, names) if i.code == "outlier"]
    assert [i.items for i in out] == [(names[k],)]


def test_smooth_family_has_no_outlier(rng):
    X, D = angle_family(rng)
    assert not [i for i in example_issues(X, D) if i.code == "outlier"]


# ------------------------------------------------------------------ input validation
@pytest.mark.parametrize("case", ["poses_1d", "poses_3d", "count", "last_dim", "corr_2d", "nan_pose",
                                  "inf_corr", "empty"])
def test_bad_shapes_and_values(rng, case):
    X, D = rng.normal(size=(5, 2)), rng.normal(size=(5, 4, 3))
    code = "shape"
    if case == "poses_1d":
        X = X[:, 0]
    elif case == "poses_3d":
        X = X[:, :, None]
    elif case == "count":
        D = D[:4]
    elif case == "last_dim":
        D = D[..., :2]
    elif case == "corr_2d":
        D = D[:, :, 0]
    elif case == "nan_pose":
        X[2, 1], code = np.nan, "non_finite"
    elif case == "inf_corr":
        D[1, 2, 0], code = np.inf, "non_finite"
    elif case == "empty":
        X, D, code = np.zeros((0, 2)), np.zeros((0, 4, 3)), "no_examples"
    for method in ("psd", "sbe", "wpsd"):
        with pytest.raises(ShapeSpaceError) as e:
            train_psd(X, D, method)
        assert e.value.code == code


def test_unknown_method(rng):
    with pytest.raises(ShapeSpaceError) as e:
        train_psd(rng.normal(size=(4, 2)), rng.normal(size=(4, 3, 3)), "rbf")
    assert e.value.code == "method"


def test_deformer_is_plain_data(rng):
    X, D = rng.normal(size=(5, 2)), rng.normal(size=(5, 4, 3))
    m = train_psd(X, D, "psd")
    assert isinstance(m, PoseSpaceDeformer)
    np.testing.assert_array_equal(m.correctives, D)
    np.testing.assert_array_equal(m.poses, X)
    assert m.evaluate(X[0]).shape == (4, 3)


# ------------------------------------------------------------------ scalar drivers
def test_train_driver_interpolates_and_names(rng):
    X = rng.normal(size=(9, 3))
    V = rng.normal(size=(9, 3))
    names = ["smile", "jaw.rot", "exertion"]
    drv = train_driver(X, V, names)
    for k in range(9):
        out = drv(X[k])
        assert isinstance(out, dict) and list(out) == names
        assert all(isinstance(v, float) for v in out.values())
        np.testing.assert_allclose([out[n] for n in names], V[k], rtol=0, atol=1e-9)
    ref = RBFInterpolator(X, V, kernel="thin_plate_spline", epsilon=1.0, degree=1)
    for x in rng.normal(size=(5, 3)):
        out = drv(x)
        np.testing.assert_allclose([out[n] for n in names], ref(x[None])[0], rtol=0, atol=1e-9)


def test_train_driver_few_examples_and_single_target(rng):
    X = rng.normal(size=(3, 3))                 # K < d + 2: constant polynomial, multiquadric
    v = rng.normal(size=3)
    drv = train_driver(X, v, ["key"])
    for k in range(3):
        assert drv(X[k]) == {"key": pytest.approx(v[k], abs=1e-9)}
    ref = RBFInterpolator(X, v, kernel="multiquadric", epsilon=1.0, degree=0)
    x = rng.normal(size=3)
    assert drv(x)["key"] == pytest.approx(ref(x[None])[0], abs=1e-9)


def test_train_driver_gaussian_and_name_count(rng):
    X, V = rng.normal(size=(6, 2)), rng.normal(size=(6, 2))
    drv = train_driver(X, V, ["a", "b"], kernel="gaussian", epsilon=0.8, degree=-1)
    ref = gaussian_cardinal(X, [0.3, -0.2], 0.8)[0] @ V
    out = drv([0.3, -0.2])
    np.testing.assert_allclose([out["a"], out["b"]], ref, atol=1e-9)
    with pytest.raises(ShapeSpaceError) as e:
        train_driver(X, V, ["a"])
    assert e.value.code == "shape"


def test_train_driver_duplicate_pose_regularised(rng):
    X, V = rng.normal(size=(7, 2)), rng.normal(size=(7, 1))
    X[4], V[4] = X[1], V[1]
    drv = train_driver(X, V, ["k"])
    lam = drv.interpolant.smoothing
    assert lam > 0
    ref = RBFInterpolator(X, V, kernel="thin_plate_spline", epsilon=1.0, degree=1, smoothing=lam)
    for x in np.vstack([X[1], rng.normal(size=(4, 2))]):
        assert drv(x)["k"] == pytest.approx(ref(x[None])[0, 0], abs=1e-7)


def test_wpsd_stabiliser_leaves_well_conditioned_vertices_exact_and_tames_the_rest(rng):
    """The default per-vertex ridge only touches vertices whose coefficients blow up."""
    X, D, gi, gw = wpsd_setup(rng)
    exact = train_psd(X, D, "wpsd", vertex_ridge=0.0, vertex_groups=gi, vertex_weights=gw,
                      group_columns=GROUP_COLUMNS)
    tamed = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=GROUP_COLUMNS)
    from core.posespace.psd import AMPLIFICATION_LIMIT
    scale = np.abs(D).max(axis=(0, 2))
    wild = np.abs(exact.folded).max(axis=(1, 2)) > AMPLIFICATION_LIMIT * scale
    np.testing.assert_array_equal(tamed.folded[~wild], exact.folded[~wild])
    assert np.all(np.abs(tamed.folded).max(axis=(1, 2)) <= AMPLIFICATION_LIMIT * scale + 1e-12) or wild.any()
    assert tamed.diagnostics["ridged_vertices"] == int(wild.sum())


# ------------------------------------------------------------------ ShapeSpace's own choices
def test_skin_group_inputs_map_bones_to_pose_space_sources():
    from core.posespace import PoseReader, skin_group_inputs
    readers = [PoseReader("rotation", "arm"), PoseReader("twist", "fore"), PoseReader("swing", "arm"),
               PoseReader("property", "exertion")]
    bone_names = ["root", "arm", "fore", "hand"]
    bone_index = np.array([[1, 2, -1], [0, 3, -1], [2, 1, 0]])
    bone_weights = np.array([[0.7, 0.3, 0.0], [0.5, 0.5, 0.0], [0.2, 0.6, 0.2]])
    out = skin_group_inputs(readers, bone_names, bone_index, bone_weights)
    # sources in first-seen order: arm (rotation 0-8, swing 11-13), fore (twist 9-10), exertion (14)
    assert [c.tolist() for c in out["group_columns"]] == [list(range(9)) + [11, 12, 13], [9, 10], [14]]
    np.testing.assert_array_equal(out["vertex_groups"], [[0, 1, -1], [-1, -1, -1], [1, 0, -1]])
    np.testing.assert_array_equal(out["vertex_weights"], [[0.7, 0.3, 0.0], [0.0, 0.0, 0.0], [0.2, 0.6, 0.0]])


def test_train_target_driver_is_a_gaussian_of_the_default_width(rng):
    from core.posespace import train_target_driver
    for K, degree in ((1, -1), (2, -1), (4, 0), (6, 1)):   # linear part once K ≥ d + 2 (random poses)
        X, V = rng.normal(size=(K, 3)), rng.normal(size=(K, 2))
        drv = train_target_driver(X, V, ["a", "b"])
        d = cdist(X, X)
        eps = 1.0 / np.median(d[d > 0]) if K > 1 else 1.0
        ref = RBFInterpolator(X, V, kernel="gaussian", epsilon=eps, degree=degree)
        x = rng.normal(size=3)
        out = drv(x)
        np.testing.assert_allclose([out["a"], out["b"]], ref(x[None])[0], rtol=0, atol=1e-9)
        assert drv.interpolant.kernel == "gaussian" and drv.interpolant.epsilon == pytest.approx(eps)


# ------------------------------------------------------------------ weighted PSD at memory speed (#16)
# The float32 layout against the float64 evaluation, and the blended distance.
COLUMNS = [np.arange(0, 3), np.arange(3, 6), np.arange(6, 9)]


@pytest.fixture
def wpsd_rng():
    return np.random.default_rng(3)


def setup(wpsd_rng, K=9, p=40, smooth=True):
    X = wpsd_rng.normal(size=(K, 9)) * 0.5
    gi = np.stack([wpsd_rng.permutation(3)[:2] for _ in range(p)])
    gw = wpsd_rng.uniform(0.1, 1.0, size=(p, 2))
    if smooth:   # correctives that are smooth functions of the pose
        dirs = wpsd_rng.normal(size=(p, 3))
        D = np.stack([np.sin(x[:3].sum()) * np.cos(x[3:6].sum() + x[6]) * dirs for x in X]) * 0.05
    else:
        D = wpsd_rng.normal(size=(K, p, 3)) * 0.05
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
def test_fast_float32_within_1e6_of_the_size(wpsd_rng, smooth):
    X, D, gi, gw = setup(wpsd_rng, smooth=smooth)
    m = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)
    size = 1.0                                     # a mesh 20× the largest corrective coordinate or more
    m.prepare_fast(size)
    for _ in range(10):
        x = wpsd_rng.normal(size=9) * 0.6
        fast = m.evaluate_fast(x)
        assert fast.dtype == np.float32
        assert np.abs(fast - m.evaluate(x)).max() <= 1e-6 * size


def test_fast_default_size_is_the_corrective_and_cancelling_vertices_stay_float64(wpsd_rng):
    X, D, gi, gw = setup(wpsd_rng, smooth=False)
    m = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)
    m.prepare_fast()
    fast = m._fast
    assert fast.idx32.size + fast.idx64.size == D.shape[1]
    big = np.abs(m.folded).max(axis=(1, 2))
    assert (big[fast.idx64] > big[fast.idx32].max()).all() if fast.idx32.size and fast.idx64.size else True
    for _ in range(5):
        x = wpsd_rng.normal(size=9) * 0.6
        assert np.abs(m.evaluate_fast(x) - m.evaluate(x)).max() <= 1e-6 * np.abs(D).max()


def test_fast_skips_vertices_without_correctives_and_survives_far_poses(wpsd_rng):
    X, D, gi, gw = setup(wpsd_rng)
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


def test_blend_zero_is_todays_weighted_psd_exactly(wpsd_rng):
    X, D, gi, gw = setup(wpsd_rng)
    kw = dict(vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)
    today = train_psd(X, D, "wpsd", **kw)
    for blend in (0.0, np.zeros(D.shape[1])):
        m = train_psd(X, D, "wpsd", blend=blend, **kw)
        assert m.blend is None
        np.testing.assert_array_equal(m.folded, today.folded)
        x = wpsd_rng.normal(size=9)
        np.testing.assert_array_equal(m.evaluate(x), today.evaluate(x))


def test_blend_one_is_global_distance_psd_exactly(wpsd_rng):
    X, D, gi, gw = setup(wpsd_rng, K=7, p=6)
    m = train_psd(X, D, "wpsd", blend=1.0, vertex_ridge=0.0, vertex_groups=gi, vertex_weights=gw,
                  group_columns=COLUMNS)
    for _ in range(4):
        x = wpsd_rng.normal(size=9) * 0.5
        ref = normalised_rbf(X, D, m.epsilon, lambda a, b: 0.25 * np.sum((a - b) ** 2), x).reshape(-1, 3)
        np.testing.assert_allclose(m.evaluate(x), ref, rtol=0, atol=1e-10)
        np.testing.assert_allclose(m.evaluate_fast(x), ref, rtol=0, atol=1e-6 * np.abs(D).max())
    for k in range(len(X)):        # interpolates the examples
        np.testing.assert_allclose(m.evaluate(X[k]), D[k], rtol=0, atol=1e-9)


def test_blend_in_between_is_the_blended_metric(wpsd_rng):
    X, D, gi, gw = setup(wpsd_rng, K=6, p=5)
    lam = np.array([0.0, 0.3, 0.5, 0.9, 1.0])
    m = train_psd(X, D, "wpsd", blend=lam, vertex_ridge=0.0, vertex_groups=gi, vertex_weights=gw,
                  group_columns=COLUMNS)
    x = wpsd_rng.normal(size=9) * 0.5
    for v in range(5):
        w = np.zeros(3)
        np.add.at(w, gi[v], gw[v])
        w /= w.sum()

        def d2(a, b, v=v, w=w):
            skin = sum(w[j] * np.sum((a[c] - b[c]) ** 2) for j, c in enumerate(COLUMNS))
            return (1 - lam[v]) * skin + lam[v] * 0.25 * np.sum((a - b) ** 2)
        ref = normalised_rbf(X, D[:, v:v + 1], m.epsilon, d2, x)
        np.testing.assert_allclose(m.evaluate(x)[v], ref, rtol=0, atol=1e-10)


def test_blend_refuses_out_of_range(wpsd_rng):
    X, D, gi, gw = setup(wpsd_rng)
    with pytest.raises(ShapeSpaceError) as e:
        train_psd(X, D, "wpsd", blend=1.5, vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)
    assert e.value.code == ErrorCode.RANGE
    with pytest.raises(ShapeSpaceError):
        train_psd(X, D, "wpsd", blend="sometimes", vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)


def test_loo_closed_form_equals_refitting(wpsd_rng):
    X, D, gi, gw = setup(wpsd_rng, K=7, p=3)
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


def test_auto_blend_helps_a_corrective_of_joints_the_vertex_ignores(wpsd_rng):
    """The two-joint bulge: vertices skinned to joint 0 only, corrective driven by joints 0 and 1."""
    K, p = 16, 30
    X = wpsd_rng.uniform(-1, 1, size=(K, 9))
    gi = np.zeros((p, 1), dtype=int)
    gw = np.ones((p, 1))
    dirs = wpsd_rng.normal(size=(p, 3))

    def bulge(x):
        return 0.05 * np.sin(x[0] + x[1]) * np.sin(x[3] + x[4]) * dirs
    D = np.stack([bulge(x) for x in X])
    kw = dict(vertex_groups=gi, vertex_weights=gw, group_columns=COLUMNS)
    plain = train_psd(X, D, "wpsd", **kw)
    auto = train_psd(X, D, "wpsd", blend="auto", **kw)
    assert auto.diagnostics["blend_regions"][0][0] > 0
    tests = wpsd_rng.uniform(-1, 1, size=(40, 9))
    err = lambda m: np.mean([np.abs(m.evaluate(x) - bulge(x)).max() for x in tests])  # noqa: E731
    assert err(auto) < 0.7 * err(plain)
