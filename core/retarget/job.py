"""The middle step of a retarget job: from the inputs read out of Blender to every curve to write (thesis 3.5, ch. 5).

A retarget runs in three steps so a modal operator can run the middle one in a worker thread
(:class:`core.jobs.BackgroundJob`):

1. ``bridge.retarget.read_retarget`` (main thread) reads everything from Blender into a :class:`RetargetPlan`;
2. :func:`compute_retarget` (any thread; touches no Blender data) makes the fit, reduces the keys and checks
   every value finite, with progress and :class:`~core.progress.Cancelled`: a :class:`RetargetOutcome`;
3. ``bridge.retarget.write_retarget`` (main thread) writes the outcome in one step.

This module is step 2 and the pure checks the others share: the settings (:func:`check_settings`), the landmark
count of a dense performance (:func:`check_landmark_pairs`), the curves to write (:func:`plan_curves`) and the
frames they key (:func:`written_range`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..blendshape import BlendshapeModel
from ..errors import ErrorCode
from ..headpose import bone_curves
from ..keyreduce import reduce_keys, reduce_keys_bezier_curves
from ..progress import ProgressFn, notify, scaled
from ..result import ShapeSpaceError
from ..validate import choice, non_negative, positive
from .cloning import copy_weights
from .performance import GEOMETRIC_METHODS, check_finite_weights, retarget_positions, retarget_weights
from .report import RetargetReport
from .transfer import stabilise, transfer_motion

__all__ = ["KEY_SHAPES", "LANDMARK_PREFIX", "RetargetPlan", "RetargetOutcome", "check_settings",
           "check_landmark_pairs", "dense_positions", "compute_retarget", "plan_curves", "written_range"]

#: How reduced keys are shaped: smooth Bézier keys with slopes, or linear ones.
KEY_SHAPES = ("BEZIER", "LINEAR")

#: Name prefix of the landmark vertex groups (``lm_<name>``) that pair a mesh performance with the target.
LANDMARK_PREFIX = "lm_"


@dataclass
class RetargetPlan:
    """Everything a retarget needs, read from Blender (``bridge.retarget.read_retarget``); no Blender references.

    ``raw`` is the unbounded weight performance on the target's sliders when it is already known (learned);
    ``pairs``/``gain``/``offset`` with ``source_weights`` give it by copying (copy and the fits of a weight
    source); ``dense`` holds a mesh performance's transfer inputs (:func:`dense_positions`).  ``bones`` (with
    ``rotations`` (f, 9)) are the head / eye bones to key, ``bone_paths`` their curves'
    ``(data path, array index, bone name)`` in the order of :func:`core.headpose.bone_curves`' columns.

    Attributes
    ----------
    model : BlendshapeModel
        The target rig (n sliders).
    paths : list of str
        The data path of each slider's curve (n,).
    frames : ndarray (f,)
        Scene frame of each row.
    report : RetargetReport
        Filled by the read (source, method, frames, issues) and by :func:`compute_retarget`.
    rig : tuple
        What the result depends on and the artist could change meanwhile (checked before writing).
    """

    obj_name: str
    method: str
    lam: float
    key_tolerance: float
    key_shape: str
    action_name: str
    extend_scene_range: bool
    model: BlendshapeModel
    paths: list
    frames: np.ndarray
    report: RetargetReport
    rig: tuple
    raw: np.ndarray | None = None
    source_weights: np.ndarray | None = None
    pairs: list | None = None
    gain: np.ndarray | None = None
    offset: np.ndarray | None = None
    dense: dict | None = None
    bones: list | None = None
    rotations: np.ndarray | None = None
    armature: str = ""
    mirror: bool = False
    bone_paths: list | None = None


@dataclass
class RetargetOutcome:
    """A computed retarget (:func:`compute_retarget`): the report and every curve to write, checked finite.

    Attributes
    ----------
    weights : ndarray (f, n)
        The retargeted slider values, within the slider ranges.
    curves : list
        ``[(data path, frames, values, slopes or None)]`` (:func:`plan_curves`).
    bone_curves : list or None
        ``[(data path, index, bone, frames, values, slopes or None)]`` for the head / eye bones.
    """

    plan: RetargetPlan
    weights: np.ndarray
    curves: list
    report: RetargetReport
    bone_curves: list | None = None


def check_settings(lam: float, key_tolerance: float, key_shape: str) -> tuple:
    """The retarget settings checked before any work: ``(λ > 0, key tolerance ≥ 0)``, both finite; the key shape
    one of :data:`KEY_SHAPES`."""
    choice(key_shape, "key shape", KEY_SHAPES, ErrorCode.KEY_SHAPE)
    return positive(lam, "lam"), non_negative(key_tolerance, "key tolerance")


def check_landmark_pairs(source_vertices: int, target_vertices: int, pairs: int) -> None:
    """Refuse a mesh performance on a mesh of other topology (or with landmarks) that has fewer than 3 landmark
    pairs: the same topology without landmarks is transferred vertex to vertex, anything else by a landmark warp."""
    same_topology = int(source_vertices) == int(target_vertices) and not pairs
    if not same_topology and pairs < 3:
        raise ShapeSpaceError(f"different meshes need at least 3 landmark pairs (vertex groups named "
                              f"'{LANDMARK_PREFIX}…' on both); found {int(pairs)}", "too_few_landmarks")


def dense_positions(inputs: dict, target_model: BlendshapeModel) -> np.ndarray:
    """A mesh performance transferred onto the target's vertices (:func:`~.transfer.transfer_motion`).

    Parameters
    ----------
    inputs : dict
        ``seq`` (f, p_s, 3) the source's positions per frame (stabilised in place: head motion removed),
        ``rest`` (p_s, 3) its neutral, ``stable`` its stable vertex indices, ``src_lm``/``dst_lm`` (m,) landmark
        vertex pairs (empty for the same topology).
    target_model : BlendshapeModel
        The target (p_t vertices).

    Returns
    -------
    ndarray (f, p_t·3)
    """
    seq = inputs["seq"]
    stabilise(seq, inputs["rest"], inputs["stable"])
    src_lm, dst_lm = inputs["src_lm"], inputs["dst_lm"]
    check_landmark_pairs(seq.shape[1], target_model.neutral.shape[0], src_lm.size)
    return transfer_motion(seq, inputs["rest"], target_model.neutral, target_model.deltas, target_model.scale,
                           src_lm, dst_lm)


def _shares(plan: RetargetPlan) -> tuple:
    """Fractions of the progress bar at which :func:`compute_retarget`'s stages end: (copy, transfer, fit)."""
    keys = 0.0 if plan.key_tolerance <= 0 else (0.3 if plan.method in GEOMETRIC_METHODS else 0.85)
    if plan.dense is not None:
        return 0.0, 0.15, 1.0 - keys
    return 0.02, 0.02, 1.0 - keys


