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

Also: detection of duplicate / conflicting / outlier examples (8.2.1, 8.2.3)
and driving arbitrary scalar targets from pose space (7.3.3).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import rbf
from ..result import Issue, ShapeSpaceError

__all__ = ["PoseSpaceDeformer", "train_psd", "example_issues", "ScalarDriver", "train_driver"]

METHODS = ("psd", "sbe", "wpsd")
#: Weighted PSD: per-vertex coefficients larger than this times the vertex's largest corrective
#: mark an ill-conditioned vertex system (see train_psd's ``vertex_ridge``).
AMPLIFICATION_LIMIT = 2000.0


def _check_examples(poses, correctives):
    X = np.asarray(poses, dtype=np.float64)
    if X.ndim != 2:
        raise ShapeSpaceError(f"poses must have shape (examples, features), got {X.shape}", "shape")
    D = np.asarray(correctives, dtype=np.float64)
    if D.ndim != 3 or D.shape[0] != X.shape[0] or D.shape[2] != 3:
        raise ShapeSpaceError(f"correctives must have shape ({X.shape[0]}, p, 3), got {D.shape}", "shape")
    if not (np.isfinite(X).all() and np.isfinite(D).all()):
        raise ShapeSpaceError("example poses or correctives contain NaN or infinite values", "non_finite")
    if X.shape[0] < 1:
        raise ShapeSpaceError("pose-space deformation needs at least one example", "no_examples")
    return X, D


def example_issues(poses, correctives=None, names=None, rel_tol: float = 1e-6, outlier_factor: float = 4.0):
    """Find bad examples (thesis 8.2.1, 8.2.3), naming them for the artist.

    - the same pose saved twice (distance ≤ ``rel_tol`` × pose-space size):
      ``duplicate_pose`` when the sculpts agree, ``conflicting_examples`` when
      two different sculpts sit at (nearly) the same pose;
    - a pose dimension that never varies: ``constant_dimension`` (it cannot
      influence the interpolation);
    - an outlier: the example farthest from a regularised fit of the others,
      when its residual exceeds ``outlier_factor`` × the median residual.

    Returns
    -------
    list of Issue
    """
    X = np.asarray(poses, dtype=np.float64)
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
        eps = _default_epsilon(X)
        try:
            fit = rbf.fit_rbf(X, D, "gaussian", eps, 1 if _affine_determined(X) else 0, smoothing=0.1)
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


def _affine_determined(X) -> bool:
    """True when the examples determine an affine function of the pose (Shape-by-Example's linear part)."""
    K, d = X.shape
    return K >= d + 2 and np.linalg.matrix_rank(np.hstack([np.ones((K, 1)), X])) == d + 1


def _default_epsilon(X):
    d = rbf.pairwise_distances(X, X)
    pos = d[d > 0]
    return 1.0 / float(np.median(pos)) if pos.size else 1.0


def _regularisation(X, smoothing):
    """Smoothing that keeps (near-)duplicate examples solvable (8.2.1)."""
    if X.shape[0] < 2:
        return smoothing
    d = rbf.pairwise_distances(X, X)
    np.fill_diagonal(d, np.inf)
    size = max(float(np.ptp(X, axis=0).max()), 1e-300)
    return max(smoothing, 1e-6) if d.min() <= 1e-6 * size else smoothing


