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
- **Blended distance** (weighted PSD option): a vertex whose corrective
  depends on joints it is not skinned to sees them through a blend of the
  skin-weighted and the global pose distance,
  ``d_v² = (1 − λ_v) Σ_j w_vj ‖x_j − x_kj‖² + λ_v ¼ ‖x − x_k‖²`` (the global
  part at PSD's kernel width: weighted PSD's kernel is twice as narrow), with
  λ chosen per region (the vertices a joint dominates) by leave-one-out cross
  validation over the examples.  λ = 0 is weighted PSD, λ = 1 a normalised
  Gaussian PSD over the whole pose.
- **Bone-pair distance** (weighted PSD option, :mod:`.pairs`): a vertex sees how its bones turn
  *relative to each other* — the relative rotations ``C_aᵀ C_b`` whose differences skinning artefacts grow
  with — weighted ``w_va w_vb``, plus a quarter of each bone's own rotation weighted ``w_va²``; with
  ``blend="auto"`` it is one more per-region candidate of the leave-one-out choice.
- **Evaluation at memory speed** (:meth:`PoseSpaceDeformer.evaluate_fast`):
  float32 coefficients in one contiguous block; vertices whose coefficients
  cancel strongly (an ill-conditioned vertex system) keep float64, so the
  result stays within 1e-6 of the mesh size of the float64 evaluation.

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
from .pairs import BonePairs, pair_metric
from .readers import PoseReader, feature_groups

__all__ = ["METHODS", "AMPLIFICATION_LIMIT", "BLEND_CANDIDATES", "BLEND_MARGIN", "WIDTH_CANDIDATES",
           "PAIR_WIDTH_CANDIDATES", "GLOBAL_DISTANCE_SCALE", "FAST_TOLERANCE", "PoseSpaceDeformer", "train_psd",
           "default_epsilon",
           "affine_determined", "regularisation", "skin_group_inputs", "blend_regions", "loo_errors_wpsd"]

