"""Pure-NumPy work of ``core`` in child Python processes (foundation; no Blender).

Work that is Python-heavy (key reduction's absorption sweeps hold the GIL between small NumPy calls) does not speed
up on threads; a second process does.  :class:`ChildCall` runs ``core.<module>.<function>(*args)`` in a child of
the running interpreter (``sys.executable``: Blender's bundled Python inside Blender, the venv's under the PyPI
``bpy``), with ``core`` imported as a top-level package from this extension's folder and the parent's
``sys.path`` (so the child finds the same NumPy and the SciPy wheels the extension ships; the paths travel first,
and a child whose NumPy is not the parent's gives up).  The arguments and the result travel pickled through pipes;
the child never touches Blender data.

A child is an optimisation, never a requirement: :meth:`ChildCall.result` returns ``None`` when the child could not
start, failed or returned something unreadable, and the caller computes that part itself — the same function on
the same arguments, so the same result.  :meth:`ChildCall.stop` kills the child (a cancel, an error in the
parent).  The child's stdin stays open until its result is read: when the parent goes away (Blender quits or
crashes), the pipe closes and the child exits at once instead of finishing its work.  The thread that writes to
the child blocks SIGPIPE, so a child that died early is a ``BrokenPipeError`` there, never a signal that would end
Blender (whose embedded Python may leave SIGPIPE at its default).
"""
from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import threading

import numpy as np

from .progress import ProgressFn, notify

__all__ = ["ChildCall", "child_cpus"]

#: The extension's folder: ``core`` is imported from here as a top-level package in the child.
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: What the child runs: take the parent's paths (before anything imports NumPy), check it has the parent's NumPy,
#: watch stdin for the parent going away, call the target, write the result.
_BOOT = (
    "import os, pickle, sys, threading\n"
    "sys.path[:0] = pickle.load(sys.stdin.buffer)\n"
    "import numpy\n"
    "numpy_file, module, name, args = pickle.load(sys.stdin.buffer)\n"
    "if os.path.realpath(numpy.__file__) != numpy_file:\n"
    "    sys.exit(3)\n"
    "def orphaned():\n"
    "    sys.stdin.buffer.read()\n"
    "    os._exit(4)\n"
    "threading.Thread(target=orphaned, daemon=True).start()\n"
    "try:\n"
    "    import importlib\n"
    "    fn = getattr(importlib.import_module('core.' + module), name)\n"
    "    out = pickle.dumps(fn(*args), protocol=pickle.HIGHEST_PROTOCOL)\n"
    "    sys.stdout.buffer.write(out)\n"
    "    sys.stdout.buffer.flush()\n"
    "except BaseException:\n"
    "    os._exit(1)\n"
    "os._exit(0)\n"                 # no interpreter shutdown: the watcher holds stdin's lock (a daemon thread)
)

#: Seconds between checks for a cancel while waiting for a child.
_POLL_S = 0.1


def child_cpus() -> int:
    """CPUs this process may use (its affinity where the platform tells it), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _interpreter() -> str | None:
    """The running Python interpreter, or None when ``sys.executable`` is not one (an embedding without it)."""
    exe = sys.executable
    if not exe or not os.path.isfile(exe) or "python" not in os.path.basename(exe).lower():
        return None
    return exe


class ChildCall:
    """``core.<module>.<name>(*args)`` running in a child process (started at once).

    Parameters
    ----------
    module : str
        Module of ``core`` (``"keyreduce"``).
    name : str
        Function in it; its arguments and result must pickle (arrays, lists, numbers).
    args : tuple
    """

    def __init__(self, module: str, name: str, args: tuple):
        self._out: list = []
        self._proc = None
        exe = _interpreter()
        if exe is None:
            return
        paths = [_ROOT, *[p for p in sys.path if isinstance(p, str) and p]]
        payload = (pickle.dumps(paths, protocol=pickle.HIGHEST_PROTOCOL)
                   + pickle.dumps((os.path.realpath(np.__file__), module, name, args),
                                  protocol=pickle.HIGHEST_PROTOCOL))
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
        flags = getattr(subprocess, "CREATE_NO_WINDOW", 0)
        try:
            self._proc = subprocess.Popen([exe, "-I", "-c", _BOOT], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                          stderr=subprocess.DEVNULL, env=env, creationflags=flags, bufsize=0)
        except (OSError, ValueError):
            self._proc = None
            return
        self._io = threading.Thread(target=self._talk, args=(payload,), name="shapespace-child-io", daemon=True)
        try:
            self._io.start()
        except RuntimeError:                                          # no thread to talk to it: no child
            self._proc.kill()
            self._proc.wait()
            self._proc = None

    def _talk(self, payload: bytes) -> None:
        """Write the arguments, then read the whole result (a thread, so neither side waits on a full pipe).
        stdin stays open: its end is how the child sees its parent go away.  The pipes are unbuffered, so closing
        stdin later (another thread) never flushes a write into a dead child."""
        if hasattr(signal, "pthread_sigmask"):
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGPIPE})
        try:
            view = memoryview(payload)
            while view:
                view = view[self._proc.stdin.write(view):]
            self._out.append(self._proc.stdout.read())
        except (OSError, ValueError):
            pass

    def result(self, progress: ProgressFn | None = None, fraction: float = 0.0) -> object | None:
        """Wait for the child and return its result, or None if it did not give one.  ``progress(fraction)`` is
        called while waiting, so a cancel raised from it (:class:`~core.progress.Cancelled`) stops the child and
        propagates."""
        if self._proc is None:
            return None
        try:
            while self._io.is_alive():
                notify(progress, fraction)
                self._io.join(_POLL_S)
            self._close_stdin()
            code = self._proc.wait()
        except BaseException:
            self.stop()
            raise
        if code != 0 or not self._out or not self._out[0]:
            return None
        try:
            return pickle.loads(self._out[0])
        except Exception:                                             # noqa: BLE001 - unreadable: compute it here
            return None

    def stop(self) -> None:
        """Kill the child if it still runs and reap it."""
        if self._proc is None:
            return
        if self._proc.poll() is None:
            self._proc.kill()
        self._proc.wait()
        self._io.join()
        self._close_stdin()

    def _close_stdin(self) -> None:
        """Close the child's stdin (it then exits if it still runs; a closed pipe is fine)."""
        try:
            self._proc.stdin.close()
        except (OSError, ValueError):
            pass