@dataclass
class PoseSpaceDeformer:
    """Trained pose-space correctives.  Call :meth:`evaluate` with a pose feature vector.

    Attributes
    ----------
    method : {"psd", "sbe", "wpsd"}
    poses : ndarray (K, d)
        Interpolation locations (pseudo-example locations where set).
    correctives : ndarray (K, p, 3)
        Rest-space correctives.
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
        return self.poses.shape[0]

    def weights(self, pose) -> np.ndarray:
        """Per-example weights at ``pose`` (K,) (PSD, Shape-by-Example)."""
        if self.method == "wpsd":
            raise ShapeSpaceError("weighted PSD has per-vertex weights; use vertex_weights_at()", "method")
        return self.interpolant.cardinal(np.asarray(pose, dtype=np.float64)[None])[0]

    def _group_d2(self, pose):
        x = np.asarray(pose, dtype=np.float64)
        return np.stack([np.sum((x[cols] - self.poses[:, cols]) ** 2, axis=1) for cols in self.group_columns])

    def vertex_weights_at(self, pose) -> np.ndarray:
        """Weighted PSD: normalised kernel values per vertex and example, (p, K)."""
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

    def evaluate_fast(self, pose) -> np.ndarray:
        """Weighted PSD for live preview, (p, 3): the same result as :meth:`evaluate`, faster.

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

    def evaluate(self, pose) -> np.ndarray:
        """Rest-space corrective displacement at ``pose``, (p, 3)."""
        if self.method == "wpsd":
            return np.einsum("pk,pkc->pc", self.vertex_weights_at(pose), self.folded)
        w = self.weights(pose)
        return np.tensordot(w, self.correctives, axes=1)


