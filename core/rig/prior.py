"""The learned prior of pin-and-drag on any face rig (thesis 4.3, issue #25 item 2): a Gaussian on the controls.

Thesis ch. 4 regularises a drag by a Gaussian prior learned from earlier animation.  On a linear shape-key face
that prior lives on the slider weights (:mod:`core.manipulation.prior`); on a rig that is not linear (bones,
drivers, hybrids) it lives on the rig's *control channels* — a bone's rotation, location or scale axis, a custom
property, a slider — sampled per frame from the action(s) that key them.  :func:`train_control_prior` fits

    μ = mean of the frames (n,),   Σ = their covariance (n, n) + diag(ε),

and the rig solve (:func:`core.rig.solve.solve_controls`) uses ``λ Σ⁻¹`` as the metric of its regulariser
``λ (x − r)ᵀ Σ⁻¹ (x − r)`` around the controls at mouse-down ``r`` — as the linear path's Learned mode centres its
prior metric on the weights at mouse-down: moves the animation makes together are cheap, the face is never pulled
toward the training mean ``μ`` (:meth:`ControlPrior.mahalanobis` measures from it).

Units and weight — the linear path's Learned-mode convention (:func:`core.manipulation.prior.prior_terms`: the
data term measured at a 30-unit head diagonal, the prior metric ``σ̄² (Σ + ε σ̄² I)⁻¹``, weight α) carried to
channels of mixed units through their natural scales ``s_i`` (surface displacement per unit): in normalised surface
coordinates ``z_i = s_i x_i / u`` (``u`` = the evaluated diagonal / 30) the mean variance ``σ̄²`` is the mean of the
non-zero eigenvalues of ``Σ_z = diag(s/u) Σ diag(s/u)`` (above ``1e-12`` of the largest, as the linear path keeps
only its non-zero PCA variances: channels the animation never moves do not weaken the prior) and the ridge adds
``ε σ̄²`` to every direction, i.e. ``ε_i = eps · σ̄² u² / s_i²`` in the channel's own unit;
the weight is ``λ = α u² σ̄²``, so with an isotropic Σ the term is ``α/(1 + eps) Σ (s_i (x_i − r_i))²`` — the
Direct regulariser in surface lengths, weighted as the linear path weights its sliders.  Channels the animation
never moves keep only ``ε_i``: moving one by a surface distance δ costs ``α/eps · δ²`` (as a slider outside the
training span does on the linear path).

Refused by name: fewer than 2 frames (``prior_frames``), a non-finite value (``non_finite``), animation that moves
no channel (``prior_constant``), shapes that do not match (``shape``), a non-positive scale, unit or weight
(``range``).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..result import ShapeSpaceError

__all__ = ["ControlPrior", "train_control_prior"]

#: The ridge's default fraction of the mean variance (the linear path's :class:`~core.manipulation.WeightPrior`).
DEFAULT_EPS = 0.1


@dataclass(frozen=True)
class ControlPrior:
    """A Gaussian prior on a rig's controls (module doc); :func:`train_control_prior` makes one.

    Attributes
    ----------
    names : tuple of str
        The channels, in the control vector's order (n).
    mean : ndarray (n,)
        ``μ``.
    covariance : ndarray (n, n)
        ``Σ``, regularised (``+ diag(ε)``): symmetric positive definite.
    weight : float
        ``λ`` (surface length², the data term's unit).
    frames : int
        Training frames.
    keyed : ndarray (n,) bool
        Channels the animation moves.
    precision : ndarray (n, n)
        ``λ Σ⁻¹``: the Hessian of the prior term is twice this.
    """

    names: tuple
    mean: np.ndarray
    covariance: np.ndarray
    weight: float
    frames: int
    keyed: np.ndarray
    precision: np.ndarray

    def energy(self, x: ArrayLike, reference: ArrayLike | None = None) -> float:
        """``λ (x − r)ᵀ Σ⁻¹ (x − r)`` for controls ``x`` (n,) around ``reference`` ``r`` (n,) (``μ`` by default;
        a drag's regulariser is this around the controls at mouse-down)."""
        r = self.mean if reference is None else np.asarray(reference, dtype=np.float64).reshape(-1)
        d = np.asarray(x, dtype=np.float64).reshape(-1) - r
        return float(d @ self.precision @ d)

    def mahalanobis(self, x: ArrayLike) -> float:
        """Mahalanobis distance ``√((x − μ)ᵀ Σ⁻¹ (x − μ))`` of controls ``x`` (n,) from the training frames."""
        return float(np.sqrt(max(self.energy(x) / self.weight, 0.0)))


def train_control_prior(samples: ArrayLike, names: Sequence[str], scale: ArrayLike, unit: float,
                        alpha: float = 0.1, eps: float = DEFAULT_EPS) -> ControlPrior:
    """Fit the Gaussian prior on the controls from animation frames (module doc).

    Parameters
    ----------
    samples : array_like (f, n)
        Control values per training frame (channels the animation does not key hold one value).
    names : sequence of str (n)
    scale : array_like (n,)
        Natural scales ``s`` (surface displacement per unit of each channel, > 0).
    unit : float
        The normalised unit ``u`` (the face's evaluated bounding-box diagonal / 30, > 0).
    alpha : float
        The panel's regularisation weight α (> 0).
    eps : float
        Ridge as a fraction of the mean variance (> 0).

    Returns
    -------
    ControlPrior
    """
    names = tuple(names)
    x = np.asarray(samples, dtype=np.float64)
    n = len(names)
    if x.ndim != 2 or x.shape[1] != n:
        raise ShapeSpaceError(f"prior samples must have shape (frames, {n}), got {x.shape}", ErrorCode.SHAPE)
    if x.shape[0] < 2:
        raise ShapeSpaceError(f"a prior needs at least 2 frames of animation, got {x.shape[0]}",
                              ErrorCode.PRIOR_FRAMES)
    bad = np.argwhere(~np.isfinite(x))
    if bad.size:
        f, j = (int(v) for v in bad[0])
        raise ShapeSpaceError(f"the prior's animation has {x[f, j]} in channel {names[j]!r} at sample {f}",
                              ErrorCode.NON_FINITE)
    s = np.asarray(scale, dtype=np.float64).reshape(-1)
    if s.shape != (n,) or not np.all(np.isfinite(s) & (s > 0)):
        raise ShapeSpaceError(f"natural scales: expected {n} positive numbers", ErrorCode.RANGE)
    for value, what in ((unit, "unit"), (alpha, "alpha"), (eps, "eps")):
        if not (np.isfinite(value) and value > 0):
            raise ShapeSpaceError(f"prior {what} = {value} must be a positive number", ErrorCode.RANGE)
    mean = x.mean(axis=0)
    centred = x - mean
    cov = centred.T @ centred / (x.shape[0] - 1)
    z = s / unit
    var_z = np.diag(cov) * z * z
    keyed = var_z > 1e-12 * max(float(var_z.max()), 1e-300)
    sigma2 = _mean_variance(cov * np.outer(z, z))
    if not (sigma2 > 1e-24):
        raise ShapeSpaceError("the prior's animation moves none of the control channels", ErrorCode.PRIOR_CONSTANT)
    ridge = eps * sigma2 * unit * unit / (s * s)
    cov = 0.5 * (cov + cov.T) + np.diag(ridge)
    weight = float(alpha * unit * unit * sigma2)
    try:
        chol = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise ShapeSpaceError("the prior's covariance is not positive definite", ErrorCode.NON_FINITE) from None
    inv_chol = np.linalg.solve(chol, np.eye(n))
    precision = weight * (inv_chol.T @ inv_chol)
    precision = 0.5 * (precision + precision.T)
    return ControlPrior(names, mean, cov, weight, int(x.shape[0]), keyed, precision)


def _mean_variance(cov_z: np.ndarray) -> float:
    """``σ̄²``: the mean of the eigenvalues of ``Σ_z`` (n, n) above ``1e-12`` of the largest — the directions the
    animation moves in, as the linear path's :func:`core.manipulation.prior.train_prior` keeps only its non-zero
    PCA variances — so channels the animation never moves do not dilute it (0 when nothing moves)."""
    ev = np.linalg.eigvalsh(0.5 * (cov_z + cov_z.T))
    top = float(ev.max(initial=0.0))
    if not (top > 0.0):
        return 0.0
    return float(ev[ev > 1e-12 * top].mean())
