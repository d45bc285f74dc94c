"""Issue #10 hardening of the drag solve (core): non-finite input is refused naming the culprit, keys that move
no vertex keep their sliders in every solver route, and a solver stopped at its iteration limit says so."""
import numpy as np
import pytest

from core.blendshape import BlendshapeModel, Combination, InBetween
from core.manipulation import DragSession, Pin, WeightPrior, solve_drag, solve_drag_reference, train_prior
from core.result import ShapeSpaceError, Status

N, P = 12, 300
EMPTY = 4          # the key that moves no vertex
PARTNER = 2        # a live key the training animation couples EMPTY to


def _model(seed=0, empty=(EMPTY,), **kw):
    rng = np.random.default_rng(seed)
    neutral = rng.uniform(-1, 1, size=(P, 3)) * np.array([8.0, 11.0, 7.0])
    deltas = rng.normal(size=(N, P, 3)) * 0.5
    for e in empty:
        deltas[e] = 0.0
    return BlendshapeModel(neutral, deltas, [f"key{i:02d}" for i in range(N)], **kw)


def _pins_and_targets(model, seed=0, k=4, reach=0.3):
    rng = np.random.default_rng(seed + 100)
    verts = rng.choice(P, size=k, replace=False)
    pins = [Pin.at_vertex(int(v)) for v in verts]
    goal = np.clip(rng.uniform(0, 1, N) + reach, 0, 1)
    targets = model.neutral[verts] + np.tensordot(goal, model.deltas[:, verts, :], axes=1)
    return pins, targets


def _coupled_frames(f=200, seed=3):
    """Training animation in which the empty key always moves with PARTNER (so a prior couples them)."""
    rng = np.random.default_rng(seed)
    W = np.clip(rng.uniform(0.1, 0.6, size=(f, N)) * 0.3 + 0.2, 0, 1)
    drive = rng.uniform(0, 1, f)
    W[:, PARTNER] = drive
    W[:, EMPTY] = 0.9 * drive + 0.05
    W[:, 7] = 0.8 * drive + 0.1 * rng.normal(size=f)
    return np.clip(W, 0, 1)


# =========================================================================== non-finite input (r08)
def _raises(fn, *words):
    with pytest.raises(ShapeSpaceError) as exc:
        fn()
    assert exc.value.code == "non_finite", (exc.value.code, str(exc.value))
    for word in words:
        assert word in str(exc.value), (word, str(exc.value))
    return str(exc.value)


def test_nan_neutral_is_refused_naming_the_vertex():
    model = _model()
    model.neutral[17, 1] = np.nan
    pins, targets = _pins_and_targets(_model())
    _raises(lambda: solve_drag(model, pins, targets), "reference key", "vertex 17", "y = nan")
    _raises(lambda: solve_drag_reference(model, pins, targets), "vertex 17")


def test_nan_delta_is_refused_naming_key_and_vertex():
    model = _model()
    model.deltas[6, 40, 2] = np.inf
    pins, targets = _pins_and_targets(_model())
    _raises(lambda: solve_drag(model, pins, targets), "'key06'", "vertex 40", "z = inf")
    # also when only a vertex far from every pin is bad, and through a drag session
    _raises(lambda: solve_drag(model, pins, targets, session=DragSession()), "'key06'")


def test_nan_inbetween_and_combination_deltas_are_refused():
    base = _model()
    bad = np.zeros((P, 3))
    bad[9, 0] = np.nan
    pins, targets = _pins_and_targets(base)
    ib = BlendshapeModel(base.neutral, base.deltas, base.names,
                         inbetweens=[InBetween("key00_half", 0, (0.0, 0.5, 1.0), bad)])
    _raises(lambda: solve_drag(ib, pins, targets), "in-between key 'key00_half'", "vertex 9")
    cb = BlendshapeModel(base.neutral, base.deltas, base.names,
                         combinations=[Combination("key00_key01", (0, 1), bad)])
    _raises(lambda: solve_drag(cb, pins, targets), "combination key 'key00_key01'", "vertex 9")


