"""BlendshapeModel evaluation and diagnose_model, against hand-written references."""
import numpy as np
import pytest

from core.blendshape import BlendshapeModel, bounding_box_diagonal, diagnose_model
from core.result import ShapeSpaceError


def random_model(seed=0, p=7, n=5, **kw):
    rng = np.random.default_rng(seed)
    neutral = rng.normal(size=(p, 3))
    deltas = rng.normal(size=(n, p, 3)) * 0.1
    names = [f"key{k}" for k in range(n)]
    return BlendshapeModel(neutral, deltas, names, **kw), neutral, deltas


def reference_eval(neutral, deltas, w, lo, hi, mute=None):
    """neutral + sum_k clamp(w_k) * delta_k, one key at a time (no matrix algebra)."""
    out = neutral.copy()
    for k in range(deltas.shape[0]):
        if mute is not None and mute[k]:
            continue
        wk = min(max(w[k], lo[k]), hi[k])
        out = out + wk * deltas[k]
    return out


# ----------------------------------------------------------------- evaluation
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_evaluate_matches_hand_sum(seed):
    model, neutral, deltas = random_model(seed)
    w = np.random.default_rng(100 + seed).uniform(0, 1, size=5)
    expected = reference_eval(neutral, deltas, w, np.zeros(5), np.ones(5))
    np.testing.assert_allclose(model.evaluate(w), expected, rtol=0, atol=1e-12)


def test_evaluate_defaults_to_stored_values():
    _, neutral, deltas = random_model(3)
    values = np.array([0.1, 0.0, 0.5, 1.0, 0.25])
    model = BlendshapeModel(neutral, deltas, list("abcde"), values=values)
    np.testing.assert_allclose(model.evaluate(), reference_eval(neutral, deltas, values, np.zeros(5), np.ones(5)),
                               atol=1e-12)


def test_zero_weights_give_neutral():
    model, neutral, _ = random_model(4)
    np.testing.assert_array_equal(model.evaluate(np.zeros(5)), neutral)


def test_delta_matrix_layout_and_row_order():
    model, _, deltas = random_model(5, p=4, n=3)
    B = model.delta_matrix
    assert B.shape == (12, 3)
    for k in range(3):
        for i in range(4):
            for c in range(3):  # row 3*i + c is coordinate c of vertex i
                assert B[3 * i + c, k] == deltas[k, i, c]


def test_accepts_3p_by_n_layout():
    model, neutral, deltas = random_model(6, p=6, n=4)
    p, n = 6, 4
    B = np.zeros((3 * p, n))
    for k in range(n):
        for i in range(p):
            B[3 * i:3 * i + 3, k] = deltas[k, i]
    model2 = BlendshapeModel(neutral, B, list("abcd"))
    assert model2.deltas.shape == (n, p, 3)
    np.testing.assert_array_equal(model2.deltas, deltas)
    np.testing.assert_array_equal(model2.delta_matrix, B)
    w = np.array([0.3, 0.9, 0.0, 0.6])
    np.testing.assert_array_equal(model2.evaluate(w), model.evaluate(w))


def test_evaluate_equals_b0_plus_Bw():
    model, neutral, _ = random_model(7)
    w = np.array([0.2, 0.4, 0.6, 0.8, 1.0])
    flat = neutral.reshape(-1) + model.delta_matrix @ w
    np.testing.assert_allclose(model.evaluate(w).reshape(-1), flat, atol=1e-12)


@pytest.mark.parametrize("lo,hi", [(0.0, 1.0), (-1.0, 2.0), (-0.5, 0.25), (0.3, 0.3)])
def test_weights_are_clamped_to_slider_range(lo, hi):
    _, neutral, deltas = random_model(8)
    smin, smax = np.full(5, lo), np.full(5, hi)
    model = BlendshapeModel(neutral, deltas, list("abcde"), slider_min=smin, slider_max=smax)
    w = np.array([-5.0, -0.7, 0.1, 1.5, 9.0])
    expected = reference_eval(neutral, deltas, w, smin, smax)
    np.testing.assert_allclose(model.evaluate(w), expected, atol=1e-12)
    np.testing.assert_array_equal(model.effective_weights(w), np.clip(w, lo, hi))


