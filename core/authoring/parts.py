"""Facial parts of a target head and how each moves in a transferred shape (issue #22 §1; thesis 3.4.1).

A head is rarely one surface: eyes, teeth, gums, tongue, lashes, brows, eyelines and the mouth cavity are
separate connected parts (ICT FaceKit: 56, Face Cap: 17 plus separate eye and teeth meshes, Ready Player Me:
separate eye and teeth objects).  Deformation transfer moves the skin and every target part the source has
too (a part matched by the registration to a source part other than the source's skin); every other part is
moved here, as an artist would rig it:

``follow``
    lashes, brows, eyelines, sheets of teeth lying behind the lips: each vertex is bound to its closest point
    ``p`` on the skin (triangle, barycentric coordinates, offset ``x − p``), like a surface binding: its
    displacement is the skin's at ``p`` plus the offset turned by the skin triangle's rotation (polar factor of
    its deformation gradient).  The binding fades with the distance to the skin, ``w = 1 / (1 + (dist / r)²)``
    with ``r`` = :data:`FOLLOW_RADIUS` (2 % of the head's diagonal: half weight there), towards the jaw/skull
    motion of that vertex.  A sheet of teeth is bound
    to its own lip: the upper row (:data:`UPPER_SHEET`, by the skin's skull share only) to the skin that stays
    with the skull, the lower row (:data:`LOWER_SHEET`) to the skin the jaw moves.  The mouth cavity is not
    bound to the lips at all, its rim included: it is carried by its jaw share of the jaw's rigid motion (the
    skin's under it; in a cavity that holds the teeth, by the nearest row of teeth: floor with the jaw, roof
    with the skull, see ``_cavity_shares``), as every shared head's artist skins it — still in every lip shape
    (ICT FaceKit, Face Cap, Ready Player Me: 0.00 of the lips' motion), opened by the jaw's shapes.
``jaw``
    lower teeth, lower gums, tongue: the rigid motion of the jaw (the tongue, :data:`TONGUE`, also slides
    forward in ``tongueOut`` by :data:`TONGUE_OUT` of its depth, see ``_tongues``), fitted per shape
    (weighted Procrustes, Umeyama) to the transferred motion of the chin — the skin that the transferred
    ``jawOpen`` moves most — in the ``jaw*`` shapes only where the rig has them (ARKit: ``mouthClose``
    closes the lips over a still jaw; a fit to the chin would take the lower lip's motion for the jaw's).
``skull``
    upper teeth and gums: still.
``eye``
    eyeballs: turned about their centre for the ``eyeLook*`` shapes by :data:`EYE_LOOK_DEGREES` (ARKit
    names the direction, not the angle), about the eye's own axes: left the mirror plane's normal, up
    perpendicular to the eye's gaze (from the sphere's centre to the centroid of the eye's parts: a cornea,
    an iris or a front-only eyeball), see ``_eye_gaze``; the face frame's up (against the chin's drop in
    ``jawOpen``, 30–40° off the vertical on the shared heads) only where the gaze is not known.
``source``
    parts the source has too: deformation transfer already moved them.
``still``
    kept still: the user's choice, or a part object its rig moves by itself (an eye the rig turns by its
    transform, a part an armature deforms that does not deform the face: ``bridge.authoring.parts``), which
    shape keys would move twice.
``skin``
    the largest part.

The proposal (:func:`propose_parts`) classifies by geometry only: a near-spherical part off the mirror plane
is an eye; an open part lying within 1.2 % of the diagonal of the skin (median), or touching it (closer
than 0.3 %), follows it; any other part — and every closed one: teeth and gums are solids, even right behind
the lips — is rigid: with the jaw if most of it lies in the jaw's sector (seen along the hinge of the rigid
motion fitted to the transferred ``jawOpen``, the angles where the front midline moves with the jaw by more
than half: from the lip line round the chin), else with the skull; where there are at least four rigid
parts, the rows decide instead (their heights along the face's up fall into a lower row, with the jaw, and
an upper one, with the skull; open sheets of teeth lying on the mouth's skin join the split and in the
upper row follow the lips only by the skin's skull share, ``1 − jaw``).  A target part is ``source`` only
where the source's matched part is the same part: the same kind for the same reason, at a similar extent (a
mouth cavity: the source's cavity, open or closed, see ``_same_part``).  Each kind carries a confidence and a
reason; the user corrects it, naming a part by any of its vertices (:meth:`PartPlan.with_vertex_kinds`,
``kinds`` of :func:`plan_for_transfer`; the panel's *Parts* list).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree

from ..errors import ErrorCode
from ..names import canonical_name
from ..progress import ProgressFn, notify
from ..result import ShapeSpaceError
from ..surface import TriangleSurface
from .mesh import bbox_diagonal, inv3, symmetry_plane, triangle_parts
from .transfer import frames

__all__ = ["KINDS", "USER_KINDS", "UNSURE", "UPPER_SHEET", "LOWER_SHEET", "TONGUE", "TONGUE_OUT", "EYE_LOOK_DEGREES",
           "PartPlan", "still_vertices", "propose_parts", "plan_for_transfer",
           "move_parts", "jaw_membership",
           "fit_rigid", "sphere_fit"]

KINDS = ("skin", "source", "follow", "jaw", "skull", "eye", "still")
#: The kinds a user may give a part (``skin`` is the largest part; ``source`` is the registration's finding).
USER_KINDS = ("follow", "jaw", "skull", "eye", "still")
# eyeLook* at weight 1, degrees (ARKit documents the direction only).  Of the shared heads only Ready Player Me's
# keys turn the eyeballs (23.5° in every direction; ICT FaceKit's eyeLook* move the lids only); a real ARKit
# stream (Live Link Face, eye angles against weights, R² ≥ 0.97) turns by Up 25°, Down 35°, In/Out 34°
EYE_LOOK_DEGREES = {"Up": 20.0, "Down": 25.0, "In": 25.0, "Out": 30.0}
FOLLOW_RADIUS = 0.02          # × diagonal: binding falloff, half weight here (the cavity is not bound, ``_follow``)
FOLLOW_MEDIAN = 0.012         # × diagonal: a part whose median distance to the skin is below this follows it
TOUCH = 0.003                 # × diagonal: a part closer than this somewhere touches the skin (cavity)
EYE_RESIDUAL = 0.06           # relative RMS of a sphere fit below which a part is an eyeball
UNSURE = 0.6                  # a proposed kind below this confidence is marked unsure
UPPER_SHEET = "lies behind the upper lip, in the upper row (follows the lips where they do not move with the jaw)"
LOWER_SHEET = "lies behind the lower lip, in the lower row (follows the lips that move with the jaw)"
TONGUE = "inside, in the lower row, across the mirror plane: the tongue (moves with the jaw, out in tongueOut)"
# tongueOut at weight 1: the tongue slides forward by this share of its own depth (ARKit documents the extension,
# not the distance; Ready Player Me's artist: 0.75, the only shared head whose tongue moves)
TONGUE_OUT = 0.75


@dataclass
class PartPlan:
    """How each connected part of the target moves.

    Attributes
    ----------
    labels : ndarray of int (n_t,)
        Part per vertex (0 = skin, −1 = in no triangle), as :func:`~core.authoring.mesh.triangle_parts`.
    kinds : dict
        Part → one of :data:`KINDS`.
    confidence : dict
        Part → confidence of the proposal in [0, 1] (1 for a kind the user set).
    reasons : dict
        Part → why (shown in the panel and the report).
    """

    labels: np.ndarray
    kinds: dict
    confidence: dict = field(default_factory=dict)
    reasons: dict = field(default_factory=dict)
    frame: object = field(default=None, repr=False, compare=False)      # the face frame the proposal used
    extents: dict = field(default_factory=dict, repr=False, compare=False)    # part → its extent / diagonal

    def with_kinds(self, kinds: dict, reasons: dict | None = None) -> PartPlan:
        """A copy with some parts' kinds set (confidence 1); ``reasons`` (part → why) defaults to "set by the
        user"."""
        out = PartPlan(self.labels, dict(self.kinds), dict(self.confidence), dict(self.reasons), self.frame,
                       self.extents)
        for p, k in kinds.items():
            p = int(p)
            if p not in out.kinds:
                raise ShapeSpaceError(f"part {p} does not exist (the target has parts 0–{max(out.kinds)})",
                                      ErrorCode.RANGE)
            if k not in KINDS:
                raise ShapeSpaceError(f"part {p}: kind {k!r} is not one of {', '.join(KINDS)}", ErrorCode.INVALID)
            out.kinds[p], out.confidence[p] = k, 1.0
            out.reasons[p] = (reasons or {}).get(p, "set by the user")
        return out

    def with_vertex_kinds(self, kinds: dict) -> PartPlan:
        """A copy with the parts of some vertices set: ``{vertex: (kind, reason)}`` (a part is named by any of
        its vertices; kinds from :data:`USER_KINDS`).

        Raises
        ------
        ShapeSpaceError
            A vertex out of range or in no triangle (no part), the skin, a kind not in :data:`USER_KINDS`, or
            one part given two different kinds — naming the vertex.
        """
        by_part, why = {}, {}
        n = self.labels.shape[0]
        for v, (kind, reason) in sorted(kinds.items()):
            v = int(v)
            if not 0 <= v < n:
                raise ShapeSpaceError(f"part at vertex {v}: the target has {n} vertices", ErrorCode.RANGE)
            p = int(self.labels[v])
            if p <= 0:
                what = "is the skin (the largest part)" if p == 0 else "is in no triangle: no part"
                raise ShapeSpaceError(f"part at vertex {v}: that vertex {what}", ErrorCode.INVALID)
            if kind not in USER_KINDS:
                raise ShapeSpaceError(f"part at vertex {v}: kind {kind!r} is not one of {', '.join(USER_KINDS)}",
                                      ErrorCode.INVALID)
            if by_part.get(p, kind) != kind:
                raise ShapeSpaceError(f"part at vertex {v} is given {kind!r} and {by_part[p]!r}", ErrorCode.INVALID)
            by_part[p], why[p] = kind, str(reason)
        return self.with_kinds(by_part, why)

    def to_json(self) -> dict:
        """Plain data (labels are re-derived from the mesh; only per-part choices are stored)."""
        return {"kinds": {str(p): k for p, k in self.kinds.items()},
                "confidence": {str(p): float(c) for p, c in self.confidence.items()},
                "reasons": {str(p): r for p, r in self.reasons.items()}}

    def summary(self) -> list:
        """One dict per part: part, kind, vertices, ``first`` (its lowest vertex index: how the panel and
        :meth:`with_vertex_kinds` name it), confidence, ``unsure`` (confidence below :data:`UNSURE`: check it in
        the panel), reason."""
        on = self.labels >= 0
        sizes = np.bincount(self.labels[on]) if np.any(on) else np.zeros(0, int)
        first = np.full(sizes.size, -1, dtype=np.int64)
        idx = np.flatnonzero(on)
        labels, at = np.unique(self.labels[idx], return_index=True)
        first[labels] = idx[at]                                  # each label's lowest index
        return [{"part": int(p), "kind": k, "vertices": int(sizes[p]) if p < sizes.size else 0,
                 "first": int(first[p]) if p < first.size else -1,
                 "confidence": round(float(self.confidence.get(p, 1.0)), 3),
                 "unsure": bool(self.confidence.get(p, 1.0) < UNSURE), "reason": self.reasons.get(p, "")}
                for p, k in sorted(self.kinds.items())]


