"""Window-manager progress (the percentage on the cursor) for operators that can take a while."""
from contextlib import contextmanager


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
