"""Rest-space inversion of sculpts made on the posed character (thesis 7.2.1).

Shape keys act before the Armature modifier, so a corrective sculpted on the
posed mesh must be pulled back to rest space: find δ with
``deform(rest + δ) = sculpt``.  Skinning acts on each vertex independently,
so the Jacobian is block-diagonal (3 × 3 per vertex) and Newton's method is
``δ ← δ + J_v⁻¹ (sculpt − deform(rest + δ))`` for all vertices at once.

For linear blend skinning and rigid dual-quaternion skinning the map is
affine per vertex, so one step is exact (up to rounding); Blender's
scale-at-pivot dual quaternions, stacked modifiers, or any deformer the
caller supplies as a black box converge in a few steps.  ``J_v`` comes from
central differences of the deformer (6 evaluations per step), which are
exact for affine maps.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..result import ShapeSpaceError

__all__ = ["InversionResult", "vertex_jacobians", "invert_deformation"]


@dataclass
class InversionResult:
    corrective: np.ndarray     # (p, 3) rest-space corrective δ
    residual: float            # max |deform(rest + δ) − sculpt|
    iterations: int
    status: int
    message: str


def vertex_jacobians(deform, coords, h: float) -> np.ndarray:
    """Per-vertex 3 × 3 Jacobians of a vertex-wise deformer by central differences, (p, 3, 3)."""
    coords = np.asarray(coords, dtype=np.float64)
    J = np.empty(coords.shape + (3,))
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        J[:, :, i] = (deform(coords + e) - deform(coords - e)) / (2 * h)
    return J


def invert_deformation(deform, rest, sculpt, tol: float = None, max_iter: int = 20) -> InversionResult:
    """Rest-space corrective δ with ``deform(rest + δ) ≈ sculpt``.

    Parameters
    ----------
    deform : callable
        ``(p, 3) → (p, 3)``, vertex-wise (each output depends only on its own
        input vertex), e.g. ``lambda x: core.skinning.deform(x, rig, poses)``.
    rest : array_like (p, 3)
        The mesh before the deformer at this pose (basis plus any active keys).
    sculpt : array_like (p, 3)
        The wanted posed positions (same space as ``deform``'s output).
    tol : float, optional
        Stop when the largest residual is below this (default 1e-9 × size).
    """
    rest = np.asarray(rest, dtype=np.float64)
    sculpt = np.asarray(sculpt, dtype=np.float64)
    if rest.shape != sculpt.shape or rest.ndim != 2 or rest.shape[1] != 3:
        raise ShapeSpaceError(f"rest and sculpt must both have shape (p, 3); got {rest.shape} and {sculpt.shape}",
                              "shape")
    if not (np.isfinite(rest).all() and np.isfinite(sculpt).all()):
        raise ShapeSpaceError("rest or sculpt positions contain NaN or infinite values", "non_finite")
    size = float(np.linalg.norm(np.ptp(rest, axis=0))) or 1.0
    tol = 1e-9 * size if tol is None else tol
    h = 1e-3 * size
    delta = np.zeros_like(rest)
    res = sculpt - deform(rest)
    err = float(np.abs(res).max())
    for it in range(1, max_iter + 1):
        if err <= tol:
            return InversionResult(delta, err, it - 1, 0, "converged")
        J = vertex_jacobians(deform, rest + delta, h)
        det = np.linalg.det(J)
        bad = np.abs(det) <= 1e-12 * max(float(np.abs(J).max()), 1e-300) ** 3
        if bad.any():
            raise ShapeSpaceError(f"{int(bad.sum())} vertices are collapsed by the deformation at this pose "
                                  f"(first: {int(np.flatnonzero(bad)[0])}); they cannot be inverted", "singular")
        try:
            step = np.linalg.solve(J, res[..., None])[..., 0]
        except np.linalg.LinAlgError:
            raise ShapeSpaceError("the deformation collapses some vertices at this pose; they cannot be "
                                  "inverted", "singular") from None
        t = 1.0
        while True:
            cand = delta + t * step
            res_c = sculpt - deform(rest + cand)
            err_c = float(np.abs(res_c).max())
            if err_c < err or t < 1e-4:
                break
            t *= 0.5
        if err_c >= err:
            return InversionResult(delta, err, it, 1, "stalled: the deformation cannot be inverted further")
        delta, res, err = cand, res_c, err_c
    status = 0 if err <= tol else 1
    return InversionResult(delta, err, max_iter, status, "converged" if status == 0 else "iteration limit reached")