def sphere_fit(points: ArrayLike) -> tuple:
    """Least-squares sphere through points (algebraic fit ``‖x‖² = 2 c·x + (r² − ‖c‖²)``).

    Returns
    -------
    centre : ndarray (3,)
    radius : float
    residual : float
        RMS of ``‖x − c‖ − r`` relative to ``r`` (``inf`` for fewer than 4 points or a degenerate set).
    """
    P = np.asarray(points, dtype=np.float64)
    if P.shape[0] < 4:
        return P.mean(axis=0) if P.size else np.zeros(3), 0.0, float("inf")
    mu = P.mean(axis=0)
    X = P - mu
    A = np.c_[2.0 * X, np.ones(len(X))]
    sol, *_ = np.linalg.lstsq(A, np.sum(X * X, axis=1), rcond=None)
    c = sol[:3]
    r2 = sol[3] + c @ c
    if not np.isfinite(r2) or r2 <= 0:
        return mu, 0.0, float("inf")
    r = float(np.sqrt(r2))
    res = float(np.sqrt(np.mean((np.linalg.norm(X - c, axis=1) - r) ** 2)) / r)
    return c + mu, r, res


def fit_rigid(X: np.ndarray, Y: np.ndarray, w: np.ndarray) -> tuple:
    """Weighted rigid fit ``Y ≈ R X + t`` (Umeyama without scale): R (3, 3), t (3,); identity for no weight."""
    sw = w.sum()
    if sw <= 0:
        return np.eye(3), np.zeros(3)
    mx, my = w @ X / sw, w @ Y / sw
    H = ((Y - my) * w[:, None]).T @ (X - mx)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    R = U @ np.diag([1.0, 1.0, d]) @ Vt
    return R, my - R @ mx


