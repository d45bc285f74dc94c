"""Pose-space deformation: PSD, Shape-by-Example and weighted PSD (thesis ch. 7–8).

The rigger sculpts correctives at example poses; each is stored in rest space
(see :mod:`core.posespace.inversion`) and interpolated over pose space:

- **PSD** (Lewis et al. 2000): every vertex's corrective interpolated by a
  Gaussian RBF over pose space.  With one kernel for all vertices this is the
  cardinal form ``δ(x) = Σ_k c_k(x) Δ_k``.
- **Shape-by-Example** (Sloan et al. 2001): one set of cardinal weights for
  all vertices from a linear polynomial plus radial part (Eq. 8.4), and
  *pseudo-examples*: an example's pose location can be moved without
  resculpting.
- **Weighted PSD** (Kurihara & Miyata 2004): the pose distance of vertex v
  weighs each joint's part of the pose by v's skinning weight on that joint,
  ``d_v(x, x_k)² = Σ_j w_vj ‖x_j − x_kj‖²``, with normalised RBF cardinal
  interpolation per vertex.  Training factors one K × K system per vertex
  and folds it into the correctives, so evaluation is a kernel evaluation
  and a K-term contraction per vertex.

Detection of bad examples (8.2.1, 8.2.3) is in :mod:`.examples`, scalar
targets driven from pose space (7.3.3) in :mod:`.drivers`; both share the
kernel-width and regularisation rules defined here.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .. import rbf, validate
from ..errors import ErrorCode
from ..result import ShapeSpaceError
from .readers import PoseReader, feature_groups

__all__ = ["METHODS", "AMPLIFICATION_LIMIT", "PoseSpaceDeformer", "train_psd", "default_epsilon",
           "affine_determined", "regularisation", "skin_group_inputs"]

METHODS = ("psd", "sbe", "wpsd")
#: Weighted PSD: per-vertex coefficients larger than this times the vertex's largest corrective
#: mark an ill-conditioned vertex system (see train_psd's ``vertex_ridge``).
AMPLIFICATION_LIMIT = 2000.0


# ------------------------------------------------------------------ shared rules
def affine_determined(X: np.ndarray) -> bool:
    """True when the examples determine an affine function of the pose (Shape-by-Example's linear part).

    Parameters
    ----------
    X : ndarray, shape (K, d)
        Example poses.  Needs K ≥ d + 2 and affinely independent poses.
    """
    K, d = X.shape
    return K >= d + 2 and np.linalg.matrix_rank(np.hstack([np.ones((K, 1)), X])) == d + 1


def default_epsilon(X: np.ndarray) -> float:
    """Default Gaussian width: 1 / the median distance between distinct examples (1 when there are none).

    Parameters
    ----------
    X : ndarray, shape (K, d)
    """
    d = rbf.pairwise_distances(X, X)
    pos = d[d > 0]
    return 1.0 / float(np.median(pos)) if pos.size else 1.0


def regularisation(X: np.ndarray, smoothing: float) -> float:
    """Smoothing (weight decay, Eq. 8.3) that keeps (near-)duplicate examples solvable (8.2.1).

    Parameters
    ----------
    X : ndarray, shape (K, d)
    smoothing : float
        The caller's λ.

    Returns
    -------
    float
        ``max(smoothing, 1e-6)`` when two examples are within 1e-6 of the pose-space size, else ``smoothing``.
    """
    if X.shape[0] < 2:
        return smoothing
    d = rbf.pairwise_distances(X, X)
    np.fill_diagonal(d, np.inf)
    size = max(float(np.ptp(X, axis=0).max()), 1e-300)
    return max(smoothing, 1e-6) if d.min() <= 1e-6 * size else smoothing


def _check_examples(poses, correctives):
    X = validate.array(poses, "poses", ndim=2)
    D = validate.array(correctives, "correctives", shape=(X.shape[0], None, 3))
    if X.shape[0] < 1:
        raise ShapeSpaceError("pose-space deformation needs at least one example", ErrorCode.NO_EXAMPLES)
    return X, D


# ------------------------------------------------------------------ the trained model
@dataclass
class PoseSpaceDeformer:
    """Trained pose-space correctives.  Call :meth:`evaluate` with a pose feature vector.

    Attributes
    ----------
    method : {"psd", "sbe", "wpsd"}
    poses : ndarray, shape (K, d)
        Interpolation locations (pseudo-example locations where set).
    correctives : ndarray, shape (K, p, 3)
        Rest-space correctives.
    epsilon : float
        Kernel width.
    interpolant : RBFInterpolant
        PSD / Shape-by-Example: the cardinal interpolant over pose space.
    vertex_groups, vertex_weights : ndarray, shape (p, m)
        Weighted PSD: per-vertex joint index (−1 padding) and normalised skinning weight.
    group_columns : list of ndarray
        Weighted PSD: the pose columns of each joint.
    folded : ndarray, shape (p, K, 3)
        Weighted PSD: ``A_v⁻¹ Δ_v``, the per-vertex system folded into the correctives.
    diagnostics : dict
        ``smoothing``, ``degree``, ``loo_rms``, ``unweighted_vertices``, ``ridged_vertices`` as applicable.
    """

    method: str
    poses: np.ndarray
    correctives: np.ndarray
    epsilon: float
    interpolant: object = None
    # weighted PSD
    vertex_groups: np.ndarray = None     # (p, m) group index per influence, −1 padding
    vertex_weights: np.ndarray = None    # (p, m)
    group_columns: list = None           # feature columns per group
    folded: np.ndarray = None            # (p, K, 3): A_v⁻¹ Δ_v
    diagnostics: dict = field(default_factory=dict)
    _fast: tuple = None                  # sparse weights and (3, p, K) coefficients
    _W: object = None                    # sparse (p × joints) skin weights

    @property
    def n_examples(self) -> int:
        """Number of examples K."""
        return self.poses.shape[0]

    def weights(self, pose: ArrayLike) -> np.ndarray:
        """Per-example cardinal weights at ``pose`` (d,), shape (K,) (PSD, Shape-by-Example)."""
        if self.method == "wpsd":
            raise ShapeSpaceError("weighted PSD has per-vertex weights; use vertex_weights_at()", ErrorCode.METHOD)
        return self.interpolant.cardinal(np.asarray(pose, dtype=np.float64)[None])[0]

    def _group_d2(self, pose):
        x = np.asarray(pose, dtype=np.float64)
        return np.stack([np.sum((x[cols] - self.poses[:, cols]) ** 2, axis=1) for cols in self.group_columns])

    def vertex_weights_at(self, pose: ArrayLike) -> np.ndarray:
        """Weighted PSD: normalised kernel values per vertex and example at ``pose`` (d,), shape (p, K)."""
        g2 = self._group_d2(pose)                               # (G, K)
        gi = np.where(self.vertex_groups >= 0, self.vertex_groups, 0)
        d2 = np.einsum("pm,pmk->pk", self.vertex_weights, g2[gi])
        phi = np.exp(-(self.epsilon ** 2) * d2)
        return phi / phi.sum(axis=1, keepdims=True)

    def _prepare_fast_weights(self):
        """Sparse (p × joints) skin-weight matrix."""
        import scipy.sparse as sp
        p, m = self.vertex_groups.shape
        ok = self.vertex_groups >= 0
        rows = np.repeat(np.arange(p), m)[ok.ravel()]
        self._W = sp.csr_matrix((self.vertex_weights.ravel()[ok.ravel()],
                                 (rows, self.vertex_groups.ravel()[ok.ravel()])),
                                shape=(p, len(self.group_columns)))

    def _prepare_fast(self):
        if self._W is None:
            self._prepare_fast_weights()
        self._fast = (self._W, np.ascontiguousarray(self.folded.transpose(2, 0, 1)))

    def evaluate_fast(self, pose: ArrayLike) -> np.ndarray:
        """Weighted PSD for live preview at ``pose`` (d,), shape (p, 3): the same result as :meth:`evaluate`,
        faster.

        A sparse (p × joints) weight matrix gives every vertex's pose distances
        at once; normalisation is applied to the 3 output columns instead of
        the p × K kernel matrix.  Double precision throughout: the folded
        coefficients A_v⁻¹Δ_v can cancel strongly, which single precision
        would amplify.
        """
        if self.method != "wpsd":
            return self.evaluate(pose).astype(np.float32)
        if self._fast is None:
            self._prepare_fast()
        W, coeffs = self._fast
        d2 = W @ self._group_d2(pose)
        d2 *= -(self.epsilon ** 2)
        phi = np.exp(d2, out=d2)
        out = np.einsum("pk,cpk->pc", phi, coeffs)
        out /= phi.sum(axis=1, keepdims=True)
        return out

    def evaluate(self, pose: ArrayLike) -> np.ndarray:
        """Rest-space corrective displacement at ``pose`` (d,), shape (p, 3): ``Σ_k c_k(x) Δ_k``."""
        if self.method == "wpsd":
            return np.einsum("pk,pkc->pc", self.vertex_weights_at(pose), self.folded)
        w = self.weights(pose)
        return np.tensordot(w, self.correctives, axes=1)


# ------------------------------------------------------------------ training
def train_psd(poses: ArrayLike, correctives: ArrayLike, method: str = "psd", epsilon: float | None = None,
              smoothing: float = 0.0, kernel: str | None = None, pseudo_poses: Mapping[int, ArrayLike] | None = None,
              vertex_groups: ArrayLike | None = None, vertex_weights: ArrayLike | None = None,
              group_columns: Sequence[ArrayLike] | None = None, vertex_ridge: float = 1e-3,
              chunk: int = 4096) -> PoseSpaceDeformer:
    """Train pose-space correctives (thesis ch. 7–8).

    Parameters
    ----------
    poses : array_like, shape (K, d)
        Pose features of the examples (see :mod:`core.posespace.readers`).
    correctives : array_like, shape (K, p, 3)
        Rest-space correctives.
    method : {"psd", "sbe", "wpsd"}
    epsilon : float, optional
        Kernel width (PSD/WPSD Gaussian, SbE radial part); default: by
        leave-one-out cross validation (PSD, SbE) or 2 / median distance
        between the examples (WPSD: each vertex sees only its joints' part of
        the pose, so its distances are shorter).
    smoothing : float
        Weight decay (Eq. 8.3); raised automatically for (near-)duplicate poses.
    kernel : str, optional
        Radial kernel (default gaussian for PSD, thin_plate_spline for SbE).
    pseudo_poses : dict {k: pose}, optional
        Shape-by-Example pseudo-examples: interpolate example k's sculpt at
        this pose location (d,) instead of where it was sculpted.
    vertex_groups, vertex_weights : array_like, shape (p, m)
        Weighted PSD: per-vertex influences (index into ``group_columns``, −1 padding) and weights.
    group_columns : list of index arrays
        Weighted PSD: the feature columns of each joint.
    vertex_ridge : float
        Weighted PSD: starting ridge for the vertices whose examples nearly
        coincide in that vertex's own (skin-weighted) pose metric, detected by
        coefficients over :data:`AMPLIFICATION_LIMIT` × the vertex's largest
        corrective; the ridge grows ×10 until they are tame.  Those vertices
        reproduce their examples approximately instead of blowing up between
        them; all other vertices interpolate exactly.  0 turns it off.
    chunk : int
        Weighted PSD: vertices solved per batch (memory bound only; the result does not depend on it).

    Returns
    -------
    PoseSpaceDeformer
    """
    X, D = _check_examples(poses, correctives)
    validate.choice(method, "method", METHODS)
    X = X.copy()
    for k, p in (pseudo_poses or {}).items():
        if not 0 <= int(k) < X.shape[0]:
            raise ShapeSpaceError(f"pseudo-example {k} does not exist", ErrorCode.RANGE)
        X[int(k)] = np.asarray(p, dtype=np.float64)
    smoothing = regularisation(X, smoothing)
    if method in ("psd", "sbe"):
        return _train_rbf(X, D, method, epsilon, smoothing, kernel)
    return _train_wpsd(X, D, epsilon, smoothing, vertex_groups, vertex_weights, group_columns, vertex_ridge, chunk)


def _train_rbf(X, D, method, epsilon, smoothing, kernel) -> PoseSpaceDeformer:
    """PSD (Gaussian, no polynomial) or Shape-by-Example (linear + radial, Eq. 8.4): one cardinal interpolant."""
    diag = {"smoothing": smoothing}
    K = X.shape[0]
    if method == "psd":
        kern, degree = kernel or "gaussian", -1
    else:
        kern = kernel or "thin_plate_spline"
        degree = 1 if affine_determined(X) else 0
        if degree == 0 and rbf.KERNELS[kern][1] >= 1:
            kern = "multiquadric"       # a polyharmonic kernel needs the linear part the examples cannot fix
        diag["degree"] = degree
    if epsilon is None:
        epsilon = default_epsilon(X)
        if K >= 3:
            cands = np.geomspace(0.1, 10.0, 21) * epsilon
            epsilon, scores = rbf.choose_epsilon(X, D.reshape(K, -1), kern, degree, smoothing, cands)
            diag["loo_rms"] = float(np.nanmin(scores))
    interp = rbf.fit_rbf(X, None, kern, epsilon, degree, smoothing)
    return PoseSpaceDeformer(method, X, D, float(epsilon), interp, diagnostics=diag)


def _normalised_skin(vertex_groups, vertex_weights, group_columns, p):
    """Per-vertex joint weights normalised to sum 1; vertices no joint moves use every joint equally."""
    if vertex_groups is None or vertex_weights is None or group_columns is None:
        raise ShapeSpaceError("weighted PSD needs per-vertex skinning weights and the joints' pose columns",
                              ErrorCode.WPSD_INPUTS)
    gi = np.array(vertex_groups, dtype=np.int64, copy=True)
    gw = np.array(vertex_weights, dtype=np.float64, copy=True)
    if gi.shape != gw.shape or gi.shape[0] != p:
        raise ShapeSpaceError(f"vertex_groups and vertex_weights must both have shape ({p}, m)", ErrorCode.SHAPE)
    gw = np.where(gi >= 0, gw, 0.0)
    total = gw.sum(axis=1, keepdims=True)
    unweighted = total[:, 0] <= 1e-12
    gw = np.where(total > 1e-12, gw / np.where(total > 1e-12, total, 1.0), 0.0)
    if unweighted.any():
        G = len(group_columns)
        m = gi.shape[1]
        if m < G:
            gi = np.hstack([gi, np.full((p, G - m), -1)])
            gw = np.hstack([gw, np.zeros((p, G - m))])
        gi[unweighted, :G] = np.arange(G)
        gw[unweighted, :G] = 1.0 / G
    return gi, gw, int(unweighted.sum())


def _train_wpsd(X, D, epsilon, smoothing, vertex_groups, vertex_weights, group_columns, vertex_ridge,
                chunk) -> PoseSpaceDeformer:
    """Weighted PSD: one normalised-RBF system per vertex in its skin-weighted pose metric, folded into
    the correctives."""
    K, p = X.shape[0], D.shape[1]
    gi, gw, n_unweighted = _normalised_skin(vertex_groups, vertex_weights, group_columns, p)
    if epsilon is None:
        # a vertex sees only its own joints' part of the pose, so its distances are shorter than the
        # full pose distance: a kernel twice as narrow as PSD's default
        epsilon = 2.0 * default_epsilon(X)
    model = PoseSpaceDeformer("wpsd", X, D, float(epsilon), None, gi, gw, [np.asarray(c) for c in group_columns],
                              diagnostics={"smoothing": smoothing, "unweighted_vertices": n_unweighted})
    folded = np.empty((p, K, 3))
    # squared distances between examples, per joint: (G, K, K)
    pair = np.stack([rbf.pairwise_distances(X[:, c], X[:, c]) ** 2 for c in model.group_columns])
    pair_flat = pair.reshape(pair.shape[0], -1)                            # (G, K·K)
    model._prepare_fast_weights()
    ridged = 0
    for start in range(0, p, chunk):
        sl = slice(start, min(start + chunk, p))
        d2 = (model._W[sl] @ pair_flat).reshape(-1, K, K)                  # vertex metric, example pairs
        A = np.exp(-(epsilon ** 2) * d2)
        A /= A.sum(axis=2, keepdims=True)                                  # normalised rows (i: at example i)
        if smoothing > 0:
            A = A + smoothing * np.eye(K)
        rhs = np.transpose(D[:, sl, :], (1, 0, 2))                         # (chunk, K, 3)
        folded[sl], n = _solve_vertex_systems(A, rhs, vertex_ridge)
        ridged += n
    model.folded = folded
    model.diagnostics["ridged_vertices"] = ridged
    return model


def _solve_vertex_systems(A, rhs, vertex_ridge):
    """Solve the per-vertex K × K systems; returns the coefficients (chunk, K, 3) and how many vertices
    needed a ridge."""
    K = A.shape[-1]
    try:
        coeff = np.linalg.solve(A, rhs)
    except np.linalg.LinAlgError:
        if vertex_ridge <= 0:
            raise ShapeSpaceError("a vertex's interpolation system is singular: examples too close together "
                                  "for its joints; add smoothing or remove an example", ErrorCode.SINGULAR) from None
        coeff = np.linalg.solve(A + 1e-12 * np.eye(K), rhs)   # the ridge pass below tames these
    if vertex_ridge <= 0:
        return coeff, 0
    # Examples that differ mostly in joints a vertex ignores are near-duplicates *for that
    # vertex*: its system is ill-conditioned and its coefficients blow up (large values that
    # cancel at the examples and swing wildly between them).  Those vertices, and only those,
    # are solved again with a growing ridge until the coefficients are tame.
    ridged = 0
    scale = np.abs(rhs).max(axis=(1, 2)) + 1e-300
    wild = np.abs(coeff).max(axis=(1, 2)) > AMPLIFICATION_LIMIT * scale
    lam = vertex_ridge
    while wild.any() and lam <= 1.0:
        idx = np.flatnonzero(wild)
        coeff[idx] = np.linalg.solve(A[idx] + lam * np.eye(K), rhs[idx])
        ridged_now = idx[np.abs(coeff[idx]).max(axis=(1, 2)) <= AMPLIFICATION_LIMIT * scale[idx]]
        ridged += ridged_now.size
        wild[ridged_now] = False
        lam *= 10.0
    ridged += int(wild.sum())
    return coeff, ridged


def skin_group_inputs(readers: Sequence[PoseReader], bone_names: Sequence[str], bone_index: ArrayLike,
                      bone_weights: ArrayLike) -> dict[str, Any]:
    """Weighted-PSD inputs of :func:`train_psd` from a mesh's skinning and its pose space.

    Each pose-space source (bone, property, key) is one joint group; a vertex's skinning weights on
    bones that are not sources are dropped (they do not move the pose).

    Parameters
    ----------
    readers : sequence of PoseReader
        The pose space.
    bone_names : sequence of str, length B
        The skinning's bone names.
    bone_index : array_like of int, shape (p, m)
        Per-vertex bone indices into ``bone_names`` (−1 padding).
    bone_weights : array_like, shape (p, m)

    Returns
    -------
    dict
        ``vertex_groups`` (p, m) group indices (−1 for bones that are not sources), ``vertex_weights``
        (p, m) and ``group_columns`` (the pose columns of each source), ready for ``train_psd(**...)``.
    """
    groups = feature_groups(readers)
    sources = list(groups)
    lookup = {name: i for i, name in enumerate(sources)}
    remap = np.array([lookup.get(b, -1) for b in bone_names] + [-1])
    gi = remap[np.asarray(bone_index, dtype=np.int64)]
    gw = np.where(gi >= 0, np.asarray(bone_weights, dtype=np.float64), 0.0)
    return {"vertex_groups": gi, "vertex_weights": gw, "group_columns": [groups[s] for s in sources]}