def test_per_key_slider_ranges_and_values_beyond_one():
    _, neutral, deltas = random_model(9)
    smin = np.array([0.0, -1.0, -2.0, 0.5, 0.0])
    smax = np.array([1.0, 2.0, -1.0, 0.75, 10.0])
    model = BlendshapeModel(neutral, deltas, list("abcde"), slider_min=smin, slider_max=smax)
    w = np.array([1.7, 1.7, 1.7, 1.7, 1.7])
    eff = [1.0, 1.7, -1.0, 0.75, 1.7]
    expected = neutral + sum(e * d for e, d in zip(eff, deltas))
    np.testing.assert_allclose(model.evaluate(w), expected, atol=1e-12)


def test_muted_keys_contribute_nothing():
    _, neutral, deltas = random_model(10)
    mute = np.array([False, True, False, True, False])
    model = BlendshapeModel(neutral, deltas, list("abcde"), mute=mute)
    w = np.full(5, 0.8)
    expected = neutral + 0.8 * (deltas[0] + deltas[2] + deltas[4])
    np.testing.assert_allclose(model.evaluate(w), expected, atol=1e-12)
    # a muted key at any value leaves the mesh alone
    only_muted = np.array([0.0, 1.0, 0.0, 1.0, 0.0])
    np.testing.assert_array_equal(model.evaluate(only_muted), neutral)


def test_batch_evaluation_equals_per_frame():
    _, neutral, deltas = random_model(11)
    smin, smax = np.full(5, -1.0), np.full(5, 2.0)
    model = BlendshapeModel(neutral, deltas, list("abcde"), slider_min=smin, slider_max=smax,
                            mute=[False, False, True, False, False])
    W = np.random.default_rng(12).uniform(-2, 3, size=(9, 5))
    batch = model.evaluate(W)
    assert batch.shape == (9, 7, 3)
    for f in range(9):
        np.testing.assert_allclose(batch[f], model.evaluate(W[f]), atol=1e-12)
        np.testing.assert_allclose(batch[f], reference_eval(neutral, deltas, W[f], smin, smax,
                                                            [False, False, True, False, False]),
                                   atol=1e-12)


def test_index_and_counts():
    model, _, _ = random_model(13)
    assert model.n_targets == 5 and model.n_vertices == 7
    assert model.index("key3") == 3
    with pytest.raises(ShapeSpaceError) as exc:
        model.index("nope")
    assert "nope" in str(exc.value)


def test_bounding_box_diagonal():
    pts = np.array([[0, 0, 0], [1, 2, 2], [0.5, 0.5, 0.5]])
    assert bounding_box_diagonal(pts) == pytest.approx(3.0)
    assert bounding_box_diagonal(np.zeros((0, 3))) == 0.0


def test_model_without_targets_evaluates_to_neutral():
    neutral = np.arange(12.0).reshape(4, 3)
    model = BlendshapeModel(neutral, np.zeros((0, 4, 3)), [])
    np.testing.assert_array_equal(model.evaluate(np.zeros(0)), neutral)
    assert model.delta_matrix.shape == (12, 0)
    assert diagnose_model(model).value == 0


# --------------------------------------------------------------------- errors
def _base():
    rng = np.random.default_rng(0)
    return rng.normal(size=(4, 3)), rng.normal(size=(2, 4, 3))