class _Skin:
    """The skin part's triangles prepared once per call for closest-point queries."""

    def __init__(self, V, TT, labels):
        self.V = V
        self.tris = TT[labels[TT[:, 0]] == 0]
        self.surface = TriangleSurface(V, self.tris)

    def closest(self, points):
        """(tri into ``self.tris``, bary, point, distance) of each point."""
        return self.surface.closest(points)


def jaw_membership(verts: np.ndarray, labels: np.ndarray, jaw_delta: np.ndarray | None) -> np.ndarray:
    """How much each skin vertex moves with the jaw, in [0, 1] (n_t,): the transferred ``jawOpen``'s
    displacement length over its 99th percentile on the skin; zero everywhere without a ``jawOpen``."""
    m = np.zeros(verts.shape[0])
    if jaw_delta is None:
        return m
    length = np.linalg.norm(jaw_delta, axis=1)
    skin = labels == 0
    top = np.quantile(length[skin], 0.99) if skin.any() else 0.0
    if top > 0:
        m[skin] = np.clip(length[skin] / top, 0.0, 1.0)
    return m


def propose_parts(verts: ArrayLike, tris: ArrayLike, labels: ArrayLike, part_map: dict | None = None,
                  jaw_delta: np.ndarray | None = None, source_plan: PartPlan | None = None,
                  source_moving: Sequence[int] = (), progress: ProgressFn | None = None) -> PartPlan:
    """Classify the target's parts (see the module docstring).

    Parameters
    ----------
    verts : array_like (n_t, 3)
    tris : array_like of int (f_t, 3)
    labels : array_like of int (n_t,)
        Connected part per vertex (0 = skin).
    part_map : dict, optional
        Target part → source part from the registration (:attr:`Correspondence.part_map`).  A part matched
        to a source part other than the source's skin is ``source`` when that source part moves in the
        source's shapes (``source_moving``) and is of the same kind in ``source_plan`` (a lash matched to a
        source tooth is not).
    jaw_delta : ndarray (n_t, 3), optional
        The transferred ``jawOpen`` (skin part), deciding jaw against skull.
    source_plan : PartPlan, optional
        The source's own parts (proposed with its authored ``jawOpen``).
    source_moving : sequence of int
        Source parts that its shapes move.
    progress : callable, optional
        ``progress(fraction)`` between steps and parts (:mod:`core.progress`; it may raise ``Cancelled``).

    Returns
    -------
    PartPlan
    """
    notify(progress, 0.0)
    V = np.asarray(verts, dtype=np.float64)
    TT = np.asarray(tris, dtype=np.int64)
    lab = np.asarray(labels, dtype=np.int64)
    diag = max(bbox_diagonal(V), 1e-300)
    jaw = jaw_membership(V, lab, jaw_delta)
    kinds, conf, why = {0: "skin"}, {0: 1.0}, {0: "the largest part"}
    skin = _Skin(V, TT, lab)
    notify(progress, 0.05)
    frame = _face_frame(V, lab, jaw, None if jaw_delta is None else np.asarray(jaw_delta, dtype=np.float64))
    notify(progress, 0.4)
    closed = _closed_parts(TT, lab)
    others = np.flatnonzero(lab > 0)
    to_skin = np.zeros(len(V))
    if others.size:                                      # one query for every part (thousands of hair cards)
        to_skin[others] = skin.closest(V[others])[3]
    notify(progress, 0.55)
    ids = np.unique(lab[lab > 0])
    for i, p in enumerate(ids):
        p = int(p)
        idx = np.flatnonzero(lab == p)
        kinds[p], conf[p], why[p] = _classify(V, to_skin[idx], frame, idx, diag, p in closed)
        notify(progress, 0.55 + 0.15 * (i + 1) / len(ids))
    _beside_eyes(V, lab, kinds, conf, why, diag)
    notify(progress, 0.75)
    _teeth_rows(V, lab, PartPlan(lab, kinds, conf, why, frame), diag, _mouth_sheets(V, skin, lab, kinds, why, jaw))
    notify(progress, 0.95)
    _tongues(V, TT, lab, kinds, why, frame, diag)
    extents = {int(p): float(np.ptp(V[lab == p], axis=0).max()) / diag for p in np.unique(lab[lab >= 0])}
    plan = PartPlan(lab, kinds, conf, why, frame, extents)
    for p in np.unique(lab[lab > 0]):
        p = int(p)
        q = (part_map or {}).get(p, -1)
        if q > 0 and q in set(source_moving) and _same_part(plan, p, source_plan, q):
            kinds[p], conf[p], why[p] = "source", conf[p], f"the source has it and moves it (source part {q})"
    return plan


def _same_part(plan, p, source_plan, q):
    """Whether target part ``p`` and the source part ``q`` the registration matched it to are the same part:
    the same kind for the same reason (a mouth cavity touching the lips is not a row of teeth lying behind
    them, though both follow the skin) and extents (relative to each head's diagonal) within a factor 2 (a
    tongue is not a tooth).  A mouth cavity is the source's mouth cavity whatever kind the source's was
    proposed: an open bag touching the lips, or a closed bag of the cavity's size (Face Cap models its mouth
    interior closed, so it is proposed rigid) — not a sheet of teeth lying on the skin (Ready Player Me's):
    the source's own cavity motion, carried by deformation transfer, has the lower half going with the jaw
    and the back staying, which the binding to the lips and the chin's rigid motion miss (ICT FaceKit's cavity
    from Face Cap: ``jawOpen`` error 0.27 of its authored motion, 0.44 bound)."""
    if source_plan is None:
        return False
    a, b = plan.extents.get(p, 0.0), source_plan.extents.get(q, 0.0)
    similar = a > 0 and b > 0 and 0.5 <= a / b <= 2.0
    if _is_cavity(plan, p):
        return similar and (_is_cavity(source_plan, q) or source_plan.kinds.get(q) in ("jaw", "skull"))
    if source_plan.kinds.get(q) != plan.kinds[p]:
        return False
    if plan.kinds[p] == "follow" and source_plan.reasons.get(q) != plan.reasons[p]:
        return False
    return similar


def _is_cavity(plan, p):
    """Whether part ``p`` is a mouth cavity: an open part touching the skin (not lying on it)."""
    return plan.kinds.get(p) == "follow" and plan.reasons.get(p) == "touches the skin"


