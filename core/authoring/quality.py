"""The per-key checks of a transfer (issue #22 §6): a report that tells the truth, not the registration residual.

For every transferred key:

- ``gap_left`` (eye openings, ``eyeBlink`` keys): the widest remaining lid gap at weight 1 over the widest
  open gap (:func:`~core.authoring.contacts.gap_left`); fails above
  :data:`MAX_GAP_LEFT` where the source's own gap left is at most that;
- ``crossings``: facing pairs whose sides passed each other (gap fraction below :data:`CROSSING`) where the
  source's do not; fails when any;
- ``lips`` (openings shut at rest, the inner lips): a key that leaves the source's lips meeting must leave the
  target's meeting (median gap below :data:`~core.authoring.contacts.SHUT` × the contour's span);
- ``symmetry``: for a key with a side (``…Left``/``…_L``) and its partner, ``‖Δ_L − H Δ_R∘m‖ / max(‖Δ_L‖,
  ‖Δ_R‖)`` with ``H`` the reflection across the target's mirror plane and ``m`` the mirror map (barycentric
  on the closest triangle at each vertex's reflection, :func:`mirror_map`);
  fails when it exceeds the source pair's own by more than :data:`MAX_ASYMMETRY` (authored pairs on the
  shared heads differ by up to 0.43 through their imperfect mirror maps; a transfer must not add to that);
- ``size``: the key's largest displacement over the target's diagonal against the source's over its own
  (feature-normalised by the head size); fails outside [1/:data:`MAX_SIZE_RATIO`, :data:`MAX_SIZE_RATIO`];
- ``parts``: the parts each key moves and the parts kept still, with the reason (:mod:`.parts`).

A failed check is an ``error`` issue and makes the status WARNING (the command line then exits 1).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..names import canonical_name
from ..result import Issue, Status
from ..symmetry import counterpart_name
from .contacts import SHUT, Opening, gap_fractions, gap_left
from .mesh import bbox_diagonal, closest_on_triangles, symmetry_plane
from .parts import PartPlan

__all__ = ["MAX_GAP_LEFT", "CROSSING", "MAX_ASYMMETRY", "MAX_SIZE_RATIO", "check_keys", "mirror_map"]

MAX_GAP_LEFT = 0.2
CROSSING = -0.05
MAX_ASYMMETRY = 0.25
MAX_SIZE_RATIO = 3.0


def mirror_map(verts: np.ndarray, tris: np.ndarray | None = None) -> tuple:
    """Mirror map across the mirror plane: (M, reflection H (3, 3)).  ``M`` (n, n) sparse interpolates a
    per-vertex field at each vertex's reflection: barycentric on the closest triangle when ``tris`` is given
    (exact for a field linear over the surface: no mesh needs mirror-symmetric topology), else the closest
    vertex."""
    n, offset, _ = symmetry_plane(verts)
    H = np.eye(3) - 2.0 * np.outer(n, n)
    reflected = verts @ H + 2.0 * offset * n
    N = verts.shape[0]
    if tris is None or len(tris) == 0:
        _, m = cKDTree(verts).query(reflected)
        return sp.csr_matrix((np.ones(N), (np.arange(N), m)), shape=(N, N)), H
    tri, bary, _, _ = closest_on_triangles(reflected, verts, tris)
    rows = np.repeat(np.arange(N), 3)
    return sp.csr_matrix((bary.ravel(), (rows, tris[tri].ravel())), shape=(N, N)), H


def _side(canon):
    for s in ("Left", "Right"):
        if canon.endswith(s):
            return s
    return None


def _gap_checks(o: Opening, S, SD, T, TD):
    """(gap left on target, gap left on source, target crossings, source crossings) for one opening, per key."""
    g_t = gap_fractions(T, TD, o.target_pairs)
    g_s = gap_fractions(S, SD, o.source_pairs)
    return (gap_left(T, TD, o.target_pairs), gap_left(S, SD, o.source_pairs), (g_t < CROSSING).sum(axis=1),
            (g_s < CROSSING).sum(axis=1))


def check_keys(src_verts: np.ndarray, src_deltas: np.ndarray, names: Sequence[str], dst_verts: np.ndarray,
               deltas: np.ndarray, *, openings: Sequence[Opening] = (), plan: PartPlan | None = None,
               moved: dict | None = None, src_tris: np.ndarray | None = None,
               dst_tris: np.ndarray | None = None) -> tuple:
    """Check every transferred key.

    Parameters
    ----------
    src_verts : ndarray (n_s, 3)
    src_deltas : ndarray (k, n_s, 3)
    names : sequence of str (k,)
        The keys' names (their side and ``eyeBlink`` are read through :func:`core.names.canonical_name`).
    dst_verts : ndarray (n_t, 3)
    deltas : ndarray (k, n_t, 3)
        The transferred keys.
    openings : sequence of Opening
    plan : PartPlan, optional
    moved : dict, optional
        Part → largest displacement (:func:`~core.authoring.parts.move_parts`).
    src_tris, dst_tris : ndarray of int (f, 3), optional
        The meshes' triangles: the mirror maps then interpolate on the surface (see :func:`mirror_map`).

    Returns
    -------
    keys : list of dict
        Per key: ``name``, ``size_ratio``, ``gap_left`` / ``source_gap_left`` (eye keys), ``crossings``,
        ``asymmetry`` (sided keys), ``parts_moved``, ``failed`` (names of the failed checks).
    issues : list of Issue
        One ``error`` issue per failed check, naming the key (a refused quality check: the key is usable but
        must be looked at; :class:`~core.authoring.report.TransferReport` then exits 1).
    status : Status
        WARNING when any check failed, else OK.
    """
    k = len(names)
    canon = [canonical_name(n) for n in names]
    ds, dt = max(bbox_diagonal(src_verts), 1e-300), max(bbox_diagonal(dst_verts), 1e-300)
    ps = np.abs(src_deltas).reshape(k, -1).max(axis=1) / ds if k else np.zeros(0)
    pt = np.abs(deltas).reshape(k, -1).max(axis=1) / dt if k else np.zeros(0)
    keys = [{"name": str(n), "size_ratio": float(pt[i] / ps[i]) if ps[i] > 0 else None, "failed": []}
            for i, n in enumerate(names)]
    for i, key in enumerate(keys):
        r = key["size_ratio"]
        if r is not None and ps[i] > 1e-4 and not 1.0 / MAX_SIZE_RATIO <= r <= MAX_SIZE_RATIO:
            key["failed"].append("size")
    _check_openings(keys, canon, openings, src_verts, src_deltas, dst_verts, deltas)
    _check_symmetry(keys, canon, names, src_verts, src_deltas, dst_verts, deltas, src_tris, dst_tris)
    if plan is not None:
        _parts(keys, plan, deltas, dt)
    issues = [Issue("error", f"transfer_{c}", f"{key['name']}: {_MESSAGES[c](key)}", (key["name"],))
              for key in keys for c in key["failed"]]
    return keys, issues, Status.WARNING if issues else Status.OK


_MESSAGES = {
    "size": lambda k: f"moves {k['size_ratio']:.2f}× as far as the source's (relative to head size)",
    "gap": lambda k: f"leaves {100 * k['gap_left']:.0f} % of the lid gap open at full weight (source "
                     f"{100 * k['source_gap_left']:.0f} %)",
    "crossing": lambda k: f"{k['crossings']} lid points pass through the other lid",
    "symmetry": lambda k: f"differs from its mirrored partner by {100 * k['asymmetry']:.0f} %",
    "lips": lambda k: "leaves the lips apart where the source's meet",
}


def _shut(V, D, pairs):
    """Per shape (k,): is the opening shut after the shape (median gap below SHUT × the contour's span)?"""
    span = max(float(np.linalg.norm(V[pairs[0, 0]] - V[pairs[-1, 0]])), 1e-300)
    G = V[pairs[:, 0]] - V[pairs[:, 1]]
    gap = np.linalg.norm(G[None] + D[:, pairs[:, 0]] - D[:, pairs[:, 1]], axis=2)
    return np.median(gap, axis=1) < SHUT * span


def _check_lips(keys, o, S, SD, T, TD):
    """An opening shut at rest (lips): a key that leaves the source's shut must leave the target's shut."""
    src, dst = _shut(S, SD, o.source_pairs), _shut(T, TD, o.target_pairs)
    for i, key in enumerate(keys):
        key["lips_meet"] = bool(dst[i])
        if src[i] and not dst[i]:
            key["failed"].append("lips")


def _check_openings(keys, canon, openings, S, SD, T, TD):
    for o in openings:
        if o.mode == "offset":
            _check_lips(keys, o, S, SD, T, TD)
            continue
        side = {"L": "Left", "R": "Right"}.get(o.name[-1])
        left_t, left_s, cross_t, cross_s = _gap_checks(o, S, SD, T, TD)
        for i, c in enumerate(canon):
            if c.startswith("eyeBlink") and _side(c) == side:
                keys[i]["gap_left"], keys[i]["source_gap_left"] = float(left_t[i]), float(left_s[i])
                if left_s[i] <= MAX_GAP_LEFT < left_t[i]:
                    keys[i]["failed"].append("gap")
            keys[i]["crossings"] = keys[i].get("crossings", 0) + int(cross_t[i])
            if cross_t[i] > 0 and cross_s[i] == 0 and "crossing" not in keys[i]["failed"]:
                keys[i]["failed"].append("crossing")


def _asymmetry(d_l, d_r, m, H):
    mirrored = (m @ d_r) @ H
    scale = max(np.linalg.norm(d_l), np.linalg.norm(d_r), 1e-300)
    return float(np.linalg.norm(d_l - mirrored) / scale)


def _check_symmetry(keys, canon, names, S, SD, T, TD, src_tris, dst_tris):
    index = {c: i for i, c in enumerate(canon)}
    pairs = [(i, index[counterpart_name(c)]) for i, c in enumerate(canon)
             if _side(c) == "Left" and counterpart_name(c) in index]
    if not pairs:
        return
    mt, Ht = mirror_map(T, dst_tris)
    ms, Hs = mirror_map(S, src_tris)
    for i, j in pairs:
        a_t, a_s = _asymmetry(TD[i], TD[j], mt, Ht), _asymmetry(SD[i], SD[j], ms, Hs)
        for x in (i, j):
            keys[x]["asymmetry"] = a_t
            if a_t > a_s + MAX_ASYMMETRY:
                keys[x]["failed"].append("symmetry")


def _parts(keys, plan, deltas, diag):
    for p, kind in plan.kinds.items():
        if kind == "skin":
            continue
        idx = plan.labels == p
        for i, key in enumerate(keys):
            if np.abs(deltas[i, idx]).max(initial=0.0) > 1e-4 * diag:
                key.setdefault("parts_moved", []).append(int(p))
