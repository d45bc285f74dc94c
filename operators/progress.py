"""Progress for operators that can take a while.

- :func:`window_progress` — window-manager progress (the percentage on the cursor) around a synchronous block;
- :class:`JobModal` — a modal operator whose computation runs in a :class:`core.jobs.BackgroundJob`: progress
  and a status-bar line while it runs, Esc cancels it (nothing is written), the result is written on the main
  thread once the job finished.
"""
from contextlib import contextmanager

from ..core.progress import Cancelled
from .reporting import FAILED, attempt

#: Seconds between a modal job's progress updates.
TICK = 0.1

#: Events passed on to Blender while a job computes (view navigation only; everything else waits).
NAVIGATION = {"MIDDLEMOUSE", "WHEELUPMOUSE", "WHEELDOWNMOUSE", "MOUSEMOVE", "INBETWEEN_MOUSEMOVE", "TRACKPADPAN",
              "TRACKPADZOOM", "NDOF_MOTION"}


@contextmanager
def window_progress(context, steps: int = 100):
    """Show progress while the block runs; yields ``update(fraction)`` for the bridge verbs' ``progress``."""
    wm = getattr(context, "window_manager", None)
    if wm is None:
        yield lambda fraction: None
        return
    wm.progress_begin(0, steps)

    def update(fraction: float) -> None:
        wm.progress_update(int(round(max(0.0, min(1.0, fraction)) * steps)))

    try:
        yield update
    finally:
        wm.progress_end()


def status_text(context, text) -> None:
    """Show ``text`` in the status bar (``None`` clears it); nothing without a workspace (background)."""
    workspace = getattr(context, "workspace", None)
    if workspace is not None and getattr(context, "window", None) is not None:
        workspace.status_text_set(text)


#: Seconds of main-thread work per timer tick of a :class:`SteppedJobModal` (the UI stays responsive between).
STEP_BUDGET = 0.05


class JobModal:
    """Mixin for an operator that computes in a :class:`core.jobs.BackgroundJob` and writes on the main thread.

    ``invoke`` reads on the main thread, starts the job and returns :meth:`start_job`; the mixin's ``modal``
    then shows the job's progress (mapped onto ``[shown_from, 1]`` of the bar) and a status line, passes view
    navigation on, cancels on Esc (the worker stops at its next progress call; nothing was written), and calls
    ``job_finished(context, job)`` — which every subclass defines: it writes the result on the main thread and
    returns the operator's result set — once the job is done.  :attr:`job_title` names the work in the reports
    ("Retarget", "Transfer").
    """

    job_title = "Job"

    def start_job(self, context, job, label: str, shown_from: float = 0.0):
        """Poll ``job`` from a modal timer; returns ``{'RUNNING_MODAL'}`` for ``invoke``."""
        wm = context.window_manager
        self._job, self._label, self._shown_from = job, label, float(shown_from)
        self._timer = wm.event_timer_add(TICK, window=context.window)
        wm.progress_begin(0, 100)
        wm.progress_update(int(round(100 * self._shown_from)))
        wm.modal_handler_add(self)
        status_text(context, f"{label}: starting… (Esc to cancel)")
        return {"RUNNING_MODAL"}

    def _cancelled_report(self):
        self.report({"INFO"}, f"{self.job_title} cancelled: nothing was changed")
        return {"CANCELLED"}

    def modal(self, context, event):
        job = self._job
        if event.type == "ESC":
            job.cancel()                      # the worker stops at its next progress call; nothing was written
            self.stop_job(context)
            return self._cancelled_report()
        if event.type != "TIMER":
            return {"PASS_THROUGH"} if event.type in NAVIGATION else {"RUNNING_MODAL"}
        if not job.done:
            shown = self._shown_from + (1.0 - self._shown_from) * job.fraction
            context.window_manager.progress_update(int(round(100 * shown)))
            status_text(context, f"{self._label}: {100 * shown:.0f} %, {job.elapsed():.0f} s (Esc to cancel)")
            return {"RUNNING_MODAL"}
        self.stop_job(context)
        try:
            return self.job_finished(context, job)
        except Cancelled:
            return self._cancelled_report()

    def cancel(self, context):
        """Blender ends the operator (file closed, window gone): stop the worker, write nothing."""
        if getattr(self, "_job", None) is not None:
            self._job.cancel()
        self.stop_job(context)

    def stop_job(self, context):
        """Remove the timer, end the progress and clear the status line (once)."""
        wm = context.window_manager
        if getattr(self, "_timer", None) is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
            wm.progress_end()
            status_text(context, None)


class SteppedJobModal(JobModal):
    """Mixin for an operator whose job drives Blender's depsgraph and so runs on the main thread: a
    :class:`bridge.rig.steps.SteppedJob`, stepped for :data:`STEP_BUDGET` seconds per modal timer tick (progress and
    Esc from :class:`JobModal`), or run in one go with window-manager progress (:meth:`run_here`: scripts, redo, no
    window)."""

    def run_here(self, context, job):
        """Step ``job`` to its end here, with window-manager progress; returns the job."""
        with window_progress(context) as progress:
            while not job.step():
                progress(job.fraction)
        return job

    def modal(self, context, event):
        if event.type == "TIMER" and not self._job.done:
            self._job.step(STEP_BUDGET)
        return JobModal.modal(self, context, event)


class ThreeStepJob(JobModal):
    """Mixin for an operator whose work is read → compute → write through bridge functions (Transfer Shapes,
    Preview Registration): ``execute`` runs the steps in one go with window-manager progress (scripts, redo, no
    window); ``invoke`` computes in a :class:`core.jobs.BackgroundJob` polled by :class:`JobModal`.

    Subclasses give ``read_plan(context)`` (the plan, or :data:`~operators.reporting.FAILED` after reporting),
    ``job_label(plan)``, ``done(written)`` (report; return the operator's result set) and the bridge steps as
    static methods: ``compute_step(plan, progress) -> outcome``, ``write_step(outcome)``, ``start_step(plan) ->
    job`` (running ``compute_step``) and ``finish_step(job)`` (``write_step`` of the job's outcome).
    """

    def execute(self, context):
        plan = self.read_plan(context)
        if plan is FAILED:
            return {"CANCELLED"}
        with window_progress(context) as progress:
            outcome = attempt(self, self.compute_step, plan, progress)
        if outcome is FAILED:
            return {"CANCELLED"}
        return self.done(attempt(self, self.write_step, outcome))

    def invoke(self, context, event):
        if getattr(context, "window", None) is None:          # no event loop to poll from: run it here
            return self.execute(context)
        plan = self.read_plan(context)
        if plan is FAILED:
            return {"CANCELLED"}
        return self.start_job(context, self.start_step(plan), self.job_label(plan))

    def job_finished(self, context, job):
        return self.done(attempt(self, self.finish_step, job))