def plan_for_transfer(src_verts: np.ndarray, src_tris: np.ndarray, src_deltas: np.ndarray, names: Sequence[str],
                      dst_verts: np.ndarray, dst_tris: np.ndarray, deltas: np.ndarray, part_map: dict,
                      kinds: dict | None = None) -> PartPlan:
    """The proposed :class:`PartPlan` of a transfer: the source's parts from its own ``jawOpen``, the target's
    from the transferred one, a target part ``source`` where the source has and moves the same kind.

    Parameters
    ----------
    src_verts, src_tris, src_deltas : (n_s, 3), (f_s, 3), (k, n_s, 3)
    names : sequence of str (k,)
    dst_verts, dst_tris, deltas : (n_t, 3), (f_t, 3), (k, n_t, 3) transferred
    part_map : dict
        :attr:`Correspondence.part_map`.
    kinds : dict, optional
        ``{vertex: (kind, reason)}``: parts set by the user or by their rig (:meth:`PartPlan.with_vertex_kinds`),
        over the proposal.
    """
    canon = [canonical_name(n) for n in names]
    j = canon.index("jawOpen") if "jawOpen" in canon else None
    s_lab, _ = triangle_parts(src_verts.shape[0], src_tris)
    t_lab, _ = triangle_parts(dst_verts.shape[0], dst_tris)
    s_plan = propose_parts(src_verts, src_tris, s_lab, None, None if j is None else src_deltas[j])
    motion = np.linalg.norm(src_deltas, axis=2).max(axis=0) if src_deltas.shape[0] else np.zeros(len(s_lab))
    tol = 1e-3 * bbox_diagonal(src_verts)
    moving = [int(q) for q in np.unique(s_lab[s_lab > 0]) if motion[s_lab == q].max() > tol]
    plan = propose_parts(dst_verts, dst_tris, t_lab, part_map, None if j is None else deltas[j], s_plan, moving)
    return plan.with_vertex_kinds(kinds) if kinds else plan


def still_vertices(n: int, tris: ArrayLike, kinds: dict) -> np.ndarray:
    """Vertices of the parts set ``still`` in ``kinds`` (``{vertex: (kind, reason)}``, as
    :func:`plan_for_transfer`): what a transfer that does not move parts as rigged still keeps still.

    Parameters
    ----------
    n : int
        Vertices of the target.
    tris : array_like of int (f, 3)
    kinds : dict

    Returns
    -------
    ndarray of bool (n,)
    """
    lab, _ = triangle_parts(n, np.asarray(tris, dtype=np.int64))
    parts = {int(lab[v]) for v, (kind, _) in kinds.items() if kind == "still" and 0 <= int(v) < n and lab[v] > 0}
    return np.isin(lab, sorted(parts))


def _tongues(V, TT, lab, kinds, why, frame, diag):
    """Mark the tongue (in place, :data:`TONGUE`): a solid of the lower row lying across the mirror plane (1 %
    of the diagonal on either side: a tooth lies on one side) that a rigger would call one —

    - a blob, not an arch: its triangles, seen from above (along the frame's up), cover its own centroid (a
      row of teeth or gums in one piece, as CC/Daz-style kits ship them, is a U whose centroid lies in the
      hollow of the U);
    - not what the other parts sit in: it does not hold (:func:`_holds`) the other rigid parts (a closed mouth
      bag, Face Cap's, holds the rows of teeth inside its hull);
    - behind the lower teeth: its centroid lies behind the foremost point of the lower row's other parts
      along the frame's forward (where ``jawOpen`` gave the forward its sign: the chin is in front).

    A tongue may come in several pieces, one inside the other (Ready Player Me's: two shells)."""
    rigid = [p for p, k in kinds.items() if k in ("jaw", "skull")]
    side = {p: (V[lab == p] - frame.centre) @ frame.left for p in rigid}
    across = [p for p in rigid if side[p].min() < -0.01 * diag and side[p].max() > 0.01 * diag]
    blobs = [p for p in across if kinds[p] == "jaw" and _blob(V, TT, lab, p, frame.up)]
    teeth = V[np.isin(lab, [q for q in rigid if q not in blobs])]
    lower = V[np.isin(lab, [q for q in rigid if kinds[q] == "jaw" and q not in blobs])]
    front = (lower @ frame.forward).max() if len(lower) and frame.chin is not None else np.inf
    for p in blobs:
        if V[lab == p].mean(axis=0) @ frame.forward < front and (len(teeth) == 0 or not _holds(V[lab == p], teeth)):
            why[p] = TONGUE


def _blob(V, TT, lab, p, up):
    """Whether part ``p``'s triangles, projected along ``up`` (3,), cover the projection of its centroid (the
    mean of its vertices): a blob does, an arch (a U around a hollow) does not."""
    e1 = _any_perpendicular(up)
    P = (V[TT[lab[TT[:, 0]] == p]] - V[lab == p].mean(axis=0)) @ np.stack([e1, np.cross(up, e1)]).T  # (f, 3, 2)
    a, b, c = P[:, 0], P[:, 1], P[:, 2]
    area = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    d = np.stack([u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0] for u, v in ((a, b), (b, c), (c, a))])  # origin's side
    inside = (np.all(d >= 0, axis=0) | np.all(d <= 0, axis=0)) & (np.abs(area) > 1e-12 * max(np.ptp(P) ** 2, 1e-300))
    return bool(inside.any())


def _tongue_out(V, lab, plan, canon, face_forward=None):
    """The ``tongueOut`` translation (3,) of the tongue parts: along the face's forward (``face_forward`` where
    the caller gives it, else the plan's frame's; perpendicular to the eyes' up, :func:`_face_up`),
    :data:`TONGUE_OUT` of the tongue's depth; zero without a tongue."""
    tongue = np.isin(lab, [p for p, r in plan.reasons.items() if r == TONGUE and plan.kinds.get(p) == "jaw"])
    if "tongueOut" not in canon or not tongue.any() or plan.frame is None:
        return np.zeros(3)
    up = _face_up(V, lab, plan)
    fwd = plan.frame.forward if face_forward is None else np.asarray(face_forward, dtype=np.float64)
    fwd = fwd - (fwd @ up) * up
    fwd /= max(np.linalg.norm(fwd), 1e-300)
    return TONGUE_OUT * float(np.ptp(V[tongue] @ fwd)) * fwd


def _beside_eyes(V, lab, kinds, conf, why, diag):
    """Rigid-classified parts touching an eyeball (lacrimal fluid, eye occlusion and blend shells) follow the
    lids instead: they sit in the socket between eye and lid."""
    eyes = np.flatnonzero(np.isin(lab, [p for p, k in kinds.items() if k == "eye"]))
    if eyes.size == 0:
        return
    tree = cKDTree(V[eyes])
    for p, k in list(kinds.items()):
        if k in ("jaw", "skull"):
            d, _ = tree.query(V[lab == p])
            if d.min() < 0.01 * diag:
                kinds[p], conf[p], why[p] = "follow", 0.6, "touches an eyeball: follows the lids"


