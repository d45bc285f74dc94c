"""Reliability of the Live Link Face reader under arbitrary input (Hypothesis).

Whatever the text or bytes, :func:`core.retarget.capture.read_live_link_csv` either returns a stream whose
weights are finite and whose times start at 0 and strictly increase, or raises
:class:`~core.result.ShapeSpaceError` (one line) — never another exception, never a hang.
:func:`~core.retarget.capture.resample` keeps the same promise for any stream.
"""
import contextlib
import os
import signal
import string

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from core.errors import ErrorCode
from core.names import ARKIT_52
from core.result import ShapeSpaceError
from core.retarget.capture import read_live_link_csv, resample

#: Seconds one example may take before it counts as a hang.
HANG_SECONDS = 20

#: Examples per property (``SHAPESPACE_FUZZ_EXAMPLES=5000`` for a longer hunt).
FUZZ = settings(max_examples=int(os.environ.get("SHAPESPACE_FUZZ_EXAMPLES", 300)), deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


class Hung(BaseException):
    """Raised by the alarm: the reader did not return."""


@contextlib.contextmanager
def no_hang(seconds=HANG_SECONDS):
    if not hasattr(signal, "setitimer"):
        yield
        return

    def alarm(*_):
        raise Hung(f"no answer after {seconds} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def check_stream_or_refusal(source):
    """Read ``source``: a valid stream, or a ShapeSpaceError with a one-line message and a known code."""
    with no_hang():
        try:
            s = read_live_link_csv(source)
        except ShapeSpaceError as exc:
            assert isinstance(exc.code, ErrorCode)
            assert str(exc) and "\n" not in str(exc).strip()
            return None
    assert s.weights.ndim == 2 and s.weights.shape == (s.times.size, len(s.names))
    assert s.times.size >= 3 and s.times[0] == 0 and np.all(np.diff(s.times) > 0)
    assert np.isfinite(s.weights).all() and np.isfinite(s.times).all()
    return s


# --------------------------------------------------------------------------- arbitrary text
CSV_CHARS = string.digits + ":.,-+e\"\r\n \tTimecodJawOpnbliakNIf"


@FUZZ
@given(st.text(alphabet=CSV_CHARS, max_size=400))
@example("\r0\n")                                     # CR-only line ending (found by Hypothesis)
@example('"Timecode,JawOpen\n00:00:00:00,0\n')         # a stray quote
@example("Timecode,JawOpen\r00:00:00:00,0\r00:00:00:01,0\r00:00:00:02,1\r")
def test_any_text_is_a_stream_or_a_refusal(text):
    check_stream_or_refusal("Timecode,JawOpen\n" + text if not text.startswith("Timecode") else text)
    check_stream_or_refusal(text + "\n")


# --------------------------------------------------------------------------- structured takes with damage
def timecodes():
    good = st.builds(lambda h, m, s, f, frac: f"{h:02d}:{m:02d}:{s:02d}:{f:02d}.{frac:03d}",
                     st.integers(0, 23), st.integers(0, 59), st.integers(0, 59), st.integers(0, 59),
                     st.integers(0, 999))
    bad = st.sampled_from(["25:00:00:00", "99999:00:00:00.000", "00:00:00:60", "", "nan", "00:00:00:inf",
                           "-1:00:00:00", "00:00:00", "23:59:59:59.999", "00:00:00:00.000"])
    return st.one_of(good, good, good, bad)


cells = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                  st.floats(0, 1).map(lambda v: f"{v:.4f}"), st.just(""), st.just("1e308"), st.just("-1e308"),
                  st.just("nan"), st.text(alphabet="0123456789.e-x", max_size=6))


@st.composite
def takes(draw):
    channels = draw(st.lists(st.sampled_from(ARKIT_52 + ("HeadYaw", "Foo", "BlendShapeCount")), min_size=1,
                             max_size=6, unique=True))
    header = ["Timecode"] + channels
    start = draw(st.integers(0, 86399)) * 60
    rows = []
    for k in range(draw(st.integers(0, 30))):
        if draw(st.integers(0, 9)) == 0:
            tc = draw(timecodes())
        else:
            frame = (start + k * draw(st.sampled_from([1, 1, 1, 2, 0]))) % (86400 * 60)
            sec, ff = divmod(frame, 60)
            tc = f"{sec // 3600:02d}:{sec // 60 % 60:02d}:{sec % 60:02d}:{ff:02d}.000"
        row = [tc] + [draw(cells) for _ in channels]
        if draw(st.integers(0, 19)) == 0:
            row = row[:draw(st.integers(0, len(row)))]
        rows.append(",".join(row))
    ending = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    return ending.join([",".join(header)] + rows) + ending


@FUZZ
@given(takes())
def test_damaged_takes_are_a_stream_or_a_refusal(text):
    s = check_stream_or_refusal(text)
    if s is not None:
        assert np.abs(s.weights).max(initial=0) <= 100


@FUZZ
@given(st.binary(max_size=600))
def test_any_bytes_in_a_file_are_a_stream_or_a_refusal(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("fuzz") / "take.csv"
    path.write_bytes(b"Timecode,JawOpen\n" + data)
    check_stream_or_refusal(path)
    path.write_bytes(data)
    check_stream_or_refusal(str(path))


# --------------------------------------------------------------------------- resample
@FUZZ
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=1, max_size=8),
       st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True))
def test_resample_is_finite_or_a_refusal(times, fps, start):
    w = np.linspace(0, 1, len(times))[:, None]
    with no_hang():
        try:
            frames, out = resample(np.array(times), w, fps, start_frame=start)
        except ShapeSpaceError:
            return
    assert np.isfinite(out).all() and np.isfinite(frames).all() and out.shape == (frames.size, 1)


def test_resample_refuses_a_day_long_stream_before_allocating():
    with pytest.raises(ShapeSpaceError) as exc:
        resample(np.array([0.0, 86400.0]), np.zeros((2, 52)), 30.0)
    assert exc.value.code == "too_large" and "GiB" in str(exc.value)
