"""Retarget a capture onto any rig's controls through the face's own shape keys (issue #25, item 3).

The cloning route for ARKit-named sources: a capture (Live Link Face CSV, Face Cap TXT, iFacialMocap,
Audio2Face JSON, MediaPipe JSON/CSV, or a shape-key action; :func:`bridge.retarget.sources.read_source`) gives
weights per scene frame; the source channels are mapped onto the face's own shape keys exactly as the shape-key
retarget maps them (stored overrides, then name matching: :func:`bridge.retarget.mapping.resolve_mapping`) and
copied with the mapping's gain and offset, clamped to the slider ranges (the ``copy`` method).  The target surface
of a frame is then the face's linear shape-key model at those weights (thesis Eq. 3.1,
``b₀ + Σ w_k (b_k − b₀)``, each key's vertex group and relative key honoured:
:func:`bridge.rig.take.shape_key_targets`) at a deterministic vertex sample, and the rig's controls are solved
frame by frame to reproduce it (:func:`bridge.rig.take.compute_take`) and keyed (:func:`bridge.rig.take.write_take`).

The target is the keys' model alone (sliders the source does not map stay at 0 in it); the rig is evaluated as
it is apart from its controls, so sliders that are not controls should rest at 0 and datablocks without a
control should play no action (the actions of datablocks that own controls are set aside while it solves).

Routes (``method``): ``perframe`` solves each frame (:func:`core.rig.take.solve_take`); ``spacetime`` then solves
the whole take with the shape-key space-time route's smoothing (:mod:`core.rig.spacetime`); ``cloning`` solves once,
per mapped key, the controls that reproduce that key at weight 1 (the key's surface on the face), maps the
capture's weights to controls linearly and refines each frame by a few warm-started steps (:mod:`core.rig.cloning`).
The report's ``method`` says which route ran.

So the rig may replace a key by a bone (a jaw bone for ``jawOpen``), drive keys through drivers, or be any mix:
what is matched is the surface the face's own keys would make.  Nothing is written before every frame is solved;
a failure or :class:`~core.progress.Cancelled` leaves the file as it was.
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.progress import notify, scaled
from ...core.result import Issue, ShapeSpaceError
from ...core.retarget import copy_weights, split_mapping
from ...core.rig import ControlSet, RigTakeReport
from ..retarget.mapping import resolve_mapping
from ..retarget.sources import read_source
from .analytic import key_delta
from .last_take import remember_or_give_back
from .take import compute_take, shape_key_targets, write_take

__all__ = ["MIN_SAMPLE", "capture_weights", "sample_vertices", "retarget_capture_onto_rig"]

#: Vertices the target surface is sampled at (at least this many, or every vertex of a smaller mesh).
MIN_SAMPLE = 400
#: Per mapped key, its most moved vertices are added to the sample (so a small region — a lid — is seen).
TOP_PER_KEY = 4


def _key_names(mesh_obj) -> list:
    key = mesh_obj.data.shape_keys if mesh_obj.type == "MESH" else None
    if key is None or not key.use_relative or len(key.key_blocks) < 2:
        raise ShapeSpaceError(f"{mesh_obj.name!r} has no relative shape keys to evaluate a capture's weights on",
                              ErrorCode.NO_SHAPE_KEYS)
    return [kb.name for kb in key.key_blocks if kb != key.reference_key]


def capture_weights(mesh_obj, source, scene=None) -> tuple:
    """A capture source as weights on ``mesh_obj``'s own shape keys: ``(key names (k,), scene frames (F,),
    weights (F, k), issues)`` — only the keys a source channel maps to, clamped to their slider ranges.
    Refused, naming the source's channels, when none of them maps to a key of the face."""
    targets = _key_names(mesh_obj)
    names, frames, src, issues = read_source(source, scene or bpy.context.scene)
    shown = ", ".join(names[:6]) + (" …" if len(names) > 6 else "")
    refusal = ShapeSpaceError(f"{mesh_obj.name!r} has no shape key matching the source's channels ({shown}): the "
                              "face needs the source's shape keys (ARKit names) to evaluate it", ErrorCode.NO_MAPPING)
    try:
        mapping, warnings = resolve_mapping(mesh_obj, names, targets)
    except ShapeSpaceError as exc:
        if exc.code == ErrorCode.NO_MAPPING:
            raise refusal from None
        raise
    if not mapping:
        raise refusal
    issues = list(issues) + [Issue("warning", "stale_mapping", w) for w in warnings]
    pairs, gain, offset = split_mapping(mapping, len(targets))
    key = mesh_obj.data.shape_keys
    lo = np.array([key.key_blocks[n].slider_min for n in targets])
    hi = np.array([key.key_blocks[n].slider_max for n in targets])
    W = copy_weights(src, pairs, len(targets), gain, offset, lo, hi)
    cols = sorted({j for _, j in pairs})
    return [targets[j] for j in cols], np.asarray(frames, dtype=np.float64), W[:, cols], issues