def _face_up(V, lab, plan):
    """The face's up from its eyes' gaze (:func:`_eye_gaze`, mean over the eyes), the frame's without eyes."""
    frame = plan.frame
    ups = [_eye_gaze(V, lab, plan, p, frame, _eye_centre(V, lab, plan, p, frame))[0]
           for p, k in plan.kinds.items() if k == "eye"]
    up = np.mean(ups, axis=0) if ups else frame.up
    return up / max(np.linalg.norm(up), 1e-300)


def _mouth_sheets(V, skin, lab, kinds, why, jaw):
    """Open parts lying on the skin of the mouth (the skin under them moves with the jaw by more than a fifth
    in ``jawOpen``): rows of teeth modelled as sheets behind the lips (Ready Player Me's), not lashes."""
    out = []
    for p, k in kinds.items():
        if k == "follow" and why[p] == "lies on the skin":
            tri, bary, _, _ = skin.closest(V[lab == p])
            if np.median(np.sum(bary * jaw[skin.tris[tri]], axis=1)) > 0.2:
                out.append(p)
    return out


def _teeth_rows(V, lab, plan, diag, sheets=()):
    """Split the rigid parts (jaw or skull by the sector) into the lower and the upper row (in place): the
    heights of their lowest tenths (a tongue reaches back and up, it rests low) along the face's up
    (:func:`_face_up`) fall into two groups (the threshold
    that minimises the spread within the groups, Otsu's), the lower with the jaw, the upper with the skull.
    Used where both rows have at least two parts and the groups lie at least 1 % of the diagonal apart
    (the sector alone misjudges rows on a hinge estimated from the skin: Face Cap's lower teeth).  ``sheets``
    (:func:`_mouth_sheets`) join the split: in the upper row they follow the skin only by its skull share
    (:data:`UPPER_SHEET`: the upper lip's lip shapes, not the lower lip's ``jawOpen``; Ready Player Me's
    artist moves them so), in the lower row they keep following the skin (lower lip and teeth both move with
    the jaw)."""
    rigid = [p for p, k in plan.kinds.items() if k in ("jaw", "skull")] + list(sheets)
    if len(rigid) < 4:
        return
    up = _face_up(V, lab, plan)
    h = np.array([float(np.percentile(V[lab == p] @ up, 10)) for p in rigid])
    order = np.argsort(h)
    hs = h[order]
    cost = [np.var(hs[:i]) * i + np.var(hs[i:]) * (len(hs) - i) for i in range(2, len(hs) - 1)]
    if not cost:
        return
    i = 2 + int(np.argmin(cost))
    if hs[i:].mean() - hs[:i].mean() < 0.01 * diag:
        return
    cut = 0.5 * (hs[i - 1] + hs[i])
    sure = float(np.clip((hs[i] - hs[i - 1]) / (0.01 * diag), 0.3, 1.0))
    rows = {True: ("jaw", "inside, in the lower row (moves with the jaw)"),
            False: ("skull", "inside, in the upper row (stays with the skull)")}
    for p, hp in zip(rigid, h):
        kind, why = rows[bool(hp < cut)]
        if p in sheets:
            kind, why = "follow", UPPER_SHEET if kind == "skull" else LOWER_SHEET
        plan.kinds[p], plan.confidence[p], plan.reasons[p] = kind, sure, why


def _closed_parts(TT, lab):
    """Parts whose surface is closed (every edge shared by two of its triangles): teeth, gums, a tongue — solids,
    not the sheets (lashes, brows, eyelines) or the open bag (mouth cavity) that follow the skin."""
    part = lab[TT[:, 0]]
    E = np.sort(np.concatenate([TT[:, [0, 1]], TT[:, [1, 2]], TT[:, [2, 0]]]), axis=1)
    pe = np.tile(part, 3)
    key = E[:, 0] * (int(E.max()) + 1) + E[:, 1]
    _, first, counts = np.unique(key, return_index=True, return_counts=True)
    open_parts = set(np.unique(pe[first[counts == 1]]).tolist())
    return {int(p) for p in np.unique(part) if p > 0 and int(p) not in open_parts}


def _classify(V, dist, frame, idx, diag, closed):
    """(kind, confidence, reason) of the part of vertices ``idx`` whose distances to the skin are ``dist``."""
    eye = _eye_likeness(V, frame, idx, diag)
    if eye > 0:
        return "eye", eye, "a round part off the mirror plane"
    med, low = float(np.median(dist)) / diag, float(dist.min()) / diag
    if (med < FOLLOW_MEDIAN or low < TOUCH) and not closed:
        why = "lies on the skin" if med < FOLLOW_MEDIAN else "touches the skin"
        return "follow", float(np.clip(1.0 - med / (2 * FOLLOW_MEDIAN), 0.3, 1.0)), why
    inside, sure = frame.in_jaw(V[idx])
    if inside > 0.5:
        return "jaw", sure, "inside, in the jaw's sector (moves with the jaw)"
    return "skull", sure, "inside, outside the jaw's sector (stays with the skull)"


def _eye_likeness(V, frame, idx, diag):
    """Confidence (0: not an eye) that a part is an eyeball: off the mirror plane, well above the chin
    (10 % of the diagonal, where the jaw is known), 4–12 % of the diagonal across (a tooth is smaller), not
    flat (smallest principal extent ≥ 30 % of the largest) and convex (≥ 80 % of its vertices on its convex
    hull, or a sphere fit within 6 %)."""
    P = V[idx]
    if idx.size < 8:
        return 0.0
    c = P.mean(axis=0)
    off = abs((c - frame.centre) @ frame.left) > 0.05 * diag
    high = frame.chin is None or (c - frame.chin) @ frame.up > 0.1 * diag
    ext = np.linalg.svd(P - c, compute_uv=False) / np.sqrt(idx.size)
    size = float(np.ptp(P, axis=0).max()) / diag
    if not (off and high) or not 0.04 < size < 0.12 or ext[2] < 0.3 * ext[0]:
        return 0.0
    _, _, res = sphere_fit(P)
    try:
        hull = ConvexHull(P)
        on_hull = np.unique(hull.simplices).size / idx.size
    except (QhullError, ValueError):
        on_hull = 0.0
    if on_hull < 0.8 and res > EYE_RESIDUAL:
        return 0.0
    return float(np.clip(max(on_hull, 1.0 - res / EYE_RESIDUAL), 0.3, 1.0))


def _inverse_frames(F0):
    """``F0⁻¹`` (f, 3, 3), identity where a frame is singular (a degenerate triangle turns with nothing)."""
    inv, det = inv3(F0)
    return np.where((np.abs(det) > 1e-300)[:, None, None], inv, np.eye(3))


