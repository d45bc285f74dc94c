"""Retargeting onto a redundant avatar face built from a real head (#11, item 5).

FBHead (shipped ``Live_Link_Face.blend``, read through the bridge) grown to a 124-key face like the ones
VRoid/VRM users have (``tools/synthetic_rigs.py::redundant_head_rig``): its 51 ARKit keys plus ``TongueOut``
(which FBHead lacks: an empty key), 16 exact duplicates, 10 scaled copies, 24 near-duplicates, 15 visemes and 7
more empty keys — numerical rank 90.  The source is the shipped Live Link Face take at 24 fps (131 frames), its 52
ARKit channels copied onto the ARKit keys (the vendor keys get no channel), and ``perframe`` and bounded
``spacetime`` fit the sliders, within [0, 1], to its geometry through ``performance.retarget_weights`` (what the
retarget command runs).

References are independent of the solvers: scipy's bounded least squares frame by frame; the KKT conditions
(natural residual) of each problem rebuilt here from its definition; quadprog on the space-time QP formed densely
on a shortened take.  The tie-break asserted is the one documented (``core/retarget/perframe.py``, the "Ties"
paragraph of ``core/retarget/spacetime_solver.py``): the smallest-norm split per frame (exact duplicates share
equally, a copy scaled by c takes c times the original's share), the smallest σ-weighted norm in space-time
(shares in proportion to σ²), and keys that move nothing keep their copied value (0 for the vendor keys).
"""
import os

import numpy as np
import pytest

from blender_support import bpy
from shapespace.bridge import assets, retarget, shapekeys
from shapespace.core.blendshape import BlendshapeModel, normalised_unit
from shapespace.core.result import Status
from shapespace.core.retarget import performance
from support import ASSETS
from synthetic_rigs import RANK_RTOL, arkit_columns, redundant_head_rig

BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")
CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")


@pytest.fixture(scope="module")
def head():
    """FBHead's 124-key redundant face and the 131-frame take: (model, rig dict, ideal weights (131, 124))."""
    assets.load(BLEND)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = 24, 1.0            # the take at 24 fps: 131 frames
    ob = bpy.data.objects["FBHead"]
    base = shapekeys.read_blendshape_model(ob)
    channels, frames, src, _ = retarget.read_source(CSV, scene)
    rig = redundant_head_rig(arkit_columns(base.delta_matrix, base.names, channels), base.neutral, channels)
    model = BlendshapeModel(base.neutral, rig["B"], rig["names"])                # sliders [0, 1]
    ideal = np.zeros((src.shape[0], model.n_targets))
    ideal[:, :len(channels)] = src                                 # copied by name: ARKit keys only
    return model, rig, ideal


@pytest.fixture(scope="module")
def perframe_fit(head):
    """The per-frame retarget of the take onto the face, once: (weights (131, 124), frames that needed scipy's
    general bounded least squares)."""
    from shapespace.core.retarget import perframe
    model, rig, ideal = head
    general = []
    real = perframe._bvls

    def counting(*args):                                 # counts, and solves exactly as before
        general.append(1)
        return real(*args)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(perframe, "_bvls", counting)
        W = performance.retarget_weights(model, ideal, "perframe").weights     # speed: tools/bench.py retarget
    return W, len(general)


def _spy_spacetime(monkeypatch):
    """Record the arguments of the real space-time solve the retarget makes (it still runs, unchanged)."""
    calls = []
    real = performance.spacetime

    def recording(*args, **kwargs):
        calls.append((args, kwargs))
        return real(*args, **kwargs)
    monkeypatch.setattr(performance, "spacetime", recording)
    return calls


def _perframe_problem(model, ideal):
    """The per-frame problem in normalised units, from its definition: live-key basis, targets, ridge a."""
    live = np.abs(model.delta_matrix).max(axis=0) > 0
    unit = normalised_unit(model)                                  # the size-normalised units of the fit
    B = model.delta_matrix[:, live] / unit
    S = ideal @ model.delta_matrix.T / unit                        # the source geometry, relative to the neutral
    a = 1e-6 * np.trace(B.T @ B) / B.shape[1]                      # the documented ridge: 1e-6 · tr(BᵀB)/n
    return live, B, S, a


