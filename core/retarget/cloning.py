"""Expression cloning between slider rigs (thesis 3.5.3).

- :func:`copy_weights` — corresponding parameterisation: mapped channels
  copied with per-channel gain and offset, ``w_t[:, j] = g_j w_s[:, i] + o_j``;
  :func:`resolve_channel_mapping` — which channels: the artist's overrides, then name matching.
- :func:`cloning_matrix` — linear expression cloning ``W_t ≈ W_s E`` from
  c ≥ n corresponding pose pairs; :func:`learned_cloning` applies it to a
  performance given the artist's key poses.
- :func:`key_poses` — Chuang–Bregler key-pose selection (largest / smallest
  projections on the leading principal components); :func:`suggest_key_frames`
  tops the picks up with farthest-point frames until there are enough to learn
  ``E``.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..names import match_channels
from ..progress import ProgressFn, notify
from ..result import ShapeSpaceError
from ..validate import array

__all__ = ["copy_weights", "split_mapping", "resolve_channel_mapping", "MAX_MAPPING_VALUE", "cloning_matrix",
           "key_poses", "moving_channels", "suggest_key_frames", "key_frames_in_span", "LearnedCloning",
           "learned_cloning"]

#: Peak-to-peak range below which a source channel counts as not moving.
MOVING_TOL = 1e-6

#: Largest magnitude of a mapping override's gain or offset.
MAX_MAPPING_VALUE = 100.0


def copy_weights(source: ArrayLike, mapping: Sequence, n_target: int, gain: ArrayLike | None = None,
                 offset: ArrayLike | None = None, lo: ArrayLike | None = None,
                 hi: ArrayLike | None = None, *, progress: ProgressFn | None = None) -> np.ndarray:
    """Copy mapped channels: ``w_t[:, j] = gain_j · w_s[:, i] + offset_j`` for each pair (i, j) (3.5.3).

    Parameters
    ----------
    source : ndarray (f, n_s)
    mapping : sequence of (source index, target index)
    n_target : int
    gain, offset : ndarray (n_target,), optional
    lo, hi : ndarray (n_target,), optional
        Clamp to the target sliders' ranges.
    progress : callable, optional
        ``progress(fraction)`` after each mapped channel (:mod:`core.progress`).

    Returns
    -------
    ndarray (f, n_target)
        Unmapped target channels are 0 (before clamping).
    """
    S = np.asarray(source, dtype=np.float64)
    if not mapping:
        raise ShapeSpaceError("source and target share no mapped channels", "no_mapping")
    out = np.zeros((S.shape[0], n_target))
    g = np.ones(n_target) if gain is None else np.asarray(gain, dtype=np.float64)
    o = np.zeros(n_target) if offset is None else np.asarray(offset, dtype=np.float64)
    for k, (i, j) in enumerate(mapping, start=1):
        out[:, j] = g[j] * S[:, i] + o[j]
        notify(progress, k / len(mapping))
    if lo is not None or hi is not None:
        out = np.clip(out, -np.inf if lo is None else lo, np.inf if hi is None else hi)
    return out


def split_mapping(mapping: Sequence, n_target: int) -> tuple:
    """``[(i, j, gain, offset)]`` → pairs ``[(i, j)]`` and per-target gain and offset arrays (n_target,).

    Targets not in the mapping keep gain 1 and offset 0.
    """
    gain = np.ones(n_target)
    offset = np.zeros(n_target)
    for _, j, g, o in mapping:
        gain[j], offset[j] = g, o
    return [(i, j) for i, j, _, _ in mapping], gain, offset


def resolve_channel_mapping(overrides: Mapping, source_names: Sequence[str], target_names: Sequence[str],
                            rig: str = "") -> tuple:
    """The channel mapping of a source onto a rig: the artist's overrides first, then name matching.

    Overrides win over name matching (a target an override claims is not matched by name).  An override whose
    target is not among ``target_names`` (stale: the key was deleted or renamed) is reported by name, and its
    channel is matched by name when that is possible; an override with a non-finite gain or offset, or one
    beyond ±:data:`MAX_MAPPING_VALUE`, is refused naming the channel.

    Parameters
    ----------
    overrides : mapping
        ``{source name: {"target": str, "gain": float, "offset": float}}`` (gain 1, offset 0 when absent).
    source_names, target_names : sequence of str
    rig : str
        The target's name, for the warnings.

    Returns
    -------
    mapping : list of (int, int, float, float)
        ``(source index, target index, gain, offset)``, in source order.
    warnings : list of str
        One per stale override.
    """
    auto, _, _ = match_channels(source_names, target_names)
    live, stale = {}, {}
    for name, entry in overrides.items():
        if name not in source_names:
            continue
        gain, offset = float(entry.get("gain", 1.0)), float(entry.get("offset", 0.0))
        if not all(math.isfinite(v) and abs(v) <= MAX_MAPPING_VALUE for v in (gain, offset)):
            raise ShapeSpaceError(f"the channel mapping of {name!r} has a non-finite or out-of-range gain or offset "
                                  f"({gain:g}, {offset:g}): fix it with Set Channel Mapping", ErrorCode.NON_FINITE)
        (live if entry.get("target") in target_names else stale)[name] = (entry.get("target"), gain, offset)
    claimed = {target for target, _, _ in live.values()}           # overrides win
    out, warnings = [], []
    for i, s in enumerate(source_names):
        if s in live:
            target, gain, offset = live[s]
            out.append((i, list(target_names).index(target), gain, offset))
            continue
        by_name = auto.get(s) if auto.get(s) not in claimed else None
        if s in stale:
            what = (f"{s} was matched by name to {by_name}" if by_name is not None
                    else f"{s} is not retargeted (fix or remove the override)")
            warnings.append(f"the channel mapping {s} → {stale[s][0]} names no shape key of {rig!r}: {what}")
        if by_name is not None:
            out.append((i, list(target_names).index(by_name), 1.0, 0.0))
    if not out:
        raise ShapeSpaceError("the source and the target share no channels (check the names or the mapping)",
                              "no_mapping")
    return out, warnings


def cloning_matrix(source_poses: ArrayLike, target_poses: ArrayLike, ridge: float = 1e-8) -> np.ndarray:
    """Linear expression cloning matrix ``E`` (n_s × n_t) with ``W_t ≈ W_s E`` (3.5.3).

    Needs c ≥ n_s corresponding pose pairs (rows); solved in least squares
    with a tiny ridge, ``E = (W_sᵀW_s + ε I)⁻¹ W_sᵀ W_t`` with
    ``ε = ridge · tr(W_sᵀW_s) / n_s``, so rank-deficient pairs still give the
    minimum-norm map.

    Parameters
    ----------
    source_poses : ndarray (c, n_s)
    target_poses : ndarray (c, n_t)
    ridge : float

    Returns
    -------
    ndarray (n_s, n_t)
    """
    Ws = np.asarray(source_poses, dtype=np.float64)
    Wt = np.asarray(target_poses, dtype=np.float64)
    if Ws.ndim != 2 or Wt.ndim != 2 or Ws.shape[0] != Wt.shape[0]:
        raise ShapeSpaceError(f"pose pairs must be (c, n_s) and (c, n_t) with equal c; got {Ws.shape}, {Wt.shape}",
                              "shape")
    if Ws.shape[0] < Ws.shape[1]:
        raise ShapeSpaceError(f"{Ws.shape[0]} pose pairs cannot determine a map from {Ws.shape[1]} source "
                              "channels; give at least as many pairs as source channels", "too_few")
    A = Ws.T @ Ws
    return np.linalg.solve(A + ridge * np.trace(A) / max(A.shape[0], 1) * np.eye(A.shape[0]), Ws.T @ Wt)


def key_poses(weights: ArrayLike, components: int = 3) -> np.ndarray:
    """Chuang–Bregler key poses: frames with the largest and smallest projection on each leading PC.

    Parameters
    ----------
    weights : ndarray (f, n)
    components : int
        Leading principal components of the centred weights used.

    Returns
    -------
    ndarray of int (k,), k ≤ 2 · components
        Frame indices, PC by PC (max then min), without repeats.
    """
    W = np.asarray(weights, dtype=np.float64)
    centred = W - W.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    proj = centred @ vt[:components].T
    picks = []
    for j in range(proj.shape[1]):
        for k in (int(np.argmax(proj[:, j])), int(np.argmin(proj[:, j]))):
            if k not in picks:
                picks.append(k)
    return np.array(picks, dtype=int)


def moving_channels(weights: ArrayLike, tol: float = MOVING_TOL) -> np.ndarray:
    """Channels whose peak-to-peak range over the frames exceeds ``tol``: bool (n,) for weights (f, n)."""
    return np.ptp(np.asarray(weights, dtype=np.float64), axis=0) > tol


def suggest_key_frames(frames: ArrayLike, weights: ArrayLike, count: int | None = None) -> np.ndarray:
    """Frames of a performance worth posing the target at, enough to learn a cloning matrix.

    The Chuang–Bregler extremes of the leading principal components
    (:func:`key_poses`) of the moving channels, topped up with the frame
    farthest from every pose chosen so far (extremes repeat across
    components) until there are ``count`` (default: moving channels + 2).

    Parameters
    ----------
    frames : ndarray (f,)
        Scene frame of each row of ``weights``.
    weights : ndarray (f, n)
        Source weights.
    count : int, optional

    Returns
    -------
    ndarray of int (k,)
        Sorted, distinct scene frames.
    """
    frames = np.asarray(frames)
    src = np.asarray(weights, dtype=np.float64)
    moving = moving_channels(src)
    need = int(count or moving.sum() + 2)
    X = src[:, moving]
    picks = list(dict.fromkeys(key_poses(X, components=min(int(np.ceil(need / 2)), int(moving.sum())))))
    sq = np.einsum("ij,ij->i", X, X)
    dist = np.sqrt(np.maximum(np.min(sq[:, None] + sq[picks][None] - 2.0 * X @ X[picks].T, axis=1), 0.0))
    while len(picks) < min(need, len(frames)):
        k = int(np.argmax(dist))
        picks.append(k)
        dist = np.minimum(dist, np.linalg.norm(X - X[k], axis=1))
    return np.unique(frames[picks]).astype(int)


def key_frames_in_span(key_frames: ArrayLike, frames: ArrayLike) -> np.ndarray:
    """The distinct keyed frames (sorted) that lie within the performance's frames ``[frames[0], frames[-1]]``."""
    keyed = np.unique(np.asarray(key_frames, dtype=np.float64))
    frames = np.asarray(frames, dtype=np.float64)
    return keyed[(keyed >= frames[0]) & (keyed <= frames[-1])]


