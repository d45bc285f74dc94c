"""Long rig work with progress and Esc on Blender's main thread (issue #25: Propose Controls, retarget onto a rig).

Work that evaluates a rig goes through Blender's depsgraph, which only the main thread may drive, so it cannot run
in a :class:`core.jobs.BackgroundJob` worker.  A :class:`SteppedJob` runs it instead as a generator on the main
thread, advanced a slice at a time (:meth:`SteppedJob.step`, from a modal operator's timer), with the worker job's
interface (``fraction``, ``done``, ``cancel``, ``reported``, ``elapsed``, ``result``) so
``operators.progress.JobModal`` polls both the same way.  Cancelling closes the generator where it paused: its
``with`` blocks exit and every rig evaluator puts the rig back exactly; nothing is written until the job's finish
step (``finish_*``) runs on a job that completed.

- :func:`start_proposal` / :func:`finish_proposal` — Propose Controls: the candidates of
  :func:`bridge.rig.proposal.candidates` probed a few channels per step (the same probe and ranking as
  :func:`bridge.rig.proposal.propose`), then the proposed channels stored on the face.
- :func:`start_retarget` / :func:`finish_retarget` — a capture recording or shape-key action retargeted per frame
  onto a control set (the Retarget panel's *Rig Controls* route; the steps of
  :func:`bridge.rig.capture.retarget_capture_onto_rig`): the take is solved in consecutive runs of frames by
  :func:`bridge.rig.take.compute_take`, each run warm-started from the last controls of the one before (the rig's
  channels are set there between runs and put back exactly at the end), then keyed by
  :func:`bridge.rig.take.write_take` with its key reduction.  Each run re-measures the rig (its check, natural
  scales and first Jacobian: about 3 evaluations per channel), so the take is cut into at most
  :data:`RETARGET_RUNS` runs of at least :data:`RUN_FRAMES_PER_CHANNEL` frames per channel: Esc is seen between
  runs (on a 150-channel rig, every ~380 frames).
"""
from __future__ import annotations

import time

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.progress import Cancelled
from ...core.result import ShapeSpaceError, Status
from ...core.rig import RigTakeResult
from ...core.rig.controls import ControlSet
from ...core.rig.proposal import deformation, rank_channels
from . import stored
from .capture import capture_weights, sample_vertices
from .channels import bind
from .evaluate import RigEvaluator, check_editable
from .last_take import remember_or_give_back, summary
from .proposal import checked_rest, probe_candidates
from .take import TakeOutcome, compute_take, rest_controls, shape_key_targets, write_take

__all__ = ["PROBE_CHUNK", "RETARGET_RUNS", "RUN_FRAMES_PER_CHANNEL", "SteppedJob", "finish_proposal",
           "finish_retarget", "proposal_steps", "retarget_steps", "start_proposal", "start_retarget", "summary"]

#: Channels probed per step of a stepped proposal (a step is a few dozen rig evaluations).
PROBE_CHUNK = 8
#: Runs of frames a stepped retarget is cut into at most (one step each: Esc is seen between runs).
RETARGET_RUNS = 20
#: Frames per run at least.
RETARGET_MIN_RUN = 8
#: Frames per run at least, per channel (+1): a run re-measures the rig (about 3 evaluations per channel), which
#: keeps that under ~10 % of the solve (measured on the hybrid test rig: 33 ms per run of 8 channels, 18 ms a frame).
RUN_FRAMES_PER_CHANNEL = 2.5