def _rotations(F0inv, F1):
    """Rotation (f, 3, 3) of each triangle from its rest frame (inverse ``F0inv``) to ``F1``: the polar factor
    of the deformation gradient ``F1 F0⁻¹``."""
    U, _, Vt = np.linalg.svd(F1 @ F0inv)
    d = np.sign(np.linalg.det(U @ Vt))
    U[:, :, 2] *= d[:, None]
    return U @ Vt


def move_parts(plan: PartPlan, verts: ArrayLike, tris: ArrayLike, deltas: np.ndarray, names: Sequence[str],
               face_forward: np.ndarray | None = None) -> tuple:
    """Move every ``follow``, ``jaw``, ``skull``, ``eye`` and ``still`` part of transferred shapes.

    Parameters
    ----------
    plan : PartPlan
    verts : array_like (n_t, 3)
    tris : array_like of int (f_t, 3)
    deltas : ndarray (k, n_t, 3)
        Transferred deltas (skin and ``source`` parts are kept; the others are replaced, in place).
    names : sequence of str (k,)
        Shape names (``jawOpen`` decides the jaw; ``eyeLook*`` turn the eyes).
    face_forward : ndarray (3,), optional
        The face's forward direction (default: the mean normal of the skin the shapes move).

    Returns
    -------
    deltas : ndarray (k, n_t, 3)
        The same array.
    moved : dict
        Part → largest displacement over the shapes (target units).
    """
    V = np.asarray(verts, dtype=np.float64)
    TT = np.asarray(tris, dtype=np.int64)
    lab = plan.labels
    canon = [canonical_name(n) for n in names]
    jaw_delta = deltas[canon.index("jawOpen")] if "jawOpen" in canon else None
    jaw = jaw_membership(V, lab, jaw_delta)
    jaw_motion = _jaw_motions(V, lab, deltas, jaw, canon)                   # (k, 3, 3), (k, 3)
    follow = np.flatnonzero(np.isin(lab, [p for p, k in plan.kinds.items() if k == "follow"]))
    if follow.size:
        upper = np.isin(lab[follow], [p for p, r in plan.reasons.items() if r == UPPER_SHEET])
        bound = ~np.isin(lab[follow], [p for p in plan.kinds if _is_cavity(plan, p)])   # the cavity: jaw/skull
        lower = np.isin(lab[follow], [p for p, r in plan.reasons.items() if r == LOWER_SHEET])
        side = np.where(upper, 0, np.where(lower, 1, -1))
        deltas[:, follow] = _follow(V, _Skin(V, TT, lab), follow, deltas, jaw, jaw_motion,
                                    _cavity_shares(V, plan, follow), upper, bound, side)
    frame = plan.frame if face_forward is None else None
    out_by = _tongue_out(V, lab, plan, canon, face_forward)
    for p, kind in plan.kinds.items():
        idx = np.flatnonzero(lab == p)
        if kind in ("skin", "source") or idx.size == 0:
            continue
        if kind in ("still", "skull"):
            deltas[:, idx] = 0.0
        elif kind == "jaw":
            R, t = jaw_motion
            deltas[:, idx] = np.einsum("kij,vj->kvi", R, V[idx]) + t[:, None, :] - V[idx][None]
            if plan.reasons.get(p) == TONGUE and "tongueOut" in canon:
                deltas[canon.index("tongueOut"), idx] += out_by
        elif kind == "eye":
            frame = frame or _face_frame(V, lab, jaw, jaw_delta, face_forward)
            centre = _eye_centre(V, lab, plan, p, frame)
            axes = _eye_gaze(V, lab, plan, p, frame, centre)
            deltas[:, idx] = _eye_turns(V, idx, deltas, canon, frame, centre, axes)
    moved = {int(p): float(np.linalg.norm(deltas[:, lab == p], axis=2).max()) if deltas.shape[0] else 0.0
             for p in plan.kinds}
    return deltas, moved


def _jaw_motions(V, lab, deltas, jaw, canon=()):
    """Per shape the jaw's rigid motion fitted to the chin (weights ``jaw⁴``): R (k, 3, 3), t (k, 3).

    In an ARKit rig only the ``jaw*`` shapes move the jaw (``mouthClose`` closes the lips over an open jaw,
    ``mouthFunnel`` … move the lips alone): where the names have ``jaw*`` shapes, every other shape keeps the
    jaw still — a fit to the chin would take the lower lip's motion for the jaw's."""
    k = deltas.shape[0]
    w = jaw ** 4
    sel = np.flatnonzero(w > 1e-3)
    R, t = np.tile(np.eye(3), (k, 1, 1)), np.zeros((k, 3))
    if sel.size < 3:
        return R, t
    X = V[sel]
    named = any(n.startswith("jaw") for n in canon)
    for s in range(k):
        if named and not canon[s].startswith("jaw"):
            continue
        R[s], t[s] = fit_rigid(X, X + deltas[s, sel], w[sel])
    return R, t


def _cavity_shares(V, plan, idx):
    """The jaw share (m,) of the mouth cavity's vertices among ``idx`` (NaN elsewhere): between the rows of
    teeth, ``d_skull⁴ / (d_jaw⁴ + d_skull⁴)`` with ``d`` the distance to the nearest solid part of each row —
    the floor of the mouth goes with the jaw, the roof stays with the skull, the throat between them half way
    (ICT FaceKit's authored cavity is a blend of the jaw's rigid motion: 0.4 % error with the best share per
    vertex; the fourth power, a narrow blend, takes the cavity's ``jaw*`` error from FBHead and Ready Player
    Me to 0.39 and 0.26 of its authored motion, 0.48 and 0.39 with the first).  Only where both rows have
    solid parts (``inside``: not a sheet of teeth on the lips) and for a cavity that holds them (at least half
    their vertices inside its convex hull: Ready Player Me's is a strip of the mouth's floor holding a quarter
    of them, carried by the skin it touches)."""
    lab = plan.labels
    out = np.full(idx.size, np.nan)
    rows = [np.flatnonzero(np.isin(lab, [p for p, k in plan.kinds.items()
                                         if k == kind and plan.reasons.get(p, "").startswith("inside")]))
            for kind in ("jaw", "skull")]
    if rows[0].size == 0 or rows[1].size == 0:
        return out
    teeth = V[np.concatenate(rows)]
    on = np.isin(lab[idx], [p for p in plan.kinds if _is_cavity(plan, p) and _holds(V[lab == p], teeth)])
    if not on.any():
        return out
    dj, _ = cKDTree(V[rows[0]]).query(V[idx[on]])
    dk, _ = cKDTree(V[rows[1]]).query(V[idx[on]])
    out[on] = dk ** 4 / np.maximum(dj ** 4 + dk ** 4, 1e-300)
    return out