METHODS = ("psd", "sbe", "wpsd")
#: Weighted PSD: per-vertex coefficients larger than this times the vertex's largest corrective
#: mark an ill-conditioned vertex system (see train_psd's ``vertex_ridge``).
AMPLIFICATION_LIMIT = 2000.0
#: Blended weighted PSD: the global pose distance's factor (¼: measured at PSD's kernel width, half weighted PSD's).
GLOBAL_DISTANCE_SCALE = 0.25
#: Blended weighted PSD: the λ tried per region by leave-one-out cross validation.
BLEND_CANDIDATES = (0.0, 0.1, 0.25, 0.5, 1.0)
#: Blended weighted PSD ("auto"): a region leaves the skin-weighted distance only when leave-one-out cross
#: validation shows at least this relative gain (a blend chosen on noise costs accuracy between the examples).
BLEND_MARGIN = 0.1
#: Blended weighted PSD ("auto"): the kernel-width factors tried per region with each λ (the leave-one-out
#: score prefers wider kernels than the held-out test poses do on RobotExpressive's hand, so only today's).
WIDTH_CANDIDATES = (1.0,)
#: Bone-pair distance: the kernel-width factors tried per region by leave-one-out cross validation (its
#: distances are shorter than the skin-weighted ones — a pair weighs ``w_a w_b`` ≤ ¼ — and the best width
#: differs between rigs: about 1 on RobotExpressive's hand, 2 on the RPM hand).
PAIR_WIDTH_CANDIDATES = (1.0, 1.4, 2.0)
#: Fast evaluation: largest difference from the float64 evaluation, as a fraction of the size given to
#: :meth:`PoseSpaceDeformer.prepare_fast` (4× below the 1e-6 promised).
FAST_TOLERANCE = 2.5e-7
#: Float32 evaluation error per unit of a vertex's largest coefficient: one float32 rounding unit (2⁻²⁴; the
#: largest measured on ill-conditioned 30k-vertex models is 0.64 of it: coefficient rounding plus kernel rounding).
_F32_ERROR = 2.0 ** -24


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
    blend : ndarray, shape (p,), or None
        Weighted PSD: per-vertex λ_v of the blended distance (None: the skin-weighted distance, λ = 0).
    width : ndarray, shape (p,), or None
        Weighted PSD: per-vertex kernel-width factor ε_v / ε (None: 1 everywhere).
    pairs : BonePairs or None
        Weighted PSD: the bone pairs of the bone-pair distance (None: not used).
    pair_share : ndarray, shape (p,), or None
        Weighted PSD: π_v, the bone-pair distance's share of each vertex's metric.
    diagnostics : dict
        ``smoothing``, ``degree``, ``loo_rms``, ``unweighted_vertices``, ``ridged_vertices``, ``blend_regions``
        as applicable.
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
    blend: np.ndarray = None             # (p,) λ_v of the blended distance, None = 0
    width: np.ndarray = None             # (p,) per-vertex kernel-width factor (ε_v / ε), None = 1
    pairs: BonePairs = None              # bone pairs of the bone-pair distance, None = not used
    pair_share: np.ndarray = None        # (p,) π_v of the bone-pair distance
    _space_ref: np.ndarray = None        # the examples in the distance's feature space (pair features appended)
    _space_cols: list = None             # feature columns of every distance term
    _fast: object = None                 # _FastWPSD
    _W: object = None                    # sparse (p × joints[+1]) metric weights

    @property
    def n_examples(self) -> int:
        """Number of examples K."""
        return self.poses.shape[0]

    def weights(self, pose: ArrayLike) -> np.ndarray:
        """Per-example cardinal weights at ``pose`` (d,), shape (K,) (PSD, Shape-by-Example)."""
        if self.method == "wpsd":
            raise ShapeSpaceError("weighted PSD has per-vertex weights; use vertex_weights_at()", ErrorCode.METHOD)
        return self.interpolant.cardinal(np.asarray(pose, dtype=np.float64)[None])[0]

    def _space(self, pose) -> np.ndarray:
        """A pose (d,) in the distance's feature space: with bone pairs, their relative rotations appended."""
        x = np.asarray(pose, dtype=np.float64)
        return x if self.pairs is None else np.concatenate([x, self.pairs.features(x[None])[0]])

    def _space_poses(self) -> np.ndarray:
        """The examples in the distance's feature space, (K, d [+ 9P])."""
        if self._space_ref is None:
            self._space_ref = _with_pair_features(self.poses, self.pairs)
        return self._space_ref

    def _columns(self) -> list:
        """Feature columns of every distance term: the G pose sources, then the P bone pairs (built once)."""
        if self._space_cols is None:
            self._space_cols = _distance_columns(self.group_columns, self.poses.shape[1], self.pairs)
        return self._space_cols

    def _group_d2(self, pose):
        """Squared distances to the examples per distance term (G [+ P] [+1], K); with a blend, the global
        distance (over the G pose sources) last."""
        x, ref = self._space(pose), self._space_poses()
        g2 = np.stack([np.sum((x[cols] - ref[:, cols]) ** 2, axis=1) for cols in self._columns()])
        G = len(self.group_columns)
        return g2 if self.blend is None else np.vstack([g2, g2[:G].sum(axis=0, keepdims=True)])

    def vertex_weights_at(self, pose: ArrayLike) -> np.ndarray:
        """Weighted PSD: normalised kernel values per vertex and example at ``pose`` (d,), shape (p, K)."""
        g2 = self._group_d2(pose)                               # (G, K)
        if self.blend is None and self.width is None and self.pairs is None:
            gi = np.where(self.vertex_groups >= 0, self.vertex_groups, 0)
            d2 = np.einsum("pm,pmk->pk", self.vertex_weights, g2[gi])
        else:
            if self._W is None:
                self._prepare_fast_weights()
            d2 = self._W @ g2
        phi = np.exp(-(self.epsilon ** 2) * d2)
        return phi / phi.sum(axis=1, keepdims=True)

    def _prepare_fast_weights(self):
        """Sparse (p × joints) metric weights: skin weights, scaled by 1 − λ_v, and λ_v/4 on the global distance."""
        self._W = _metric_matrix(self.vertex_groups, self.vertex_weights, len(self.group_columns), self.blend,
                                 self.width, self.pairs, self.pair_share)

    @property
    def fast_ready(self) -> bool:
        """Whether :meth:`prepare_fast` has laid out the coefficients (weighted PSD)."""
        return self._fast is not None

    def prepare_fast(self, size: float | None = None, tolerance: float = FAST_TOLERANCE) -> None:
        """Weighted PSD: lay out the coefficients for :meth:`evaluate_fast`.

        Parameters
        ----------
        size : float, optional
            The mesh's size (e.g. its bounding-box diagonal); default: the largest corrective coordinate
            (stricter).
        tolerance : float
            Largest difference from :meth:`evaluate` as a fraction of ``size``.  A vertex goes to the float32
            block when its float32 error ``u₃₂ max_k |a_vk|`` (``a_v = A_v⁻¹Δ_v``, u₃₂ = 2⁻²⁴) is within it:
            the folded coefficients of an ill-conditioned vertex system are large and cancel, and float32
            rounding of the coefficients and of the kernel is amplified by exactly that cancellation, so
            those vertices stay in float64; vertices without correctives are skipped.
        """
        if self.method != "wpsd":
            return
        if self._W is None:
            self._prepare_fast_weights()
        scale = float(size) if size else float(np.abs(self.correctives).max())
        self._fast = _FastWPSD(self._W, self.folded, max(scale, 1e-300) * tolerance)

    def evaluate_fast(self, pose: ArrayLike) -> np.ndarray:
        """Corrective displacement for live preview at ``pose`` (d,), shape (p, 3) float32.

        Weighted PSD: within ``tolerance × size`` of :meth:`evaluate` (see :meth:`prepare_fast`, called with
        defaults when it was not).  One sparse product gives every vertex's pose distances (per-joint
        distances shifted by their minimum over the examples: a per-vertex constant the normalisation
        cancels, which keeps the exponent small and float32 away from underflow), then one exponential and
        one contraction over the float32 coefficients (p × K × 3, contiguous); the few strongly cancelling
        vertices repeat this in float64.  Other methods: :meth:`evaluate` in float32.
        """
        if self.method != "wpsd":
            return self.evaluate(pose).astype(np.float32)
        if self._fast is None:
            self.prepare_fast()
        g2 = self._fast.group_d2(self._space(pose), self._space_poses(), self._columns(), self.blend is not None,
                                 len(self.group_columns))
        return self._fast(g2, self.epsilon)

    def evaluate(self, pose: ArrayLike) -> np.ndarray:
        """Rest-space corrective displacement at ``pose`` (d,), shape (p, 3): ``Σ_k c_k(x) Δ_k``."""
        if self.method == "wpsd":
            return np.einsum("pk,pkc->pc", self.vertex_weights_at(pose), self.folded)
        w = self.weights(pose)
        return np.tensordot(w, self.correctives, axes=1)