def compute_retarget(plan: RetargetPlan, progress: ProgressFn | None = None) -> RetargetOutcome:
    """Step 2 of a retarget (any thread; touches no Blender data): the fit and every curve to write.

    The weights are fitted by the plan's method (:func:`~.performance.retarget_weights` for a weight source,
    :func:`~.performance.retarget_positions` for a mesh performance), recorded in the plan's report (errors,
    clipping, the space-time solver's outcome and the report's status), reduced to keys and checked finite.

    Parameters
    ----------
    plan : RetargetPlan
    progress : callable, optional
        ``progress(fraction)`` (:mod:`core.progress`), called through the copy, the fit (by the solver) and the
        key reduction (per curve); raising :class:`~core.progress.Cancelled` from it stops the work.

    Returns
    -------
    RetargetOutcome
    """
    copy_end, transfer_end, fit_end = _shares(plan)
    model, report = plan.model, plan.report
    if plan.dense is not None:
        positions = dense_positions(plan.dense, model)
        notify(progress, transfer_end)
        fit = retarget_positions(model, positions, plan.method, plan.lam,
                                 progress=scaled(progress, transfer_end, fit_end))
    else:
        raw = plan.raw
        if raw is None:
            raw = copy_weights(plan.source_weights, plan.pairs, model.n_targets, plan.gain, plan.offset,
                               progress=scaled(progress, 0.0, copy_end))
        check_finite_weights(raw, model.names, "the mapped source")
        fit = retarget_weights(model, raw, plan.method, plan.lam, progress=scaled(progress, copy_end, fit_end))
    report.record(fit, plan.frames)
    check_finite_weights(fit.weights, model.names, "the retarget")
    curves, kept = plan_curves(model.names, plan.paths, plan.frames, fit.weights, plan.key_tolerance,
                               plan.key_shape, scaled(progress, fit_end, 1.0))
    if plan.key_tolerance > 0:
        report.keys_kept_frac = kept
    outcome = RetargetOutcome(plan, fit.weights, curves, report, _bone_plan(plan))
    notify(progress, 1.0)
    return outcome