@pytest.mark.parametrize("kwargs,word", [
    (dict(neutral=np.zeros((4, 2))), "neutral"),
    (dict(neutral=np.zeros(12)), "neutral"),
    (dict(deltas=np.zeros((2, 5, 3))), "deltas"),
    (dict(deltas=np.zeros((2, 4, 2))), "deltas"),
    (dict(deltas=np.zeros((11, 2))), "deltas"),
    (dict(names=["only_one"]), "names"),
    (dict(names=["a", "b", "c"]), "names"),
    (dict(slider_min=[0.0, 0.0, 0.0]), "slider_min"),
    (dict(slider_max=[1.0]), "slider_max"),
    (dict(values=[0.0, 0.0, 0.0]), "values"),
])
def test_constructor_errors_name_the_argument(kwargs, word):
    neutral, deltas = _base()
    args = dict(neutral=neutral, deltas=deltas, names=["a", "b"])
    args.update(kwargs)
    with pytest.raises(ShapeSpaceError) as exc:
        BlendshapeModel(**args)
    assert word in str(exc.value)


def test_slider_min_greater_than_max_is_an_error_naming_the_key():
    neutral, deltas = _base()
    with pytest.raises(ShapeSpaceError) as exc:
        BlendshapeModel(neutral, deltas, ["a", "smile"], slider_min=[0.0, 1.5], slider_max=[1.0, 1.0])
    assert "slider_min" in str(exc.value) and "smile" in str(exc.value)
    assert "a," not in str(exc.value)


@pytest.mark.parametrize("w", [np.zeros(3), np.zeros(1), np.zeros((4, 3))])
def test_wrong_weights_length(w):
    neutral, deltas = _base()
    model = BlendshapeModel(neutral, deltas, ["a", "b"])
    with pytest.raises(ShapeSpaceError) as exc:
        model.evaluate(w)
    assert "weights" in str(exc.value)


# ---------------------------------------------------------------- diagnosis
def independent_model(seed=0, p=30, n=6, scale=1.0):
    rng = np.random.default_rng(seed)
    neutral = rng.normal(size=(p, 3)) * scale
    deltas = rng.normal(size=(n, p, 3)) * 0.05 * scale
    return neutral, deltas, [f"k{i}" for i in range(n)]


def codes(result, severity=None):
    return [i.code for i in result.issues if severity is None or i.severity == severity]


def test_clean_model_has_full_rank_and_no_issues():
    neutral, deltas, names = independent_model()
    res = diagnose_model(BlendshapeModel(neutral, deltas, names))
    assert res.status == 0 and res.success and res.issues == []
    assert res.value == np.linalg.matrix_rank(deltas.reshape(6, -1)) == 6


def test_empty_target_warning_names_the_key():
    neutral, deltas, names = independent_model()
    deltas[2] = 0.0
    names[2] = "mouthClose"
    res = diagnose_model(BlendshapeModel(neutral, deltas, names))
    assert res.status == 1 and res.success
    empty = [i for i in res.issues if i.code == "empty_target"]
    assert len(empty) == 1 and empty[0].severity == "warning"
    assert empty[0].items == ("mouthClose",)
    assert "mouthClose" in empty[0].message
    assert res.value == 5


def test_duplicate_targets_warning():
    neutral, deltas, names = independent_model()
    deltas[4] = deltas[1]
    res = diagnose_model(BlendshapeModel(neutral, deltas, names))
    dup = [i for i in res.issues if i.code == "duplicate_target"]
    assert len(dup) == 1 and dup[0].severity == "warning"
    assert set(dup[0].items) == {"k1", "k4"}
    assert "k1" in dup[0].message and "k4" in dup[0].message
    assert res.value == np.linalg.matrix_rank(deltas.reshape(6, -1)) == 5


def test_scaled_copy_is_not_a_duplicate_but_lowers_rank():
    neutral, deltas, names = independent_model()
    deltas[4] = 2.0 * deltas[1]
    res = diagnose_model(BlendshapeModel(neutral, deltas, names))
    assert "duplicate_target" not in codes(res)
    assert res.value == 5