def _with_pair_features(X: np.ndarray, pairs: BonePairs | None) -> np.ndarray:
    """Poses (K, d) with the bone pairs' relative-rotation features appended (K, d + 9P)."""
    return X if pairs is None else np.hstack([X, pairs.features(X)])


def _distance_columns(group_columns, d: int, pairs: BonePairs | None) -> list:
    """Feature columns of the G pose sources, then of the P bone pairs (after the d pose features)."""
    extra = [] if pairs is None else [np.arange(d + 9 * k, d + 9 * k + 9) for k in range(pairs.n_pairs)]
    return [np.asarray(c) for c in group_columns] + extra


def _metric_matrix(vertex_groups, vertex_weights, n_groups, blend, width=None, pairs=None, pair_share=None):
    """Sparse (p × (G [+ P] [+1])) weights of the squared distance terms in each vertex's metric.

    Row v is ``α_v Σ_j w_vj d_j² + λ_v ¼ Σ_j d_j² + π_v (bone-pair distance)`` with ``α_v = 1 − λ_v − π_v``,
    times ``(ε_v / ε)²`` (a per-vertex kernel width).  Columns: the G pose sources, the P bone pairs when
    ``pairs`` is given, the global distance when ``blend`` is."""
    import scipy.sparse as sp
    p, m = vertex_groups.shape
    n_pairs = 0 if pairs is None else pairs.n_pairs
    lam = np.zeros(p) if blend is None else np.asarray(blend, dtype=np.float64)
    pi = np.zeros(p) if pair_share is None else np.asarray(pair_share, dtype=np.float64)
    ok = (vertex_groups >= 0).ravel()
    rows = np.repeat(np.arange(p), m)[ok]
    skin = sp.csr_matrix(((vertex_weights.ravel()[ok] * (1.0 - lam - pi)[rows]), (rows, vertex_groups.ravel()[ok])),
                         shape=(p, n_groups + n_pairs))
    if pairs is not None:
        skin = skin + sp.diags(pi) @ pair_metric(pairs, vertex_groups, vertex_weights, n_groups)
    if blend is not None:
        skin = sp.hstack([skin, sp.csr_matrix(GLOBAL_DISTANCE_SCALE * lam[:, None])], format="csr")
    if width is not None:
        skin = sp.diags(np.asarray(width, dtype=np.float64) ** 2) @ skin
    skin = sp.csr_matrix(skin)
    skin.eliminate_zeros()
    return skin