def _holds(P, Q):
    """Whether at least half the points ``Q`` (m, 3) lie inside the convex hull of ``P`` (n, 3)."""
    try:
        return bool(np.mean(Delaunay(P).find_simplex(Q) >= 0) >= 0.5)
    except (QhullError, ValueError):
        return False


def _closest_on_side(V, skin, idx, jaw, side):
    """:meth:`_Skin.closest` of vertices ``idx``, where ``side`` (m,) is 0 or 1 only on the skin's skull side
    (triangles moving with the jaw by at most half) or jaw side (more than half): a row of teeth lying
    behind the lips is bound to its own lip."""
    tri, bary, point, dist = skin.closest(V[idx])
    if side is None:
        return tri, bary, point, dist
    on_jaw = jaw[skin.tris].mean(axis=1) > 0.5
    for s in (0, 1):
        rows = np.flatnonzero(side == s)
        sub = np.flatnonzero(on_jaw == bool(s))
        if rows.size == 0 or sub.size == 0:
            continue
        t, b, q, d = TriangleSurface(V, skin.tris[sub]).closest(V[idx[rows]])
        tri[rows], bary[rows], point[rows], dist[rows] = sub[t], b, q, d
    return tri, bary, point, dist


def _falloff(d):
    """Binding weight at distance ``d`` (× diagonal) from the skin: 1 on it, ½ at :data:`FOLLOW_RADIUS`, then
    falling as the inverse square (a sheet of teeth or gums behind the lips moves with them all across, as
    Ready Player Me's artist authored it: 60–100 % of the lip's motion at 1.5 % of the diagonal, 25 % at 7 %)."""
    return 1.0 / (1.0 + (d / FOLLOW_RADIUS) ** 2)


def _follow(V, skin, idx, deltas, jaw, jaw_motion, shares=None, upper=None, bound=None, side=None):
    """Surface binding of vertices ``idx`` to the skin, fading into their jaw share of the jaw motion (the
    skin's under them, or ``shares`` (m,) where not NaN: :func:`_cavity_shares`).  ``upper`` (m,) bool: upper
    teeth sheets, bound to the skin by its skull share ``1 − jaw`` and never carried by the jaw (Ready Player
    Me's artist moves them with the upper lip in the lip shapes — ``mouthFunnel``, ``mouthPucker`` — not with
    the lower lip's ``jawOpen`` and ``mouthClose``).  ``bound`` (m,) bool: bound to the skin at all (False:
    the mouth cavity, carried by its jaw share alone).  ``side`` (m,): the lip each vertex binds to
    (:func:`_closest_on_side`)."""
    ST = skin.tris
    tri, bary, point, dist = _closest_on_side(V, skin, idx, jaw, side)
    diag = max(bbox_diagonal(V), 1e-300)
    w = _falloff(dist / diag)
    if bound is not None:
        w = np.where(bound, w, 0.0)
    share = np.sum(bary * jaw[ST[tri]], axis=1)
    if shares is not None:
        share = np.where(np.isnan(shares), share, shares)
    keep = np.ones(idx.size)
    if upper is not None:
        keep = np.where(upper, 1.0 - share, 1.0)
        share = np.where(upper, 0.0, share)
    used = ST[tri]                                                      # (m, 3) skin vertices
    uniq, inv = np.unique(tri, return_inverse=True)
    F0inv = _inverse_frames(frames(V, ST[uniq]))
    off = V[idx] - point
    R, t = jaw_motion
    out = np.empty((deltas.shape[0], idx.size, 3))
    for s in range(deltas.shape[0]):
        d = deltas[s]
        rot = _rotations(F0inv, frames(V + d, ST[uniq]))[inv]           # (m, 3, 3)
        bound = np.einsum("mj,mjc->mc", bary, d[used]) + np.einsum("mij,mj->mi", rot, off) - off
        rigid = (V[idx] @ R[s].T + t[s] - V[idx]) * share[:, None]
        out[s] = (w * keep)[:, None] * bound + (1.0 - w[:, None]) * rigid
    return out


def _eye_centre(V, lab, plan, part, frame):
    """The centre one eye's parts turn about (eyeball, iris, cornea …): the sphere through all the eye parts
    on the same side as ``part``."""
    side = np.sign((V[lab == part].mean(axis=0) - frame.centre) @ frame.left)
    same = [p for p, k in plan.kinds.items() if k == "eye"
            and np.sign((V[lab == p].mean(axis=0) - frame.centre) @ frame.left) == side]
    centre, _, _ = sphere_fit(V[np.isin(lab, same)])
    return centre


def _eye_gaze(V, lab, plan, part, frame, centre):
    """The eye's own (up, left) for ``part``: its gaze is the direction from ``centre`` to the centroid of each
    eye part on that side (an eyeball's front — cornea, iris — bulges forward, or is all there is of it), summed
    with the sign of the face's forward and weighted by the offset; the face frame's ``up`` is only known up to
    the tilt of the chin's drop in ``jawOpen`` (30–40° on the shared heads), the gaze is not.  Falls back to the
    face frame when the offset is under 2 % of the eye's size."""
    side = np.sign((V[lab == part].mean(axis=0) - frame.centre) @ frame.left)
    gaze, size = np.zeros(3), 0.0
    for p, k in plan.kinds.items():
        P = V[lab == p]
        if k != "eye" or P.size == 0 or np.sign((P.mean(axis=0) - frame.centre) @ frame.left) != side:
            continue
        g = P.mean(axis=0) - centre
        gaze += g * (len(P) if g @ frame.forward >= 0 else -len(P))
        size += len(P) * float(np.ptp(P, axis=0).max())
    left = frame.left
    gaze -= (gaze @ left) * left
    if size <= 0 or np.linalg.norm(gaze) < 0.02 * size:
        return frame.up, left
    up = np.cross(gaze, left)
    up /= np.linalg.norm(up)
    return (up if up @ frame.up >= 0 else -up), left


def _eye_turns(V, idx, deltas, canon, frame, centre, axes=None):
    """Eyeball vertices ``idx`` turned about ``centre`` for the ``eyeLook*`` shapes (k, m, 3); ``axes`` (up,
    left) of the eye (default: the face frame's)."""
    up, left = axes if axes is not None else (frame.up, frame.left)
    side = "Left" if (centre - frame.centre) @ left > 0 else "Right"
    out = np.zeros((deltas.shape[0], idx.size, 3))
    X = V[idx] - centre
    for s, name in enumerate(canon):
        if not name.startswith("eyeLook") or not name.endswith(side):
            continue
        direction = name[len("eyeLook"):-len(side)]
        if direction not in EYE_LOOK_DEGREES:
            continue
        axis = {"Up": -left, "Down": left}.get(direction)
        if axis is None:
            toward_left = (direction == "Out") == (side == "Left")
            axis = up if toward_left else -up
        out[s] = X @ _axis_angle(axis, np.radians(EYE_LOOK_DEGREES[direction])).T - X
    return out


