"""Scalar targets driven from pose space (thesis 7.3.3).

Besides correctives, a pose space can drive any number of scalars — shape-key
values, bone channels, custom properties: the rigger records their values at
each example and an RBF interpolant (Eq. 8.4, weight decay Eq. 8.3) carries
them between examples.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .. import rbf, validate
from ..errors import ErrorCode
from ..result import ShapeSpaceError
from .psd import affine_determined, default_epsilon, regularisation

__all__ = ["ScalarDriver", "train_driver", "train_target_driver"]


@dataclass
class ScalarDriver:
    """Scalar targets (shape-key values, bone channels, properties) driven from pose space (7.3.3).

    Attributes
    ----------
    names : list of str
        One per target, in column order.
    interpolant : RBFInterpolant
        Fitted to the (K, t) target values.
    """

    names: list
    interpolant: object

    def __call__(self, pose: ArrayLike) -> dict:
        """``{name: value}`` of every target at ``pose`` (d,)."""
        vals = self.interpolant(np.asarray(pose, dtype=np.float64)[None])[0]
        return dict(zip(self.names, np.atleast_1d(vals).tolist()))


def train_driver(poses: ArrayLike, values: ArrayLike, names: Sequence[str], kernel: str = "thin_plate_spline",
                 epsilon: float = 1.0, degree: int | None = None, smoothing: float = 0.0) -> ScalarDriver:
    """Interpolate named scalar targets over pose space (7.3.3).

    Parameters
    ----------
    poses : array_like, shape (K, d)
        Example poses.
    values : array_like, shape (K, t) or (K,)
        The targets' values at the examples, one column per name.
    names : sequence of str, length t
    kernel, epsilon, smoothing
        As :func:`core.rbf.fit_rbf`; smoothing is raised for (near-)duplicate poses.
    degree : int, optional
        Polynomial degree; default linear when the examples determine it, else constant (with a
        multiquadric in place of a kernel that needs the linear part).

    Returns
    -------
    ScalarDriver
    """
    X = validate.array(poses, "poses", ndim=2)
    V = validate.array(values, "values")
    if V.ndim < 1 or V.shape[0] != X.shape[0]:
        raise ShapeSpaceError(f"values must have {X.shape[0]} rows (one per example), got shape {V.shape}",
                              ErrorCode.SHAPE)
    V = V.reshape(X.shape[0], -1)
    if V.shape[1] != len(names):
        raise ShapeSpaceError(f"values have {V.shape[1]} columns for {len(names)} names", ErrorCode.SHAPE)
    if degree is None:
        degree = 1 if affine_determined(X) else 0
        if degree == 0 and rbf.KERNELS[kernel][1] >= 1:
            kernel = "multiquadric"
    smoothing = regularisation(X, smoothing)
    return ScalarDriver(list(names), rbf.fit_rbf(X, V, kernel, epsilon, degree, smoothing))


def train_target_driver(poses: ArrayLike, values: ArrayLike, names: Sequence[str]) -> ScalarDriver:
    """The driver ShapeSpace uses for a mesh's driven targets (7.3.3).

    A Gaussian kernel of width :func:`~core.posespace.psd.default_epsilon`, without a polynomial term
    under three examples and with :func:`train_driver`'s default polynomial otherwise.

    Parameters
    ----------
    poses : array_like, shape (K, d)
    values : array_like, shape (K, t)
    names : sequence of str, length t

    Returns
    -------
    ScalarDriver
    """
    X = validate.array(poses, "poses", ndim=2)
    return train_driver(X, values, names, kernel="gaussian", epsilon=default_epsilon(X),
                        degree=-1 if X.shape[0] < 3 else None)
