"""Example-guided transfer (issue #22 §5; thesis 3.4.1; Li, Weise & Pauly 2010, "Example-based facial rigging").

The user gives a few target expressions ``E_e`` (existing keys, sculpts, scans; deltas from the target
neutral) with approximate weights ``W_ek`` of the source's shapes.  Every transferred key ``D_k`` is refined:

0. **Approximate weights** (Li et al. re-estimate them with the blendshapes): in an example that uses several
   keys, the largest weight anchors its scale and the others are re-estimated against the plain keys,
   ``min ‖E_e − W_ea D_a − Σ_s W_es D_s‖² + ρ Σ_s ‖D_s‖² (W_es − W⁰_es)²`` (``ρ`` = :data:`WEIGHT_RIDGE`), so a
   mis-stated secondary weight is not read as a gain of the target (a one-key example is left as given: its
   weight and the gain are one unknown).  Step 1 learns with these weights, step 2 reproduces the examples
   with the given ones, step 3 mirrors the change an example asks of its key under the re-estimated ones.
1. **What the examples reveal about the target** (generalises to the keys no example uses): a smooth
   per-vertex gain ``g`` between transferred and authored motion.  With ``X_e = Σ_k W_ek D_k`` (the plain
   transfer's prediction of example ``e``) it solves

       min_g  Σ_v Σ_e ‖g_v X_e(v) − E_e(v)‖² + λ s Σ_v (g_v − 1)² + μ s Σ_(u,v) edge (g_u − g_v)²

   (``s`` the mean squared peak of the ``X_e``; the ``λ`` term is the deformation-transfer regulariser: where
   no example moves, ``g = 1`` and the key stays the plain transfer), i.e. the sparse system
   ``(μ s L + diag(Σ_e ‖X_e‖² + λ s)) g = Σ_e E_e·X_e + λ s`` with ``L`` the mesh's graph Laplacian.  The
   statistics of each vertex and its mirror image are pooled (an example on the left side teaches the right).
   ``(λ, μ)`` is chosen by cross-validation from :data:`STRENGTHS` × :data:`SMOOTHS`, ``λ = inf`` (no gain)
   included: a gain is applied only if it predicts the left-out examples better than the plain transfer by more than
   :data:`SIGNIFICANCE` standard errors of its per-fold improvements (the one-standard-error rule; the least error
   among those that do).  A gain that one left-out example favours and the others do not is no evidence about the
   keys no example uses: picking the least error alone made the held-out keys worse than the plain transfer at
   FBHead → Face Cap (0.303 → 0.308: the jaw's gain learnt from ``jawOpen`` grew ``jawLeft``/``jawRight`` by 12 %).
   The folds mimic the held-out keys: each example is predicted from the examples that share none of its keys (an
   example sharing a key with the training set would be predicted from that key's own example — leave-one-out
   leaked it and chose gains that made held-out keys worse; with one-key examples this is leave-one-out).  The gain
   is then kept only where the left-out examples were predicted at least as well with it as without (per vertex,
   mirror-pooled; the 0/1 mask smoothed by ``(I + L)⁻¹``):
   ``g ← 1 + mask ⊙ (g − 1)``, and ``D_k ← g ⊙ D_k``.
2. **The examples reproduced exactly** (rank-m update in the span of the weights): the residual
   ``R_e = E_e − Σ_k W_ek D_k`` is spread per vertex over the keys the example uses in proportion to how much
   each moves there (Li et al.'s per-shape activity weighting): with ``κ_k(v) = ‖D_k(v)‖² + δ``,
   ``ΔD_k(v) = κ_k(v) Σ_e W_ek μ_e(v)`` where ``(W diag κ(v) Wᵀ) μ(v) = R(v)`` (least squares when the
   examples contradict each other).  Keys no example uses are not touched by this step.
3. **Other-side keys**: a key no example uses whose other-side key (``eyeBlinkRight`` for ``eyeBlinkLeft``)
   an example uses takes that key's step-2 change (with the weights of step 0), mirrored:
   ``ΔD_p(v) = S ΔD_k(m(v))`` (``S`` the reflection, ``m`` the mirror vertex).
4. **Closing keys**: ARKit's ``mouthClose`` shuts the lips over an open jaw (it is played with ``jawOpen``).
   Where the plain ``mouthClose`` cancels a share ``c(v) = clip(−⟨D_c, D_o⟩ / ‖D_o‖², 0, 1)`` of the plain
   ``jawOpen``'s motion, a ``mouthClose`` no example uses keeps cancelling that share of what the examples
   changed in ``jawOpen`` beyond the gain: ``ΔD_c = −c ⊙ (D'_o − g ⊙ D_o)`` (:func:`closing_keys`).  An example
   that opens the jaw 24° where the transfer opened it 18° then has a ``mouthClose`` that still shuts the lips:
   held-out error 0.515 → 0.504 (FBHead → Ready Player Me), better at 10 of the 12 pairs, 0.752 → 0.755 at
   ICT FaceKit → Face Cap.

Measured (``tools/bench_examples.py``: every ordered pair of the four shared heads, the 5 examples jawOpen,
mouthSmileLeft, eyeBlinkLeft, browInnerUp, mouthFunnel; relative error ‖ΔT − ΔA‖/‖ΔA‖ jointly over the 42–47
other authored keys, skin and parts; "one key": each example one authored key with weight 1 on the source key
of its name (``transfer_rel_energy_examples5``; "worse": held-out keys whose error grew); "combo": example
``i`` = key ``i`` + 0.5 key ``i+1``; "approx": made with 0.7, given as 0.5; the ceilings, each fitted to the
held-out keys themselves (in-sample, so no refinement learnt from five examples reaches them): "gain" the best
per-vertex gain (any gain field), "key×gain" the best per-key scale times per-vertex gain (any rescaling, a
key's own size included), "3×3" the best per-vertex linear map (any per-vertex map of the transferred motion,
direction included))::

    pair            plain   one key (worse)   combo   approx   gain   key×gain   3×3
    facecap_fbhead  0.360   0.226 (4/44)     0.242   0.245    0.216  0.212      0.181
    facecap_ict     0.836   0.729 (3/44)     0.725   0.729    0.605  0.560      0.491
    facecap_rpm     0.640   0.521 (8/47)     0.516   0.521    0.458  0.429      0.378
    fbhead_facecap  0.303   0.295 (0/46)     0.296   0.299    0.241  0.229      0.179
    fbhead_ict      0.777   0.757 (0/44)     0.758   0.753    0.611  0.560      0.512
    fbhead_rpm      0.525   0.505 (0/46)     0.507   0.512    0.453  0.421      0.368
    ict_facecap     0.610   0.608 (1/44)     0.585   0.587    0.520  0.456      0.449
    ict_fbhead      0.706   0.677 (0/42)     0.663   0.664    0.564  0.484      0.504
    ict_rpm         0.708   0.684 (0/44)     0.685   0.684    0.580  0.532      0.485
    rpm_facecap     0.504   0.487 (0/46)     0.473   0.475    0.445  0.422      0.361
    rpm_fbhead      0.477   0.459 (18/44)    0.464   0.466    0.434  0.411      0.364
    rpm_ict         0.783   0.749 (0/44)     0.741   0.741    0.616  0.575      0.526
    mean            0.602   0.558           0.555   0.556    0.479  0.441      0.400

Face Cap's eyes are kept still there (its rig turns them by transforms, ``bridge.authoring.parts``), so the Face
Cap targets' plain and refined errors no longer count eyes turned twice (FBHead → Face Cap: refined 0.573 →
0.295).  The joint held-out error is no larger than the plain transfer's at every pair in all three variants
(the one-standard-error rule: without it FBHead → Face Cap went 0.303 → 0.308); the goal 0.5 holds onto FBHead
and from FBHead and Ready Player Me onto Face Cap (4 of 12 pairs), and the ceilings show it out of reach of
any gain field at 6 of the other 8 and of any rescaling at the three pairs onto ICT FaceKit (0.56–0.58), where
even a 3×3 map per vertex fitted to the 44 held-out keys themselves is at 0.49–0.53: what remains is
key-specific (below).  Single held-out keys still grow
(up to 1.2× with one-key examples, 1.9× with approximate weights).

Tried and dropped, issue #22 §5 second round (all 12 pairs from the cached plain transfers, one-hot examples
unless said; means over the pairs of the held-out relative error, plain 0.677, the gain of step 1 0.635):

- a local kernel (ridge) regression of the correction — a learned linear map from transferred to authored
  motion over a neighbourhood: each key takes ``Σ_e α_ke(v) R_e(v)`` of the examples' (and their mirror
  images') residuals with ``α`` from locally smoothed inner products of the key's and the examples'
  transferred motion, cross-validated like the gain: instead of the gain 0.563 vs 0.528 on the six pairs
  without ICT; after the gain 0.637 (cross-validation rarely picks it);
- the gain applied to each key in proportion to the share of its local motion in the span of the examples'
  (per-key similarity): worst held-out key ratio 1.18 → 1.05 but mean 0.646 (facecap → FBHead 0.235 → 0.265);
- separate gains of the normal and the tangential motion (the surface's local frame): 0.530 vs 0.528 on the
  six pairs;
- the gain damped where a key moves more than any example (leverage): 0.532 vs 0.528 on the six pairs;
- the grouped folds without re-estimating weights: with approximate weights (``transfer_rel_energy_examples5_
  approx``) worse than plain at 3 pairs (FBHead → RPM 0.585 vs 0.559, ICT → RPM 0.753 vs 0.719, FBHead → Face
  Cap 0.653 vs 0.638); re-estimating them but mirroring the given-weight reproduction onto the other-side
  keys: FBHead → Face Cap 0.642 vs 0.638;
- the candidate grid of the first round (λ ≥ 0.003, μ ≤ 10): one key 0.635 (FBHead → Face Cap 0.591, the
  wider grid 0.564; the cross-validation picks λ = 3e-4 at 5 pairs); the wider grid doubles the refinement's
  time on the ICT targets (4–5 s → 8–9 s CPU).

Why the held-out keys gain so little: their error is dominated by keys whose transfer is wrong in a way no
example shows — mouthClose (17–46 % of the held-out squared error on the ICT, RPM and FBHead targets, relative
error 0.5–0.96 after refinement: the rigs author it to different conventions; ICT FaceKit's is 0.17 from a
per-vertex share of its own jawOpen, the transferred ones 0.7–0.8), jawLeft/Right/Forward (0.5–0.95),
mouthLeft/Right, mouthRoll*.  (Before Face Cap's eyes were kept still, its eyeLook* keys were 67 % of the error
onto it from FBHead: relative error 5–8, eyes turned that its rig turns by transforms.)

Tried and dropped, first round (development runs on the six pairs without ICT, same examples):

- a full per-vertex 3×3 linear map ``L_v`` (ridge towards ``I``, same smoothing) instead of the scalar gain
  (best settings of each): worse than the gain at every pair and often worse than plain (facecap → FBHead
  0.365 → 0.304 vs 0.250 with the gain; facecap → RPM 0.764 → 0.707 vs 0.661; FBHead → Face Cap 0.738 → 0.739
  vs 0.737) with 10–34 keys worse: five examples do not determine a 3×3 map per vertex (its oracle is only
  0.01–0.11 below the gain's);
- the gain only along the examples' principal motion directions (``L_v = I + (g_v − 1) C_v / tr C_v``, ``C_v``
  the examples' motion covariance): facecap → FBHead 0.320, facecap → RPM 0.724 (gain: 0.247, 0.678);
- the gain learned and applied in the gradient domain (per-triangle gain of the deformation gradients,
  cross-validated likewise, re-solved with the transfer's factorised normal matrix, parts moved again):
  facecap → FBHead 0.377 (24 keys worse), RPM → FBHead 0.599 (28 worse), FBHead → Face Cap 0.744: the
  authored keys' gradients are far from the transferred ones (cross-validated relative error of the plain
  gradients 0.8–6.9), so a gradient gain learns noise; the vertex gain is kept;
- no mirror pooling: facecap → FBHead 0.250, FBHead → Face Cap 0.737, RPM → Face Cap 0.833 (pooled: 0.247,
  0.726, 0.827; with an eyeLookOutLeft example in place of browInnerUp the pooled gain reaches 0.487 and 0.637
  on the Face Cap targets: their eyes barely move in eyeLook);
- a fixed ``(λ, μ)`` without cross-validation: RPM → FBHead 0.469–0.480 with 19–23 of 44 keys worse, FBHead →
  RPM 0.603–0.621 with 18–26 worse; the cross-validation picks no gain at FBHead → RPM (0.641 → 0.633 there,
  from step 3 alone);
- without the local mask: facecap → RPM 0.668 (14 worse), RPM → FBHead 0.469 (23 worse) (with: 0.656 (10),
  0.458 (21)).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.linalg import splu
from scipy.spatial import cKDTree

from .. import validate
from ..errors import ErrorCode
from ..names import canonical_name
from ..progress import ProgressFn, notify
from ..result import ShapeSpaceError
from ..symmetry import counterpart_name
from .mesh import bbox_diagonal, check_mesh, symmetry_plane

__all__ = ["STRENGTHS", "SMOOTHS", "CLOSERS", "ExampleRefinement", "mirror_vertices", "mirror_partners", "closing_keys",
           "parse_weights", "refine_with_examples"]

STRENGTHS = (3e-4, 0.003, 0.03, 0.3)          # λ candidates of the cross-validation (inf = no gain)
SMOOTHS = (0.1, 1.0, 10.0, 100.0)             # μ candidates of the cross-validation (gain smoothness)
#: A key that closes what another opens (ARKit: mouthClose is played over jawOpen, lips shut), canonical names.
CLOSERS = {"mouthClose": "jawOpen"}
#: The largest example weight accepted (weights are slider values; ±10 is already far beyond any rig's range).
MAX_WEIGHT = 10.0
MIRROR_TOL = 0.01                                 # × diagonal: a vertex farther than this from any mirror image
WEIGHT_RIDGE = 0.01                               # × ‖D_k‖²: pull of a re-estimated weight towards the given one
SIGNIFICANCE = 1.0                                # a gain must beat the plain transfer by this many standard errors
ACTIVITY_FLOOR = 1e-3                             # δ = this × the mean ‖D_k(v)‖² over active vertices


@dataclass
class ExampleRefinement:
    """Refined keys and what the examples did.

    Attributes
    ----------
    deltas : ndarray (k, n, 3)
        Refined target deltas of every key.
    gain : ndarray (n,)
        The per-vertex gain of step 1 (all ones when cross-validation chose none).
    strength : float
        The chosen ``λ`` (``inf``: no gain).
    smooth : float
        The chosen ``μ``.
    cv_error : dict
        ``(λ, μ)`` → leave-one-example-out relative squared error of the examples (``(inf, 0)``: the plain
        transfer's).
    residual_before, residual_gain, residual_after : ndarray (m,)
        ``‖E_e − Σ_k W_ek D_k‖ / ‖E_e‖`` of each example with the plain keys, after the gain, after refinement
        (the given weights).
    key_change : ndarray (k,)
        ``‖D'_k − D_k‖ / ‖D_k‖`` per key (0 for an empty key left empty).
    weights : ndarray (m, k)
        The weights the gain was learnt with: the given ones, each example's secondary weights re-estimated
        (step 0).
    """

    deltas: np.ndarray
    gain: np.ndarray
    strength: float
    smooth: float
    cv_error: dict = field(default_factory=dict)
    residual_before: np.ndarray = None
    residual_gain: np.ndarray = None
    residual_after: np.ndarray = None
    key_change: np.ndarray = None
    weights: np.ndarray = None


def mirror_vertices(verts: ArrayLike, tol: float = MIRROR_TOL) -> tuple:
    """Each vertex's mirror image across the head's symmetry plane (nearest vertex to its reflection).

    Parameters
    ----------
    verts : array_like (n, 3)
    tol : float
        Relative to the bounding-box diagonal: farther than this from any vertex → no mirror.

    Returns
    -------
    mirror : ndarray of int (n,)
        Mirror vertex, ``-1`` where none.
    reflection : ndarray (3, 3)
        ``I − 2 n nᵀ`` of the plane's normal ``n`` (turns a displacement into its mirror image).
    """
    V = validate.array(verts, "verts", shape=(None, 3))
    normal, offset, _ = symmetry_plane(V)
    R = V - 2.0 * (V @ normal - offset)[:, None] * normal[None]
    dist, j = cKDTree(V).query(R)
    return np.where(dist <= tol * max(bbox_diagonal(V), 1e-300), j, -1), np.eye(3) - 2.0 * np.outer(normal, normal)


def mirror_partners(names: Sequence[str]) -> np.ndarray:
    """Index of each key's other-side key (``eyeBlinkLeft`` ↔ ``eyeBlinkRight``), ``-1`` where none.

    Parameters
    ----------
    names : sequence of str (k,)

    Returns
    -------
    ndarray of int (k,)
    """
    return _related_keys(names, counterpart_name)


def _related_keys(names: Sequence[str], relate) -> np.ndarray:
    """Index of the key named ``relate(canonical name)`` for each key (``-1``: none, or the key itself)."""
    where = {canonical_name(str(n)): i for i, n in enumerate(names)}
    out = np.full(len(names), -1, dtype=np.int64)
    for i, n in enumerate(names):
        j = where.get(relate(canonical_name(str(n))) or "", -1)
        if j != i:
            out[i] = j
    return out


def closing_keys(names: Sequence[str]) -> np.ndarray:
    """Index of the key each key closes (``mouthClose`` → ``jawOpen``, :data:`CLOSERS`), ``-1`` where none.

    Parameters
    ----------
    names : sequence of str (k,)

    Returns
    -------
    ndarray of int (k,)
    """
    return _related_keys(names, CLOSERS.get)


def _close_like_the_opener(out, base, gain, W, closers):
    """Step 4: a closing key no example uses cancels the same share of its opener's refinement beyond the gain
    as the plain key cancels of the plain opener (module docstring)."""
    used = np.any(W != 0, axis=0)
    for c in np.flatnonzero((closers >= 0) & ~used):
        o = closers[c]
        oo = np.einsum("vi,vi->v", base[o], base[o])
        share = np.clip(-np.einsum("vi,vi->v", base[c], base[o]) / np.where(oo > 0, oo, 1.0), 0.0, 1.0)
        out[c] = out[c] - share[:, None] * (out[o] - gain[:, None] * base[o])
    return out


def parse_weights(text: str, where: str) -> dict:
    """Approximate weights of an example as written in the panel: ``"jawOpen=1, mouthClose=0.5"``.

    Parameters
    ----------
    text : str
        ``name=weight`` pairs separated by commas (or semicolons); ``""``: none given.
    where : str
        What the text belongs to, for messages (the example's key).

    Returns
    -------
    dict
        Shape name → weight (finite, at most :data:`MAX_WEIGHT` in size), in the order written.

    Raises
    ------
    ShapeSpaceError
        A pair without ``=``, a weight that is no number, not finite or too large, a name given twice — naming
        the pair.
    """
    out = {}
    for token in (t.strip() for t in str(text).replace(";", ",").split(",")):
        if not token:
            continue
        name, eq, value = (part.strip() for part in token.rpartition("="))
        if not eq or not name:
            raise ShapeSpaceError(f"{where}: {token!r} is not name=weight", ErrorCode.INVALID)
        try:
            w = float(value)
        except ValueError:
            raise ShapeSpaceError(f"{where}: the weight of {name!r} is not a number: {value!r}",
                                  ErrorCode.NOT_NUMBER) from None
        check_weight(w, f"{where}: the weight of {name!r}")
        if name in out:
            raise ShapeSpaceError(f"{where}: {name!r} is given twice", ErrorCode.DUPLICATE_NAME)
        out[name] = w
    return out


def check_weight(w: float, what: str) -> float:
    """``w`` as a float when finite and at most :data:`MAX_WEIGHT` in size; else refused naming ``what``."""
    if not np.isfinite(w):
        raise ShapeSpaceError(f"{what} is not finite", ErrorCode.NON_FINITE)
    if abs(w) > MAX_WEIGHT:
        raise ShapeSpaceError(f"{what} is {w:g}: at most {MAX_WEIGHT:g} in size", ErrorCode.RANGE)
    return float(w)


def _mirror_to_partners(out, refined, base, W, partners, mirror, reflection):
    """Keys no example uses whose other-side key an example uses take that key's refinement (``refined``),
    mirrored."""
    used = np.any(W != 0, axis=0)
    has = mirror >= 0
    for k in np.flatnonzero(used):
        p = partners[k]
        if p < 0 or used[p]:
            continue
        change = np.zeros_like(out[k])
        change[has] = (refined[k] - base[k])[mirror[has]] @ reflection.T
        out[p] = base[p] + change
    return out


def _check(deltas, examples, weights, names, n):
    D = validate.array(deltas, "transferred deltas", shape=(None, n, 3))
    k = D.shape[0]
    E = validate.array(examples, "examples", shape=(None, n, 3), finite=False)
    m = E.shape[0]
    if m == 0:
        raise ShapeSpaceError("at least one example is needed", ErrorCode.TOO_FEW)
    names = [f"example {i}" for i in range(m)] if names is None else [str(s) for s in names]
    if len(names) != m:
        raise ShapeSpaceError(f"{len(names)} example names for {m} examples", ErrorCode.SHAPE)
    W = validate.array(weights, "example weights", ndim=2, finite=False)
    if W.shape != (m, k):
        raise ShapeSpaceError(f"example weights must be (m, k) = ({m}, {k}), got {W.shape}", ErrorCode.SHAPE)
    for e in range(m):
        if not np.isfinite(E[e]).all():
            v = int(np.flatnonzero(~np.isfinite(E[e]).all(axis=1))[0])
            raise ShapeSpaceError(f"{names[e]}: non-finite coordinate at vertex {v}", ErrorCode.NON_FINITE)
        if not np.isfinite(W[e]).all():
            k_bad = int(np.flatnonzero(~np.isfinite(W[e]))[0])
            raise ShapeSpaceError(f"{names[e]}: non-finite weight on source shape {k_bad}", ErrorCode.NON_FINITE)
        if not np.any(W[e]):
            raise ShapeSpaceError(f"{names[e]}: all its weights are zero (it names no source shape)",
                                  ErrorCode.INVALID)
    return D, E, W


def _refit_weights(D, E, W):
    """Step 0: each example's weights but its largest re-estimated by least squares against the plain keys,
    ridged towards the given values (:data:`WEIGHT_RIDGE`): (m, k)."""
    if not np.any(np.count_nonzero(W, axis=1) > 1):
        return W
    out = W.copy()
    for e in range(W.shape[0]):
        sup = np.flatnonzero(W[e])
        if sup.size < 2:
            continue
        anchor = sup[np.argmax(np.abs(W[e, sup]))]
        sec = sup[sup != anchor]
        M = D[sec].reshape(sec.size, -1)                                        # (s, 3n)
        r = (E[e] - W[e, anchor] * D[anchor]).ravel()
        ridge = WEIGHT_RIDGE * np.diag(np.sum(M ** 2, axis=1))
        out[e, sec] = np.linalg.solve(M @ M.T + ridge + 1e-300 * np.eye(sec.size), M @ r + ridge @ W[e, sec])
    return out


def _laplacian(n, tris):
    r = tris.ravel()
    c = np.roll(tris, 1, axis=1).ravel()
    A = sp.coo_matrix((np.ones(r.size), (r, c)), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    return sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A


def _stats(X, E, mirror):
    """Per example and vertex ``‖X_e‖²`` and ``E_e·X_e`` (m, n), each pooled with its mirror vertex."""
    xx = np.einsum("evi,evi->ev", X, X)
    yx = np.einsum("evi,evi->ev", E, X)
    if mirror is not None:
        has = mirror >= 0
        xx[:, has] += xx[:, mirror[has]]
        yx[:, has] += yx[:, mirror[has]]
    return xx, yx


def _gain(lap, xx, yx, lam, scale, smooth):
    """Solve ``(μ s L + diag(xx + λ s)) g = yx + λ s`` (xx, yx summed over the examples used)."""
    A = (smooth * scale * lap + sp.diags(xx + lam * scale)).tocsc()
    return splu(A).solve(yx + lam * scale)


def _folds(W):
    """Cross-validation folds: ``(e, training mask)`` of each example ``e`` that some other example shares no
    source shape with; the training set is those examples (the held-out keys are keys no example uses, so a
    left-out example is predicted without any example that uses one of its keys)."""
    used = W != 0
    out = []
    for e in range(W.shape[0]):
        rest = ~np.any(used & used[e][None], axis=1)
        if rest.any():
            out.append((e, rest))
    return out


def _cross_validate(lap, X, E, xx, yx, scale, candidates, folds, progress):
    """Left-out-example errors of each ``(λ, μ)`` over ``folds`` (:func:`_folds`): ``{candidate: (relative
    error, per-fold squared errors)}``; ``(inf, 0)`` (no gain) is the plain transfer's on the same examples."""
    if not folds:
        return {(np.inf, 0.0): (0.0, np.zeros(0))}
    tested = np.array([e for e, _ in folds])
    total = float(np.sum(E[tested] ** 2))
    plain = np.array([float(np.sum((X[e] - E[e]) ** 2)) for e, _ in folds])
    err = {(np.inf, 0.0): (float(plain.sum()) / total, plain)}
    for lam, smooth in candidates:
        per = np.array([float(np.sum((_gain(lap, xx[rest].sum(axis=0), yx[rest].sum(axis=0), lam, scale, smooth)
                                      [:, None] * X[e] - E[e]) ** 2)) for e, rest in folds])
        err[(lam, smooth)] = (float(per.sum()) / total, per)
        notify(progress, 0.9 * len(err) / (len(candidates) + 1))
    return err


def _choose(cv) -> tuple:
    """The ``(λ, μ)`` of least left-out error among those that beat the plain transfer by more than
    :data:`SIGNIFICANCE` standard errors of their per-fold gains (the one-standard-error rule); ``(inf, 0)``: none
    does.  The gains are absolute squared errors, as the joint error over the keys they stand for: a large
    example weighs as a large key does there (gains relative to each example's size made the held-out keys
    worse than plain at ICT FaceKit → Face Cap with combined examples, 0.610 → 0.611 and 0.616)."""
    plain = cv[(np.inf, 0.0)][1]
    best = (np.inf, 0.0)
    for c, (rel, per) in cv.items():
        d = plain - per
        if d.size == 0 or np.isinf(c[0]):
            continue
        se = float(np.std(d, ddof=1)) / np.sqrt(d.size) if d.size > 1 else 0.0
        if d.mean() > SIGNIFICANCE * se and (rel, -c[0], -c[1]) < (cv[best][0], -best[0], -best[1]):
            best = c
    return best


def _local_mask(lap, X, E, xx, yx, scale, lam, smooth, mirror, folds):
    """Where the left-out examples (``folds``) are predicted at least as well with the gain as without (1, else
    0), per vertex (mirror-pooled), smoothed by one step of ``(I + L)⁻¹``: (n,)."""
    n = X.shape[1]
    with_gain, without = np.zeros(n), np.zeros(n)
    for e, rest in folds:
        g = _gain(lap, xx[rest].sum(axis=0), yx[rest].sum(axis=0), lam, scale, smooth)
        with_gain += np.sum((g[:, None] * X[e] - E[e]) ** 2, axis=1)
        without += np.sum((X[e] - E[e]) ** 2, axis=1)
    if mirror is not None:
        has = mirror >= 0
        with_gain[has] += with_gain[mirror[has]].copy()
        without[has] += without[mirror[has]].copy()
    keep = (with_gain <= without).astype(np.float64)
    return splu((sp.eye(n) + lap).tocsc()).solve(keep)


def _reproduce(D, E, W):
    """Rank-m update: spread each example's residual over its keys by their per-vertex activity."""
    R = E - np.einsum("ek,kvi->evi", W, D)
    act = np.sum(D ** 2, axis=2)                                           # (k, n)
    floor = ACTIVITY_FLOOR * max(float(act[act > 0].mean()) if (act > 0).any() else 1.0, 1e-300)
    kappa = act + floor
    used = np.flatnonzero(np.any(W != 0, axis=0))
    Wu, ku = W[:, used], kappa[used]                                       # (m, u), (u, n)
    Mv = np.einsum("eu,un,fu->nef", Wu, ku, Wu)                            # (n, m, m)
    mu = np.linalg.pinv(Mv, hermitian=True) @ R.transpose(1, 0, 2)         # (n, m, 3)
    out = D.copy()
    out[used] += np.einsum("eu,un,nei->uni", Wu, ku, mu)
    return out


def _residual(D, E, W):
    R = E - np.einsum("ek,kvi->evi", W, D)
    return np.linalg.norm(R.reshape(len(E), -1), axis=1) / np.maximum(np.linalg.norm(E.reshape(len(E), -1), axis=1),
                                                                       1e-300)


def refine_with_examples(verts: ArrayLike, tris: ArrayLike, deltas: ArrayLike, examples: ArrayLike,
                         weights: ArrayLike, *, names: Sequence[str] | None = None, mirror: str | None = "auto",
                         partners: ArrayLike | None = None, closers: ArrayLike | None = None,
                         strengths: Sequence[float] = STRENGTHS, smooths: Sequence[float] = SMOOTHS,
                         progress: ProgressFn | None = None) -> ExampleRefinement:
    """Refine transferred keys so the examples are reproduced and what they reveal carries to the other keys.

    Parameters
    ----------
    verts : array_like (n, 3)
        Target neutral.
    tris : array_like of int (f, 3)
        Target triangles (the gain's smoothness follows their edges).
    deltas : array_like (k, n, 3)
        Plain transferred deltas (deformation transfer, parts moved), one per source shape.
    examples : array_like (m, n, 3)
        Example target shapes, deltas from the target neutral.
    weights : array_like (m, k)
        Approximate weights of the source shapes in each example (a row may not be all zero).
    names : sequence of str (m,), optional
        Example names used in error messages.
    mirror : "auto" or None
        ``"auto"``: pool the gain statistics of mirror vertices (:func:`mirror_vertices`) and mirror example
        refinements onto ``partners``; ``None``: neither.
    partners : array_like of int (k,), optional
        Each key's other-side key (``-1``: none; :func:`mirror_partners`).  A key no example uses whose partner
        an example uses takes the partner's refinement (step 2), mirrored (step 3).
    closers : array_like of int (k,), optional
        The key each key closes (``-1``: none; :func:`closing_keys`): a closing key no example uses follows its
        opener's refinement (step 4).
    strengths : sequence of float
        ``λ`` candidates of the cross-validation (see the module docstring); ``inf`` (no gain) is always one.
    smooths : sequence of float
        ``μ`` candidates (the gain's smoothness), each tried with every ``λ``.
    progress : callable (fraction) -> None, optional
        :mod:`core.progress` protocol, called after each cross-validated candidate; raising
        :class:`~core.progress.Cancelled` from it stops the refinement.

    Returns
    -------
    ExampleRefinement

    Raises
    ------
    ShapeSpaceError
        Shapes that do not match, NaN in an example or a weight, an example whose weights are all zero, no
        example — the message names the example.
    """
    V, TT = check_mesh(verts, tris, "target")
    n = V.shape[0]
    D, E, W = _check(deltas, examples, weights, names, n)
    cands = [(validate.positive(lam, "strength"), validate.non_negative(mu, "smooth"))
             for lam in strengths for mu in smooths]
    if mirror is not None:
        validate.choice(mirror, "mirror", ("auto",))
    mir, refl = mirror_vertices(V) if mirror is not None else (None, None)
    part = None if partners is None else np.asarray(partners, dtype=np.int64)
    if part is not None and (part.shape != (D.shape[0],) or part.max(initial=-1) >= D.shape[0]
                             or part.min(initial=-1) < -1):
        raise ShapeSpaceError(f"partners must be ({D.shape[0]},) key indices or -1", ErrorCode.SHAPE)
    shut = None if closers is None else np.asarray(closers, dtype=np.int64)
    if shut is not None and (shut.shape != (D.shape[0],) or shut.max(initial=-1) >= D.shape[0]
                             or shut.min(initial=-1) < -1):
        raise ShapeSpaceError(f"closers must be ({D.shape[0]},) key indices or -1", ErrorCode.SHAPE)
    Wf = _refit_weights(D, E, W)
    X = np.einsum("ek,kvi->evi", Wf, D)
    scale = max(float(np.mean(np.max(np.sum(X ** 2, axis=2), axis=1))), 1e-300)
    lap = _laplacian(n, TT)
    xx, yx = _stats(X, E, mir)
    notify(progress, 0.0)
    folds = _folds(W)
    cv = _cross_validate(lap, X, E, xx, yx, scale, cands, folds, progress)
    lam, smooth = _choose(cv)
    g = np.ones(n)
    if not np.isinf(lam):
        mask = _local_mask(lap, X, E, xx, yx, scale, lam, smooth, mir, folds)
        g += mask * (_gain(lap, xx.sum(axis=0), yx.sum(axis=0), lam, scale, smooth) - 1.0)
    Dg = g[None, :, None] * D
    out = _reproduce(Dg, E, W)
    if mir is not None and part is not None:
        out = _mirror_to_partners(out, out if Wf is W else _reproduce(Dg, E, Wf), Dg, W, part, mir, refl)
    if shut is not None:
        out = _close_like_the_opener(out, D, g, W, shut)
    base = np.linalg.norm(D.reshape(len(D), -1), axis=1)
    change = np.linalg.norm((out - D).reshape(len(D), -1), axis=1) / np.where(base > 0, base, 1.0)
    notify(progress, 1.0)
    return ExampleRefinement(out, g, float(lam), float(smooth), {c: v[0] for c, v in cv.items()},
                             _residual(D, E, W), _residual(Dg, E, W),
                             _residual(out, E, W), change, Wf)
