"""Per-frame retarget of a take onto any rig's controls (issue #25; thesis 3.5 beyond a linear model).

The shape-key per-frame retarget (:func:`core.retarget.perframe.fit_frames`) solves each frame on its own:
the bounded least-squares fit of the sliders to the frame's target positions, with a ridge
``reg · (tr(BᵀB)/n) · ‖w‖²`` toward the rest weights (relative to the mean squared column of the linear rig
``B``, so the result does not depend on units), each frame warm-started from the previous one.

On a rig that is not linear in its controls each frame is the bounded, regularised Levenberg–Marquardt
solve of :func:`core.rig.solve.solve_controls` with the same semantics:

- the ridge pulls toward the rest controls ``r`` (n,) with weight ``reg · (tr(J₀ᵀJ₀)/n)`` per squared
  *natural unit* — channel ``i`` weighs ``(s_i / s̄)²`` where ``s`` are the natural scales (surface motion per
  unit, :class:`~core.rig.controls.Channel`) and ``s̄²`` their mean square, ``J₀`` the Jacobian at the start:
  radians, metres, slider and property units are made comparable by how far they move the surface;
- an optional temporal smoothness weight ``smooth`` (same unit) pulls each frame toward the previous
  frame's solved controls (0: frames independent, as the shape-key per-frame retarget);
- each frame starts from the previous frame's controls, its surface points and its last Jacobian, which
  Broyden's rank-one updates keep current from step to step and frame to frame; the solve recomputes it only
  when a step is refused or stalls (``solve_controls``), so a smooth take costs a few rig evaluations a frame.

A frame stops when every pin is within ``pin_tol`` of its target, or when the Gauss–Newton step on the
current Jacobian would move no pin by more than ``xtol``, or on stationarity (``solve_controls``); a frame
that reaches ``max_iter`` is ``NOT_CONVERGED`` (its value is still the best controls found), and so is the
take (:class:`RigTakeReport`, the frames concerned listed in its issues).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..progress import ProgressFn, notify
from ..result import Issue, Report, Result, ShapeSpaceError, Status
from .solve import broyden_update, finite_difference_jacobian, solve_controls

__all__ = ["LINEARISATION_BYTES", "RigTakeReport", "RigTakeResult", "solve_take", "take_report"]

#: Largest linearisation (points and Jacobians of every frame, float64) :func:`solve_take` keeps for space-time.
LINEARISATION_BYTES = 2 * 2 ** 30


@dataclass(kw_only=True)
class RigTakeResult(Result):
    """Outcome of :func:`solve_take` (``value``: the controls per frame (F, n), also ``controls``).

    Attributes
    ----------
    frame_status : ndarray of int (F,)
        Each frame's :class:`~core.result.Status` value.
    rms : ndarray (F,)
        Root mean square pin distance of each frame (the rig's evaluation at the solved controls).
    pin_error_max : ndarray (F,)
        Largest pin distance of each frame.
    evaluations : int
        Rig evaluations (trial steps and finite differences).
    jacobians : int
        Jacobians computed (the first included).
    """

    frame_status: np.ndarray = None
    rms: np.ndarray = None
    pin_error_max: np.ndarray = None
    evaluations: int = 0
    jacobians: int = 0

    @property
    def controls(self) -> np.ndarray:
        return self.value


@dataclass(kw_only=True)
class RigTakeReport(Report):
    """What a retarget onto a rig's controls did (``status`` NOT_CONVERGED when any frame did not converge; the
    frames concerned are listed in ``issues``).

    Attributes
    ----------
    frames : int
        Frames solved.
    frame_range : list
        ``[first, last]`` frame.
    channels : list of str
        The control set's channel names.
    keyed_channels : list of str
        The channels that move in the take (keyed; the others are left as they are).
    rms, rms_max : float
        RMS pin distance over the whole take, and of its worst frame (surface units).
    pin_error_max : float
        Largest pin distance of the take.
    not_converged : list
        Frames that stopped at the iteration limit.
    evaluations, jacobians : int
        Rig evaluations and Jacobians of the whole take.
    actions : list of dict
        One entry per animated datablock written: ``id`` (``'OBJECT'``/``'KEY'``), ``name``, ``action`` (the new
        action), ``previous`` (the action it played before, ``''`` when none), ``previous_slot``,
        ``had_animation_data``, ``previous_fake_user`` (what :func:`bridge.rig.take.restore_previous` needs).
    values_before : list
        Each channel's underlying property before the write (restored with the previous actions).
    key_fraction : float
        Fraction of the dense keys kept by key reduction (1 without reduction).
    source : str
        The capture or action retargeted (``''`` for a take given as target positions).
    mapped_channels : int
        Shape keys of the face the source's channels map to (capture route; 0 otherwise).
    method : str
        The route that ran: ``'perframe'``, ``'spacetime'`` (:mod:`core.rig.spacetime`) or ``'cloning'``
        (:mod:`core.rig.cloning`).
    """

    frames: int = 0
    frame_range: list = field(default_factory=list)
    channels: list = field(default_factory=list)
    keyed_channels: list = field(default_factory=list)
    rms: float = float("nan")
    rms_max: float = float("nan")
    pin_error_max: float = float("nan")
    not_converged: list = field(default_factory=list)
    evaluations: int = 0
    jacobians: int = 0
    actions: list = field(default_factory=list)
    values_before: list = field(default_factory=list)
    key_fraction: float = 1.0
    source: str = ""
    mapped_channels: int = 0
    method: str = "perframe"


def _targets(targets: ArrayLike) -> np.ndarray:
    t = np.asarray(targets, dtype=np.float64)
    if t.ndim != 3 or t.shape[2] != 3 or t.shape[0] == 0 or t.shape[1] == 0:
        raise ShapeSpaceError(f"targets: expected (frames, points, 3) with at least one of each, got {t.shape}",
                              ErrorCode.SHAPE)
    bad = np.argwhere(~np.isfinite(t))
    if bad.size:
        raise ShapeSpaceError(f"targets: frame {bad[0][0]} point {bad[0][1]} is not finite", ErrorCode.NON_FINITE)
    return t


def _weights(reg: float, smooth: float) -> tuple:
    for name, v in (("reg", reg), ("smooth", smooth)):
        if not (np.isfinite(v) and v >= 0):
            raise ShapeSpaceError(f"{name} = {v} must be a non-negative number", ErrorCode.RANGE)
    return float(reg), float(smooth)


def solve_take(evaluate: Callable, c0: ArrayLike, targets: ArrayLike, *, lo: ArrayLike | None = None,
               hi: ArrayLike | None = None, scale: ArrayLike | None = None, jacobian: Callable | None = None,
               steps: ArrayLike | None = None, weights: ArrayLike | None = None, rest: ArrayLike | None = None,
               reg: float = 1e-6, smooth: float = 0.0, pin_tol: float = 0.0, xtol: float = 0.0,
               max_iter: int = 20, starts: ArrayLike | None = None, keep_linearisation: bool = False,
               progress: ProgressFn | None = None) -> RigTakeResult:
    """Controls of every frame of a take (module doc): frame by frame, warm-started, the Jacobian carried over.

    Parameters
    ----------
    evaluate : callable (n,) -> (p, 3)
        The rig's surface points for a control vector.
    c0 : array_like (n,)
        Start of the first frame (inside the bounds).
    targets : array_like (F, p, 3)
        Target positions of the points, per frame.
    lo, hi, scale, jacobian, steps, weights
        As in :func:`~core.rig.solve.solve_controls` (``steps`` also the finite differences of the first
        Jacobian when ``jacobian`` is not given: ``1e-3 / scale`` by default).
    rest : array_like (n,), optional
        Controls the ridge pulls toward (``c0`` by default).
    reg : float
        Ridge weight (module doc), ≥ 0.
    smooth : float
        Temporal smoothness weight toward the previous frame's controls (module doc), ≥ 0.
    pin_tol, xtol : float
        Stopping distances of a frame (module doc; 0: off).
    max_iter : int
        Trial steps per frame.
    starts : array_like (F, n), optional
        Start of every frame (clipped into the bounds) instead of the previous frame's controls — the cloning
        route's per-frame guesses (:mod:`core.rig.cloning`); the Jacobian is still carried over.
    keep_linearisation : bool
        Keep every frame's points (F, p, 3) and last Jacobian (F, 3p, n) in ``diagnostics`` (``points``,
        ``jacobians``): the linearisation the space-time pass starts from (:mod:`core.rig.spacetime`);
        refused beyond :data:`LINEARISATION_BYTES`.
    progress : callable, optional
        ``progress(fraction)`` once per frame (:mod:`core.progress`); raising
        :class:`~core.progress.Cancelled` from it stops the take (nothing is returned).

    Returns
    -------
    RigTakeResult
    """
    t = _targets(targets)
    reg, smooth = _weights(reg, smooth)
    c = np.array(c0, dtype=np.float64).reshape(-1)
    n = c.size
    s = np.ones(n) if scale is None else np.array(scale, dtype=np.float64).reshape(-1)
    if s.shape != (n,) or not np.all(np.isfinite(s) & (s > 0)):
        raise ShapeSpaceError(f"scale: expected {n} positive numbers", ErrorCode.RANGE)
    r = c.copy() if rest is None else np.array(rest, dtype=np.float64).reshape(-1)
    if r.shape != (n,) or not np.all(np.isfinite(r)):
        raise ShapeSpaceError(f"rest: expected {n} finite numbers", ErrorCode.SHAPE)
    lo_ = np.full(n, -np.inf) if lo is None else np.asarray(lo, dtype=np.float64)
    hi_ = np.full(n, np.inf) if hi is None else np.asarray(hi, dtype=np.float64)
    h = 1e-3 / s if steps is None else np.asarray(steps, dtype=np.float64)
    notify(progress, 0.0)
    first = [0]

    def counted(x):
        first[0] += 1
        return evaluate(x)

    P = np.asarray(counted(c), dtype=np.float64)
    J = (np.asarray(jacobian(c, P), dtype=np.float64) if jacobian is not None
         else finite_difference_jacobian(counted, c, h, lo_, hi_, base=P))
    w3 = np.ones(J.shape[0]) if weights is None else np.repeat(np.asarray(weights, dtype=np.float64), 3)
    unit = float(np.einsum("ij,ij,i->", J, J, w3)) / n / float(np.mean(s * s))
    F = t.shape[0]
    starts_ = None if starts is None else np.clip(np.asarray(starts, dtype=np.float64), lo_, hi_)
    if starts_ is not None and starts_.shape != (F, n):
        raise ShapeSpaceError(f"starts: expected ({F}, {n}), got {starts_.shape}", ErrorCode.SHAPE)
    keep_P = keep_J = None
    if keep_linearisation:
        size = F * J.shape[0] * n * 8
        if size > LINEARISATION_BYTES:
            raise ShapeSpaceError(f"the take's linearisation ({F} frames × {J.shape[0]} coordinates × {n} controls) "
                                  f"needs {size / 2 ** 30:.1f} GiB, more than {LINEARISATION_BYTES / 2 ** 30:g} GiB: "
                                  "split the take or sample fewer vertices", ErrorCode.TOO_LARGE)
        keep_P, keep_J = np.empty((F,) + P.shape), np.empty((F,) + J.shape)
    out = np.empty((F, n))
    status = np.empty(F, dtype=np.int64)
    rms, emax = np.empty(F), np.empty(F)
    evals, jacs, messages = first[0], 1, {}
    first[0] = 0
    for f in range(F):
        notify(progress, f / F)
        w_s = smooth if f > 0 else 0.0
        ref = (reg * r + w_s * c) / (reg + w_s) if reg + w_s > 0 else r
        if starts_ is not None:                     # the given start, its points; the Jacobian carried over
            Pn = np.asarray(counted(starts_[f]), dtype=np.float64)
            if f > 0:
                J = broyden_update(np.array(J), starts_[f] - c, (Pn - P).reshape(-1))
            c, P = starts_[f], Pn
        res = solve_controls(evaluate, c, t[f], lo=lo, hi=hi, scale=s, jacobian=jacobian, steps=steps,
                             weights=weights, reference=ref, mu=(reg + w_s) * unit, pin_tol=pin_tol, xtol=xtol,
                             max_iter=max_iter, first_jacobian=J, first_points=P)
        c, P, J = res.x, res.points, res.jacobian
        if keep_linearisation:
            keep_P[f], keep_J[f] = P, J
        out[f] = c
        status[f] = int(res.status)
        rms[f] = float(np.sqrt(np.mean(res.pin_errors ** 2)))
        emax[f] = res.pin_error_max
        evals += res.evaluations + first[0]
        first[0] = 0
        jacs += res.jacobians
        if res.status != Status.OK:
            messages[f] = res.message
    notify(progress, 1.0)
    bad = np.flatnonzero(status != Status.OK)
    take_status = Status.NOT_CONVERGED if bad.size else Status.OK
    message = (f"{bad.size} of {F} frames did not converge (first: frame index {bad[0]}: {messages[bad[0]]})"
               if bad.size else f"{F} frames solved")
    return RigTakeResult(out, status=take_status, message=message, frame_status=status, rms=rms,
                         pin_error_max=emax, evaluations=evals, jacobians=jacs,
                         diagnostics={"ridge_unit": unit, "points": keep_P, "jacobians": keep_J})


def take_report(result: RigTakeResult, frames: ArrayLike, names: Sequence[str]) -> RigTakeReport:
    """The :class:`RigTakeReport` of a solved take: ``frames`` (F,) are the frame numbers of its rows, ``names``
    the channel names; frames that did not converge are listed (by frame number) in one warning issue."""
    frames = np.asarray(frames, dtype=np.float64).reshape(-1)
    if frames.size != result.value.shape[0]:
        raise ShapeSpaceError(f"{frames.size} frame numbers for {result.value.shape[0]} frames", ErrorCode.SHAPE)
    as_num = [int(v) if float(v).is_integer() else float(v) for v in frames]
    bad = [as_num[i] for i in np.flatnonzero(result.frame_status != Status.OK)]
    issues = []
    if bad:
        shown = ", ".join(str(v) for v in bad[:20]) + (" …" if len(bad) > 20 else "")
        issues.append(Issue("warning", "not_converged",
                            f"{len(bad)} frame(s) stopped at the iteration limit before converging: {shown}",
                            tuple(str(v) for v in bad)))
    if result.status != Status.OK and not bad:        # a whole-take solve (space-time) that stopped early
        issues.append(Issue("warning", "not_converged", result.message))
    return RigTakeReport(status=Status.NOT_CONVERGED if issues else Status.OK, issues=issues, frames=len(as_num),
                         frame_range=[as_num[0], as_num[-1]], channels=list(names),
                         rms=float(np.sqrt(np.mean(result.rms ** 2))), rms_max=float(result.rms.max()),
                         pin_error_max=float(result.pin_error_max.max()), not_converged=bad,
                         evaluations=result.evaluations, jacobians=result.jacobians,
                         method=str(result.diagnostics.get("method", "perframe")))
