"""Left↔right mirroring of pose-space examples: names, pose features and correctives.

A mirrored example is the same sculpt on the other side of the character:
its pose is every reader's features flipped and moved to the counterpart
reader (:func:`mirror_pose`), and its corrective is the displacement of each
vertex's mirror partner across the mesh's local X axis, with x negated
(:func:`mirror_partners`, :func:`mirror_displacements`).  The flip follows
Blender's own "paste flipped pose": a local quaternion (w, x, y, z) becomes
(w, x, −y, −z) and a location (x, y, z) becomes (−x, y, z).
"""
from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from .. import symmetry, validate
from ..errors import ErrorCode
from ..result import ShapeSpaceError
from .readers import PoseReader

__all__ = ["mirror_name", "mirror_features", "mirror_pose", "mirror_partners", "mirror_displacements"]

_SIDES = (("Left", "Right"), ("left", "right"), (".L", ".R"), ("_L", "_R"), (".l", ".r"), ("_l", "_r"),
          ("L_", "R_"), ("l_", "r_"))

#: Reflection across the YZ plane (x → −x).
_FLIP_X = np.array([-1.0, 1.0, 1.0])


def mirror_name(name: str) -> str:
    """The left↔right counterpart of a bone/key name (``hand.L`` ↔ ``hand.R``, ``LeftArm`` ↔ ``RightArm``,
    ``hand.L.001`` ↔ ``hand.R.001``); a name without a side is its own mirror."""
    m = re.match(r"^(.*?)(\.\d{3})$", name)
    if m:
        return mirror_name(m.group(1)) + m.group(2)
    for a, b in _SIDES:
        for x, y in ((a, b), (b, a)):
            if name.endswith(x):
                return name[: -len(x)] + y
            if name.startswith(x):
                return y + name[len(x):]
    for x, y in (("Left", "Right"), ("Right", "Left")):
        if x in name:
            return name.replace(x, y, 1)
    return name


def mirror_features(reader: PoseReader, feats: ArrayLike) -> np.ndarray:
    """Features of the mirrored pose of one reader.

    With D = diag(1, −1, −1) (the flipped local quaternion's rotation is D R D): rotation features
    become D F D, swing −D f, twist (c, −s), location (−x, y, z); scalars are unchanged.

    Parameters
    ----------
    reader : PoseReader
    feats : array_like, shape (reader.dims,)
        The reader's features (scaled, as :func:`~core.posespace.readers.reader_features` returns them).

    Returns
    -------
    ndarray, shape (reader.dims,)
    """
    f = np.asarray(feats, dtype=np.float64) / reader.scale
    D = np.diag([1.0, -1.0, -1.0])
    if reader.kind == "rotation":
        out = (D @ f.reshape(3, 3) @ D).ravel()
    elif reader.kind == "swing":
        out = -(D @ f)
    elif reader.kind == "twist":
        out = np.array([f[0], -f[1]])
    elif reader.kind == "location":
        out = f * _FLIP_X
    else:
        out = f
    return out * reader.scale


def mirror_pose(readers: Sequence[PoseReader], pose: ArrayLike) -> np.ndarray:
    """Mirror a pose vector: each reader's features flipped and moved to its counterpart reader.

    Parameters
    ----------
    readers : sequence of PoseReader
        The pose space; every reader's mirror (same kind, :func:`mirror_name` of its source) must be in it.
    pose : array_like, shape (Σ dims,)

    Returns
    -------
    ndarray, shape (Σ dims,)

    Raises
    ------
    ShapeSpaceError
        When a reader's counterpart is not in the pose space (code ``no_mirror``).
    """
    readers = list(readers)
    pose = np.asarray(pose, dtype=np.float64)
    index = {(r.kind, r.source): i for i, r in enumerate(readers)}
    starts = np.concatenate([[0], np.cumsum([r.dims for r in readers])])
    out = np.empty_like(pose)
    for i, r in enumerate(readers):
        j = index.get((r.kind, mirror_name(r.source)))
        if j is None:
            raise ShapeSpaceError(f"the pose space has no {r.kind} reader for {mirror_name(r.source)!r} "
                                  f"(the mirror of {r.source!r})", ErrorCode.NO_MIRROR)
        out[starts[j]:starts[j + 1]] = mirror_features(r, pose[starts[i]:starts[i + 1]])
    return out


def mirror_partners(positions: ArrayLike, tolerance: float = 1e-4) -> np.ndarray:
    """Each vertex's mirror partner across the local X axis: the position mirror map of :mod:`core.symmetry`
    (:func:`~core.symmetry.position_map`: nearest vertex to (−x, y, z) by KD-tree, one-to-one), which the
    symmetry tools share.

    Parameters
    ----------
    positions : array_like, shape (p, 3)
        Rest positions (the basis), in the mesh's local space.
    tolerance : float
        How far a partner may be from the exact mirror position, as a fraction of the mesh's
        bounding-box diagonal.

    Returns
    -------
    ndarray of int, shape (p,)
        ``partner[v]`` is the vertex at v's mirror position (a permutation and an involution).

    Raises
    ------
    ShapeSpaceError
        Code ``not_symmetric`` when some vertex has no partner within the tolerance.
    """
    co = validate.array(positions, "positions", shape=(None, 3))
    tolerance = validate.non_negative(tolerance, "tolerance")
    mmap = symmetry.position_map(co, axis=0, offset=0.0, tolerance=tolerance)
    unmatched = len(mmap.unmapped)
    if unmatched:
        raise ShapeSpaceError(f"{unmatched} vertices have no mirror partner across the mesh's local X axis "
                              f"(within {tolerance:g} of its size; first: {mmap.unmapped[:5].tolist()}): the mesh "
                              "is not symmetric", ErrorCode.NOT_SYMMETRIC)
    return mmap.mirror


def mirror_displacements(delta: ArrayLike, partner: ArrayLike) -> np.ndarray:
    """The mirrored corrective: vertex v takes its partner's displacement with x negated.

    Parameters
    ----------
    delta : array_like, shape (p, 3)
        Corrective displacements (key minus basis).
    partner : array_like of int, shape (p,)
        From :func:`mirror_partners`.

    Returns
    -------
    ndarray, shape (p, 3)
    """
    delta = validate.array(delta, "delta", shape=(None, 3))
    partner = np.asarray(partner, dtype=np.int64)
    if partner.shape != (delta.shape[0],):
        raise ShapeSpaceError(f"partner must have shape ({delta.shape[0]},), got {partner.shape}", ErrorCode.SHAPE)
    return (delta * _FLIP_X)[partner]