def sample_vertices(mesh_obj, key_names, minimum: int = MIN_SAMPLE) -> np.ndarray:
    """A deterministic vertex sample (sorted): every k-th vertex (k = V // ``minimum``, so at least ``minimum``
    vertices, all of a smaller mesh) and the :data:`TOP_PER_KEY` vertices each of ``key_names`` moves most."""
    n = len(mesh_obj.data.vertices)
    every = np.arange(0, n, max(1, n // max(1, minimum)))
    key = mesh_obj.data.shape_keys
    all_idx, cache, top = np.arange(n), {}, []
    for name in key_names:
        mag = np.linalg.norm(key_delta(mesh_obj, key.key_blocks[name], all_idx, cache), axis=1)
        moved = np.flatnonzero(mag > 0)
        top.append(moved[np.argsort(-mag[moved], kind="stable")[:TOP_PER_KEY]])
    return np.union1d(every, np.concatenate(top)).astype(np.int64) if top else every


def retarget_capture_onto_rig(mesh_obj, controls: ControlSet, source, *, scene=None, indices=None,
                              reg: float = 1e-6, smooth: float = 0.0, key_tolerance: float = 0.0,
                              max_iter: int = 20, action_name: str | None = None, method: str = "perframe",
                              lam: float = 1e-7, progress=None) -> RigTakeReport:
    """Retarget a capture ``source`` onto ``controls`` (module doc) and key them; returns the take's report.

    Parameters
    ----------
    mesh_obj : bpy.types.Object
        The face: the mesh the rig deforms, with the source's shape keys (ARKit names) as its reference model.
    controls : ControlSet
        The rig's channels to solve and key (bones, custom properties, sliders).
    source : str or bpy.types.Action
        A capture recording's path or a shape-key action (name).
    scene : bpy.types.Scene, optional
        Whose frame rate and start frame a recording is resampled to (the context's scene by default).
    indices : array_like of int (p,), optional
        Vertices the surface is matched at (:func:`sample_vertices` by default).
    reg, smooth, max_iter
        As in :func:`bridge.rig.take.compute_take`.
    key_tolerance : float
        Key reduction in surface units (:func:`bridge.rig.take.write_take`; 0 keeps every frame).
    method : str
        ``'perframe'``, ``'spacetime'`` or ``'cloning'`` (module doc).
    lam : float
        The space-time λ (relative, as the retarget command's ``--lam``).
    progress : callable, optional
        ``progress(fraction)``; raising :class:`~core.progress.Cancelled` stops it with nothing written.
    """
    notify(progress, 0.0)
    names, frames, W, issues = capture_weights(mesh_obj, source, scene)
    idx = sample_vertices(mesh_obj, names) if indices is None else np.asarray(indices, dtype=np.int64)
    targets = shape_key_targets(mesh_obj, names, W, idx)
    notify(progress, 0.05)
    cloning = None
    if method == "cloning":
        cloning = (shape_key_targets(mesh_obj, names, np.eye(len(names)), idx), W)
    outcome = compute_take(mesh_obj, controls, idx, targets, frames, reg=reg, smooth=smooth, max_iter=max_iter,
                           action_name=action_name, method=method, lam=lam, cloning=cloning,
                           progress=scaled(progress, 0.05, 0.95))
    report = write_take(outcome, key_tolerance, scaled(progress, 0.95, 1.0))
    report.issues = issues + report.issues
    report.source = str(getattr(source, "name", source))
    report.mapped_channels = len(names)
    remember_or_give_back(mesh_obj, report, controls)
    return report