@pytest.mark.parametrize("field", ["slider_min", "slider_max"])
def test_nan_slider_range_is_refused_naming_the_key(field):
    values = np.zeros(N) if field == "slider_min" else np.ones(N)
    values[3] = np.nan
    model = _model(**{field: values})
    pins, targets = _pins_and_targets(_model())
    _raises(lambda: solve_drag(model, pins, targets, w0=np.zeros(N)), "'key03'", field)


def test_nan_slider_values_w0_and_x0_are_refused_naming_the_key():
    values = np.zeros(N)
    values[5] = np.nan
    model = _model(values=values)
    pins, targets = _pins_and_targets(model)
    _raises(lambda: solve_drag(model, pins, targets), "'key05'", "value")
    w0 = np.zeros(N)
    w0[8] = np.inf
    _raises(lambda: solve_drag(_model(), pins, targets, w0=w0), "w0", "'key08'")
    x0 = np.zeros(N)
    x0[1] = np.nan
    _raises(lambda: solve_drag(_model(), pins, targets, w0=np.zeros(N), x0=x0), "x0", "'key01'")


def test_nan_target_is_refused_naming_the_pin():
    model = _model()
    pins, targets = _pins_and_targets(model)
    targets[2, 1] = np.nan
    _raises(lambda: solve_drag(model, pins, targets), "pin 2")


@pytest.mark.parametrize("name, value", [("alpha", np.inf), ("alpha", np.nan), ("mu", np.inf), ("mu", np.nan)])
def test_non_finite_regulariser_is_refused_naming_it(name, value):
    model = _model()
    pins, targets = _pins_and_targets(model)
    _raises(lambda: solve_drag(model, pins, targets, **{name: value}), name)


def test_non_finite_prior_is_refused():
    model = _model()
    pins, targets = _pins_and_targets(model)
    prior = train_prior(_coupled_frames(), model.names)
    mean = prior.mean.copy()
    mean[0] = np.nan
    broken = WeightPrior(prior.names, mean, prior.components, prior.variances, prior.coefficients, prior.eps)
    _raises(lambda: solve_drag(model, pins, targets, prior=broken), "prior's mean")
    for form in ("covariance", "pca"):
        res = solve_drag(model, pins, targets, prior=prior, prior_form=form)
        assert np.isfinite(res.weights).all()


@pytest.mark.parametrize("kw", [{"gn_tol": np.nan}, {"gn_tol": 0.0}, {"gn_max_iter": 0}, {"gn_max_iter": 2.5}])
def test_bad_stopping_rule_is_refused(kw):
    model = _model()
    pins, targets = _pins_and_targets(model)
    with pytest.raises(ShapeSpaceError) as exc:
        solve_drag(model, pins, targets, **kw)
    assert next(iter(kw)) in str(exc.value)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_targets_near_the_float_limit_never_give_nan_sliders():
    model = _model()
    pins, targets = _pins_and_targets(model)
    targets[0] = 1e300
    try:
        res = solve_drag(model, pins, targets, w0=np.zeros(N))
    except ShapeSpaceError as exc:
        assert exc.code == "non_finite"
    else:
        assert np.isfinite(res.weights).all()


def test_check_model_accepts_a_finite_rig():
    from core.manipulation.rig import check_model

    check_model(_model())


# =========================================================================== keys that move no vertex
def test_inert_keys_finds_empty_keys_but_not_keys_that_drive_moving_shapes():
    from core.manipulation.rig import inert_keys

    base = _model(empty=(EMPTY, 5, 6))
    moving = np.random.default_rng(1).normal(size=(P, 3))
    model = BlendshapeModel(base.neutral, base.deltas, base.names,
                            inbetweens=[InBetween("key05_half", 5, (0.0, 0.5, 1.0), moving)],
                            combinations=[Combination("key06_key00", (6, 0), moving)])
    assert np.flatnonzero(inert_keys(model)).tolist() == [EMPTY]
    tiny = base.deltas.copy()
    tiny[9] = 1e-9 * base.scale          # below 1e-7 × size: moves nothing visible
    assert inert_keys(BlendshapeModel(base.neutral, tiny, base.names))[9]


def _w0():
    w0 = np.full(N, 0.25)
    w0[EMPTY] = 0.3
    return w0


