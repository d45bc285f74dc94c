"""Per-frame fitting on a redundant, rank-deficient rig (#11): 124 keys, rank far below the key count."""

import importlib.util
import os

import numpy as np

from core.retarget.perframe import fit_frames

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _redundant_rig(seed=0, m=400):
    """The synthetic redundant rig (tools/synthetic_rigs.py, Gaussian bumps: this tier has no Blender); the bench
    and tests/bridge/test_retarget_redundant_head.py build the same kind of rig from FBHead's real keys."""
    path = os.path.join(ROOT, "tools", "synthetic_rigs.py")
    spec = importlib.util.spec_from_file_location("shapespace_synthetic_rigs", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.redundant_rig(seed, m)


def test_perframe_converges_on_a_redundant_rig_and_splits_ties_by_minimum_norm():
    B, Wsrc, base = _redundant_rig()
    assert B.shape == (1200, 124) and np.linalg.matrix_rank(B) < 80
    S = Wsrc @ base.T
    lo, hi = np.zeros(124), np.ones(124)
    W = fit_frames(B, np.zeros(1200), S, lo, hi)     # speed: tools/bench.py retarget (redundant_rig_s_*)
    # KKT of min ‖B w − s‖² + a‖w‖² on [0, 1] in every frame (a as documented: 1e-6 · tr(BᵀB)/n)
    G = B.T @ B
    a = 1e-6 * np.trace(G) / 124
    grad = 2 * (W @ G - S @ B) + 2 * a * W
    nat = np.abs(W - np.clip(W - grad, lo, hi)).max()
    assert nat <= 1e-7 * max(1.0, np.abs(2 * S @ B).max())
    # the regulariser's tie-break: the minimum-norm split — exact duplicates share equally, empty keys stay 0
    np.testing.assert_allclose(W[:, :20], W[:, 52:72], atol=1e-6)
    assert np.abs(W[:, 117:]).max() == 0.0
    np.testing.assert_allclose(W @ B.T, S, atol=1e-3 * np.abs(S).max())


def _anchored_natural_residual(B, S, lam_abs, W, lo, hi):
    """KKT test of the anchored space-time problem (σ = 1), rebuilt from its definition: natural residual of
    ``½‖D(W Bᵀ − S)‖² + ½λ‖W − W⁰‖²`` over the interior frames (W⁰ the per-frame ridge), over max(1, ‖∇f(0)‖∞)."""
    W0 = np.linalg.solve(B.T @ B + lam_abs * np.eye(B.shape[1]), B.T @ S.T).T

    def grad(Wi):
        E = np.vstack([W[0], Wi, W[-1]]) @ B.T - S
        return (2 * E[1:-1] - E[:-2] - E[2:]) @ B + lam_abs * (Wi - W0[1:-1])
    Wi = W[1:-1]
    nat = np.abs(Wi - np.clip(Wi - grad(Wi), lo, hi)).max()
    return nat / max(1.0, np.abs(grad(np.zeros_like(Wi))).max())


def test_bounded_spacetime_converges_on_a_redundant_rig():
    from core.result import Status
    from core.retarget.spacetime_solver import spacetime
    B, Wsrc, base = _redundant_rig()
    S = Wsrc @ base.T
    lo, hi = np.zeros(124), np.ones(124)
    res = spacetime(B, np.zeros(1200), S, np.ones(124), 1e-7, lo=lo, hi=hi, relative=True, anchor=True)
    assert res.status == Status.OK
    assert res.diagnostics["solves"] <= 40                      # a few dozen block factorisations, no cycling
    W = res.weights
    assert W.min() >= 0.0 and W.max() <= 1.0
    lam_abs = 1e-7 * np.linalg.eigvalsh(B.T @ B).clip(0).mean()
    assert _anchored_natural_residual(B, S, lam_abs, W, lo, hi) <= 1e-8
    # the tie-break: the anchor to the per-frame ridge fit splits exact duplicates equally
    np.testing.assert_allclose(W[:, :20], W[:, 52:72], atol=1e-6)