def _spacetime_natural_residual(args, kwargs, W):
    """KKT test of the anchored bounded space-time problem the retarget posed, rebuilt from its definition:
    ``f(W) = ½‖D(W Bᵀ − S)‖² + ½β‖W Bᵀ − S‖² + ½λ‖(W − W⁰) Σ⁻¹‖²`` over the interior frames (ends fixed),
    ``W⁰ = argmin ‖W Bᵀ − S‖² + λ‖W Σ⁻¹‖²`` per frame, λ relative to the mean eigenvalue of ``ΣBᵀBΣ``; natural
    residual ``‖y − clip(y − ∇_y f)‖∞`` in the whitened weights ``y = W/σ`` over ``max(1, ‖∇_y f(0)‖∞)``."""
    B, b0, S, sig = (np.asarray(x, dtype=np.float64) for x in args[:4])
    lam = float(args[4]) if len(args) > 4 else float(kwargs.get("lam", 1e-3))
    assert kwargs.get("anchor") and kwargs.get("relative") and kwargs.get("first") is None
    beta = float(kwargs.get("beta", 0.0))
    lo, hi = kwargs["lo"], kwargs["hi"]
    G = B.T @ B
    lam = lam * np.linalg.eigvalsh(sig[:, None] * G * sig[None, :]).clip(0).mean()
    T = S - b0
    W0 = np.linalg.solve(G + lam * np.diag(1.0 / sig ** 2), B.T @ T.T).T

    def grad(Wi):
        E = np.vstack([W[0], Wi, W[-1]]) @ B.T - T
        return sig * ((2 * E[1:-1] - E[:-2] - E[2:] + beta * E[1:-1]) @ B + lam * (Wi - W0[1:-1]) / sig ** 2)
    y = W[1:-1] / sig
    nat = np.abs(y - np.clip(y - grad(W[1:-1]), lo / sig, hi / sig)).max()
    return float(nat / max(1.0, np.abs(grad(np.zeros_like(W[1:-1]))).max())), (B, T, sig, lam, beta, lo, hi)


def test_the_redundant_head_has_124_keys_of_rank_90(head):
    model, rig, ideal = head
    B, kind, of = rig["B"], rig["kind"], rig["of"]
    assert B.shape == (3 * 1497, 124) and ideal.shape == (131, 124)
    counts = {k: int(np.sum(kind == k)) for k in ("arkit", "duplicate", "scaled", "near", "viseme", "empty")}
    assert counts == {"arkit": 51, "duplicate": 16, "scaled": 10, "near": 24, "viseme": 15, "empty": 8}
    s = np.linalg.svd(B, compute_uv=False) / np.linalg.norm(B, 2)
    # rank 90 = 51 ARKit keys + 24 near-duplicates + 15 visemes; the tolerance well inside the spectrum's gap
    # (measured: 1.1e-6 above it, 1.2e-16 below)
    assert rig["rank"] == 90 and s[89] > 1e2 * RANK_RTOL and s[90] < 1e-4 * RANK_RTOL
    dup, sc, near = (np.flatnonzero(kind == k) for k in ("duplicate", "scaled", "near"))
    assert np.array_equal(B[:, dup], B[:, of[dup]])
    np.testing.assert_allclose(B[:, sc], B[:, of[sc]] * rig["factor"][sc], rtol=1e-12)
    cos = np.sum(B[:, near] * B[:, of[near]], 0) / np.linalg.norm(B[:, near], axis=0) / np.linalg.norm(
        B[:, of[near]], axis=0)
    assert cos.min() > 0.99 and cos.max() < 1 - 1e-12                  # nearly parallel, not parallel
    assert np.all(np.abs(B[:, kind == "empty"]) == 0)