class SteppedJob:
    """``steps`` (a generator yielding progress fractions and returning the value) run on the calling thread.

    Attributes
    ----------
    reported : list of float
        Every fraction the work yielded, in order.
    """

    def __init__(self, steps, name: str = "ShapeSpace job"):
        self._steps, self.name = steps, name
        self._done = self._cancelled = False
        self._value, self._error = None, None
        self._fraction = 0.0
        self.reported: list = []
        self.started_at = time.perf_counter()

    def step(self, budget: float = 0.05) -> bool:
        """Advance the work for about ``budget`` seconds (at least one step); returns :attr:`done`."""
        end = time.perf_counter() + budget
        while not self._done:
            try:
                f = float(next(self._steps))
            except StopIteration as stop:
                self._value, self._done = stop.value, True
                break
            except BaseException as exc:       # handed to the caller by result()
                self._error, self._done = exc, True
                break
            self.reported.append(f)
            self._fraction = max(self._fraction, min(1.0, max(0.0, f)))
            if time.perf_counter() >= end:
                break
        return self._done

    def run_here(self):
        """Run the work to its end (scripts, redo); returns :meth:`result`."""
        while not self.step(float("inf")):
            pass
        return self.result()

    @property
    def fraction(self) -> float:
        return 1.0 if self._done and self._error is None and not self._cancelled else self._fraction

    @property
    def done(self) -> bool:
        return self._done

    @property
    def cancelled(self) -> bool:
        return self._cancelled

    def cancel(self) -> None:
        """Stop the work where it paused (its ``finally`` and ``with`` exits run now); :meth:`result` raises
        :class:`~core.progress.Cancelled`."""
        if not self._done:
            self._steps.close()
        self._cancelled = self._done = True

    def wait(self, timeout: float | None = None) -> bool:
        return self._done

    def elapsed(self) -> float:
        return time.perf_counter() - self.started_at

    def result(self):
        """The work's value; re-raises its error, or :class:`~core.progress.Cancelled` after :meth:`cancel`."""
        if self._cancelled:
            raise Cancelled()
        if not self._done:
            raise RuntimeError("the job has not finished")
        if self._error is not None:
            raise self._error
        return self._value


# -- Propose Controls -----------------------------------------------------------------------------------------------

def _check_proposal(face, arm) -> None:
    if face is None or face.type != "MESH":
        raise ShapeSpaceError(f"{getattr(face, 'name', face)!r} is not a mesh object", ErrorCode.NOT_MESH)
    stored_arm, _ = stored.read(face)
    if arm is not None and stored_arm and stored_arm != arm.name:
        raise ShapeSpaceError(f"the control set of {face.name!r} belongs to armature {stored_arm!r}, not "
                              f"{arm.name!r}: clear it first", ErrorCode.INVALID)
    check_editable([face] + ([arm] if arm is not None else []))


def proposal_steps(face, arm=None, chunk: int = PROBE_CHUNK):
    """Generator: :func:`bridge.rig.proposal.propose` a ``chunk`` of channels per step (yields the fraction probed);
    returns ``(ProposalReport, proposed channels)``.  Nothing is written; the rig is left exactly as it was."""
    _check_proposal(face, arm)
    chans, locked, held, controls = probe_candidates(face, arm)
    with RigEvaluator(face, controls, [0], check=False) as ev:
        rest = checked_rest(face, ev)
        lo, hi = controls.solve_bounds(ev.c0)
        amounts = np.zeros(len(chans))
        yield 0.0
        for a in range(0, len(chans), chunk):
            b = min(a + chunk, len(chans))
            with RigEvaluator(face, ControlSet(tuple(chans[a:b])), [0], check=False) as part:
                part.diagonal = ev.diagonal
                amounts[a:b] = part.probe(rest, lo[a:b], hi[a:b], measure=deformation, either_side=True)[0]
            yield b / len(chans)
        report = rank_channels(controls.names, amounts, ev.diagonal, locked=locked, held=held)
    by_name = {ch.name: ch for ch in chans}
    return report, [by_name[n] for n in report.proposed]


def start_proposal(face, arm=None) -> SteppedJob:
    """The Propose Controls job (:func:`proposal_steps`), not started: the modal timer steps it."""
    return SteppedJob(proposal_steps(face, arm), "Propose Controls")


def finish_proposal(job: SteppedJob, face, arm=None) -> tuple:
    """Store what a completed proposal found (:func:`bridge.rig.proposal.propose_and_store`'s write): returns
    ``(ProposalReport, added entries)``; a cancelled job raises :class:`~core.progress.Cancelled`, writing nothing."""
    report, chans = job.result()
    _check_proposal(face, arm)
    added = stored.add_entries_of(face, arm.name if arm is not None else "", chans) if chans else []
    return report, added