@pytest.mark.parametrize("route", ["direct", "covariance", "pca", "snap", "session"])
def test_empty_key_keeps_its_slider_in_every_linear_route(route):
    model = _model()
    pins, targets = _pins_and_targets(model)
    w0 = _w0()
    kw = {}
    if route in ("covariance", "pca", "snap"):
        kw["prior"] = train_prior(_coupled_frames(), model.names)
        kw["prior_form"] = "pca" if route == "pca" else "covariance"
        kw["snap"] = route == "snap"
    if route == "session":
        session = DragSession()
        for step in (0.2, 0.6, 1.0):
            res = solve_drag(model, pins, model.neutral[[p.vertices[0] for p in pins]] * (1 - step) + targets * step,
                             w0=w0, session=session)
            assert res.weights[EMPTY] == w0[EMPTY]
    res = solve_drag(model, pins, targets, w0=w0, **kw)
    assert res.weights[EMPTY] == w0[EMPTY], route
    assert res.diagnostics["inert"] == [model.names[EMPTY]]
    assert np.abs(res.weights - w0).max() > 0.05          # the drag did move the live keys
    assert np.isfinite(res.weights).all()


def test_learned_prior_would_couple_the_empty_key():
    """The scenario is meaningful: without the fix the coupled prior moves the empty key (facecap's tongueOut
    reached 0.46): give the empty key a tiny delta above the threshold and it follows its partner."""
    model = _model()
    deltas = model.deltas.copy()
    deltas[EMPTY, 0, 0] = 1e-4 * model.scale
    live = BlendshapeModel(model.neutral, deltas, model.names)
    pins, targets = _pins_and_targets(model)
    prior = train_prior(_coupled_frames(), model.names)
    res = solve_drag(live, pins, targets, w0=_w0(), prior=prior)
    assert abs(res.weights[EMPTY] - _w0()[EMPTY]) > 1e-3


def test_empty_key_keeps_its_slider_in_the_nonlinear_route():
    base = _model()
    rng = np.random.default_rng(7)
    ib = [InBetween("key00_half", 0, (0.0, 0.5, 1.0), rng.normal(size=(P, 3)) * 0.2)]
    cb = [Combination("key01_key03", (1, 3), rng.normal(size=(P, 3)) * 0.2)]
    model = BlendshapeModel(base.neutral, base.deltas, base.names, inbetweens=ib, combinations=cb)
    pins, targets = _pins_and_targets(base)
    w0 = _w0()
    prior = train_prior(_coupled_frames(), model.names)
    for kw in ({}, {"prior": prior}, {"prior": prior, "snap": True}):
        res = solve_drag(model, pins, targets, w0=w0, **kw)
        assert res.weights[EMPTY] == w0[EMPTY], kw
        assert np.abs(res.weights - w0).max() > 0.05


def test_reference_solver_holds_empty_keys_too():
    model = _model()
    pins, targets = _pins_and_targets(model)
    w0 = _w0()
    ref = solve_drag_reference(model, pins, targets, w0=w0)
    assert ref[EMPTY] == w0[EMPTY]
    np.testing.assert_allclose(solve_drag(model, pins, targets, w0=w0).weights, ref, atol=1e-6)


# =========================================================================== iteration limit
def test_gauss_newton_at_its_iteration_limit_reports_not_converged():
    base = _model(empty=())
    rng = np.random.default_rng(11)
    ib = [InBetween(f"key{i:02d}_half", i, (0.0, 0.5, 1.0), rng.normal(size=(P, 3)) * 0.5) for i in range(4)]
    cb = [Combination("key04_key05", (4, 5), rng.normal(size=(P, 3)) * 0.5)]
    model = BlendshapeModel(base.neutral, base.deltas, base.names, inbetweens=ib, combinations=cb)
    pins, targets = _pins_and_targets(base, k=8, reach=0.5)
    full = solve_drag(model, pins, targets, w0=np.zeros(N), alpha=1e-4, mu=1e-6)
    assert full.status != Status.NOT_CONVERGED
    short = solve_drag(model, pins, targets, w0=np.zeros(N), alpha=1e-4, mu=1e-6, gn_max_iter=1)
    assert short.status == Status.NOT_CONVERGED and not short.converged
    assert short.message.startswith("not converged")
    assert short.issues[0].code == "not_converged"
    assert np.isfinite(short.weights).all()
