"""Independent references for the retarget fits' tests (tests/core/test_perframe.py, test_spacetime_solver.py):
ridge least squares on the augmented system, scipy's BVLS, OSQP and quadprog on box-constrained QPs."""
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear


def normalized_B(rng, m3, n):
    """Random (m3, n) target delta matrix scaled so trace(BᵀB)/n == 1.

    With this scaling the documented fit objective ``‖Bw − r‖² + reg‖w‖²`` and the implementation's
    trace-relative ridge ``reg·tr(BᵀB)/n`` coincide, so references can use ``reg`` as written.
    """
    B = rng.standard_normal((m3, n))
    return B * np.sqrt(n / np.trace(B.T @ B))


def smooth_weights(rng, F, n, amp=1.0):
    t = np.linspace(0.0, 1.0, F)[:, None]
    freq = rng.uniform(0.5, 2.0, n)
    phase = rng.uniform(0, 2 * np.pi, n)
    return amp * (0.5 + 0.4 * np.sin(2 * np.pi * freq * t + phase))


def ridge_lstsq(B, r, a):
    """min ‖Bw − r‖² + a‖w‖² by plain least squares on the augmented system [B; √a I]."""
    n = B.shape[1]
    A = np.vstack([B, np.sqrt(a) * np.eye(n)])
    return np.linalg.lstsq(A, np.concatenate([r, np.zeros(n)]), rcond=None)[0]


def bvls_ridge(B, r, a, lo, hi):
    n = B.shape[1]
    A = np.vstack([B, np.sqrt(a) * np.eye(n)])
    res = lsq_linear(A, np.concatenate([r, np.zeros(n)]), bounds=(lo, hi), method="bvls", tol=1e-14,
                     lsmr_tol=None)
    assert res.status > 0, res.message
    return res.x


def osqp_qp(P, q, lo, hi):
    """min ½xᵀPx + qᵀx, lo ≤ x ≤ hi with OSQP at eps 1e-10 plus polishing (asserted)."""
    n = P.shape[0]
    osqp = pytest.importorskip("osqp")  # the independent reference: skipped where not installed
    solver = osqp.OSQP()
    solver.setup(sp.triu(sp.csc_matrix(P), format="csc"), q, sp.identity(n, format="csc"), lo, hi,
                 eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=200000, verbose=False)
    res = solver.solve(raise_error=False)
    assert res.info.status == "solved", res.info.status
    assert res.info.status_polish in (1, 2), "OSQP reference did not polish"
    return np.asarray(res.x)


def quadprog_box(P, q, lo, hi):
    """min ½xᵀPx + qᵀx with finite box bounds (Goldfarb–Idnani: Cᵀx ≥ b)."""
    n = P.shape[0]
    I = np.eye(n)
    C = np.hstack([I, -I])
    b = np.concatenate([lo, -hi])
    quadprog = pytest.importorskip("quadprog")  # the independent reference: skipped where not installed
    return quadprog.solve_qp(np.asarray(P, dtype=float), -q, C, b, 0)[0]


def rel(a, b):
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))