@dataclass
class _Frame:
    """The face's frame from the skin.

    ``left`` is the mirror plane's normal turned towards the character's left; ``up`` is against the chin's
    mean motion in ``jawOpen`` (in the mirror plane); ``forward`` = left × up.  The jaw's sector: seen along
    the jaw's hinge (the axis of the rigid motion fitted to ``jawOpen``, through its pivot), the angles of
    the front midline where the jaw's share exceeds ½ — from the lip line round the chin to the throat.  A
    rigid part inside that sector moves with the jaw (lower teeth, tongue), one outside stays with the skull.
    """

    centre: np.ndarray
    left: np.ndarray
    up: np.ndarray
    forward: np.ndarray
    chin: np.ndarray = None        # jaw-weighted skin centroid, None without a jawOpen
    hinge: tuple = None            # (pivot, unit axis, e1, e2, lip end, throat end) or None without a jawOpen

    def in_jaw(self, points) -> tuple:
        """(fraction of ``points`` (m, 3) inside the jaw's sector, confidence).  Angles about the hinge, the
        chin at 0; the sector's lip end is taken half way from the lip line to the chin: the lips stand in
        front of the teeth and upper incisors reach below the lip line (ICT FaceKit's front upper teeth lie
        35–100 % of the way to it, its lower teeth within 21 %; Face Cap's lower teeth at 75–83 % are
        misjudged, with a confidence of 0.5).  The confidence grows with the median angle's distance from
        that end."""
        if self.hinge is None or not self.hinge[4]:
            return 0.0, 0.5
        p, _, e1, e2, lip, throat = self.hinge
        X = np.asarray(points) - p
        th = np.arctan2(X @ e2, X @ e1) * -np.sign(lip)             # the lip side negative
        inside = float(np.mean((th > -0.5 * abs(lip)) & (th < abs(throat))))
        return inside, float(np.clip(abs(np.median(th) + 0.5 * abs(lip)) / (0.5 * abs(lip)), 0.2, 1.0))


def _face_frame(V, lab, jaw, jaw_delta, face_forward=None):
    skin = np.flatnonzero(lab == 0)
    S = V[skin]
    c = S.mean(axis=0)
    n, _, _ = symmetry_plane(S)
    w = jaw[skin]
    has_jaw = jaw_delta is not None and w.sum() > 0
    chin = (w @ S) / w.sum() if has_jaw else c
    drop = -(w @ jaw_delta[skin]) if has_jaw else _any_perpendicular(n)
    up = drop - (drop @ n) * n                                  # jawOpen drops the chin: up is against it
    up /= max(np.linalg.norm(up), 1e-300)
    fwd = np.cross(up, n) if face_forward is None else np.asarray(face_forward, dtype=np.float64)
    fwd = fwd - (fwd @ up) * up
    fwd /= max(np.linalg.norm(fwd), 1e-300)
    if face_forward is None and has_jaw and (chin - c) @ fwd < 0:
        fwd = -fwd
    hinge = _hinge(S, w, jaw_delta[skin], n, chin, up, c - 0.1 * bbox_diagonal(S) * fwd) if has_jaw else None
    return _Frame(c, np.cross(up, fwd), up, fwd, chin if has_jaw else None, hinge)


def _hinge(S, w, d, n, chin, up, fallback):
    """The jaw's hinge and sector (see :class:`_Frame`).  A ``jawOpen`` that barely turns (its hinge would
    lie more than a head away: a jaw that slides) gets the hinge through ``fallback`` along the mirror
    normal (behind the centre of the head, where a jaw joint is)."""
    R, t = fit_rigid(S, S + d, w ** 4)
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    diag = max(float(np.ptp(S, axis=0).max()), 1e-300)
    pivot = None
    if np.linalg.norm(axis) > 1e-9:
        axis /= np.linalg.norm(axis)
        pivot, *_ = np.linalg.lstsq(np.eye(3) - R, t, rcond=1e-6)    # (I − R) is singular along the axis
        pivot += ((fallback - pivot) @ axis) * axis                    # the axis point beside the head's centre
    if pivot is None or np.linalg.norm(pivot - pivot @ axis * axis - (fallback - fallback @ axis * axis)) > diag:
        axis, pivot = n, fallback
    e1 = chin - pivot - ((chin - pivot) @ axis) * axis
    e1 /= max(np.linalg.norm(e1), 1e-300)
    e2 = np.cross(axis, e1)
    mid = np.abs((S - chin) @ n) < 0.03 * diag
    X = S[mid] - pivot
    th = np.arctan2(X @ e2, X @ e1)
    radius = np.linalg.norm(X - np.outer(X @ axis, axis), axis=1)
    lo, hi = _sector(th, radius, w[mid])
    lip_is_lo = (np.cos(lo) * e1 + np.sin(lo) * e2) @ up > (np.cos(hi) * e1 + np.sin(hi) * e2) @ up
    return (pivot, axis, e1, e2, lo, hi) if lip_is_lo else (pivot, axis, e1, e2, hi, lo)


#: The angular bin of :func:`_sector` (2°).
_SECTOR_BIN = float(np.radians(2.0))


def _sector(th, radius, w, step=_SECTOR_BIN):
    """Angles (lo, hi) around 0 over which the outer profile (the farthest midline point of each 2° bin:
    lips and chin, not the throat behind them) moves with the jaw by more than half."""
    bins = np.round(th / step).astype(int)
    order = np.lexsort((-radius, bins))
    first = np.r_[True, bins[order][1:] != bins[order][:-1]]
    outer = dict(zip(bins[order][first].tolist(), w[order][first].tolist()))
    ends = []
    for sign in (-1, 1):
        k = 0
        while outer.get(k + sign, 1.0) > 0.5 and abs(k) * step < np.pi:
            k += sign
        ends.append((k + 0.5 * sign) * step)
    return ends[0], ends[1]


def _any_perpendicular(n):
    a = np.eye(3)[int(np.argmin(np.abs(n)))]
    return np.cross(n, a) / np.linalg.norm(np.cross(n, a))


def _axis_angle(axis, angle):
    a = axis / max(np.linalg.norm(axis), 1e-300)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
