"""Model transfer by deformation transfer (thesis 3.4.1; Sumner & Popović 2004).

For every source triangle ``j`` the deformation gradient of a shape is ``Q_j = F'_j F_j⁻¹`` with the frame
``F = [v₂ − v₁, v₃ − v₁, n / √‖n‖]`` (``n = (v₂ − v₁) × (v₃ − v₁)``: Sumner's fourth vertex).  The registration
is itself a deformation ``W_j = R_j F_j⁻¹`` (``R_j`` the registered frame), so in target space the shape's
gradient is ``W_j Q_j W_j⁻¹ = R_j (F_j⁻¹ F'_j) R_j⁻¹`` — local rotation and stretch of the registration are
taken out.  Each target triangle takes the gradient of the source triangle under its centroid
(:class:`~core.authoring.registration.Correspondence`), and the target displacements ``d`` solve

    min_d  Σ_j a_j ‖∇_j d − (Q_j − I) P_j‖²_F + ε ‖d − d₀‖²_M

(``∇_j`` the gradient of a piecewise-linear function on target triangle ``j``, ``a_j`` its area, ``P_j`` the
projector onto its plane — Sumner's fourth vertex is used on the source side, the target side is the
equivalent gradient-domain (cotangent) form; ``d₀`` the closest-point copy of the deltas rotated and scaled by
the landmark similarity, ``M`` the lumped mass).  The ``ε`` term fixes each part's translation, places
vertices that are in no triangle, and — at the default ``3·10⁻²`` of the Laplacian's scale — pulls towards
the copy where the transferred gradients disagree with each other (on the shared ARKit heads this lowered
the mean relative error against the authored shapes at every pair, e.g. facecap → FBHead 0.663 → 0.635,
facecap → ICT 1.61 → 1.01, compared with ``ε = 10⁻⁶``, measured with exactly interpolated landmarks).
Source triangles the registration folded or
stretched more than ``max_stretch`` give no constraint (their target triangles follow their neighbours).
The normal matrix ``∇ᵀA∇ + εM`` (the cotangent Laplacian plus a mass term) is factorised
once with :func:`scipy.sparse.linalg.splu` and re-used for every shape and coordinate (a chunk of shapes'
three coordinates in one multi-column solve); the gradients are evaluated only on the source triangles under
some target triangle, and the projection and area weights are folded into one sparse ``∇ᵀ A P`` built once.

Target parts without a source counterpart (eyes a source does not have) stay still (reported), or are
refused with ``unmatched_parts="refuse"``.
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.linalg import splu

from .. import validate
from ..errors import ErrorCode
from ..names import canonical_name
from ..progress import ProgressFn, notify
from ..result import Issue, Result, ShapeSpaceError, Status
from .contacts import Opening, carried, constraint_matrix, gap_changes
from .mesh import check_mesh, face_normals, inv3
from .registration import Correspondence

__all__ = ["Transfer", "TransferredShapes", "transfer_shapes", "convert_name", "NAMINGS", "frames"]

NAMINGS = ("arkit", "suffix", "pascal", "source")


def frames(verts: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Sumner's triangle frames ``[v₂ − v₁, v₃ − v₁, n/√‖n‖]`` as (..., f, 3, 3) (columns); ``verts`` (..., n, 3)."""
    a, b, c = verts[..., tris[:, 0], :], verts[..., tris[:, 1], :], verts[..., tris[:, 2], :]
    e1, e2 = b - a, c - a
    n = np.cross(e1, e2)
    ln = np.sqrt(np.linalg.norm(n, axis=-1, keepdims=True))
    n = n / np.where(ln > 0, ln, 1.0)
    return np.stack([e1, e2, n], axis=-1)


def _safe_inv(F):
    inv, det = inv3(F)
    scale = np.abs(F).max(axis=(-1, -2)) ** 3
    ok = np.abs(det) > 1e-12 * np.where(scale > 0, scale, 1.0)
    return np.where(ok[..., None, None], inv, 0.0), ok


