"""Reliability of every capture-format reader under arbitrary input (Hypothesis), as for the Live Link Face CSV.

Whatever the text, :func:`core.retarget.formats.parse_capture` of each kind either returns a stream whose
weights (and rotations) are finite and whose times start at 0 and strictly increase, or raises
:class:`~core.result.ShapeSpaceError` with a one-line message and a known code — never another exception,
never a hang.  Arbitrary text and structured recordings with damaged cells, per reader.
"""
import json

import numpy as np
from hypothesis import example, given
from hypothesis import strategies as st

from core.errors import ErrorCode
from core.names import ARKIT_52
from core.result import ShapeSpaceError
from core.retarget.formats import parse_capture
from test_capture_fuzz import FUZZ, no_hang


def check(text, kind=None):
    with no_hang():
        try:
            s = parse_capture(text, kind=kind)
        except ShapeSpaceError as exc:
            assert isinstance(exc.code, ErrorCode)
            assert str(exc) and "\n" not in str(exc).strip()
            return None
    assert s.weights.shape == (s.times.size, len(s.names)) and s.times.size >= 3
    assert s.times[0] == 0 and np.all(np.diff(s.times) > 0)
    assert np.isfinite(s.weights).all() and np.isfinite(s.times).all()
    assert s.rotations is None or (s.rotations.shape == (s.times.size, 9) and np.isfinite(s.rotations).all())
    return s


cells = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.floats(0, 1).map(lambda v: f"{v:.4f}"),
                  st.just(""), st.just("1e308"), st.just("nan"), st.text(alphabet="0123456789.e-x", max_size=6))
names = st.lists(st.sampled_from(ARKIT_52[:8] + ("_neutral", "Foo", "eyeBlink_L")), min_size=1, max_size=5,
                 unique=True)
times = st.one_of(st.integers(0, 10 ** 6).map(str), cells)


# --------------------------------------------------------------------------- Face Cap TXT
@FUZZ
@given(st.text(alphabet="kbsinfo,0123456789.-e \n\rjawOpen_L", max_size=400))
@example("bs,jawOpen\nk,0,0,0,0,0,0,0,0,0,0,0,0.5\nk,1e12,0,0,0,0,0,0,0,0,0,0,0.5\n")
def test_facecap_any_text(text):
    check(text, "facecap_txt")
    check("bs,jawOpen\n" + text, "facecap_txt")


@st.composite
def facecap_takes(draw):
    chans = draw(names)
    lines = ["info,fuzz", "bs," + ",".join(chans)]
    for k in range(draw(st.integers(0, 20))):
        row = [draw(times) if draw(st.integers(0, 9)) == 0 else str(k * draw(st.sampled_from([16, 33, 0, 1])))]
        row += [draw(cells) for _ in range(10 + len(chans) + (draw(st.integers(0, 19)) == 0))]
        lines.append("k," + ",".join(row))
    return "\n".join(lines) + "\n"


@FUZZ
@given(facecap_takes())
def test_facecap_damaged_takes(text):
    check(text)


# --------------------------------------------------------------------------- iFacialMocap
@FUZZ
@given(st.text(alphabet="|=#&-,.0123456789headrightEyeleftjawOpen_L\n ", max_size=400))
@example("jawOpen-10|=head#0,0,0,0,0,0|___iFacialMocapjawOpen-1|___iFacialMocap")
def test_ifacialmocap_any_text(text):
    check(text, "ifacialmocap")


@st.composite
def ifm_takes(draw):
    chans = draw(names)
    frames = []
    for _ in range(draw(st.integers(0, 20))):
        sep = draw(st.sampled_from(["-", "&"]))
        parts = [f"{n}{sep}{draw(cells)}" for n in chans if draw(st.integers(0, 9))]
        parts.append("=head#" + ",".join(draw(cells) for _ in range(draw(st.sampled_from([6, 6, 6, 5])))))
        parts.append("rightEye#" + ",".join(draw(cells) for _ in range(3)))
        frames.append("|".join(parts) + "|")
    return draw(st.sampled_from(["\n", "___iFacialMocap"])).join(frames)


@FUZZ
@given(ifm_takes())
def test_ifacialmocap_damaged_takes(text):
    check(text, "ifacialmocap")


# --------------------------------------------------------------------------- JSON (Audio2Face, MediaPipe)
json_values = st.recursive(st.one_of(st.none(), st.booleans(), st.floats(allow_nan=False), st.integers(-5, 5),
                                     st.text(max_size=5)),
                           lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                   st.dictionaries(st.text(max_size=10), inner, max_size=4)),
                           max_leaves=20)


@FUZZ
@given(json_values)
def test_json_readers_any_structure(value):
    text = json.dumps(value)
    check(text, "audio2face_json")
    check(text, "mediapipe_json")


@st.composite
def a2f_takes(draw):
    chans = draw(names)
    n = draw(st.integers(0, 12))
    rows = [[draw(st.one_of(st.floats(0, 1), st.floats(allow_nan=True, allow_infinity=True), st.none(),
                            st.just("x"))) for _ in range(len(chans) + (draw(st.integers(0, 19)) == 0))]
            for _ in range(n)]
    data = {"exportFps": draw(st.sampled_from([30, 60, 0, -1, 1e9, "x"])), "numPoses": len(chans),
            "numFrames": n + (draw(st.integers(0, 19)) == 0), "facsNames": chans, "weightMat": rows}
    return json.dumps(data)


@FUZZ
@given(a2f_takes())
def test_audio2face_damaged_exports(text):
    check(text)


@st.composite
def mediapipe_takes(draw):
    chans = draw(names)
    frames = []
    for k in range(draw(st.integers(0, 12))):
        cats = [{"category_name": n, "score": draw(st.one_of(st.floats(0, 1), st.floats(allow_nan=False),
                                                              st.just("x")))} for n in chans]
        t = draw(st.one_of(st.just(k * 33.3), st.floats(allow_nan=False), st.just("x")))
        frames.append({"timestamp_ms": t, "face_blendshapes": [cats] if draw(st.integers(0, 5)) else []})
    return json.dumps(frames)


@FUZZ
@given(mediapipe_takes())
def test_mediapipe_json_damaged(text):
    check(text)


@st.composite
def mediapipe_csv_takes(draw):
    chans = draw(names)
    lines = [",".join(["timestamp_ms"] + chans)]
    for k in range(draw(st.integers(0, 20))):
        row = [str(k * 33) if draw(st.integers(0, 9)) else draw(times)] + [draw(cells) for _ in chans]
        lines.append(",".join(row[:draw(st.integers(0, len(row)))] if draw(st.integers(0, 19)) == 0 else row))
    return draw(st.sampled_from(["\n", "\r\n", "\r"])).join(lines)


@FUZZ
@given(mediapipe_csv_takes())
def test_mediapipe_csv_damaged(text):
    check(text)


@FUZZ
@given(st.text(max_size=300))
def test_detection_any_text(text):
    check(text)
