"""Bad pose-space examples: duplicates, conflicts, flat dimensions and outliers (thesis 8.2.1, 8.2.3).

Examples are made by hand, one pose at a time, so the same pose gets saved
twice, two different sculpts land on (nearly) the same pose, or one sculpt
disagrees with all the others.  :func:`example_issues` names such examples
for the artist; training regularises instead of failing (Eq. 8.3).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from .. import rbf, validate
from ..result import Issue, ShapeSpaceError
from .psd import affine_determined, default_epsilon

__all__ = ["example_issues"]


def example_issues(poses: ArrayLike, correctives: ArrayLike | None = None, names: Sequence[str] | None = None,
                   rel_tol: float = 1e-6, outlier_factor: float = 4.0) -> list[Issue]:
    """Find bad examples (thesis 8.2.1, 8.2.3), naming them for the artist.

    - the same pose saved twice (distance ≤ ``rel_tol`` × pose-space size):
      ``duplicate_pose`` when the sculpts agree, ``conflicting_examples`` when
      two different sculpts sit at (nearly) the same pose;
    - a pose dimension that never varies: ``constant_dimension`` (it cannot
      influence the interpolation);
    - an outlier: the example farthest from a regularised fit of the others,
      when its residual exceeds ``outlier_factor`` × the median residual.

    Parameters
    ----------
    poses : array_like, shape (K, d)
        Example poses (pseudo-example locations where set).
    correctives : array_like, shape (K, p, 3), optional
        Their correctives (needed to tell duplicates from conflicts and for outliers).
    names : sequence of str, optional
        Example names for the messages (default ``example k``).
    rel_tol : float
        Poses closer than this fraction of the pose-space size are the same pose.
    outlier_factor : float
        How many median residuals make an outlier.

    Returns
    -------
    list of Issue
    """
    X = validate.array(poses, "poses", ndim=2)
    K = X.shape[0]
    names = list(names) if names is not None else [f"example {k}" for k in range(K)]
    issues = []
    spread = float(np.ptp(X, axis=0).max()) if K > 1 else 0.0
    size = spread if spread > 0 else 1.0
    d = rbf.pairwise_distances(X, X)
    D = None if correctives is None else np.asarray(correctives, dtype=np.float64).reshape(K, -1)
    for a in range(K):
        for b in range(a + 1, K):
            if d[a, b] <= rel_tol * size:
                same = D is None or np.allclose(D[a], D[b], atol=1e-9 * (np.abs(D).max() + 1e-300))
                code = "duplicate_pose" if same else "conflicting_examples"
                text = ("are the same pose" if same else "are (nearly) the same pose with different sculpts")
                issues.append(Issue("warning", code, f"{names[a]} and {names[b]} {text}; "
                                    "ShapeSpace regularises instead of failing", (names[a], names[b])))
    if K > 1:
        flat = np.flatnonzero(np.ptp(X, axis=0) <= 1e-12 * size)
        if flat.size:
            issues.append(Issue("info", "constant_dimension",
                                f"{flat.size} pose-space dimensions never vary across the examples", ()))
    if D is not None and K >= 4 and not any(i.code in ("duplicate_pose", "conflicting_examples") for i in issues):
        # 8.2.3: regularise, then flag the example farthest from the regularised fit.  Residuals are
        # measured against the fit of all examples (no extrapolation from left-out ends) and compared
        # with the spread of the others.
        eps = default_epsilon(X)
        try:
            fit = rbf.fit_rbf(X, D, "gaussian", eps, 1 if affine_determined(X) else 0, smoothing=0.1)
            res = np.linalg.norm(fit(X) - D, axis=1)
            worst = int(np.argmax(res))
            med = float(np.median(np.delete(res, worst)))
            if res[worst] > outlier_factor * max(med, 1e-12 * (np.abs(D).max() + 1e-300)):
                issues.append(Issue("warning", "outlier",
                                    f"{names[worst]} disagrees with the other examples "
                                    f"({res[worst] / max(med, 1e-300):.1f}× their typical distance from a smooth "
                                    "fit): check the sculpt or its pose", (names[worst],)))
        except ShapeSpaceError:
            pass
    return issues
