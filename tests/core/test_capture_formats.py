"""core.retarget.formats: every capture app's recording reads back to the take it was written from.

The known take is the shared Live Link Face CSV (re-read here with the ``csv`` module and hand-converted
timecodes), with a synthetic head motion added (the real take's head columns are all 0).  Each format's
file is written by the test from that take following the format's documentation (see the module docstring
of :mod:`core.retarget.formats`): names are respelled by hand, angles converted to the format's units and
axes by hand.  Reading it back must give the same weights per ARKit channel, the same times, and the same
head / eye rotations (where the format records them).
"""
import csv
import json
import os
from pathlib import Path

import numpy as np
import pytest

from capture_files import (
    arkit_name,
    load_llf_take,
    write_audio2face,
    write_facecap,
    write_ifacialmocap,
    write_mediapipe_csv,
    write_mediapipe_json,
)
from core.result import ShapeSpaceError
from core.retarget.capture import MAX_FILE_BYTES, ROTATION_CHANNELS, read_live_link_csv, resample
from core.retarget.formats import describe_stream, detect_kind, parse_capture, read_capture

REPO = Path(__file__).resolve().parents[2]
LLF_CSV = REPO.parent / "shared" / "data" / "llf_fbhead" / "MySlate_3_Jason_Millers_iPhone.csv"
if not LLF_CSV.exists():
    LLF_CSV = REPO / "assets" / "llf_fbhead" / "MySlate_3_Jason_Millers_iPhone.csv"


@pytest.fixture(scope="module")
def take():
    """The LLF take by hand (:func:`capture_files.load_llf_take`), with a synthetic head motion."""
    return load_llf_take(LLF_CSV)


def by_channel(stream):
    return {n.lower().replace("_l", "left").replace("_r", "right"): stream.weights[:, j]
            for j, n in enumerate(stream.names)}


def assert_same_weights(stream, take, drop=()):
    names, _, w, _ = take
    got = by_channel(stream)
    for j, n in enumerate(names):
        if arkit_name(n) in drop:
            continue
        np.testing.assert_allclose(got[n.lower()], w[:, j], rtol=0, atol=1e-9, err_msg=n)
    assert len(got) == len(names) - len(drop)


# --------------------------------------------------------------------------- round trips
def test_llf_csv_with_head_and_eyes(take):
    s = read_capture(LLF_CSV)
    assert s.kind == "llf_csv"
    np.testing.assert_allclose(s.times, take[1], atol=1e-9)
    assert_same_weights(s, take)
    with open(LLF_CSV, newline="", encoding="utf-8") as fh:
        raw = np.array([[float(c) for c in r[54:63]] for r in list(csv.reader(fh))[1:]])
    np.testing.assert_array_equal(s.rotations, raw)
    assert read_live_link_csv(LLF_CSV).rotations is None          # the LLF reader's default is unchanged


def test_facecap_txt_round_trip(take):
    s = parse_capture(write_facecap(take))
    assert s.kind == "facecap_txt"
    np.testing.assert_allclose(s.times, take[1], atol=1e-9)
    assert_same_weights(s, take)
    expected = take[3].copy()
    expected[:, [5, 8]] = 0.0                           # Face Cap records no eye roll
    np.testing.assert_allclose(s.rotations, expected, atol=1e-12)


def test_ifacialmocap_round_trip_lines_and_tcp_stream(take):
    for text in (write_ifacialmocap(take), write_ifacialmocap(take, tcp=True)):
        s = parse_capture(text)
        assert s.kind == "ifacialmocap"
        np.testing.assert_allclose(s.times, np.arange(take[1].size) / 60.0, atol=1e-12)   # no time: 60 fps
        assert_same_weights(s, take)
        np.testing.assert_allclose(s.rotations, take[3], atol=1e-12)


def test_audio2face_round_trip(take):
    s = parse_capture(write_audio2face(take, fps=30))
    assert s.kind == "audio2face_json" and s.rate == 30
    np.testing.assert_allclose(s.times, np.arange(take[1].size) / 30.0, atol=1e-12)
    assert_same_weights(s, take)
    assert s.rotations is None


@pytest.mark.parametrize("writer, kind", [(write_mediapipe_json, "mediapipe_json"),
                                          (write_mediapipe_csv, "mediapipe_csv")])
def test_mediapipe_round_trip_neutral_ignored(take, writer, kind):
    s = parse_capture(writer(take))
    assert s.kind == kind
    np.testing.assert_allclose(s.times, take[1], atol=1e-9)
    assert_same_weights(s, take, drop=("tongueOut",))
    assert "_neutral" not in s.names
    missing = [i for i in s.issues if i.code == "missing_channels"]
    assert missing and missing[0].items == ("tongueOut",)
    assert not [i for i in s.issues if i.code == "extra_columns"]