def test_perframe_on_the_redundant_head_converges_and_splits_ties_by_minimum_norm(head, perframe_fit):
    from scipy.optimize import lsq_linear
    model, rig, ideal = head
    W = perframe_fit[0]
    live, B, S, a = _perframe_problem(model, ideal)
    Wl = W[:, live]
    lo, hi = np.zeros(Wl.shape[1]), np.ones(Wl.shape[1])
    # KKT of min ‖B w − s‖² + a‖w‖² on [0, 1], every frame
    G = B.T @ B
    grad = 2 * (Wl @ G - S @ B) + 2 * a * Wl
    nat = np.abs(Wl - np.clip(Wl - grad, lo, hi)).max(axis=1) / np.maximum(1.0, np.abs(2 * S @ B).max(axis=1))
    assert nat.max() <= 1e-7
    # scipy's bounded least squares on the ridge-augmented system, a few frames
    A = np.vstack([B, np.sqrt(a) * np.eye(B.shape[1])])
    for f in (0, 33, 66, 99, 130):
        ref = lsq_linear(A, np.concatenate([S[f], np.zeros(B.shape[1])]), bounds=(lo, hi), method="bvls",
                         tol=1e-14).x
        np.testing.assert_allclose(Wl[f], ref, rtol=0, atol=1e-6)
    # the tie-break: minimum norm — duplicates share equally, a copy scaled by c takes c× the original's share
    kind, of, c = rig["kind"], rig["of"], rig["factor"]
    dup, sc = np.flatnonzero(kind == "duplicate"), np.flatnonzero(kind == "scaled")
    np.testing.assert_allclose(W[:, dup], W[:, of[dup]], rtol=0, atol=1e-7)
    assert np.abs(W[:, dup]).max() > 0.05                             # they do carry motion
    inside = (W[:, sc] > 1e-6) & (W[:, sc] < 1 - 1e-6) & (W[:, of[sc]] > 1e-6) & (W[:, of[sc]] < 1 - 1e-6)
    np.testing.assert_allclose(W[:, sc][inside], (c[sc] * W[:, of[sc]])[inside], rtol=0, atol=1e-6)
    # keys that move nothing keep their copied value: 0 for the vendor keys, the take's TongueOut for TongueOut
    empty = np.flatnonzero(kind == "empty")
    np.testing.assert_array_equal(W[:, empty], np.clip(ideal[:, empty], 0, 1))
    assert np.abs(W[:, empty[1:]]).max() == 0.0
    # the take's geometry is reproduced (nothing clips), to the ridge's bias
    assert np.abs((W - ideal) @ model.delta_matrix.T).max() <= 1e-3 * np.abs(ideal @ model.delta_matrix.T).max()


def test_perframe_on_the_redundant_head_needs_no_general_solver_and_stays_in_range(head, perframe_fit):
    """#11: "Per-frame fitting must not call a general solver per frame" (one factorisation, one bounded solve
    per frame warm-started from the previous one); and the weights are within the slider ranges exactly, as
    ``retarget_weights`` promises."""
    W, general = perframe_fit
    assert general == 0, f"scipy's bounded least squares ran on {general} of {W.shape[0]} frames"
    assert W.min() >= 0 and W.max() <= 1, (W.min(), W.max())


