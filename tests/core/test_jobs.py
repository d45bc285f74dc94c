"""core.jobs.BackgroundJob: a computation in a worker thread, polled, cancelled through its progress calls."""
import threading
import time

import numpy as np
import pytest

from core.jobs import BackgroundJob
from core.progress import Cancelled, notify


def _work(steps, gate=None):
    def work(progress):
        total = 0.0
        for k in range(steps):
            if gate is not None:
                assert gate.acquire(timeout=30)
            total += float(np.linalg.norm(np.ones(100) * k))
            notify(progress, (k + 1) / steps)
        return total
    return work


def test_job_runs_in_a_worker_and_reports_monotone_progress():
    job = BackgroundJob(_work(20)).start()
    assert job.wait(30)
    assert job.done and not job.cancelled
    assert job.result() == pytest.approx(sum(100 ** 0.5 * k for k in range(20)))
    assert job.reported == sorted(job.reported) and job.reported[-1] == 1.0
    assert job.fraction == 1.0


def test_cancel_mid_way_raises_cancelled_and_keeps_no_result():
    gate = threading.Semaphore(0)
    job = BackgroundJob(_work(10, gate)).start()
    for _ in range(3):                                             # let three steps run
        gate.release()
    deadline = time.perf_counter() + 30
    while len(job.reported) < 3 and time.perf_counter() < deadline:
        time.sleep(0.001)
    assert not job.done and job.fraction == pytest.approx(0.3)
    job.cancel()
    for _ in range(7):
        gate.release()
    assert job.wait(30) and job.cancelled
    assert job.reported == pytest.approx([0.1, 0.2, 0.3])         # the fourth step's report raised Cancelled
    with pytest.raises(Cancelled):
        job.result()


def test_errors_reach_the_caller_and_result_needs_a_finished_job():
    def boom(progress):
        notify(progress, 0.5)
        raise ValueError("bad take")
    job = BackgroundJob(boom)
    with pytest.raises(RuntimeError, match="has not finished"):
        job.result()
    job.start().wait(30)
    with pytest.raises(ValueError, match="bad take"):
        job.result()
    assert job.fraction == 0.5              # not 1: it failed


def test_run_here_is_the_same_work_synchronously():
    job = BackgroundJob(_work(5))
    assert job.run_here() == pytest.approx(sum(100 ** 0.5 * k for k in range(5)))
    assert job.done and job.reported[-1] == 1.0