def _gradient_operator(V, T):
    """Per-triangle gradient of a piecewise-linear function: sparse (3f, n), rows 3j..3j+2 = ∇ on triangle j;
    also areas (f,) and unit normals (f, 3)."""
    nrm, area = face_normals(V, T)
    f = T.shape[0]
    inv2a = np.where(area > 0, 1.0 / (2.0 * np.where(area > 0, area, 1.0)), 0.0)
    p1, p2, p3 = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    grads = [np.cross(nrm, p3 - p2), np.cross(nrm, p1 - p3), np.cross(nrm, p2 - p1)]   # ∇φ_i · 2a
    rows, cols, vals = [], [], []
    for i in range(3):
        g = grads[i] * inv2a[:, None]
        for r in range(3):
            rows.append(3 * np.arange(f) + r)
            cols.append(T[:, i])
            vals.append(g[:, r])
    G = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * f, V.shape[0]))
    return G, area, nrm


def _projected_operator(G, weight, nrm, faces):
    """``∇ᵀ A P`` restricted to the columns of ``faces``: sparse (n, 3·len(faces)), column ``3i + m`` of face
    ``j = faces[i]`` is ``Σ_r a_j P_j[r, m] ∇_j[r]`` (``P_j = I − n_j n_jᵀ`` the projector onto its plane)."""
    m = faces.size
    P = np.eye(3)[None] - nrm[faces, :, None] * nrm[faces, None, :]                     # (m, 3, 3)
    rows = (3 * faces[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)   # [i, r, m] → 3 j + r
    cols = (3 * np.arange(m)[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
    Pb = sp.csr_matrix(((weight[faces, None, None] * P).ravel(), (rows.ravel(), cols.ravel())),
                       shape=(G.shape[0], 3 * m))
    return (G.T @ Pb).tocsr()


class Transfer:
    """Deformation transfer from one source mesh onto one target mesh, factorised once.

    Parameters
    ----------
    src_verts : array_like (n_s, 3)
    src_tris : array_like of int (f_s, 3)
    dst_verts : array_like (n_t, 3)
    dst_tris : array_like of int (f_t, 3)
    corr : Correspondence
        From :func:`~core.authoring.registration.register` on the same meshes.
    unmatched_parts : {"keep", "refuse"}
        Target parts without a source counterpart (teeth, eyeballs the source has not) stay still (``keep``,
        listed in :attr:`issues`) or raise ``ShapeSpaceError`` naming the part (``refuse``).  (Moving them
        rigidly with the nearest source surface was tried and measured worse on the shared heads.)
    anchor : float
        ``ε`` relative to the Laplacian's scale (see the module docstring).
    max_stretch : float
        Source triangles whose registration gradient is folded or has a singular-value ratio above this give
        no constraint (:attr:`folded` counts them).
    openings : sequence of Opening
        Eye and mouth openings; the closure of those open at rest is carried from source to target
        (:func:`~core.authoring.contacts.carried`).
    contact_weight : float
        Weight of the contact rows relative to the mean diagonal of the Laplacian term.
    """

    def __init__(self, src_verts: ArrayLike, src_tris: ArrayLike, dst_verts: ArrayLike, dst_tris: ArrayLike,
                 corr: Correspondence, *, unmatched_parts: str = "keep", anchor: float = 3e-2,
                 max_stretch: float = 8.0, openings: Sequence[Opening] = (), contact_weight: float = 10.0):
        S, ST = check_mesh(src_verts, src_tris, "source")
        T, TT = check_mesh(dst_verts, dst_tris, "target")
        validate.choice(unmatched_parts, "unmatched_parts", ("keep", "refuse"))
        if corr.registered.shape != S.shape or corr.tri.shape != (T.shape[0],) or corr.face_tri.shape != (TT.shape[0],):
            raise ShapeSpaceError("the correspondence was made for other meshes (vertex or triangle counts differ): "
                                  "register again", ErrorCode.VERTEX_COUNT_MISMATCH)
        self.issues = []
        unmatched = corr.unmatched_parts()
        if unmatched:
            text = ", ".join(f"part {p} ({n} vertices from vertex {v})" for p, n, v in unmatched)
            if unmatched_parts == "refuse":
                raise ShapeSpaceError(f"the target has parts with no counterpart on the source: {text}; separate "
                                      f"them or register with a source that has them", ErrorCode.NO_MAPPING)
            self.issues.append(Issue("warning", "unmatched_parts", f"left still (no source counterpart): {text}",
                                     tuple(str(p) for p, _, _ in unmatched)))
        self.S, self.ST, self.T, self.TT, self.corr = S, ST, T, TT, corr
        self.n_s, self.n_t = S.shape[0], T.shape[0]
        F = frames(S, ST)
        Finv, ok_s = _safe_inv(F)
        R = frames(corr.registered, ST)
        Rinv, ok_r = _safe_inv(R)
        W = R @ Finv                                                          # registration gradient
        sv = np.linalg.svd(W, compute_uv=False)
        good = (np.linalg.det(W) > 0) & (sv[:, 0] <= max_stretch * np.maximum(sv[:, 2], 1e-300))
        self._ok_src = ok_s & ok_r & good
        self.folded = int((~good).sum())
        G, area, nrm = _gradient_operator(T, TT)
        ft = corr.face_tri
        face_src = np.where(ft >= 0, ft, 0)
        self._face_ok = (ft >= 0) & self._ok_src[face_src] & (area > 0)
        # folded / over-stretched source triangles give no constraint; unmatched parts are held still (Q = I)
        weight = np.where(self._face_ok | (ft < 0), area, 0.0)
        self._a = np.repeat(weight, 3)
        K = (G.T @ sp.diags(self._a) @ G).tocsc()
        # only the target triangles with a source gradient have a nonzero right-hand side (Q − I = 0 elsewhere):
        # H = ∇ᵀ A P over those, so that the right-hand side is H (Q − I) (the projector folded in once)
        ok = np.flatnonzero(self._face_ok)
        self._src_used, self._slot = np.unique(face_src[ok], return_inverse=True)
        self._W, self._Rinv_used = W[self._src_used], Rinv[self._src_used]
        self._ST_used = ST[self._src_used]
        self._H = _projected_operator(G, weight, nrm, ok)
        mass = np.zeros(self.n_t)
        for k in range(3):
            np.add.at(mass, TT[:, k], area / 3.0)
        loose = mass <= 0
        mass[loose] = mass[~loose].mean() if (~loose).any() else 1.0
        self._eps = anchor * K.diagonal().sum() / mass.sum()
        self._M = self._eps * mass
        self.openings = carried(openings)
        self._C = constraint_matrix(self.openings, self.n_t)
        self._wc = contact_weight * K.diagonal().mean()
        K = K + self._wc * (self._C.T @ self._C)
        self._lu = splu((K + sp.diags(self._M)).tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                        options={"SymmetricMode": True})
        # barycentric interpolation (n_t, n_s) of the closest registered source point (zero rows: unmapped)
        rows = np.repeat(np.arange(self.n_t), 3)
        tri = np.where(corr.tri >= 0, corr.tri, 0)
        vals = (corr.bary * (corr.tri >= 0)[:, None]).ravel()
        self._B = sp.csr_matrix((vals, (rows, ST[tri].ravel())), shape=(self.n_t, self.n_s))
        s, Rot, _ = corr.similarity
        self._sR = s * np.asarray(Rot)

    def naive(self, src_deltas: ArrayLike) -> np.ndarray:
        """The baseline: each target vertex copies the delta at its closest registered source point,
        rotated and scaled by the landmark similarity.

        Parameters
        ----------
        src_deltas : array_like (k, n_s, 3)

        Returns
        -------
        ndarray (k, n_t, 3)
        """
        D = validate.array(src_deltas, "source deltas", shape=(None, self.n_s, 3))
        out = np.einsum("ij,kvj->kvi", self._sR, D)
        return np.stack([self._B @ out[i] for i in range(D.shape[0])]) if D.shape[0] else np.zeros((0, self.n_t, 3))

    def solve(self, src_deltas: ArrayLike, chunk: int = 8) -> np.ndarray:
        """Transfer source shapes (deltas from the source neutral) onto the target.

        Parameters
        ----------
        src_deltas : array_like (k, n_s, 3)
        chunk : int
            Shapes solved together (memory: ~``chunk`` × 9 × f_t floats).

        Returns
        -------
        ndarray (k, n_t, 3)
            Target deltas.
        """
        D = validate.array(src_deltas, "source deltas", shape=(None, self.n_s, 3))
        k = D.shape[0]
        out = np.empty((k, self.n_t, 3))
        I3 = np.eye(3)
        n_ok = self._slot.size
        for c0 in range(0, k, chunk):
            sl = slice(c0, min(k, c0 + chunk))
            kk = sl.stop - sl.start
            Fd = frames(self.S[None] + D[sl], self._ST_used)                  # (kk, u, 3, 3): used source faces
            Q = (self._W[None] @ Fd) @ self._Rinv_used[None]                   # R F⁻¹ F' R⁻¹ (registered space)
            Q -= I3
            # rows 3j + m (the target triangles with a source gradient), columns 3s + c
            rhs_g = Q.transpose(1, 3, 0, 2)[self._slot].reshape(3 * n_ok, 3 * kk)
            rhs = self._H @ rhs_g
            # the anchor d₀ (:meth:`naive`), built directly in the (n_t, 3·kk) layout of the right-hand side
            rotated = np.einsum("ij,kvj->vki", self._sR, D[sl]).reshape(self.n_s, 3 * kk)
            rhs += self._M[:, None] * (self._B @ rotated)
            if self.openings:
                z = gap_changes(self.openings, self.S, D[sl], self.T)                # (kk, m, 3)
                rhs += self._wc * (self._C.T @ z.transpose(1, 0, 2).reshape(-1, 3 * kk))
            # three columns (one shape) per call: ~2× faster than one by one, and as fast as more at once
            # without letting OpenBLAS thread SuperLU's wider triangular solves (3× the CPU time on a busy machine)
            x = np.empty((self.n_t, 3 * kk), order="F")
            for col in range(0, 3 * kk, 3):
                x[:, col:col + 3] = self._lu.solve(np.asfortranarray(rhs[:, col:col + 3]))
            out[sl] = x.T.reshape(kk, 3, self.n_t).transpose(0, 2, 1)
        return out


@dataclass
class TransferredShapes:
    """Shapes transferred onto the target.

    Attributes
    ----------
    names : list of str
        Target-convention names, in input order.
    source_names : list of str
    deltas : ndarray (k, n_t, 3)
        Offsets to add to the target neutral.
    empty : list of str
        Source shapes that move nothing (their result is an all-zero delta).
    metadata : list of dict
        Per shape, passed through with names inside renamed to the chosen convention.
    """

    names: list
    source_names: list
    deltas: np.ndarray
    empty: list = field(default_factory=list)
    metadata: list = field(default_factory=list)


_PASCAL_SPLIT = ("Left", "Right")


def convert_name(name: str, naming: str) -> str:
    """A channel name in another naming convention.

    Parameters
    ----------
    name : str
        In any convention ``core.names.canonical_name`` understands.
    naming : {"arkit", "suffix", "pascal", "source"}
        ``eyeBlinkLeft``, ``eyeBlink_L``, ``EyeBlinkLeft``, or unchanged.

    Returns
    -------
    str
    """
    validate.choice(naming, "naming", NAMINGS)
    if naming == "source":
        return name
    canon = canonical_name(name)
    if naming == "arkit":
        return canon
    if naming == "pascal":
        return canon[:1].upper() + canon[1:]
    for side, suffix in zip(_PASCAL_SPLIT, ("_L", "_R")):
        if canon.endswith(side) and len(canon) > len(side):
            return canon[: -len(side)] + suffix
    return canon


def _rename_meta(meta, rename):
    out = {}
    for key, value in meta.items():
        if isinstance(value, str) and key in ("name", "inbetween_of", "primary", "relative_to"):
            out[key] = rename.get(value, value)
        elif isinstance(value, (list, tuple)) and key in ("combination", "inputs"):
            out[key] = [rename.get(v, v) if isinstance(v, str) else v for v in value]
        else:
            out[key] = value
    return out


def transfer_shapes(src_verts: ArrayLike, src_tris: ArrayLike, src_deltas: ArrayLike, src_names: Sequence[str],
                    dst_verts: ArrayLike, dst_tris: ArrayLike, corr: Correspondence, *, naming: str = "arkit",
                    metadata: Sequence[dict] | None = None, existing_names: Sequence[str] = (),
                    unmatched_parts: str = "keep", empty_tol: float = 1e-9,
                    progress: ProgressFn | None = None) -> Result:
    """Transfer every source shape onto the target mesh (deformation transfer, factorised once).

    Parameters
    ----------
    src_verts : array_like (n_s, 3)
    src_tris : array_like of int (f_s, 3)
    src_deltas : array_like (k, n_s, 3)
    src_names : sequence of str (k,)
    dst_verts : array_like (n_t, 3)
    dst_tris : array_like of int (f_t, 3)
    corr : Correspondence
    naming : {"arkit", "suffix", "pascal", "source"}
    metadata : sequence of dict (k,), optional
        Slider ranges, vertex-group masks, in-between/combination descriptions: passed through, with
        names inside (``name``, ``inbetween_of``, ``primary``, ``relative_to``, ``combination``, ``inputs``)
        converted to ``naming``.
    existing_names : sequence of str
        The target's current shape keys: a clash (same name after conversion) is refused, never
        overwritten (code ``duplicate_name``).
    unmatched_parts : {"keep", "refuse"}
    empty_tol : float
        A source shape whose largest displacement is ≤ ``empty_tol`` × the source's size is empty.
    progress : callable (fraction) -> None, optional
        :mod:`core.progress` protocol; raising :class:`~core.progress.Cancelled` from it stops the transfer.

    Returns
    -------
    Result
        ``value``: :class:`TransferredShapes`; WARNING when shapes were empty or parts were left still;
        ``diagnostics["seconds"]``.
    """
    t0 = time.perf_counter()
    S, _ = check_mesh(src_verts, src_tris, "source")
    D = validate.array(src_deltas, "source deltas", shape=(None, S.shape[0], 3))
    names = [str(n) for n in src_names]
    if len(names) != D.shape[0]:
        raise ShapeSpaceError(f"{len(names)} source names for {D.shape[0]} shapes", ErrorCode.SHAPE)
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise ShapeSpaceError(f"source shape name {dup!r} occurs twice", ErrorCode.DUPLICATE_NAME)
    if D.shape[0] == 0:
        raise ShapeSpaceError("the source rig has no shapes to transfer", ErrorCode.NO_SHAPE_KEYS)
    meta = [dict(m) for m in metadata] if metadata is not None else [{} for _ in names]
    if len(meta) != len(names):
        raise ShapeSpaceError(f"{len(meta)} metadata entries for {len(names)} shapes", ErrorCode.SHAPE)
    new = [convert_name(n, naming) for n in names]
    if len(set(new)) != len(new):
        dup = next(n for n in new if new.count(n) > 1)
        raise ShapeSpaceError(f"two source shapes become {dup!r} in the {naming} convention: choose 'source' "
                              f"naming or rename one", ErrorCode.DUPLICATE_NAME)
    clash = [n for n in new if n in set(existing_names)]
    if clash:
        raise ShapeSpaceError(f"the target already has a shape key {clash[0]!r} ({len(clash)} clash in all): "
                              f"rename or delete them first; nothing was overwritten", ErrorCode.DUPLICATE_NAME)
    notify(progress, 0.0)
    tr = Transfer(src_verts, src_tris, dst_verts, dst_tris, corr, unmatched_parts=unmatched_parts)
    size = max(float(np.ptp(S, axis=0).max()), 1e-300)
    peak = np.abs(D).reshape(D.shape[0], -1).max(axis=1) if D.size else np.zeros(0)
    empty = peak <= empty_tol * size
    out = np.zeros((D.shape[0], tr.n_t, 3))
    live = np.flatnonzero(~empty)
    step = 8
    for i in range(0, live.size, step):
        idx = live[i:i + step]
        out[idx] = tr.solve(D[idx])
        notify(progress, min(1.0, (i + step) / max(live.size, 1)))
    rename = dict(zip(names, new))
    meta_out = [_rename_meta({**m, "name": m.get("name", n)}, rename) for m, n in zip(meta, names)]
    issues = list(tr.issues)
    empty_names = [new[i] for i in np.flatnonzero(empty)]
    if empty_names:
        issues.insert(0, Issue("warning", "empty_target", f"empty on the source (result is an empty delta): "
                                                          f"{', '.join(empty_names)}", tuple(empty_names)))
    value = TransferredShapes(new, names, out, empty_names, meta_out)
    msg = f"transferred {live.size} shapes" + (f"; {len(empty_names)} empty" if empty_names else "")
    if tr.issues:
        msg += "; " + tr.issues[0].message
    return Result(value, status=Status.WARNING if issues else Status.OK, message=msg, issues=issues,
                  diagnostics={"seconds": time.perf_counter() - t0})