#: Exponent floors: exp stays a normal number (float32: e⁻⁸⁰ ≈ 1.8e-35; float64: e⁻⁷⁰⁰).
_EXP_FLOOR = {np.float32: np.float32(-80.0), np.float64: -700.0}
#: A float32 denominator (Σ_k φ_vk) below this is re-evaluated in float64: the floored terms then stay below
#: 1e-9 of it.
_DEN_FLOOR = 1e-25


class _FastWPSD:
    """Weighted PSD laid out for evaluation: a float32 block, a float64 block (cancelling vertices), and the
    vertices without correctives skipped."""

    def __init__(self, W, folded, tol_abs):
        p = folded.shape[0]
        cmax = np.abs(folded).max(axis=(1, 2)) if folded.size else np.zeros(p)
        live = cmax > 0
        f32 = live & (_F32_ERROR * cmax <= tol_abs)
        self.p = p
        self.idx32 = np.flatnonzero(f32)
        self.idx64 = np.flatnonzero(live & ~f32)
        self.all32 = self.idx32.size == p
        self.W32_exact = W[self.idx32]                  # float64 rows for the underflow fallback
        self.W32 = self.W32_exact.astype(np.float32)
        # (n, 3, K): one contiguous pass, the example axis innermost
        self.C32 = np.ascontiguousarray(folded[self.idx32].transpose(0, 2, 1), dtype=np.float32)
        self.W64 = W[self.idx64]
        self.C64 = np.ascontiguousarray(folded[self.idx64].transpose(0, 2, 1))
        self.wmax32, self.wmax64 = self._row_max(self.W32), self._row_max(self.W64)

    def group_d2(self, pose, poses, group_columns, with_total, n_joint=None):
        """:meth:`PoseSpaceDeformer._group_d2` in one vectorised pass (columns gathered once, summed per joint)."""
        if not hasattr(self, "_cols"):
            lengths = np.array([len(c) for c in group_columns])
            self._cols = np.concatenate([np.asarray(c, dtype=np.int64) for c in group_columns]) \
                if len(group_columns) else np.zeros(0, dtype=np.int64)
            self._starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
            self._empty = lengths == 0
            self._ref = np.ascontiguousarray(poses[:, self._cols])
        x = np.asarray(pose, dtype=np.float64)[self._cols]
        sq = self._ref - x
        sq *= sq
        g2 = np.add.reduceat(sq, np.minimum(self._starts, max(sq.shape[1] - 1, 0)), axis=1).T \
            if sq.shape[1] else np.zeros((len(self._starts), poses.shape[0]))
        if self._empty.any():
            g2[self._empty] = 0.0
        return np.vstack([g2, g2[:n_joint].sum(axis=0, keepdims=True)]) if with_total else g2

    @staticmethod
    def _row_max(W) -> float:
        return float(abs(W).sum(axis=1).max()) if W.shape[0] else 0.0

    @staticmethod
    def _block(W, C, g2, eps2, dtype, wmax):
        d2 = W @ g2.astype(dtype)
        d2 *= dtype(-eps2)
        # no subnormal results (exp is many times slower on them); terms this small are far below the
        # precision of any vertex whose denominator passes the check in __call__.  Skipped when the largest
        # row sum of W times the largest shifted joint distance cannot reach the floor.
        if eps2 * wmax * float(g2.max(initial=0.0)) > -_EXP_FLOOR[dtype]:
            np.maximum(d2, _EXP_FLOOR[dtype], out=d2)
        phi = np.exp(d2, out=d2)
        den = phi @ np.ones(phi.shape[1], dtype=dtype)      # a BLAS matrix-vector product: faster than sum
        out = np.einsum("pk,pck->pc", phi, C)
        out /= den[:, None]
        return out, den

    def __call__(self, g2, epsilon):
        g2 = g2 - g2.min(axis=1, keepdims=True)          # a per-vertex constant shift (cancels)
        eps2 = float(epsilon) ** 2
        out32, den = self._block(self.W32, self.C32, g2, eps2, np.float32, self.wmax32)
        if self.all32 and (den > _DEN_FLOOR).all():
            return out32
        out = np.zeros((self.p, 3), dtype=np.float32)
        out[self.idx32] = out32
        idx64 = self.idx64
        low = np.flatnonzero(~(den > _DEN_FLOOR))
        if low.size:                                     # float32 underflow far from every example
            idx64 = np.concatenate([idx64, self.idx32[low]])
        if idx64.size:
            W, C, wmax = self.W64, self.C64, self.wmax64
            if low.size:
                W = _vstack_rows(self.W64, self.W32_exact[low])
                C = np.concatenate([self.C64, self.C32[low].astype(np.float64)])
                wmax = self._row_max(W)
            out64, _ = self._block(W, C, g2, eps2, np.float64, wmax)
            out[idx64] = out64
        return out