def train_psd(poses, correctives, method: str = "psd", epsilon: float = None, smoothing: float = 0.0,
              kernel: str = None, pseudo_poses=None, vertex_groups=None, vertex_weights=None,
              group_columns=None, vertex_ridge: float = 1e-3, chunk: int = 4096) -> PoseSpaceDeformer:
    """Train pose-space correctives.

    Parameters
    ----------
    poses : array_like (K, d)
        Pose features of the examples (see :mod:`core.posespace`).
    correctives : array_like (K, p, 3)
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
        this pose location instead of where it was sculpted.
    vertex_groups, vertex_weights : array_like (p, m)
        Weighted PSD: per-vertex influences (index into ``group_columns``).
    group_columns : list of index arrays
        Weighted PSD: the feature columns of each joint.
    vertex_ridge : float
        Weighted PSD: starting ridge for the vertices whose examples nearly
        coincide in that vertex's own (skin-weighted) pose metric, detected by
        coefficients over :data:`AMPLIFICATION_LIMIT` × the vertex's largest
        corrective; the ridge grows ×10 until they are tame.  Those vertices
        reproduce their examples approximately instead of blowing up between
        them; all other vertices interpolate exactly.  0 turns it off.
    """
    X, D = _check_examples(poses, correctives)
    if method not in METHODS:
        raise ShapeSpaceError(f"method must be one of {', '.join(METHODS)}, got {method!r}", "method")
    X = X.copy()
    for k, p in (pseudo_poses or {}).items():
        if not 0 <= int(k) < X.shape[0]:
            raise ShapeSpaceError(f"pseudo-example {k} does not exist", "range")
        X[int(k)] = np.asarray(p, dtype=np.float64)
    smoothing = _regularisation(X, smoothing)
    diag = {"smoothing": smoothing}
    K = X.shape[0]
    if method in ("psd", "sbe"):
        if method == "psd":
            kern, degree = kernel or "gaussian", -1
        else:
            kern = kernel or "thin_plate_spline"
            degree = 1 if _affine_determined(X) else 0
            if degree == 0 and rbf.KERNELS[kern][1] >= 1:
                kern = "multiquadric" if rbf.KERNELS[kern][1] >= 1 else kern
            diag["degree"] = degree
        if epsilon is None:
            epsilon = _default_epsilon(X)
            if K >= 3:
                cands = np.geomspace(0.1, 10.0, 21) * epsilon
                epsilon, scores = rbf.choose_epsilon(X, D.reshape(K, -1), kern, degree, smoothing, cands)
                diag["loo_rms"] = float(np.nanmin(scores))
        interp = rbf.fit_rbf(X, None, kern, epsilon, degree, smoothing)
        return PoseSpaceDeformer(method, X, D, float(epsilon), interp, diagnostics=diag)
    # weighted PSD
    if vertex_groups is None or vertex_weights is None or group_columns is None:
        raise ShapeSpaceError("weighted PSD needs per-vertex skinning weights and the joints' pose columns",
                              "wpsd_inputs")
    gi = np.array(vertex_groups, dtype=np.int64, copy=True)
    gw = np.array(vertex_weights, dtype=np.float64, copy=True)
    p = D.shape[1]
    if gi.shape != gw.shape or gi.shape[0] != p:
        raise ShapeSpaceError(f"vertex_groups and vertex_weights must both have shape ({p}, m)", "shape")
    gw = np.where(gi >= 0, gw, 0.0)
    total = gw.sum(axis=1, keepdims=True)
    unweighted = total[:, 0] <= 1e-12
    gw = np.where(total > 1e-12, gw / np.where(total > 1e-12, total, 1.0), 0.0)
    if unweighted.any():  # vertices no joint moves: use every joint equally
        G = len(group_columns)
        m = gi.shape[1]
        if m < G:
            gi = np.hstack([gi, np.full((p, G - m), -1)])
            gw = np.hstack([gw, np.zeros((p, G - m))])
        gi[unweighted, :G] = np.arange(G)
        gw[unweighted, :G] = 1.0 / G
    if epsilon is None:
        # a vertex sees only its own joints' part of the pose, so its distances are shorter than the
        # full pose distance: a kernel twice as narrow as PSD's default
        epsilon = 2.0 * _default_epsilon(X)
    model = PoseSpaceDeformer("wpsd", X, D, float(epsilon), None, gi, gw, [np.asarray(c) for c in group_columns],
                              diagnostics={**diag, "unweighted_vertices": int(unweighted.sum())})
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
        rhs = np.transpose(D[:, sl, :], (1, 0, 2))                               # (chunk, K, 3)
        try:
            coeff = np.linalg.solve(A, rhs)
        except np.linalg.LinAlgError:
            if vertex_ridge <= 0:
                raise ShapeSpaceError("a vertex's interpolation system is singular: examples too close together "
                                      "for its joints; add smoothing or remove an example", "singular") from None
            coeff = np.linalg.solve(A + 1e-12 * np.eye(K), rhs)   # the ridge pass below tames these
        if vertex_ridge > 0:
            # Examples that differ mostly in joints a vertex ignores are near-duplicates *for that
            # vertex*: its system is ill-conditioned and its coefficients blow up (large values that
            # cancel at the examples and swing wildly between them).  Those vertices, and only those,
            # are solved again with a growing ridge until the coefficients are tame.
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
        folded[sl] = coeff
    model.folded = folded
    model.diagnostics["ridged_vertices"] = ridged
    return model


@dataclass
class ScalarDriver:
    """Scalar targets (shape-key values, bone channels, properties) driven from pose space (7.3.3)."""

    names: list
    interpolant: object

    def __call__(self, pose) -> dict:
        vals = self.interpolant(np.asarray(pose, dtype=np.float64)[None])[0]
        return dict(zip(self.names, np.atleast_1d(vals).tolist()))


def train_driver(poses, values, names, kernel="thin_plate_spline", epsilon=1.0, degree=None, smoothing=0.0):
    """Interpolate named scalar targets (K, t) over pose space; returns a :class:`ScalarDriver`."""
    X = np.asarray(poses, dtype=np.float64)
    V = np.asarray(values, dtype=np.float64).reshape(X.shape[0], -1)
    if V.shape[1] != len(names):
        raise ShapeSpaceError(f"values have {V.shape[1]} columns for {len(names)} names", "shape")
    if degree is None:
        degree = 1 if _affine_determined(X) else 0
        if degree == 0 and rbf.KERNELS[kernel][1] >= 1:
            kernel = "multiquadric"
    smoothing = _regularisation(X, smoothing)
    return ScalarDriver(list(names), rbf.fit_rbf(X, V, kernel, epsilon, degree, smoothing))
