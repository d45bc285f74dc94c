"""The middle step of *Transfer Shapes* and of its registration preview: pure computation on what the bridge read.

:mod:`bridge.authoring` reads the source rig and the target into arrays (:class:`SourceRig`, :class:`TargetMesh`,
gathered in a :class:`TransferPlan` or a :class:`PreviewPlan`) on Blender's main thread; this module computes on
any thread (touching no Blender data): :func:`compute_preview` registers the source neutral onto the target,
:func:`compute_transfer` registers, transfers every shape (deformation transfer), moves the target's unmatched
parts, refines every key to the examples the user gave (:class:`TransferExample`), runs the per-key checks and
maps the vertex-group masks; the bridge then writes the outcome in one step.
Both raise :class:`~core.progress.Cancelled` from ``progress`` (nothing computed is kept) and
:class:`~core.result.ShapeSpaceError` when the registration fails or the result is not finite.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..blas_threads import single_threaded
from ..errors import ErrorCode
from ..progress import ProgressFn, notify, scaled
from ..result import Issue, Result, ShapeSpaceError, Status
from .contacts import with_references
from .examples import closing_keys, mirror_partners, refine_with_examples
from .landmarks import LandmarkPairs
from .parts import move_parts, plan_for_transfer, still_vertices
from .quality import check_keys
from .registration import Correspondence, register
from .report import TransferReport
from .transfer import Transfer

__all__ = ["SourceRig", "TargetMesh", "PreviewPlan", "PreviewOutcome", "TransferExample", "TransferPlan",
           "TransferOutcome", "compute_preview", "compute_transfer", "map_weights"]

#: The transfer solves this many shapes at a time (the same numbers as all at once; progress between chunks).
CHUNK = 8
#: An example the refinement reproduces further than this (relative) is reported: the examples contradict.
EXAMPLE_RESIDUAL = 1e-3


@dataclass
class SourceRig:
    """A source rig as arrays: every non-reference key, unmasked deltas, and what to rebuild on the target."""

    name: str
    neutral: np.ndarray                 # (p, 3) reference-key positions, object space
    triangles: np.ndarray               # (f, 3) int
    names: list                         # every key to transfer, in key order
    deltas: np.ndarray                  # (n, p, 3) key − its relative key, unmasked
    slider_min: np.ndarray              # (n,)
    slider_max: np.ndarray              # (n,)
    mute: np.ndarray                    # (n,) bool
    groups: dict                        # key name → vertex-group name (masks)
    group_weights: dict                 # vertex-group name → (p,) weights
    inbetweens: dict                    # key name → {"primary", "at"}
    combinations: dict                  # key name → {"inputs"}

    def full_sculpts(self) -> np.ndarray:
        """Each key's full shape at its slider = 1: a driven key's correction plus what its drivers add
        (``t·S_P`` for an in-between of ``P`` at ``t``, ``ΣS_inputs`` for a combination), (n, p, 3)."""
        index = {n: i for i, n in enumerate(self.names)}
        out = self.deltas.copy()
        for name, v in self.inbetweens.items():
            out[index[name]] += float(v["at"]) * self.deltas[index[v["primary"]]]
        for name, v in self.combinations.items():
            out[index[name]] += sum(self.deltas[index[i]] for i in v["inputs"])
        return out


@dataclass
class TargetMesh:
    """The mesh to transfer onto, as arrays."""

    name: str
    neutral: np.ndarray                 # (q, 3) reference key (or mesh) positions, object space
    triangles: np.ndarray               # (u, 3) int
    keys: list                          # existing shape-key names (reference first), [] without keys
    parts: int                          # connected parts through triangles (loose vertices in none)
    own: int = -1                       # the target object's own vertices (the first rows); -1: all
    objects: list = field(default_factory=list)     # part objects appended after them (bridge.part_objects)


# ------------------------------------------------------------------ registration preview
@dataclass
class PreviewPlan:
    """What a registration preview needs, read from Blender (``bridge.authoring.read_preview``)."""

    source: str
    target: str
    rig: SourceRig
    tgt: TargetMesh
    pairs: LandmarkPairs
    signature: tuple                     # the target as read (the bridge checks it again before writing)


@dataclass
class PreviewOutcome:
    """What :func:`compute_preview` computed; ``bridge.authoring.write_preview`` shows it."""

    plan: PreviewPlan
    result: Result                       # the registration (value: the correspondence)


def _registration(rig: SourceRig, tgt: TargetMesh, pairs: LandmarkPairs, source: str, target: str,
                  progress: ProgressFn | None) -> Result:
    """Register the source neutral onto the target; a failed registration is refused naming both meshes."""
    result = register(rig.neutral, rig.triangles, tgt.neutral, tgt.triangles, pairs, progress=progress)
    if result.value is None or result.status == Status.FAILED:
        raise ShapeSpaceError(f"registration of {source!r} onto {target!r} failed: "
                              f"{result.message or 'no result'}", ErrorCode.DEGENERATE)
    return result


def compute_preview(plan: PreviewPlan, progress: ProgressFn | None = None) -> PreviewOutcome:
    """The registration of a preview (any thread; touches no Blender data); raising
    :class:`~core.progress.Cancelled` from ``progress`` stops it."""
    return PreviewOutcome(plan=plan, result=_registration(plan.rig, plan.tgt, plan.pairs, plan.source, plan.target,
                                                          progress))


# ------------------------------------------------------------------ transfer
@dataclass
class TransferExample:
    """A target shape given as an example of the source's shapes (thesis 3.4.1; Li, Weise & Pauly 2010).

    ``deltas`` (q, 3): the shape minus the target's neutral on every row of :class:`TargetMesh` (NaN rows: not
    given — a part object without a key of that name; the plain transfer's prediction stands there);
    ``weights``: source key name → approximate weight (keys of :attr:`TransferPlan.write` or
    :attr:`TransferPlan.kept`).
    """

    key: str
    deltas: np.ndarray
    weights: dict


@dataclass
class TransferPlan:
    """Everything a transfer needs, read from Blender (``bridge.authoring.read_transfer``); no Blender references."""

    source: str
    target: str
    rig: SourceRig
    tgt: TargetMesh
    pairs: LandmarkPairs
    names: dict                          # source key name → new name
    write: list                          # source keys to write, in order
    replace: list                        # target keys they replace
    skipped: list
    groups_clash: list
    existing: str
    unmatched_parts: str                 # "move", "keep" or "refuse"
    signature: tuple                     # the target as read (the bridge checks it again before writing)
    started: float
    part_plans: list = field(default_factory=list)   # (PartObject, write, replace, skipped) per part object
    openings: list = field(default_factory=list)     # core.authoring.contacts.Opening (named lid/lip contours)
    examples: list = field(default_factory=list)     # TransferExample: the transferred keys are refined to them
    kept: list = field(default_factory=list)         # source keys computed but not written: their name is an example
    part_kinds: dict = field(default_factory=dict)   # vertex → (kind, reason): parts set in the panel or by their rig
    # (keys an example weights are computed too, written or not)


@dataclass
class TransferOutcome:
    """What :func:`compute_transfer` computed; ``bridge.authoring.write_transfer`` writes it."""

    plan: TransferPlan
    full: np.ndarray                     # (n, q, 3) transferred sculpt of every source key (zero for unwritten)
    masks: dict                          # vertex-group name → (q,) mapped weights
    report: TransferReport


def compute_transfer(plan: TransferPlan, progress: ProgressFn | None = None) -> TransferOutcome:
    """Registration, deformation transfer, parts, the examples' refinement, per-key checks and mapped masks (any
    thread; no Blender data).

    ``progress(fraction)`` (:mod:`core.progress`) is called through the registration and between the shape
    chunks; raising :class:`~core.progress.Cancelled` from it stops the work before anything is written.

    Raises
    ------
    ShapeSpaceError
        The registration failed, or a transferred shape is not finite (naming it).
    """
    with single_threaded():        # sparse factors and many 3×3 blocks: OpenBLAS threads only spin (core.blas_threads)
        return _compute_transfer(plan, progress)


def _compute_transfer(plan: TransferPlan, progress: ProgressFn | None) -> TransferOutcome:
    rig, tgt, names, write = plan.rig, plan.tgt, plan.names, plan.write
    report = TransferReport(source=plan.source, target=plan.target, skipped=[names[n] for n in plan.skipped])
    notify(progress, 0.0)
    result = _registration(rig, tgt, plan.pairs, plan.source, plan.target, scaled(progress, 0.0, 0.6))
    corr = result.value
    report.landmarks = len(plan.pairs)
    report.registration_residual_mm = float(getattr(corr, "residual_mm", result.diagnostics.get("residual_mm", 0.0)))
    report.registration_status = result.status
    if result.status != Status.OK and result.message:
        report.warnings.append(f"registration: {result.message}")
    moving = plan.unmatched_parts == "move"
    openings = with_references(plan.openings, rig.neutral, rig.full_sculpts(), rig.names)
    transfer = Transfer(rig.neutral, rig.triangles, tgt.neutral, tgt.triangles, corr,
                        unmatched_parts="keep" if moving else plan.unmatched_parts, openings=openings)
    if not moving:
        report.warnings.extend(issue.message for issue in transfer.issues)
    notify(progress, 0.7)
    used = [n for ex in plan.examples for n in ex.weights]          # an example may weight a key not written
    computed = write + [n for n in dict.fromkeys(plan.kept + used) if n not in write]
    rows = [rig.names.index(n) for n in computed]
    sculpts = rig.full_sculpts()[rows]
    solved = _solve(transfer, sculpts, tgt.neutral.shape, progress)
    if not np.isfinite(solved).all():
        bad = computed[int(np.argwhere(~np.isfinite(solved))[0][0])]
        raise ShapeSpaceError(f"the transfer of {bad!r} produced non-finite positions: nothing was written",
                              ErrorCode.NON_FINITE)
    part_plan, moved = None, None
    if moving:
        part_plan = plan_for_transfer(rig.neutral, rig.triangles, sculpts, computed, tgt.neutral, tgt.triangles,
                                      solved, corr.part_map, plan.part_kinds)
        solved, moved = move_parts(part_plan, tgt.neutral, tgt.triangles, solved, computed)
        report.parts = part_plan.summary()
    elif plan.part_kinds:
        unused = sorted({kind for kind, _ in plan.part_kinds.values()} - {"still"})
        if unused:
            report.warnings.append(f"parts set to {', '.join(unused)} are moved only with Unmatched Parts: Move as "
                                   f"Rigged (now {plan.unmatched_parts}); parts set still are kept still")
    held = still_vertices(tgt.neutral.shape[0], tgt.triangles, plan.part_kinds) if plan.part_kinds else None
    if held is not None:
        solved[:, held] = 0.0
    if plan.examples:
        solved = _refine(plan, computed, solved, report, scaled(progress, 0.95, 0.99))
        if held is not None:
            solved[:, held] = 0.0                  # the examples' refinement does not move what is held still
    _check(rig, tgt, write, sculpts[:len(write)], solved[:len(write)], part_plan, moved, report, plan.openings)
    full = np.zeros((len(rig.names),) + tgt.neutral.shape)
    full[rows] = solved
    scale = float(np.linalg.norm(np.ptp(rig.neutral, axis=0))) or 1.0
    report.empty = [names[n] for n, d in zip(write, sculpts) if np.abs(d).max() <= 1e-9 * scale]
    masks = {}
    for n in write:
        group = rig.groups.get(n)
        if group is not None and group not in masks:
            masks[group] = map_weights(corr, rig.triangles, rig.group_weights[group])
    notify(progress, 1.0)
    return TransferOutcome(plan=plan, full=full, masks=masks, report=report)


def _solve(transfer: Transfer, sculpts: np.ndarray, shape: tuple, progress: ProgressFn | None) -> np.ndarray:
    """Every sculpt (k, p, 3) transferred onto the target (k, ``shape``), :data:`CHUNK` at a time with progress
    from 0.7 to 0.95."""
    solved = np.zeros((len(sculpts),) + tuple(shape))
    for c0 in range(0, len(sculpts), CHUNK):
        solved[c0:c0 + CHUNK] = transfer.solve(sculpts[c0:c0 + CHUNK])
        notify(progress, 0.7 + 0.25 * min(len(sculpts), c0 + CHUNK) / len(sculpts))
    return solved


def _refine(plan: TransferPlan, computed: list, solved: np.ndarray, report: TransferReport,
            progress: ProgressFn | None) -> np.ndarray:
    """The transferred keys refined so the examples are reproduced (:func:`core.authoring.examples.
    refine_with_examples`); rows an example leaves out (NaN) take the plain transfer's prediction."""
    index = {n: i for i, n in enumerate(computed)}
    W = np.zeros((len(plan.examples), len(computed)))
    E = np.empty((len(plan.examples),) + solved.shape[1:])
    for e, ex in enumerate(plan.examples):
        for name, w in ex.weights.items():
            W[e, index[name]] = w
        predicted = np.einsum("k,kvi->vi", W[e], solved)
        E[e] = np.where(np.isnan(ex.deltas), predicted, ex.deltas)
    names = [ex.key for ex in plan.examples]
    ref = refine_with_examples(plan.tgt.neutral, plan.tgt.triangles, solved, E, W, names=names,
                               partners=mirror_partners(computed), closers=closing_keys(computed), progress=progress)
    report.examples = [{"key": ex.key, "weights": {plan.names[n]: w for n, w in ex.weights.items()},
                        "residual_before": float(r0), "residual_after": float(r1)}
                       for ex, r0, r1 in zip(plan.examples, ref.residual_before, ref.residual_after)]
    report.examples_gain = not np.isinf(ref.strength)
    written = set(plan.write)
    report.examples_changed = [plan.names[n] for n, c in zip(computed, ref.key_change) if c > 1e-6 and n in written]
    for ex in report.examples:
        if ex["residual_after"] > EXAMPLE_RESIDUAL:
            message = (f"example {ex['key']!r} is reproduced within {100 * ex['residual_after']:.1f} % only (the "
                       f"examples contradict each other: give each its weights)")
            report.issues.append(Issue("error", ErrorCode.TRANSFER_EXAMPLE_RESIDUAL, message, (ex["key"],)))
            report.warnings.append(message)
    return ref.deltas