def _vstack_rows(a, b):
    import scipy.sparse as sp
    return sp.vstack([a, b], format="csr")


# ------------------------------------------------------------------ training
def train_psd(poses: ArrayLike, correctives: ArrayLike, method: str = "psd", epsilon: float | None = None,
              smoothing: float = 0.0, kernel: str | None = None, pseudo_poses: Mapping[int, ArrayLike] | None = None,
              vertex_groups: ArrayLike | None = None, vertex_weights: ArrayLike | None = None,
              group_columns: Sequence[ArrayLike] | None = None, vertex_ridge: float = 1e-3,
              chunk: int = 4096, blend: float | str | ArrayLike | None = None,
              pairs: BonePairs | None = None) -> PoseSpaceDeformer:
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
    blend : float, array_like of shape (p,), "auto" or None
        Weighted PSD: λ of the blended distance ``d_v² = (1 − λ_v) Σ_j w_vj ‖x_j − x_kj‖² + λ_v ¼ ‖x − x_k‖²``
        — one value for every vertex, one per vertex, or ``"auto"``: per region (the vertices whose
        largest skin weight is on the same joint) the λ of :data:`BLEND_CANDIDATES` and kernel-width factor
        of :data:`WIDTH_CANDIDATES` with the smallest leave-one-out error over the examples
        (:func:`blend_regions`), each vertex then taking its skin-weighted average of its joints' values
        (no seams where regions meet).  None or 0: the
        skin-weighted distance (weighted PSD as published); 1: a normalised Gaussian PSD over the whole pose.
        ``"pairs"``: the bone-pair distance (:mod:`.pairs`) for every vertex; with ``pairs`` given, ``"auto"``
        also tries it per region.
    pairs : BonePairs, optional
        Weighted PSD: the rig's bone pairs (:func:`core.posespace.pairs.bone_pairs`), needed by
        ``blend="pairs"`` and tried by ``blend="auto"``.

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
    return _train_wpsd(X, D, epsilon, smoothing, vertex_groups, vertex_weights, group_columns, vertex_ridge, chunk,
                       blend, pairs)


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
                chunk, blend=None, pairs=None) -> PoseSpaceDeformer:
    """Weighted PSD: one normalised-RBF system per vertex in its skin-weighted (or blended) pose metric,
    folded into the correctives."""
    K, p = X.shape[0], D.shape[1]
    gi, gw, n_unweighted = _normalised_skin(vertex_groups, vertex_weights, group_columns, p)
    if epsilon is None:
        # a vertex sees only its own joints' part of the pose, so its distances are shorter than the
        # full pose distance: a kernel twice as narrow as PSD's default
        epsilon = 2.0 * default_epsilon(X)
    columns = [np.asarray(c) for c in group_columns]
    diagnostics = {"smoothing": smoothing, "unweighted_vertices": n_unweighted}
    pairs = _pairs_in_use(blend, pairs, columns)
    # squared distances between examples, per distance term (pose source, then bone pair): (G [+ P], K, K)
    Xs = _with_pair_features(X, pairs)
    pair = np.stack([rbf.pairwise_distances(Xs[:, c], Xs[:, c]) ** 2
                     for c in _distance_columns(columns, X.shape[1], pairs)])
    lam, width, share = _blend_per_vertex(blend, X, D, gi, gw, pair, float(epsilon), smoothing, diagnostics,
                                          pairs, len(columns), vertex_ridge)
    pairs = pairs if share is not None else None
    pair = pair if pairs is not None else pair[:len(columns)]
    model = PoseSpaceDeformer("wpsd", X, D, float(epsilon), None, gi, gw, columns, diagnostics=diagnostics,
                              blend=lam, width=width, pairs=pairs, pair_share=share)
    if lam is not None:
        pair = np.concatenate([pair, pair[:len(columns)].sum(axis=0, keepdims=True)])
    folded = np.empty((p, K, 3))
    pair_flat = pair.reshape(pair.shape[0], -1)                            # (G[+1], K·K)
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
        folded[sl], ridge = _solve_vertex_systems(A, rhs, vertex_ridge)
        ridged += int(np.count_nonzero(ridge))
    model.folded = folded
    model.diagnostics["ridged_vertices"] = ridged
    return model


