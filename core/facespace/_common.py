"""Checks and constants shared by the face-space modules (not part of the public API).

Array and scalar checks go through :mod:`core.validate`; :func:`shaped` only adds the
face-space way of spelling an expected shape in the message (``"(n,) or (f, n)"``,
``"(..., 3) (3 channels)"``) where a single :func:`core.validate.array` shape cannot.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from .. import validate
from ..blendshape import BlendshapeModel
from ..errors import ErrorCode
from ..result import ShapeSpaceError

EPS = np.finfo(np.float64).eps
#: Relative "moves no vertex" threshold (× the neutral's bounding-box diagonal), as in ``diagnose_model``.
REL_TOL = 1e-7


def check_model(model: object, need_targets: bool = True) -> None:
    """Refuse anything but a :class:`BlendshapeModel` (and, with ``need_targets``, an empty rig)."""
    if not isinstance(model, BlendshapeModel):
        raise ShapeSpaceError(f"model must be a BlendshapeModel, got {type(model).__name__}", ErrorCode.TYPE)
    if need_targets and (model.n_targets == 0 or model.n_vertices == 0):
        raise ShapeSpaceError(f"model is an empty rig ({model.n_targets} targets, "
                              f"{model.n_vertices} vertices)", ErrorCode.EMPTY)


def shaped(x: ArrayLike, name: str, spec: str, ndims: Sequence[int] | None = None,
           last: int | None = None) -> np.ndarray:
    """``x`` as a finite float64 array (:func:`core.validate.array`) with ``ndim`` in ``ndims`` and last
    dimension ``last``; a wrong shape is reported as ``"{name} must have shape {spec}, got …"``."""
    arr = validate.array(x, name, finite=False)
    if (ndims is not None and arr.ndim not in ndims) or \
            (last is not None and (arr.ndim == 0 or arr.shape[-1] != last)):
        raise ShapeSpaceError(f"{name} must have shape {spec}, got {arr.shape}", ErrorCode.SHAPE)
    return validate.array(arr, name)


def count(x: object, name: str, minimum: int, what: str = "integer") -> int:
    """``x`` as an int ≥ ``minimum`` (whole numbers only), code ``range``."""
    try:
        ok = int(x) == x and x >= minimum
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        kind = "positive" if minimum == 1 else ("non-negative" if minimum == 0 else f"≥ {minimum}")
        raise ShapeSpaceError(f"{name} must be a {kind} {what}, got {x}", ErrorCode.RANGE)
    return int(x)
