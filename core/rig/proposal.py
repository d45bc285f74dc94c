"""What moves the face (issue #25 item 5): rank the candidate channels of a rig by how much they deform it.

The bridge probes every candidate channel through Blender's evaluation (:meth:`bridge.rig.RigEvaluator.probe`)
with :func:`deformation` as the measure: the largest distance a vertex moves *after the best rigid motion of
the whole surface is taken out* — a root, torso or head bone that carries the face along without changing it
does not control an expression.  :func:`rank_channels` keeps the channels that deform the surface by more than
a fraction of its size and orders them, largest deformation first; locked, held-still and inert channels are
skipped, each by name and reason (:class:`ProposalReport`).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..result import Report, ShapeSpaceError, Status

__all__ = ["DEFORM_REL_TOL", "ProposalReport", "deformation", "rank_channels"]

#: A channel deforms the face when some vertex moves more than this fraction of the surface's bounding-box
#: diagonal beyond the best rigid motion of the whole surface (float32 positions round at ~1e-7).
DEFORM_REL_TOL = 1e-5

#: Why a candidate was skipped (value: the words of the report).
REASONS = {"locked": "locked", "held": "held still by its bounds", "inert": "does not deform the face"}


@dataclass(kw_only=True)
class ProposalReport(Report):
    """The proposal: channels kept (largest deformation first) and channels skipped, by name.

    Attributes
    ----------
    proposed : list of str
        Names of the kept channels, in rank order.
    deformation : list of float
        Their deformation over the probe, as a fraction of the surface's diagonal (same order).
    skipped : dict of str to list of str
        ``{"locked" | "held" | "inert": [names]}``.
    """

    proposed: list = field(default_factory=list)
    deformation: list = field(default_factory=list)
    skipped: dict = field(default_factory=dict)

    def summary(self, shown: int = 4) -> str:
        """One line: how many were proposed, and the skipped ones by reason (the first ``shown`` names each)."""
        parts = []
        for key, names in self.skipped.items():
            if names:
                more = f" … (+{len(names) - shown})" if len(names) > shown else ""
                parts.append(f"{len(names)} {REASONS[key]} ({', '.join(names[:shown])}{more})")
        tail = f"; skipped {'; '.join(parts)}" if parts else ""
        return f"proposed {len(self.proposed)} channels{tail}"


def deformation(rest: ArrayLike, moved: ArrayLike) -> float:
    """Largest vertex distance between ``moved`` and the best rigid motion of ``rest`` (Kabsch, least squares).

    Parameters
    ----------
    rest, moved : array_like (V, 3)

    Returns
    -------
    float
        ``max_v ‖moved_v − (R rest_v + t)‖`` for the rotation ``R`` and translation ``t`` minimising
        ``Σ_v ‖moved_v − (R rest_v + t)‖²``.
    """
    a = np.asarray(rest, dtype=np.float64)
    b = np.asarray(moved, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2 or a.shape[1] != 3 or not len(a):
        raise ShapeSpaceError(f"rest {a.shape} and moved {b.shape} must be the same (V, 3)", ErrorCode.SHAPE)
    for name, x in (("rest", a), ("moved", b)):
        bad = np.flatnonzero(~np.isfinite(x).all(1))
        if bad.size:
            raise ShapeSpaceError(f"{name}: vertex {int(bad[0])} is not finite", ErrorCode.NON_FINITE)
    ca, cb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    fit = (a - ca) @ R.T + cb
    return float(np.linalg.norm(b - fit, axis=1).max())


def rank_channels(names: Sequence[str], deform: ArrayLike, diagonal: float, *, locked: Sequence[str] = (),
                  held: Sequence[str] = (),
                  rel_tol: float = DEFORM_REL_TOL) -> ProposalReport:
    """Keep the probed channels that deform the face, largest first; name the others.

    Parameters
    ----------
    names : sequence of str (n,)
        The probed channels.
    deform : array_like (n,)
        Each channel's largest deformation over its probe (:func:`deformation`), in the surface's unit.
    diagonal : float
        The surface's bounding-box diagonal (> 0).
    locked, held : sequence of str
        Candidates skipped before the probe (locked by the rig; held still by their bounds).
    rel_tol : float
        Deformation below ``rel_tol × diagonal`` counts as none.

    Returns
    -------
    ProposalReport
        ``OK`` when something was proposed, ``FAILED`` (with the skipped channels) when nothing deforms the face.
    """
    names = list(names)
    d = np.asarray(deform, dtype=np.float64).reshape(-1)
    if d.shape != (len(names),) or not np.all(np.isfinite(d)):
        raise ShapeSpaceError(f"deform: expected {len(names)} finite values, got {d.size}", ErrorCode.SHAPE)
    if not (np.isfinite(diagonal) and diagonal > 0):
        raise ShapeSpaceError(f"the surface's diagonal {diagonal} is not a positive size", ErrorCode.DEGENERATE)
    rel = d / diagonal
    keep = np.flatnonzero(rel > rel_tol)
    order = keep[np.argsort(-rel[keep], kind="stable")]
    inert = [names[i] for i in range(len(names)) if rel[i] <= rel_tol]
    report = ProposalReport(proposed=[names[i] for i in order], deformation=[float(rel[i]) for i in order],
                            skipped={"locked": list(locked), "held": list(held), "inert": inert})
    if not report.proposed:
        report.status = Status.FAILED
    return report