@dataclass
class LearnedCloning:
    """A performance mapped by a learned cloning matrix.

    Attributes
    ----------
    weights : ndarray (f, n_t)
        ``W_s E`` on every frame: the unbounded target weights.
    matrix : ndarray (n_moving, n_t)
        ``E``, from the moving source channels.
    key_poses : int
        Pose pairs it was learned from.
    fit_rms : float
        RMS of ``W_s E − W_t`` over the key poses (slider units).
    mapped_channels : int
        Moving source channels used.
    """

    weights: np.ndarray
    matrix: np.ndarray
    key_poses: int
    fit_rms: float
    mapped_channels: int


def learned_cloning(frames: ArrayLike, source: ArrayLike, key_frames: ArrayLike,
                    target_poses: ArrayLike) -> LearnedCloning:
    """Linear expression cloning (3.5.3) learned from key poses and applied to a whole performance.

    The source at the key frames (linearly interpolated between its frames)
    and the target posed there give pose pairs ``(W_s, W_t)``; ``E`` from
    :func:`cloning_matrix` then maps every frame, ``W = S_moving E``.  Only
    moving source channels take part (a constant channel carries no
    information and would make ``W_sᵀW_s`` singular).

    Parameters
    ----------
    frames : ndarray (f,)
        Scene frames of ``source``.
    source : ndarray (f, n_s)
    key_frames : ndarray (c,)
        Frames where the target was posed (within the span of ``frames``).
    target_poses : ndarray (c, n_t)
        The target's slider values at ``key_frames``.

    Returns
    -------
    LearnedCloning
    """
    frames = array(frames, "frames", ndim=1)
    src = array(source, "source", shape=(frames.size, None))
    keyed = array(key_frames, "key_frames", ndim=1)
    Wt = array(target_poses, "target_poses", shape=(keyed.size, None))
    moving = moving_channels(src)
    Ws = np.column_stack([np.interp(keyed, frames, src[:, i]) for i in np.flatnonzero(moving)])
    E = cloning_matrix(Ws, Wt)
    rms = float(np.sqrt(np.mean((Ws @ E - Wt) ** 2)))
    return LearnedCloning(src[:, moving] @ E, E, int(keyed.size), rms, int(moving.sum()))
