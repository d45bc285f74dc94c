"""Window-manager progress (the percentage on the cursor) for face-space operators that can take seconds."""


class WindowProgress:
    """``with WindowProgress(context) as progress:`` — ``progress(fraction)`` shows 0 … 1 as a percentage;
    the indicator ends however the block ends.  Bridge functions take it as their ``progress`` argument."""

    STEPS = 100

    def __init__(self, context):
        self.wm = context.window_manager

    def __enter__(self):
        self.wm.progress_begin(0, self.STEPS)
        return self

    def __call__(self, fraction: float) -> None:
        self.wm.progress_update(int(round(self.STEPS * min(max(float(fraction), 0.0), 1.0))))

    def __exit__(self, *exc) -> bool:
        self.wm.progress_end()
        return False