def test_mediapipe_lost_face_is_filled(take):
    frames = json.loads(write_mediapipe_json(take))
    frames[10]["face_blendshapes"] = []
    s = parse_capture(json.dumps({"frames": frames}))
    j = s.names.index("jawOpen")
    k = take[0].index("JawOpen")
    t, w = take[1], take[2][:, k]
    expected = w[9] + (w[11] - w[9]) * (t[10] - t[9]) / (t[11] - t[9])
    assert s.weights[10, j] == pytest.approx(expected, abs=1e-12)
    assert "no_face" in {i.code for i in s.issues}


def test_variable_rate_facecap_resamples_like_a_csv(take):
    """Face Cap times are the recording's own: uneven keys land on the scene's frames by interpolation."""
    names, t, w, rot = take
    uneven = t + 0.005 * np.sin(np.arange(t.size))          # steps of 1/60 s ± 0.01 s: still increasing
    s = parse_capture(write_facecap((names, uneven, w, rot)))
    np.testing.assert_allclose(s.times, uneven - uneven[0], atol=1e-9)
    frames, out = resample(s.times, s.weights, 24.0)
    j, k = s.names.index("jawOpen"), names.index("JawOpen")
    np.testing.assert_allclose(out[:, j], np.interp(np.arange(frames.size) / 24.0, uneven - uneven[0], w[:, k]),
                               atol=1e-12)


# --------------------------------------------------------------------------- detection, describe, limits
def test_kind_from_content_not_extension(take, tmp_path):
    path = tmp_path / "take.csv"                               # a Face Cap TXT under a CSV name
    path.write_text(write_facecap(take), encoding="utf-8")
    assert read_capture(path).kind == "facecap_txt"
    path = tmp_path / "take.txt"
    path.write_text(write_audio2face(take), encoding="utf-8")
    assert read_capture(path).kind == "audio2face_json"


def test_unknown_content_named_in_one_line():
    with pytest.raises(ShapeSpaceError) as exc:
        detect_kind("hello world\n1 2\n")
    assert exc.value.code == "unsupported_file" and "Face Cap TXT" in str(exc.value)
    with pytest.raises(ShapeSpaceError) as exc:
        detect_kind("Time,JawOpen\n1,0.5\n")
    assert exc.value.code == "no_timecode" and "no Timecode column" in str(exc.value)


def test_describe_stream(take):
    d = describe_stream(parse_capture(write_facecap(take)))
    assert d["kind"] == "facecap_txt" and d["frames"] == take[1].size and d["channels"] == 52
    assert d["duration_s"] == pytest.approx(take[1][-1], abs=1e-9)
    assert d["head_eye_channels"] == list(ROTATION_CHANNELS)
    assert set(d["head_eye_moving"]) == {"HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw", "LeftEyePitch",
                                         "RightEyeYaw", "RightEyePitch"}
    assert d["measured_rate"] == pytest.approx(60, rel=0.01)
    assert describe_stream(parse_capture(write_audio2face(take)))["head_eye_channels"] == []


@pytest.mark.parametrize("text, where", [
    ("bs,jawOpen\nk,0,0,0,0,0,0,0,0,0,0,0,0.1\nk,16,0,0,0,0,0,0,0,0,0,0,x\n", "line 3, field 13 (jawOpen)"),
    ("bs,jawOpen\nk,0,0,0,0,0,0,0,0,0,0,0,0.1\nk,16,0,0,0,0,0,0,0,0,0,0\n", "line 3"),
    ("jawOpen-10|=head#0,0,0,0,0,0|\njawOpen-1e9|=head#0,0,0,0,0,0|\n", "line 2, jawOpen"),
    ('{"exportFps": 30, "facsNames": ["jawOpen"], "weightMat": [[0.1], [0.2], ["a"]]}', "weightMat frame 3"),
    ('[{"timestamp_ms": 0, "face_blendshapes": [[{"category_name": "jawOpen"}]]}]', "frame 1"),
    ("timestamp_ms,jawOpen\n0,0.1\n16,\"x\"\n", "line 3, column 'jawOpen'"),
])
def test_damaged_cells_named_in_one_line(text, where):
    with pytest.raises(ShapeSpaceError) as exc:
        parse_capture(text)
    assert where in str(exc.value) and "\n" not in str(exc.value)


def test_fifo_and_huge_files_are_refused_without_reading(tmp_path):
    if hasattr(os, "mkfifo"):
        fifo = tmp_path / "take.txt"
        os.mkfifo(fifo)
        with pytest.raises(ShapeSpaceError) as exc:
            read_capture(fifo)
        assert "FIFO" in str(exc.value)
    big = tmp_path / "huge.json"
    with open(big, "wb") as fh:
        fh.truncate(MAX_FILE_BYTES + 1)                      # sparse: nothing is written or read
    with pytest.raises(ShapeSpaceError) as exc:
        read_capture(big)
    assert exc.value.code == "too_large"