@pytest.mark.parametrize("where", ["neutral", "target"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_is_an_error(where, bad):
    neutral, deltas, names = independent_model()
    if where == "neutral":
        neutral[3, 1] = bad
    else:
        deltas[2, 5, 0] = bad
    res = diagnose_model(BlendshapeModel(neutral, deltas, names))
    assert res.status < 0 and not res.success
    errs = res.errors()
    assert errs and errs[0].code == "non_finite"
    if where == "target":
        assert errs[0].items == ("k2",) and "k2" in errs[0].message


def test_relative_to_non_basis_warning():
    neutral, deltas, names = independent_model(n=3)
    rel = ["Basis", "k0", "Basis"]
    res = diagnose_model(BlendshapeModel(neutral, deltas, names, relative_to=rel))
    w = [i for i in res.issues if i.code == "relative_to_non_basis"]
    assert len(w) == 1 and w[0].severity == "warning" and w[0].items == ("k1",)
    assert "k1" in w[0].message and "k0" in w[0].message


def test_custom_reference_name_is_basis():
    neutral, deltas, names = independent_model(n=3)
    model = BlendshapeModel(neutral, deltas, names, reference_name="Neutral")
    assert model.relative_to == ["Neutral"] * 3
    assert diagnose_model(model).issues == []


def test_zero_slider_range_warning():
    neutral, deltas, names = independent_model(n=3)
    res = diagnose_model(BlendshapeModel(neutral, deltas, names, slider_min=[0, 0.5, 0], slider_max=[1, 0.5, 1]))
    z = [i for i in res.issues if i.code == "zero_range"]
    assert len(z) == 1 and z[0].items == ("k1",)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_rank_equals_numpy_rank_of_live_targets(seed):
    rng = np.random.default_rng(seed)
    neutral, deltas, names = independent_model(seed, n=8)
    deltas[5] = 0.3 * deltas[0] - 1.2 * deltas[1] + deltas[2]  # dependent combination
    deltas[6] = 0.0                                              # empty
    deltas[7] = rng.normal() * deltas[3]                         # parallel
    res = diagnose_model(BlendshapeModel(neutral, deltas, names))
    live = [k for k in range(8) if np.abs(deltas[k]).max() > 0]
    assert res.value == res.diagnostics["rank"] == np.linalg.matrix_rank(deltas[live].reshape(len(live), -1)) == 5


def test_rank_counts_small_localised_live_target():
    rng = np.random.default_rng(0)
    p = 4000
    neutral = rng.normal(size=(p, 3))
    deltas = np.zeros((3, p, 3))
    deltas[0] = rng.normal(size=(p, 3)) * 0.1
    deltas[1] = rng.normal(size=(p, 3)) * 0.1
    deltas[2, 5, 0] = 1e-5 * bounding_box_diagonal(neutral)  # 100x above the "counts as zero" threshold
    res = diagnose_model(BlendshapeModel(neutral, deltas, ["a", "b", "c"]))
    assert "empty_target" not in codes(res)
    assert res.value == np.linalg.matrix_rank(deltas.reshape(3, -1)) == 3


@pytest.mark.parametrize("factor", [1e4, 1e-2])
def test_diagnosis_is_unit_invariant(factor):
    neutral, deltas, names = independent_model(4, n=7)
    deltas[2] = 0.0
    deltas[5] = deltas[1]
    deltas[6] = deltas[0] + deltas[3]
    # a tiny-but-real target, well above the relative threshold
    deltas[4] *= 1e-3
    base = diagnose_model(BlendshapeModel(neutral, deltas, names))
    scaled = diagnose_model(BlendshapeModel(neutral * factor, deltas * factor, names))
    assert base.value == scaled.value == 4
    assert [(i.severity, i.code, i.items) for i in base.issues] == \
           [(i.severity, i.code, i.items) for i in scaled.issues]
    assert base.status == scaled.status == 1
    assert scaled.diagnostics["scale"] == pytest.approx(base.diagnostics["scale"] * factor)
