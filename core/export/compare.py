"""Round-trip measures: how far a re-imported mesh is from the source, per frame, relative to its size.

Exporters may split vertices (glTF writes one vertex per corner attribute set) and importers may reorder
them, so vertices are matched by position first; every copy of a split vertex follows its source vertex.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from ..blendshape import bounding_box_diagonal
from ..errors import ErrorCode
from ..result import ShapeSpaceError
from ..validate import array

__all__ = ["match_vertices", "roundtrip_error"]


def match_vertices(source: ArrayLike, imported: ArrayLike) -> np.ndarray:
    """For every imported vertex, the source vertex it stands for (nearest at one shared frame).

    Parameters
    ----------
    source : array_like, shape (p, 3)
        Source positions (world space) at a frame where both are compared.
    imported : array_like, shape (q, 3)
        Re-imported positions at the same frame.

    Returns
    -------
    ndarray of int, shape (q,)
        Index into ``source``; the identity when the counts agree and the vertices line up already.
    """
    src = array(source, "source", shape=(None, 3))
    imp = array(imported, "imported", shape=(None, 3))
    if not len(src) or not len(imp):
        raise ShapeSpaceError("a mesh without vertices cannot be compared", ErrorCode.EMPTY)
    if src.shape == imp.shape:
        tol = 1e-4 * max(bounding_box_diagonal(src), 1e-12)
        if np.abs(src - imp).max() <= tol:
            return np.arange(len(imp))
    return cKDTree(src).query(imp)[1].astype(np.int64)


def roundtrip_error(source: ArrayLike, imported: ArrayLike, mapping: ArrayLike) -> np.ndarray:
    """Max vertex distance per frame relative to the source's bounding-box diagonal at that frame.

    Parameters
    ----------
    source : array_like, shape (f, p, 3)
    imported : array_like, shape (f, q, 3)
    mapping : array_like of int, shape (q,)
        From :func:`match_vertices`.

    Returns
    -------
    ndarray, shape (f,)
        ``max_i ‖imported[t, i] − source[t, mapping[i]]‖ / diag(source[t])``.
    """
    src = array(source, "source", shape=(None, None, 3))
    imp = array(imported, "imported", shape=(len(src), None, 3))
    idx = np.asarray(mapping, dtype=np.int64)
    if idx.shape != (imp.shape[1],) or (idx.size and (idx.min() < 0 or idx.max() >= src.shape[1])):
        raise ShapeSpaceError(f"mapping must index the {src.shape[1]} source vertices for each of the "
                              f"{imp.shape[1]} imported ones", ErrorCode.SHAPE)
    out = np.empty(len(src))
    for t in range(len(src)):
        dist = np.linalg.norm(imp[t] - src[t][idx], axis=1)
        out[t] = dist.max() / max(bounding_box_diagonal(src[t]), 1e-300)
    return out