def test_audio2face_counts_must_match(take):
    data = json.loads(write_audio2face(take))
    data["numFrames"] += 1
    with pytest.raises(ShapeSpaceError) as exc:
        parse_capture(json.dumps(data))
    assert "numFrames" in str(exc.value)


def test_binary_file_refused_in_one_line():
    """The shared Face Cap capture is a glTF (its action is read by the action path), not a recording."""
    glb = REPO.parent / "shared" / "data" / "facecap" / "facecap.glb"
    if not glb.exists():
        pytest.skip("no shared Face Cap data")
    with pytest.raises(ShapeSpaceError) as exc:
        read_capture(glb)
    assert str(exc.value).startswith(str(glb)) and "\n" not in str(exc.value)


# --------------------------------------------------------------------------- one-pass readers = cell readers
def test_plain_fast_paths_engage_and_equal_the_cell_readers(take):
    """Plain recordings are read in one pass; the result is the per-cell reader's, value for value."""
    from core.retarget import capture, formats
    text = write_facecap(take)
    fast, slow = formats._facecap_plain(text), formats._facecap_cells(text)
    assert fast is not None
    assert fast[0] == slow[0]
    for a, b in zip(fast[1:], slow[1:]):
        np.testing.assert_array_equal(a, b)
    text = LLF_CSV.read_text(encoding="utf-8")
    header = [h.strip() for h in text.split("\n", 1)[0].split(",")]
    fast = capture._plain_llf_rows(text, header, 0, list(range(2, 63)), 60.0)
    slow = capture._read_rows(capture._csv_rows(text.split("\n", 1)[1]), header, 0, list(range(2, 63)), 60.0)
    assert fast is not None
    np.testing.assert_array_equal(fast[0], slow[0])
    np.testing.assert_array_equal(fast[1], slow[1])
    np.testing.assert_array_equal(fast[2], slow[2] + 1)          # the header is line 1 of the file
    assert fast[3][0] == slow[3][0]
    text = write_ifacialmocap(take)
    fast, slow = formats._ifm_plain(text), formats._ifm_cells(text)
    assert fast is not None and fast[0] == slow[0]
    for a, b in zip(fast[1:], slow[1:]):
        np.testing.assert_array_equal(a, b)
    assert formats._ifm_plain(text.replace("jawOpen&", "jawOpenX&", 1)) is None    # another field: cell by cell
    text = write_mediapipe_csv(take)
    fast = parse_capture(text)
    slow = parse_capture(text.replace("timestamp_ms", '"timestamp_ms"', 1))     # a quote: read cell by cell
    np.testing.assert_array_equal(fast.weights, slow.weights)
    np.testing.assert_array_equal(fast.times, slow.times)


# --------------------------------------------------------------------------- MediaPipe JSON read in pieces
@pytest.fixture()
def small_pieces(monkeypatch):
    """Pieces far smaller than a frame (~5 K): every frame crosses pieces, and the reader reads on mid-frame."""
    from core.retarget import capture, formats
    monkeypatch.setattr(capture, "PLAIN_CHUNK", 1000)
    monkeypatch.setattr(formats, "_JSON_AHEAD", 300)


def _mediapipe_variants(take):
    """A plain recording, and one with a lost face, a NaN score, an integer score, categories in another order,
    CRLF line breaks and indentation (each frame then not read by the plain path)."""
    short = (take[0], take[1][:40], take[2][:40], take[3][:40])
    plain = write_mediapipe_json(short)
    frames = json.loads(plain)
    frames[3]["face_blendshapes"] = []
    frames[5]["face_blendshapes"][0][7]["score"] = float("nan")
    frames[6]["face_blendshapes"][0][2]["score"] = 1
    frames[8]["face_blendshapes"][0].reverse()
    frames[9]["face_blendshapes"][0][4]["category_name"] = "cheekPuff2"
    return [plain, json.dumps(frames), json.dumps(frames, indent=1).replace("\n", "\r\n")]


def test_mediapipe_json_file_read_in_pieces_equals_the_text(take, tmp_path, small_pieces):
    path = tmp_path / "take.json"
    for text in _mediapipe_variants(take):
        path.write_text(text, encoding="utf-8")
        whole, pieces = parse_capture(text), read_capture(path)
        assert pieces.kind == whole.kind == "mediapipe_json" and pieces.names == whole.names
        np.testing.assert_array_equal(pieces.times, whole.times)
        np.testing.assert_array_equal(pieces.weights, whole.weights)
        assert [i.message for i in pieces.issues] == [i.message for i in whole.issues]