def _pairs_in_use(blend, pairs, columns):
    """The bone pairs a ``blend`` choice can use (None when it cannot), checked against the pose space."""
    if isinstance(blend, str):
        validate.choice(blend, "blend", ("auto", "pairs"))
    wants = isinstance(blend, str)
    if wants and blend == "pairs" and pairs is None:
        raise ShapeSpaceError("blend='pairs' needs the rig's bone pairs (pairs=bone_pairs(...)): no vertex is "
                              "skinned to two bones that the pose space reads rotations of", ErrorCode.WPSD_INPUTS)
    if not wants or pairs is None:
        return None
    if pairs.groups.size and int(pairs.groups.max()) >= len(columns):
        raise ShapeSpaceError(f"pairs refers to pose source {int(pairs.groups.max())} of {len(columns)}",
                              ErrorCode.SHAPE)
    return pairs


def _blend_per_vertex(blend, X, D, gi, gw, pair, epsilon, smoothing, diagnostics, pairs=None, n_joint=None,
                      vertex_ridge=0.0):
    """λ_v (p,), the width factor ε_v/ε (p,) and the bone-pair share π_v (p,) from the caller's ``blend``;
    None where they change nothing (λ = 0, factor 1, π = 0: the skin-weighted distance)."""
    p = D.shape[1]
    G = pair.shape[0] if n_joint is None else n_joint
    share = None
    if blend is None:
        return None, None, None
    width = None
    if isinstance(blend, str):
        rows = None if pairs is None else pair_metric(pairs, gi, gw, G)
        lam_g, width_g, pairs_g = blend_regions(D, gi, gw, pair, epsilon, smoothing, pair_rows=rows, n_joint=G,
                                                pairs_only=blend == "pairs", vertex_ridge=vertex_ridge)
        diagnostics["blend_regions"] = {int(g): (float(v), float(w)) for g, (v, w) in enumerate(zip(lam_g, width_g))}
        diagnostics["pair_regions"] = [int(g) for g in np.flatnonzero(pairs_g)]
        index = np.where(gi >= 0, gi, G)                                   # −1 padding → index G (weight 0)
        lam = np.einsum("pm,pm->p", gw, np.append(lam_g, 0.0)[index])
        width = np.einsum("pm,pm->p", gw, np.append(width_g, 0.0)[index])
        width = np.where(width > 0, width, 1.0)
        width = None if np.all(width == 1.0) else width
        if blend == "pairs":
            share = np.ones(p)
        elif pairs_g.any():
            share = np.clip(np.einsum("pm,pm->p", gw, np.append(pairs_g.astype(np.float64), 0.0)[index]), 0.0, 1.0)
    else:
        lam = np.broadcast_to(np.asarray(blend, dtype=np.float64), (p,)).copy()
        if not np.isfinite(lam).all() or lam.min() < 0.0 or lam.max() > 1.0:
            raise ShapeSpaceError("the distance blend λ must lie in [0, 1]", ErrorCode.RANGE)
    lam = np.clip(lam, 0.0, 1.0)
    return (None if not lam.any() else lam), width, share


