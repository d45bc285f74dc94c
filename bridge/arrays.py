"""Bulk conversion between Blender collections and numpy arrays."""
from __future__ import annotations

import numpy as np


def read_float(collection, attr: str, width: int) -> np.ndarray:
    """``collection.foreach_get(attr)`` into a float32 array of shape (len, width)."""
    buf = np.empty(len(collection) * width, dtype=np.float32)
    collection.foreach_get(attr, buf)
    return buf.reshape(-1, width) if width > 1 else buf


def write_float(collection, attr: str, values) -> None:
    """``collection.foreach_set(attr)`` from any array, via contiguous float32."""
    buf = np.ascontiguousarray(values, dtype=np.float32).ravel()
    collection.foreach_set(attr, buf)


def read_matrices(collection, attr: str = "matrix") -> np.ndarray:
    """4×4 matrix property of every item, shape (len, 4, 4), row-major (math convention).

    RNA stores matrices column-major, so the raw buffer is transposed.
    """
    buf = np.empty(len(collection) * 16, dtype=np.float32)
    collection.foreach_get(attr, buf)
    return buf.reshape(-1, 4, 4).transpose(0, 2, 1).astype(np.float64)


def matrix(m) -> np.ndarray:
    """A ``mathutils.Matrix`` as a float64 ndarray (row-major)."""
    return np.array([list(row) for row in m], dtype=np.float64)