# -- Retarget onto a rig's controls ------------------------------------------------------------------------------

def _joined(parts) -> RigTakeResult:
    """One take result from the results of consecutive runs of frames."""
    status = np.concatenate([p.frame_status for p in parts])
    bad = np.flatnonzero(status != Status.OK)
    message = f"{bad.size} of {status.size} frames did not converge" if bad.size else f"{status.size} frames solved"
    return RigTakeResult(np.concatenate([p.value for p in parts]),
                         status=Status.NOT_CONVERGED if bad.size else Status.OK, message=message,
                         frame_status=status, rms=np.concatenate([p.rms for p in parts]),
                         pin_error_max=np.concatenate([p.pin_error_max for p in parts]),
                         evaluations=sum(p.evaluations for p in parts), jacobians=sum(p.jacobians for p in parts),
                         diagnostics={"runs": len(parts)})


def retarget_steps(mesh_obj, controls: ControlSet, source, *, scene=None, reg: float = 1e-6, max_iter: int = 20,
                   action_name: str | None = None, runs: int = RETARGET_RUNS):
    """Generator: the capture ``source`` solved onto ``controls`` per frame, one run of frames per step (module
    doc; yields the fraction done).  Returns ``(TakeOutcome, issues, mapped key names)``; nothing is written and
    the rig's channels are put back exactly (also when the generator is closed: Esc)."""
    names, frames, W, issues = capture_weights(mesh_obj, source, scene)
    idx = sample_vertices(mesh_obj, names)
    targets = shape_key_targets(mesh_obj, names, W, idx)
    rest = rest_controls(controls)
    name = action_name or f"{mesh_obj.name} rig take"
    bindings = bind(controls)
    saved = [b.raw() for b in bindings]
    F = len(frames)
    if F == 0:
        raise ShapeSpaceError(f"{getattr(source, 'name', source)!r} has no frames to retarget", ErrorCode.EMPTY)
    size = max(RETARGET_MIN_RUN, -(-F // max(1, runs)), int(np.ceil(RUN_FRAMES_PER_CHANNEL * (len(controls) + 1))))
    parts = []
    try:
        yield 0.05
        for a in range(0, F, size):
            b = min(F, a + size)
            if parts:
                for binding, v in zip(bindings, parts[-1].result.value[-1]):
                    binding.set(v)                                  # warm start: the last run's last controls
            parts.append(compute_take(mesh_obj, controls, idx, targets[a:b], frames[a:b], reg=reg, rest=rest,
                                      max_iter=max_iter, action_name=name))
            yield 0.05 + 0.9 * b / F
    finally:
        for binding, raw in zip(bindings, saved):
            binding.set_raw(raw)
        bpy.context.view_layer.update()
    result = _joined([p.result for p in parts])
    first = parts[0]
    outcome = TakeOutcome(first.controls, np.asarray(frames, dtype=np.float64), result.value, result, first.diagonal,
                          name)
    return outcome, issues, names


def start_retarget(mesh_obj, controls: ControlSet, source, *, scene=None, action_name: str | None = None
                   ) -> SteppedJob:
    """The retarget-onto-controls job (:func:`retarget_steps`), not started: the modal timer steps it."""
    return SteppedJob(retarget_steps(mesh_obj, controls, source, scene=scene, action_name=action_name),
                      "Retarget onto rig controls")


def finish_retarget(job: SteppedJob, mesh_obj, source, key_tolerance: float = 0.0):
    """Key a completed retarget (:func:`bridge.rig.take.write_take`, with key reduction in surface units), keep its
    one-line summary and what *Discard Result* needs on the face (:func:`bridge.rig.last_take.remember`) and return its
    :class:`~core.rig.RigTakeReport`; a cancelled job raises :class:`~core.progress.Cancelled`, writing nothing."""
    outcome, issues, names = job.result()
    report = write_take(outcome, key_tolerance)
    report.issues = list(issues) + report.issues
    report.source = str(getattr(source, "name", source))
    report.mapped_channels = len(names)
    remember_or_give_back(mesh_obj, report, outcome.controls)
    return report
