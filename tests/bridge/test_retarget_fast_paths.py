"""The geometric retarget's fast paths on real data (#24): the shipped Live Link Face take onto FBHead.

The batched per-frame active set (:func:`core.retarget.perframe.batched_active_set`) against SciPy's bounded
least squares (BVLS) frame by frame, and the space-time peak active set holding each violated run's deepest half
(:data:`core.retarget.spacetime_solver.PEAK_FRACTION`), going on from the clipped solve, against holding the deepest
entry alone from the unbounded solution (the route before)."""
import os

import numpy as np
from scipy.optimize import lsq_linear

from blender_support import bpy, import_file
from shapespace.bridge import retarget
from shapespace.core.result import Status
from shapespace.core.retarget import copy_weights, performance
from shapespace.core.retarget.metrics import slider_scales
from shapespace.core.retarget.perframe import batched_active_set, fit_frames
from shapespace.core.retarget.spacetime_solver import bounded, spacetime
from shapespace.core.retarget.spacetime_solver import solve as solve_module
from support import ASSETS

CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")


def _reduced_take(tiles: int = 1):
    """The take onto FBHead in the rig's own coordinates (as the retarget command fits it): R, S, lo, hi, raw."""
    import_file(BLEND)
    plan = retarget.read_retarget(bpy.data.objects["FBHead"], CSV, "perframe")
    model = plan.model
    raw = copy_weights(plan.source_weights, plan.pairs, model.n_targets, plan.gain, plan.offset)
    raw = np.tile(raw, (tiles, 1))
    live = ~performance.empty_keys(model)
    R, S = performance.reduced_geometry(model, raw, live)
    return R, S, model.slider_min[live], model.slider_max[live], raw[:, live]


def test_batched_per_frame_fit_is_scipy_bvls_frame_by_frame():
    R, S, lo, hi, raw = _reduced_take()
    G = R.T @ R
    a = 1e-6 * np.trace(G) / G.shape[0]                                       # fit_frames' default ridge
    H = 2.0 * (G + a * np.eye(G.shape[0]))
    free = np.linalg.solve(H, 2.0 * (S @ R).T).T
    assert np.count_nonzero((free < lo) | (free > hi)) > 100                # the bounds matter
    X, done = batched_active_set(H, 2.0 * (S @ R), lo, hi)
    assert done.all()
    W = fit_frames(R, np.zeros(R.shape[0]), S, lo, hi)
    np.testing.assert_allclose(W, X, rtol=0, atol=1e-10)                    # H up to rounding
    A = np.vstack([R, np.sqrt(a) * np.eye(R.shape[1])])
    zeros = np.zeros(R.shape[1])
    worst = 0.0
    for f in range(0, S.shape[0], 5):
        ref = lsq_linear(A, np.concatenate([S[f], zeros]), bounds=(lo, hi), method="bvls", tol=1e-12).x
        worst = max(worst, float(np.abs(W[f] - ref).max()))
    assert worst < 1e-8, worst
    assert np.all(W >= lo) and np.all(W <= hi)


def test_space_time_fast_route_reaches_the_deepest_entry_route_s_answer_in_two_solves(monkeypatch):
    """Onto FBHead the unbounded solution only dips by slivers, but holding them all is not the answer; the peak
    iteration goes on from that clipped solve (holding each run's deepest half) instead of starting over from the
    unbounded solution holding each run's deepest entry (the route before, 12 exact solves on this take)."""
    R, S, lo, hi, raw = _reduced_take(tiles=10)
    sig = slider_scales(raw, lo, hi)

    def solve():
        return spacetime(R, np.zeros(R.shape[0]), S, sig, 1e-7, lo=lo, hi=hi, relative=True, anchor=True)
    new = solve()
    monkeypatch.setattr(bounded, "PEAK_FRACTION", 1.0)
    monkeypatch.setattr(solve_module, "shallow_violation", lambda *a: False)
    old = solve()
    assert old.status == Status.OK and new.status == Status.OK
    assert new.diagnostics["clipped_solve"] and new.diagnostics["peak_iterations"] > 0
    assert new.diagnostics["solves"] <= 2 < old.diagnostics["solves"]
    np.testing.assert_allclose(new.weights, old.weights, rtol=0, atol=1e-5)