def loo_errors_wpsd(D: np.ndarray, weights: np.ndarray, pair: np.ndarray, epsilon: float,
                    smoothing: float = 0.0, vertex_ridge: float = 0.0) -> np.ndarray:
    """Leave-one-out errors of the normalised-RBF interpolant of each vertex, in closed form.

    Leaving example k out of vertex v's system ``A c = Δ`` (rows ``A_ik = φ_ik / Σ_l φ_il``) removes row and
    column k and renormalises the other rows by ``1 / (1 − A_ik)``; the reduced inverse comes from
    ``B = A⁻¹`` by the bordering formula ``B − B₍:,ₖ₎ B₍ₖ,:₎ / Bₖₖ`` (row and column k become 0), so all K
    held-out predictions cost O(K³) per vertex, like one training solve.  (With smoothing s the held-out
    system is taken as ``D_k Ā + s I ≈ D_k (Ā + s I)``: a selection score, not a model.)

    Parameters
    ----------
    D : ndarray, shape (K, n, 3)
        The vertices' correctives.
    weights : ndarray, shape (n, G)
        Each vertex's weights of the per-joint squared distances (kernel width folded in).
    pair : ndarray, shape (G, K, K)
        Per-joint squared distances between the examples.
    epsilon, smoothing : float
    vertex_ridge : float
        Score each vertex with the ridge its training solve would need (:func:`train_psd`'s
        ``vertex_ridge`` rule; 0: none), added to the smoothing: a metric that leaves a vertex's examples
        nearly coincident is scored as the tamed model it trains to, not as the exact interpolant.

    Returns
    -------
    ndarray, shape (n,)
        Sum over the held-out examples of the squared prediction error.
    """
    K, n = D.shape[0], D.shape[1]
    if K < 3 or n == 0:
        return np.zeros(n)
    d2 = np.einsum("ng,gkl->nkl", weights, pair)
    A = np.exp(-(epsilon ** 2) * d2)
    A /= A.sum(axis=2, keepdims=True)
    As = A + smoothing * np.eye(K) if smoothing > 0 else A
    rhs = np.transpose(D, (1, 0, 2))                                       # (n, K, 3)
    if vertex_ridge > 0:
        As = As + _solve_vertex_systems(As, rhs, vertex_ridge)[1][:, None, None] * np.eye(K)
    B = np.linalg.inv(As + 1e-12 * np.eye(K))
    keep = 1.0 - A                                                         # (n, i, k): row i's renormalisation
    r = np.transpose(keep, (0, 2, 1))[:, :, :, None] * rhs[:, None]        # (n, k, j, 3): r_k
    Br = np.matmul(B[:, None], r)                                          # (n, k, i, 3): B r_k for every k
    Bkr = np.einsum("nkkc->nkc", Br)                                       # (B r_k)_k
    diagB = np.einsum("nkk->nk", B)
    c = Br - np.einsum("nik,nkc->nkic", B, Bkr / diagB[:, :, None])      # (n, k, i, 3); entry i = k is 0
    row = A / (1.0 - np.einsum("nkk->nk", A))[:, :, None]                 # (n, k, i)
    row = row * (1.0 - np.eye(K))
    pred = np.einsum("nki,nkic->nkc", row, c)
    return np.sum((pred - rhs) ** 2, axis=(1, 2))


