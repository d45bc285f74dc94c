"""One BLAS thread for loops of small dense blocks (foundation; no Blender).

The bounded space-time and per-frame fits call LAPACK/BLAS thousands of times on n × n blocks (n ≈ 50–120).
OpenBLAS splits such calls over its threads; with the cores busy (Blender's own threads, a depsgraph
evaluation, other jobs) the threads spin and wait, and the loop runs 5–10× slower than on one thread (measured:
the facecap→FBHead bounded solve 2.8 s against 0.29 s).  :func:`single_threaded` sets every loaded OpenBLAS
(NumPy's and SciPy's copies) to one thread for the duration of a ``with`` block and restores the previous counts.
It finds the libraries through ``/proc/self/maps`` (Linux); elsewhere it does nothing.
"""
from __future__ import annotations

import contextlib
import ctypes
import sys
from collections.abc import Iterator

__all__ = ["single_threaded"]

_SET = ("openblas_set_num_threads", "openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
        "scipy_openblas_set_num_threads64_")
_GET = ("openblas_get_num_threads", "openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
        "scipy_openblas_get_num_threads64_")
_controls: list | None = None


def _find() -> list:
    """``(set, get)`` function pairs of every OpenBLAS loaded in this process (Linux; else none)."""
    if not sys.platform.startswith("linux"):
        return []
    try:
        with open("/proc/self/maps") as maps:
            paths = sorted({line.split()[-1] for line in maps if "openblas" in line.lower() and "/" in line})
    except OSError:
        return []
    found = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(lib, name) for name in _SET if hasattr(lib, name)), None)
        getter = next((getattr(lib, name) for name in _GET if hasattr(lib, name)), None)
        if setter is not None and getter is not None:
            found.append((setter, getter))
    return found


@contextlib.contextmanager
def single_threaded() -> Iterator[None]:
    """Run the ``with`` block with one OpenBLAS thread; the previous thread counts are restored afterwards."""
    global _controls
    if _controls is None:
        _controls = _find()
    previous = []
    try:
        for setter, getter in _controls:
            count = int(getter())
            if count > 1:
                setter(1)
                previous.append((setter, count))
        yield
    finally:
        for setter, count in previous:
            setter(count)
