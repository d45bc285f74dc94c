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

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .. import validate
from ..errors import ErrorCode
from ..result import Result, ShapeSpaceError, Status

__all__ = ["InversionResult", "vertex_jacobians", "invert_deformation", "invert_affine"]

#: A vertex-wise deformer: (p, 3) positions before it → (p, 3) positions after it.
Deformer = Callable[[np.ndarray], np.ndarray]


@dataclass(kw_only=True)
class InversionResult(Result):
    """Outcome of :func:`invert_deformation`.

    ``value`` (alias :attr:`corrective`) is the rest-space corrective δ, shape (p, 3).  Status ``OK``
    when the largest residual reached the tolerance, ``NOT_CONVERGED`` when Newton's method stopped at
    its iteration limit or stalled (δ is then the best iterate).

    Attributes
    ----------
    residual : float
        max |deform(rest + δ) − sculpt| over all vertices and coordinates.
    """

    residual: float = 0.0

    @property
    def corrective(self) -> np.ndarray:
        """The rest-space corrective δ, shape (p, 3) (the result's ``value``)."""
        return self.value


def vertex_jacobians(deform: Deformer, coords: ArrayLike, h: float) -> np.ndarray:
    """Per-vertex 3 × 3 Jacobians of a vertex-wise deformer by central differences (thesis 7.2.1).

    ``J_v[:, i] = (deform(x + h e_i) − deform(x − h e_i))_v / 2h`` — exact for affine and quadratic maps.

    Parameters
    ----------
    deform : callable
        ``(p, 3) → (p, 3)``, each output vertex depending only on its own input vertex.
    coords : array_like, shape (p, 3)
        Where to differentiate.
    h : float
        Step.

    Returns
    -------
    ndarray, shape (p, 3, 3)
    """
    coords = np.asarray(coords, dtype=np.float64)
    J = np.empty(coords.shape + (3,))
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        J[:, :, i] = (deform(coords + e) - deform(coords - e)) / (2 * h)
    return J


def _newton_step(deform, rest, delta, res, h):
    """The Newton step J_v⁻¹ (sculpt − deform(rest + δ)) of every vertex, (p, 3)."""
    J = vertex_jacobians(deform, rest + delta, h)
    det = np.linalg.det(J)
    bad = np.abs(det) <= 1e-12 * max(float(np.abs(J).max()), 1e-300) ** 3
    if bad.any():
        raise ShapeSpaceError(f"{int(bad.sum())} vertices are collapsed by the deformation at this pose "
                              f"(first: {int(np.flatnonzero(bad)[0])}); they cannot be inverted", ErrorCode.SINGULAR)
    try:
        return np.linalg.solve(J, res[..., None])[..., 0]
    except np.linalg.LinAlgError:
        raise ShapeSpaceError("the deformation collapses some vertices at this pose; they cannot be "
                              "inverted", ErrorCode.SINGULAR) from None


