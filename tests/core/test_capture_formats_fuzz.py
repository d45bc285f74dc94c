"""Reliability of every capture-format reader under arbitrary input (Hypothesis), as for the Live Link Face CSV.

Whatever the text, :func:`core.retarget.formats.parse_capture` of each kind either returns a stream whose
weights (and rotations) are finite and whose times start at 0 and strictly increase, or raises
:class:`~core.result.ShapeSpaceError` with a one-line message and a known code — never another exception,
never a hang.  Arbitrary text and structured recordings with damaged cells, per reader.
"""
import json
import re
from contextlib import contextmanager

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


# --------------------------------------------------------------------------- MediaPipe JSON: template = parser
@contextmanager
def json_parser_only():
    """The MediaPipe JSON reader without its frame template (:class:`core.retarget.formats._FrameTemplate`):
    every frame through the JSON parser."""
    from core.retarget import formats
    tries = formats._TEMPLATE_TRIES
    formats._TEMPLATE_TRIES = 0
    try:
        yield
    finally:
        formats._TEMPLATE_TRIES = tries


def outcome(text):
    """What reading ``text`` gives: the stream's names, times, weights (bytes) and issues, or the refusal."""
    with no_hang():
        try:
            s = parse_capture(text, kind="mediapipe_json")
        except ShapeSpaceError as exc:
            return "refused", str(exc), exc.code
    return s.names, s.times.tobytes(), s.weights.tobytes(), [i.message for i in s.issues]


tokens = st.sampled_from(["-0", "0", "01", "1.", ".5", "+1", "1e5", "-1.5E-3", "NaN", "Infinity", "-Infinity",
                          "12345678901234567890", "1e400", "-0.0", "true", "null", '"1"', "[]", "{}", "7", "0.25"])


@st.composite
def mediapipe_texts(draw):
    """A plain MediaPipe recording as some writer lays it out (spacing, key order, extra keys), then damaged:
    numbers swapped for other tokens, characters replaced."""
    chans = draw(st.lists(st.sampled_from(("jawOpen", "eyeBlinkLeft", "cheekPuff", "_neutral", "mouthClose")),
                          min_size=1, max_size=4, unique=True))
    last = draw(st.booleans())
    frames = []
    for k in range(draw(st.integers(2, 7))):
        cats = [{"index": j, "score": draw(st.floats(0, 1)), "category_name": n, "display_name": "% 1"}
                for j, n in enumerate(chans)]
        frame = {"face_blendshapes": [cats], "timestamp_ms": k * 33} if last else \
            {"timestamp_ms": draw(st.sampled_from([k * 33, k * 33.5])), "face_blendshapes": [cats]}
        frames.append(frame)
    text = json.dumps(frames, indent=draw(st.sampled_from([None, 1])),
                      separators=draw(st.sampled_from([None, (",", ":")])))
    for _ in range(draw(st.integers(0, 3))):
        numbers = [m.span() for m in re.finditer(r"-?[0-9][0-9.eE+-]*", text)]
        if numbers and draw(st.booleans()):
            a, b = draw(st.sampled_from(numbers))
            text = text[:a] + draw(tokens) + text[b:]
        else:
            at = draw(st.integers(0, len(text) - 1))
            text = text[:at] + draw(st.sampled_from('0123456789.-eE",{}[]:% \n')) + text[at + 1:]
    return text


@FUZZ
@given(mediapipe_texts())
def test_mediapipe_json_template_reads_as_the_json_parser(text):
    """Whatever the text, the frame template changes nothing: the same stream, value for value (bits), or the
    same refusal (message and code) as the JSON parser frame by frame."""
    fast = outcome(text)
    with json_parser_only():
        assert fast == outcome(text)


# --------------------------------------------------------------------------- iFacialMocap: one-pass = cell reader
@st.composite
def ifm_texts(draw):
    """A plain iFacialMocap recording (every frame the first one's fields), then damaged: values swapped for other
    text, characters replaced."""
    chans = draw(names)
    sep, trail = draw(st.sampled_from(["-", "&"])), draw(st.sampled_from(["|", ""]))
    value = st.floats(-100, 100).map(lambda v: f"{v:.3f}")
    frames = []
    for _ in range(draw(st.integers(1, 6))):
        parts = [f"{n}{sep}{draw(value)}" for n in chans]
        parts.append("=head#" + ",".join(draw(value) for _ in range(6)))
        parts.append("rightEye#" + ",".join(draw(value) for _ in range(3)))
        parts.append("leftEye#" + ",".join(draw(value) for _ in range(3)))
        frames.append("|".join(draw(st.permutations(parts)) if draw(st.integers(0, 9)) == 0 else parts) + trail)
    text = draw(st.sampled_from(["\n", "\r\n"])).join(frames) + draw(st.sampled_from(["", "\n", "\n\n"]))
    for _ in range(draw(st.integers(0, 3))):
        numbers = [m.span() for m in re.finditer(r"-?[0-9][0-9.]*", text)]
        if numbers and draw(st.booleans()):
            a, b = draw(st.sampled_from(numbers))
            text = text[:a] + draw(st.sampled_from(["", "1e5", "nan", "inf", "-", "1-2", "1,2", ".5", "5.", "1e999",
                                                    " 1", "1\x00", "é"])) + text[b:]
        else:
            at = draw(st.integers(0, len(text) - 1))
            text = text[:at] + draw(st.sampled_from("0123456789.-e,|&#=\n x")) + text[at + 1:]
    return text


@FUZZ
@given(ifm_texts())
def test_ifacialmocap_one_pass_reads_as_the_cell_reader(text):
    """The one-pass reader reads a recording exactly as the cell reader (names, weights, poses, lines), or leaves
    it to the cell reader."""
    from core.retarget import formats
    frames = text.replace("\r\n", "\n")
    fast = formats._ifm_plain(frames)
    if fast is None:
        return
    slow = formats._ifm_cells(frames)
    assert fast[0] == slow[0]
    for a, b in zip(fast[1:], slow[1:]):
        assert a.shape == b.shape and a.tobytes() == b.tobytes()
