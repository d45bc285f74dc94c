"""Issue #17 (core): what makes a drag solve cheap on a production face — the rig is checked once per model,
a cold solve costs only its own pins, the small systems are solved by Cholesky — without changing a result."""
import numpy as np
import pytest

import core.boxqp as boxqp
import core.manipulation.rig as rig
from core.blendshape import BlendshapeModel, InBetween
from core.manipulation import DragSession, Pin, PinRows, rig_facts, solve_drag, solve_drag_reference
from core.manipulation.pins import pin_matrix
from core.result import ShapeSpaceError

N, P = 30, 400


def _model(seed=0):
    rng = np.random.default_rng(seed)
    neutral = rng.uniform(-1, 1, size=(P, 3)) * np.array([8.0, 11.0, 7.0])
    deltas = rng.normal(size=(N, P, 3)) * 0.4
    deltas[5] = 0.0                                         # a key that moves nothing
    return BlendshapeModel(neutral, deltas, [f"key{i:02d}" for i in range(N)])


def _problem(model, k=6, seed=1):
    rng = np.random.default_rng(seed)
    verts = rng.choice(P, size=k, replace=False)
    pins = [Pin.at_vertex(int(v)) for v in verts[:-2]]
    pins += [Pin((int(verts[-2]), int(verts[-1]), 3), (0.2, 0.5, 0.3)), Pin((int(verts[-1]), 7), (0.6, 0.4))]
    goal = rng.uniform(0, 1, N)
    targets = PinRows(model, pins).positions(goal)
    return pins, targets


def test_rig_facts_are_computed_once_per_model_object(monkeypatch):
    model = _model()
    calls = []
    real = rig._peaks
    monkeypatch.setattr(rig, "_peaks", lambda d: calls.append(1) or real(d))
    pins, targets = _problem(model)
    for seed in range(3):                                   # three cold solves with different pins
        p, t = _problem(model, seed=seed + 5)
        solve_drag(model, p, t)
    solve_drag(model, pins, targets, session=DragSession())
    assert len(calls) == 1
    assert PinRows(model, pins).inert is rig_facts(model).inert
    assert rig_facts(model).inert.tolist() == [i == 5 for i in range(N)]
    solve_drag(_model(), pins, targets)                     # another model object: checked on its own
    assert len(calls) == 2


def test_a_refused_model_keeps_no_facts_and_is_refused_again():
    model = _model()
    model.deltas[9, 33, 1] = np.nan
    pins, targets = _problem(_model())
    for _ in range(2):
        with pytest.raises(ShapeSpaceError, match=r"'key09'.*vertex 33"):
            solve_drag(model, pins, targets)
    model.deltas[9, 33, 1] = 0.0
    assert solve_drag(model, pins, targets).success


@pytest.mark.parametrize("bad", [np.inf, -np.inf])
def test_infinite_displacements_and_driven_deltas_are_caught_by_the_fast_check(bad):
    model = _model()
    model.deltas[2, 0, 0] = bad
    pins, targets = _problem(_model())
    with pytest.raises(ShapeSpaceError, match=r"'key02'.*vertex 0"):
        solve_drag(model, pins, targets)
    base = _model()
    delta = np.zeros((P, 3))
    delta[12, 2] = bad
    driven = BlendshapeModel(base.neutral, base.deltas, base.names, inbetweens=[InBetween("key01_half", 1,
                                                                                         (0.0, 0.5, 1.0), delta)])
    with pytest.raises(ShapeSpaceError, match=r"in-between key 'key01_half'.*vertex 12"):
        solve_drag(driven, pins, targets)


def test_the_pin_rows_match_the_dense_gather():
    """Rows gathered slot by slot (a vertex pin uses one of its three) equal the plain barycentric sum."""
    model = _model()
    model.mute[[3, 17]] = True
    pins, _ = _problem(model)
    dense = np.stack([sum(w * model.deltas[:, v, :] for v, w in zip(p.vertices, p.weights)) for p in pins])
    want = np.transpose(dense, (0, 2, 1)).reshape(-1, N).copy()
    want[:, model.mute] = 0.0
    np.testing.assert_array_equal(pin_matrix(model, pins), want)


def test_cold_and_warm_solves_agree_with_the_reference():
    model = _model()
    pins, targets = _problem(model)
    ref = solve_drag_reference(model, pins, targets, alpha=0.05, mu=1e-3)
    np.testing.assert_allclose(solve_drag(model, pins, targets, alpha=0.05, mu=1e-3).weights, ref, atol=1e-8)
    session = DragSession()
    for t in np.linspace(0.2, 1.0, 5):
        res = solve_drag(model, pins, model.neutral[0] * 0 + targets * t + (1 - t) * PinRows(model, pins).rest,
                         alpha=0.05, mu=1e-3, session=session)
    np.testing.assert_allclose(res.weights, ref, atol=1e-8)


def test_spd_solve_uses_cholesky_and_falls_back_for_an_indefinite_matrix():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(12, 12))
    spd, b = A @ A.T + 12 * np.eye(12), rng.normal(size=12)
    np.testing.assert_allclose(boxqp.spd_solve(spd, b), np.linalg.solve(spd, b), rtol=1e-10)
    indefinite = A + A.T
    np.testing.assert_allclose(boxqp.spd_solve(indefinite, b), np.linalg.solve(indefinite, b), rtol=1e-8)
