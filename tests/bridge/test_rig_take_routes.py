"""Issue #25 item 3: the space-time and cloning routes onto a rig's controls, checked by Blender's evaluation.

References: on a control set of shape-key sliders only (a rig linear in its controls) the space-time route must
give the shape-key space-time solver's weights (core.retarget.spacetime_solver on the keys' deltas read from the
file, same σ, λ, anchor and end frames); on the hybrid rig (jaw bone + keys) a take the rig made itself must be
played back by the written actions within 1e-3 of the diagonal; the cloning route's written take, played by
Blender, must match the capture's surface as closely as the per-frame route's.
"""
import numpy as np

import rigs
from blender_support import bpy  # noqa: F401  (Blender first)
from shapespace.bridge import rig as brig
from shapespace.bridge.rig import take as btake
from shapespace.core.result import Status
from shapespace.core.retarget.spacetime_solver import spacetime
from support import ROOT, shared

TAKE_TOL = 1e-3
CSV = f"{ROOT}/assets/llf_fbhead/MySlate_3_Jason_Millers_iPhone.csv"


def _head():
    return shared(*rigs.FACECAP.split("/"))


def _rms(a, b) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=-1))))


def test_spacetime_on_sliders_equals_the_shape_key_spacetime_solver():
    rig = rigs.hybrid_rig(_head())
    names = ["mouthSmile_L", "cheekPuff", "eyeBlink_L", "browInnerUp"]
    controls = brig.control_set([brig.shape_key_channel(rig.mesh, n) for n in names])
    rng = np.random.default_rng(7)
    F = 24
    W = np.clip(np.cumsum(rng.normal(size=(F, len(names))) * 0.25, axis=0) + 0.3, -0.3, 1.3)   # leaves [0, 1]
    idx = rigs.take_vertices(rig, rng, every=40)
    targets = brig.shape_key_targets(rig.mesh, names, W, idx)
    frames = np.arange(1, F + 1)
    pf = btake.compute_take(rig.mesh, controls, idx, targets, frames)
    st = btake.compute_take(rig.mesh, controls, idx, targets, frames, method="spacetime", lam=1e-3)
    assert st.result.status == Status.OK, st.result.message
    assert st.result.diagnostics["method"] == "spacetime"
    base = brig.shape_key_targets(rig.mesh, names, np.zeros((1, len(names))), idx)[0].reshape(-1)
    B = np.stack([(brig.shape_key_targets(rig.mesh, names, np.eye(len(names))[[k]], idx)[0].reshape(-1) - base)
                  for k in range(len(names))], axis=1)
    sigma = btake.control_sigma(pf.values, np.zeros(len(names)), np.ones(len(names)), controls.scale, pf.diagonal)
    ref = spacetime(B, base, targets.reshape(F, -1), sigma, 1e-3, first=pf.values[0], last=pf.values[-1],
                    lo=np.zeros(len(names)), hi=np.ones(len(names)), relative=True, anchor=True, tol=1e-12)
    np.testing.assert_allclose(st.values, ref.weights, atol=2e-4)
    assert np.abs(st.values - pf.values).max() > 1e-3                 # the smoothing did something


def test_spacetime_self_take_on_the_hybrid_rig_is_played_back():
    rig = rigs.hybrid_rig(_head())
    rng = np.random.default_rng(3)
    values = rigs.smooth_take(rig, rng, 20)
    surface = rigs.take_surface(rig, values)
    idx = rigs.take_vertices(rig, rng)
    diag = rigs.diagonal(surface[0])
    frames = np.arange(1, 21)
    rep = brig.retarget_take(rig.mesh, rig.controls, idx, surface[:, idx], frames, method="spacetime")
    assert rep.status == Status.OK and rep.method == "spacetime", rep.issues
    assert _rms(rigs.played_surface(rig, frames), surface) / diag <= TAKE_TOL


def test_cloning_route_matches_the_capture_as_the_per_frame_route_does():
    rig = rigs.hybrid_rig(_head())
    names, frames, W, _ = brig.capture_weights(rig.mesh, CSV)
    idx = brig.sample_vertices(rig.mesh, names)
    truth_idx = brig.shape_key_targets(rig.mesh, names, W, idx)
    keep = np.arange(0, len(frames), max(1, len(frames) // 6))
    out = {}
    for method in ("perframe", "cloning"):
        rep = brig.retarget_capture_onto_rig(rig.mesh, rig.controls, CSV, method=method)
        assert rep.method == method and rep.status in (Status.OK, Status.NOT_CONVERGED)
        played = rigs.played_surface(rig, frames[keep])[:, idx]
        out[method] = _rms(played, truth_idx[keep])
        brig.restore_previous(rep, rig.controls)
    diag = rigs.diagonal(rig.world_points())
    assert out["cloning"] <= 1.05 * out["perframe"] + 1e-5 * diag, out
