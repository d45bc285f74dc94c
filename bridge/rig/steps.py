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
"""
from __future__ import annotations

import time

import numpy as np

from ...core.errors import ErrorCode
from ...core.progress import Cancelled
from ...core.result import ShapeSpaceError
from ...core.rig.controls import ControlSet
from ...core.rig.proposal import deformation, rank_channels
from . import stored
from .evaluate import RigEvaluator, check_editable
from .proposal import candidates

__all__ = ["PROBE_CHUNK", "SteppedJob", "finish_proposal", "proposal_steps", "start_proposal"]

#: Channels probed per step of a stepped proposal (a step is a few dozen rig evaluations).
PROBE_CHUNK = 8


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
    chans, locked, held = candidates(face, arm)
    if not chans:
        raise ShapeSpaceError(f"{face.name!r} has no channels to probe (no visible bones, shape keys or driven "
                              "properties)", ErrorCode.NO_CHANNELS)
    controls = ControlSet(tuple(chans))
    with RigEvaluator(face, controls, [0], check=False) as ev:
        rest = ev.check_rig()
        bad = np.flatnonzero(~np.isfinite(rest).all(1))
        if bad.size:
            raise ShapeSpaceError(f"{face.name!r}: evaluated vertex {int(bad[0])} is not finite (NaN or infinite "
                                  "coordinates, shape keys or drivers)", ErrorCode.NON_FINITE)
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