def test_bounded_spacetime_on_the_redundant_head_converges_to_the_kkt_point(head, monkeypatch):
    model, rig, ideal = head
    calls = _spy_spacetime(monkeypatch)
    fit = performance.retarget_weights(model, ideal, "spacetime")
    assert fit.solver is not None and fit.solver.status == Status.OK, fit.solver.message
    assert len(calls) == 1
    (args, kwargs), W = calls[0], fit.weights
    live = np.abs(model.delta_matrix).max(axis=0) > 0
    nat, (B, T, sig, lam, beta, lo, hi) = _spacetime_natural_residual(args, kwargs, W[:, live])
    assert nat <= 1e-8                                                # the solver's own KKT test, rebuilt
    assert W.min() >= 0 and W.max() <= 1
    # the tie-break: the anchored regulariser's smallest σ-weighted norm, so exact duplicates j, j' split their
    # sum t in proportion to σ², w_j = t σ_j² / (σ_j² + σ_j'²), on the interior frames where neither is at a bound.
    # Only λ (1e-7 of the data) curves the tie direction, so the KKT tolerance (1e-8 of the right-hand side)
    # fixes the split to about 1e-4: a hundredth of a percent of the slider range.
    kind, of = rig["kind"], rig["of"]
    pos = np.cumsum(live) - 1                                       # column of each live key in the fit
    dup = np.flatnonzero(kind == "duplicate")
    wd, wo = W[1:-1, dup], W[1:-1, of[dup]]
    sd, so = sig[pos[dup]] ** 2, sig[pos[of[dup]]] ** 2
    inside = (wd > 1e-6) & (wd < 1 - 1e-6) & (wo > 1e-6) & (wo < 1 - 1e-6)
    assert inside.sum() > 100 and (sd / so).min() < 0.1               # σ differ by 3×+: the rule is tested
    np.testing.assert_allclose(wd[inside], ((wd + wo) * sd / (sd + so))[inside], rtol=0, atol=1e-4)
    empty = np.flatnonzero(kind == "empty")
    np.testing.assert_array_equal(W[:, empty], np.clip(ideal[:, empty], 0, 1))
    # the fit follows the take (no clipping to speak of): every frame within 1e-3 of the geometry's size
    assert np.abs((W - ideal) @ model.delta_matrix.T).max() <= 1e-3 * np.abs(ideal @ model.delta_matrix.T).max()


def test_bounded_spacetime_on_the_redundant_head_matches_quadprog_on_a_short_take(head, monkeypatch):
    quadprog = pytest.importorskip("quadprog")
    model, rig, ideal = head
    calls = _spy_spacetime(monkeypatch)
    fit = performance.retarget_weights(model, ideal[40:60], "spacetime")     # 20 frames: 18 × 116 unknowns
    assert fit.solver.status == Status.OK, fit.solver.message
    live = np.abs(model.delta_matrix).max(axis=0) > 0
    W = fit.weights[:, live]
    nat, (B, T, sig, lam, beta, lo, hi) = _spacetime_natural_residual(*calls[0], W)
    assert nat <= 1e-8
    # the same QP formed densely in the whitened weights y = W/σ and solved by Goldfarb–Idnani
    F, n = W.shape
    M = sig[:, None] * (B.T @ B) * sig[None, :]
    W0 = np.linalg.solve(B.T @ B + lam * np.diag(1.0 / sig ** 2), B.T @ T.T).T
    D2 = 2 * np.eye(F - 2) - np.eye(F - 2, k=1) - np.eye(F - 2, k=-1) + beta * np.eye(F - 2)
    H = np.kron(D2, M) + lam * np.eye((F - 2) * n)
    TB = T @ B * sig
    rhs = 2 * TB[1:-1] - TB[:-2] - TB[2:] + beta * TB[1:-1] + lam * W0[1:-1] / sig
    rhs[0] += (W[0] / sig) @ M
    rhs[-1] += (W[-1] / sig) @ M
    C = np.hstack([np.eye(H.shape[0]), -np.eye(H.shape[0])])
    bnd = np.concatenate([np.tile(lo / sig, F - 2), -np.tile(hi / sig, F - 2)])
    y = quadprog.solve_qp(H, rhs.ravel(), C, bnd)[0].reshape(F - 2, n)
    ref = y * sig

    def objective(Yi):
        v = Yi.ravel()
        return 0.5 * v @ H @ v - rhs.ravel() @ v
    # equal to the tie direction's precision (curved by λ only: see the test above), and no worse a minimum
    np.testing.assert_allclose(W[1:-1], ref, rtol=0, atol=1e-4)
    assert objective(W[1:-1] / sig) <= objective(y) + 1e-9 * abs(objective(y))