def _stray_x(text, at):
    """``text`` with an ``x`` at the start of the line after ``at`` (invalid JSON there)."""
    at = text.index("\n", at) + 1
    return text[:at] + "x" + text[at:]


@pytest.mark.parametrize("damage", [
    lambda text: _stray_x(text, len(text) - 900),                       # invalid JSON in the last frame
    lambda text: text.replace('"score": 0.5', '"score": 0.5.5', 30),     # invalid JSON in frame 30
    lambda text: text.replace('"score": 0.5', '"score": 500', 7).replace('"timestamp_ms": 1000.0', '"x": 1'),
    lambda text: text.replace('"score": 0.5', '"score": "a"', 12),
    lambda text: text[:-1] + ", 7]",
    lambda text: text + " {}",
])
def test_mediapipe_json_file_read_in_pieces_refused_as_the_text(take, tmp_path, small_pieces, damage):
    """Every refusal of the piecewise reader is the whole text's, line and column included (multi-line JSON)."""
    short = (take[0], take[1][:70], take[2][:70], take[3][:70])
    text = damage(json.dumps(json.loads(write_mediapipe_json(short)), indent=1))
    path = tmp_path / "take.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ShapeSpaceError) as whole:
        parse_capture(text)
    with pytest.raises(ShapeSpaceError) as pieces:
        read_capture(path)
    assert str(pieces.value) == f"{path}: {whole.value}" and pieces.value.code == whole.value.code


def test_mediapipe_json_damaged_score_named_before_a_later_damaged_frame():
    frame = '{"timestamp_ms": %d, "face_blendshapes": [[{"category_name": "jawOpen", "score": %s}]]}'
    frames = [frame % (k * 33, "0.5") for k in range(9)]
    frames[4] = frame % (4 * 33, "500")
    frames[7] = '{"timestamp_ms": 231, "face_blendshapes": [[{"category_name": "jawOpen"}]]}'
    with pytest.raises(ShapeSpaceError) as exc:
        parse_capture("[" + ", ".join(frames) + "]")
    assert str(exc.value) == "frame 5, jawOpen: 500 is beyond ±100: a damaged value"


def test_mediapipe_json_not_utf8_further_on_is_refused_as_such(take, tmp_path, small_pieces):
    """A file that is not UTF-8 is refused as such even when its JSON is damaged before the bad byte."""
    short = (take[0], take[1][:20], take[2][:20], take[3][:20])
    data = write_mediapipe_json(short).replace('"score": 0.5', '"score": x', 1).encode("utf-8") + b"\xff"
    path = tmp_path / "take.json"
    path.write_bytes(data)
    with pytest.raises(ShapeSpaceError) as exc:
        read_capture(path)
    assert str(exc.value) == f"{path}: line 1: not UTF-8 text (byte {len(data) - 1}): not a Live Link Face CSV"


def test_mediapipe_json_file_memory_is_bounded(take, tmp_path, monkeypatch):
    """A long MediaPipe JSON is read in pieces: the peak of traced memory (the weights and their copies) stays
    under half the file (the whole text, and its bytes besides, were held before: twice the file)."""
    import tracemalloc

    from capture_files import long_take
    from core.retarget import capture, formats
    monkeypatch.setattr(capture, "PLAIN_CHUNK", 1 << 16)
    monkeypatch.setattr(formats, "_JSON_AHEAD", 1 << 14)
    path = tmp_path / "take.json"
    path.write_text(write_mediapipe_json(long_take(take, 2000)), encoding="utf-8")
    tracemalloc.start()
    try:
        s = read_capture(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert s.times.size == 2000
    assert peak < 0.5 * path.stat().st_size


def test_mediapipe_json_frame_template_engages_and_equals_the_parser(take, tmp_path, monkeypatch):
    """A recording of repeated frames is read by the frame template (all but the first and the last frame),
    from the text and from the file in pieces; the stream is the JSON parser's, value for value."""
    from core.retarget import formats
    short = (take[0], take[1][:300], take[2][:300], take[3][:300])
    text = write_mediapipe_json(short)
    path = tmp_path / "take.json"
    path.write_text(text, encoding="utf-8")
    taken = []
    real = formats._FrameTemplate.take

    def counted(self, src, at):
        end, count = real(self, src, at)
        taken.append(count)
        return end, count

    monkeypatch.setattr(formats._FrameTemplate, "take", counted)
    fast, pieces = parse_capture(text), read_capture(path)
    assert sum(taken) == 2 * (300 - 2)
    monkeypatch.setattr(formats, "_TEMPLATE_TRIES", 0)
    slow = parse_capture(text)
    for s in (fast, pieces):
        assert s.names == slow.names
        assert s.times.tobytes() == slow.times.tobytes() and s.weights.tobytes() == slow.weights.tobytes()