def invert_deformation(deform: Deformer, rest: ArrayLike, sculpt: ArrayLike, tol: float | None = None,
                       max_iter: int = 20) -> InversionResult:
    """Rest-space corrective δ with ``deform(rest + δ) ≈ sculpt`` (thesis 7.2.1).

    Newton's method on the block-diagonal system, ``δ ← δ + t J_v⁻¹ (sculpt − deform(rest + δ))``,
    with step halving (t = 1, ½, …) whenever a full step does not reduce the largest residual.

    Parameters
    ----------
    deform : callable
        ``(p, 3) → (p, 3)``, vertex-wise (each output depends only on its own
        input vertex), e.g. ``lambda x: core.skinning.deform(x, rig, poses)``.
    rest : array_like, shape (p, 3)
        The mesh before the deformer at this pose (basis plus any active keys).
    sculpt : array_like, shape (p, 3)
        The wanted posed positions (same space as ``deform``'s output).
    tol : float, optional
        Stop when the largest residual is below this (default 1e-9 × size).
    max_iter : int
        Newton iterations at most.

    Returns
    -------
    InversionResult
        ``corrective`` (p, 3), ``residual``, ``iterations``; status ``OK`` or ``NOT_CONVERGED``.

    Raises
    ------
    ShapeSpaceError
        Bad shapes or non-finite positions; vertices the deformation collapses (code ``singular``).
    """
    rest = validate.array(rest, "rest", shape=(None, 3))
    sculpt = validate.array(sculpt, "sculpt", shape=rest.shape)
    size = float(np.linalg.norm(np.ptp(rest, axis=0))) or 1.0
    tol = 1e-9 * size if tol is None else tol
    h = 1e-3 * size
    delta = np.zeros_like(rest)
    res = sculpt - deform(rest)
    err = float(np.abs(res).max())
    for it in range(1, max_iter + 1):
        if err <= tol:
            return InversionResult(delta, residual=err, iterations=it - 1, status=Status.OK, message="converged")
        step = _newton_step(deform, rest, delta, res, h)
        t = 1.0
        while True:
            cand = delta + t * step
            res_c = sculpt - deform(rest + cand)
            err_c = float(np.abs(res_c).max())
            if err_c < err or t < 1e-4:
                break
            t *= 0.5
        if err_c >= err:
            return InversionResult(delta, residual=err, iterations=it, status=Status.NOT_CONVERGED,
                                   message="stalled: the deformation cannot be inverted further")
        delta, res, err = cand, res_c, err_c
    if err <= tol:
        return InversionResult(delta, residual=err, iterations=max_iter, status=Status.OK, message="converged")
    return InversionResult(delta, residual=err, iterations=max_iter, status=Status.NOT_CONVERGED,
                           message="iteration limit reached")


def invert_affine(maps: ArrayLike, rest: ArrayLike, sculpt: ArrayLike, deform: Deformer | None = None,
                  tol: float | None = None) -> InversionResult:
    """Rest-space corrective of a per-vertex affine deformer in one solve (thesis 7.2.1).

    For ``deform(x)_v = A_v x_v + b_v`` (linear blend skinning), ``deform(rest + δ) = sculpt`` gives
    ``δ_v = A_v⁻¹ (sculpt_v − A_v rest_v − b_v)`` exactly; no Newton iterations, no finite differences.

    Parameters
    ----------
    maps : array_like, shape (p, 3, 4)
        ``[A_v | b_v]`` per vertex.
    rest : array_like, shape (p, 3)
    sculpt : array_like, shape (p, 3)
    deform : callable, optional
        The deformer itself, to measure the residual independently of ``maps`` (else ``maps`` are used).
    tol : float, optional
        Residual that counts as converged (default 1e-9 × size).

    Returns
    -------
    InversionResult
        Status ``NOT_CONVERGED`` when the residual exceeds ``tol`` (the maps do not describe ``deform``).

    Raises
    ------
    ShapeSpaceError
        Bad shapes; vertices the map collapses (code ``singular``).
    """
    rest = validate.array(rest, "rest", shape=(None, 3))
    sculpt = validate.array(sculpt, "sculpt", shape=rest.shape)
    maps = validate.array(maps, "maps", shape=(rest.shape[0], 3, 4))
    size = float(np.linalg.norm(np.ptp(rest, axis=0))) if len(rest) else 1.0
    tol = 1e-9 * (size or 1.0) if tol is None else tol
    A, b = maps[:, :, :3], maps[:, :, 3]
    det = np.linalg.det(A) if len(A) else np.zeros(0)
    bad = np.abs(det) <= 1e-12 * max(float(np.abs(A).max()) if len(A) else 1.0, 1e-300) ** 3
    if bad.any():
        raise ShapeSpaceError(f"{int(bad.sum())} vertices are collapsed by the deformation at this pose "
                              f"(first: {int(np.flatnonzero(bad)[0])}); they cannot be inverted", ErrorCode.SINGULAR)
    posed = np.einsum("pij,pj->pi", A, rest) + b
    delta = np.linalg.solve(A, (sculpt - posed)[..., None])[..., 0] if len(A) else np.zeros_like(rest)
    check = deform(rest + delta) if deform is not None else np.einsum("pij,pj->pi", A, rest + delta) + b
    err = float(np.abs(check - sculpt).max()) if len(rest) else 0.0
    if err <= tol:
        return InversionResult(delta, residual=err, iterations=1, status=Status.OK, message="converged")
    return InversionResult(delta, residual=err, iterations=1, status=Status.NOT_CONVERGED,
                           message="the affine maps do not reproduce the deformer")
