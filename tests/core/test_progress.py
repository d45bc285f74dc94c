"""core.progress: clipping, sub-ranges and cancellation unwinding through a caller."""
import pytest

from core.progress import Cancelled, notify, scaled


def test_notify_clips_and_ignores_none():
    seen = []
    notify(seen.append, 1.5)
    notify(seen.append, -0.2)
    notify(None, 0.5)
    assert seen == [1.0, 0.0]


def test_scaled_maps_onto_the_parent_range():
    seen = []
    sub = scaled(seen.append, 0.25, 0.75)
    for f in (0.0, 0.5, 1.0, 2.0):
        sub(f)
    assert seen == pytest.approx([0.25, 0.5, 0.75, 0.75])
    assert scaled(None, 0.0, 1.0) is None


def test_cancelled_unwinds_from_the_callback():
    def work(progress):
        for i in range(10):
            notify(progress, i / 10)
        return "done"

    def cancel_at_half(fraction):
        if fraction >= 0.5:
            raise Cancelled()

    with pytest.raises(Cancelled):
        work(cancel_at_half)
    assert work(None) == "done"