def _check(rig: SourceRig, tgt: TargetMesh, write: list, sculpts: np.ndarray, solved: np.ndarray, plan, moved,
           report: TransferReport, openings: list) -> None:
    """Run the per-key checks into ``report``: a failed check is an error issue (and a warning line) and makes
    the status WARNING."""
    keys, issues, status = check_keys(rig.neutral, sculpts, write, tgt.neutral, solved, plan=plan, moved=moved,
                                      src_tris=rig.triangles, dst_tris=tgt.triangles, openings=openings)
    report.openings = [o.name for o in openings]
    report.keys = keys
    report.issues.extend(issues)
    report.warnings.extend(issue.message for issue in issues)
    report.status = Status.WARNING if status != Status.OK or report.issues else Status.OK


def map_weights(corr: Correspondence, src_tris: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per-vertex source values at each target vertex's corresponding source point (0 where unmapped).

    Parameters
    ----------
    corr : Correspondence
        Its ``tri`` (q,) and ``bary`` (q, 3).
    src_tris : ndarray of int (f, 3)
    weights : ndarray (p,)
        A value per source vertex (a vertex group's weights).

    Returns
    -------
    ndarray (q,)
        The barycentric interpolation at each target vertex, clipped to [0, 1].
    """
    tri = np.asarray(corr.tri, dtype=np.int64)
    ok = tri >= 0
    out = np.zeros(len(tri), dtype=np.float64)
    corners = src_tris[tri[ok]]                                  # (m, 3)
    out[ok] = np.einsum("ij,ij->i", np.asarray(corr.bary, dtype=np.float64)[ok], weights[corners])
    return np.clip(out, 0.0, 1.0)