def blend_regions(D: np.ndarray, vertex_groups: np.ndarray, vertex_weights: np.ndarray, pair: np.ndarray,
                  epsilon: float, smoothing: float = 0.0, candidates: Sequence[float] = BLEND_CANDIDATES,
                  widths: Sequence[float] = WIDTH_CANDIDATES, max_vertices: int = 128, pair_rows: Any = None,
                  n_joint: int | None = None, pairs_only: bool = False, vertex_ridge: float = 0.0) -> tuple:
    """λ, kernel-width factor and distance kind per joint region, by leave-one-out cross validation.

    A region is the set of vertices whose largest (normalised) skin weight is on one joint.  For each, the
    ``max_vertices`` vertices with the largest correctives are scored with :func:`loo_errors_wpsd` for every
    pair (λ, f) of candidates (distance ``f² ((1 − λ) Σ_j w_vj d_j² + λ ¼ Σ_j d_j²)``) and, with
    ``pair_rows``, for the bone-pair distance (:mod:`.pairs`) at each width factor of
    :data:`PAIR_WIDTH_CANDIDATES`; the candidate with the smallest total wins if
    it beats today's (λ = 0, f = 1) by :data:`BLEND_MARGIN` (ties: the skin-weighted blend with the smaller
    λ).  Regions without correctives keep λ = 0, f = 1.

    Parameters
    ----------
    D : ndarray, shape (K, p, 3)
    vertex_groups, vertex_weights : ndarray, shape (p, m)
        Normalised skinning (−1 padding).
    pair : ndarray, shape (G [+ P], K, K)
        Squared distances between the examples per joint (then per bone pair).
    epsilon, smoothing : float
    candidates, widths : sequence of float
        λ and width factors tried.
    max_vertices : int
    pair_rows : sparse matrix, shape (p, G + P), optional
        The bone-pair distance's weights per vertex (:func:`core.posespace.pairs.pair_metric`).
    n_joint : int, optional
        G (default: every term of ``pair``).
    pairs_only : bool
        Choose only the bone-pair distance's width factor (:data:`PAIR_WIDTH_CANDIDATES`) per region.
    vertex_ridge : float
        The training's ridge rule, applied in the scores (:func:`loo_errors_wpsd`).

    Returns
    -------
    (ndarray, ndarray, ndarray), each shape (G,)
        λ, the width factor and whether the bone-pair distance won, per joint.
    """
    G = pair.shape[0] if n_joint is None else n_joint
    T = pair.shape[0]                      # distance terms: G joints [+ P bone pairs]
    K, p = D.shape[0], D.shape[1]
    lam_out, width_out, pairs_out = np.zeros(G), np.ones(G), np.zeros(G, dtype=bool)
    if K < 3:
        return lam_out, width_out, pairs_out
    dense = np.zeros((p, G + 1))
    np.add.at(dense, (np.repeat(np.arange(p), vertex_groups.shape[1]),
                      np.where(vertex_groups >= 0, vertex_groups, G).ravel()), vertex_weights.ravel())
    dense = dense[:, :G]
    dominant = dense.argmax(axis=1)
    size = np.abs(D).max(axis=(0, 2))
    pg = np.concatenate([pair, pair[:G].sum(axis=0)[None]])
    combos = sorted(((lam, f) for lam in candidates for f in widths),
                    key=lambda c: (c != (0.0, 1.0), c[0], abs(np.log(c[1]))))
    for g in range(G):
        members = np.flatnonzero((dominant == g) & (size > 0))
        if members.size == 0:
            continue
        members = members[np.argsort(-size[members], kind="stable")[:max_vertices]]
        w = np.hstack([dense[members], np.zeros((members.size, T - G))])
        rows = []
        for lam, f in combos:
            rows.append(f * f * np.concatenate([(1.0 - lam) * w, np.full((members.size, 1),
                                                                        GLOBAL_DISTANCE_SCALE * lam)], 1))
        if pair_rows is not None:
            pr = np.hstack([pair_rows[members].toarray(), np.zeros((members.size, 1))])
            rows.extend(f * f * pr for f in PAIR_WIDTH_CANDIDATES)
        scores = np.array([float(loo_errors_wpsd(D[:, members], r, pg, epsilon, smoothing, vertex_ridge).sum())
                           for r in rows])
        if pairs_only:                                           # the bone-pair distance: its best width
            scores[:len(combos)] = np.inf
        best = int(np.flatnonzero(scores <= scores.min() * (1 + 1e-9))[0])
        if pairs_only or scores[best] < (1.0 - BLEND_MARGIN) * scores[0]:     # rows[0] is today's (λ = 0, f = 1)
            if best < len(combos):
                lam_out[g], width_out[g] = combos[best]
            else:
                pairs_out[g], width_out[g] = True, PAIR_WIDTH_CANDIDATES[best - len(combos)]
    return lam_out, width_out, pairs_out


def _solve_vertex_systems(A, rhs, vertex_ridge):
    """Solve the per-vertex K × K systems; returns the coefficients (chunk, K, 3) and the ridge each vertex
    needed (chunk,) (0: solved exactly; the last ridge tried for a vertex still wild)."""
    K = A.shape[-1]
    try:
        coeff = np.linalg.solve(A, rhs)
    except np.linalg.LinAlgError:
        if vertex_ridge <= 0:
            raise ShapeSpaceError("a vertex's interpolation system is singular: examples too close together "
                                  "for its joints; add smoothing or remove an example", ErrorCode.SINGULAR) from None
        coeff = np.linalg.solve(A + 1e-12 * np.eye(K), rhs)   # the ridge pass below tames these
    ridge = np.zeros(A.shape[0])
    if vertex_ridge <= 0:
        return coeff, ridge
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
        ridge[idx] = lam
        wild[idx[np.abs(coeff[idx]).max(axis=(1, 2)) <= AMPLIFICATION_LIMIT * scale[idx]]] = False
        lam *= 10.0
    return coeff, ridge


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