def _bone_plan(plan: RetargetPlan) -> list | None:
    """The bones' curves, as the live session keys them (:func:`core.headpose.bone_curves`), with the weight
    curves' key reduction: ``[(data path, index, bone, frames, values, slopes or None)]``."""
    if not plan.bones:
        return None
    values = bone_curves(plan.rotations, plan.bones, plan.mirror)
    columns, labels = [], []
    for b in plan.bones:
        prop, count = b.channel
        for i in range(count):
            columns.append(values[b.name][:, i])
            labels.append(f"{b.name} {prop}[{i}]")
    paths = plan.bone_paths or []
    if len(paths) != len(columns):
        raise ShapeSpaceError(f"the plan names {len(paths)} bone curves for {len(columns)} bone channels",
                              ErrorCode.INVALID)
    planned, _ = plan_curves(labels, [p for p, _, _ in paths], plan.frames, np.stack(columns, axis=1),
                             plan.key_tolerance, plan.key_shape)
    return [(path, index, bone, x, y, slopes) for (path, index, bone), (_, x, y, slopes) in zip(paths, planned)]


def plan_curves(names: list, paths: list, frames: ArrayLike, W: ArrayLike, key_tolerance: float, key_shape: str,
                progress: ProgressFn | None = None) -> tuple:
    """Every curve to write, computed and checked before anything is written.

    Without key reduction (``key_tolerance ≤ 0``) every frame is a key; else the fewest keys within
    ``key_tolerance`` of each curve: smooth Bézier keys with slopes (:func:`core.keyreduce.reduce_keys_bezier_curves`,
    every curve in one vectorised call) or linear keys (:func:`core.keyreduce.reduce_keys`, per curve).

    Parameters
    ----------
    names : list of str
        One per curve (n,), for the messages.
    paths : list of str
        The data path of each curve (n,).
    frames : ndarray (f,)
    W : ndarray (f, n)
        The dense curves.
    key_tolerance : float
    key_shape : {"BEZIER", "LINEAR"}
    progress : callable, optional
        Called per curve (linear keys and no reduction) or by the vectorised reduction.

    Returns
    -------
    curves : list
        ``[(data path, key frames (k,), key values (k,), slopes (k,) or None)]``, finite.
    kept : float
        Fraction of the dense keys kept.
    """
    choice(key_shape, "key shape", KEY_SHAPES, ErrorCode.KEY_SHAPE)
    frames = np.asarray(frames, dtype=np.float64)
    W = np.asarray(W, dtype=np.float64)
    plan, kept = [], 0
    reduced = (reduce_keys_bezier_curves(frames, W, key_tolerance, progress=progress)
               if key_tolerance > 0 and key_shape == "BEZIER" else None)
    for j, (name, path) in enumerate(zip(names, paths)):
        if key_tolerance <= 0:
            plan.append((path, frames, W[:, j], None))
        elif reduced is not None:
            idx, key_values, slopes = reduced[j]
            plan.append((path, frames[idx], key_values, slopes))
        else:
            idx = reduce_keys(frames, W[:, j], key_tolerance)
            plan.append((path, frames[idx], W[idx, j], None))
        kept += len(plan[-1][1])
        if not all(np.isfinite(a).all() for a in plan[-1][1:] if a is not None):
            raise ShapeSpaceError(f"the keys of {name!r} came out NaN or infinite; nothing was written",
                                  ErrorCode.NON_FINITE)
        if reduced is None:
            notify(progress, (j + 1) / max(len(names), 1))
    notify(progress, 1.0)
    return plan, kept / max(len(frames) * len(names), 1)


def written_range(curves: list) -> tuple | None:
    """``(first, last)`` frame keyed by the planned ``curves`` (:func:`plan_curves`), or None when they key
    nothing."""
    firsts = [float(c[1][0]) for c in curves if len(c[1])]
    lasts = [float(c[1][-1]) for c in curves if len(c[1])]
    return (min(firsts), max(lasts)) if firsts else None
