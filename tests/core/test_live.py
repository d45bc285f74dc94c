"""core.live: packet decoders (Live Link Face v6, iFacialMocap, Face Cap messages), One-Euro filter,
calibration and rotations, per-frame solvers against the offline methods, scene-rate resampling.

References are independent where they can be: packets are built with ``struct`` by hand, the offline
methods are core.retarget's own (copy_weights, fit_frames, resample), rotations are checked against
their defining properties (orthogonality, composition, inverse).
"""
import math
import struct

import numpy as np
import pytest

from core.live import (
    FACECAP_52,
    LLF_BLENDSHAPES,
    LLF_CURVES,
    MAX_OSC_DEPTH,
    CopySolver,
    FaceCapAssembler,
    GeometricSolver,
    LearnedSolver,
    Neutral,
    OneEuroFilter,
    SceneResampler,
    bone_local,
    calibrate,
    check_osc_message,
    decode_ifacialmocap,
    decode_llf,
    encode_ifacialmocap,
    encode_llf,
    euler_matrix,
    face_to_armature,
    format_timecode,
    implausible_channel,
    matrix_euler,
    matrix_quaternion,
    osc_bundle_messages,
    quaternion_to_yaw_pitch_roll,
    rotation_power,
)
from core.live import frames as live_frames
from core.names import canonical_name
from core.result import ShapeSpaceError
from core.retarget import capture, copy_weights, fit_frames, resample

CSV_ORDER = ("EyeBlinkLeft,EyeLookDownLeft,EyeLookInLeft,EyeLookOutLeft,EyeLookUpLeft,EyeSquintLeft,EyeWideLeft,"
             "EyeBlinkRight,EyeLookDownRight,EyeLookInRight,EyeLookOutRight,EyeLookUpRight,EyeSquintRight,"
             "EyeWideRight,JawForward,JawRight,JawLeft,JawOpen").split(",")


def _hand_packet(values, frame=1000, sub=0.25, fps=60, den=1, version=6, count=61, subject=b"iPhone"):
    dev = b"0123456789abcdef0123456789abcdef0123"
    return (bytes([version]) + struct.pack(">i", len(dev)) + dev + struct.pack(">i", len(subject)) + subject
            + struct.pack(">ifiiB", frame, sub, fps, den, count) + struct.pack(f">{len(values)}f", *values))


# ------------------------------------------------------------------ Live Link Face
def test_llf_packet_decodes_by_name_in_the_arkit_enum_order():
    values = np.arange(61, dtype=np.float32) / 100.0
    f = decode_llf(_hand_packet(values), arrival=5.0)
    assert f.names == LLF_BLENDSHAPES and f.weights.shape == (52,)
    # the enum order differs from the CSV's: JawLeft is curve 15 in packets, after JawRight in the CSV
    assert LLF_CURVES.index("JawLeft") == 15 and CSV_ORDER.index("JawLeft") == 16
    assert f.weights[LLF_BLENDSHAPES.index("JawLeft")] == pytest.approx(0.15)
    np.testing.assert_allclose(f.head, values[52:55], rtol=1e-7)
    np.testing.assert_allclose(f.eye_left, values[55:58], rtol=1e-7)
    np.testing.assert_allclose(f.eye_right, values[58:61], rtol=1e-7)
    assert f.frame == 1000 and f.rate == 60 and f.time == pytest.approx(1000.25 / 60)
    assert f.subject == "iPhone" and f.arrival == 5.0


def test_llf_encoder_matches_the_hand_packet_and_rate_denominator():
    values = np.linspace(0, 1, 61)
    assert encode_llf(values, 1000, 0.25, device_id="0123456789abcdef0123456789abcdef0123") == \
        _hand_packet(values.astype(np.float32))
    f = decode_llf(encode_llf(values, 30, 0.5, fps=30000, denominator=1001))
    assert f.time == pytest.approx(30.5 * 1001 / 30000)


def test_llf_no_face_packet_is_none():
    dev, subj = b"x" * 36, b"s"
    assert decode_llf(bytes([6]) + struct.pack(">i", 36) + dev + struct.pack(">i", 1) + subj) is None


@pytest.mark.parametrize("case", ["empty", "version", "count", "truncated_floats", "truncated_header",
                                  "trailing", "name_length", "nan", "rate", "subframe", "huge"])
def test_llf_malformed_packets_raise_one_line(case):
    good = _hand_packet(np.zeros(61))
    bad = {"empty": b"", "version": _hand_packet(np.zeros(61), version=5),
           "count": _hand_packet(np.zeros(52), count=52),
           "truncated_floats": good[:-3], "truncated_header": good[:30], "trailing": good + b"\0",
           "name_length": bytes([6]) + struct.pack(">i", 10_000) + b"abc",
           "nan": _hand_packet([np.nan] + [0.0] * 60), "rate": _hand_packet(np.zeros(61), fps=0),
           "subframe": _hand_packet(np.zeros(61), sub=1.5), "huge": good + bytes(65_000)}[case]
    with pytest.raises(ShapeSpaceError) as err:
        decode_llf(bad)
    assert err.value.code == "malformed_packet" and "\n" not in str(err.value)


def test_llf_every_truncation_and_random_bytes_never_crash():
    good = _hand_packet(np.full(61, 0.5))
    for n in range(len(good)):
        out = None
        try:
            out = decode_llf(good[:n])
        except ShapeSpaceError as exc:
            assert exc.code == "malformed_packet"
        assert out is None or n == len(good)
    rng = np.random.default_rng(0)
    for _ in range(2000):
        blob = rng.integers(0, 256, size=int(rng.integers(0, 400)), dtype=np.uint8).tobytes()
        if blob and rng.random() < 0.5:
            blob = bytes([6]) + blob[1:]
        try:
            decode_llf(blob)
        except ShapeSpaceError as exc:
            assert exc.code == "malformed_packet"


def test_timecode_text():
    assert format_timecode(1929.1311166666666) == "00:32:09:07.867"
    assert format_timecode(0.0) == "00:00:00:00.000"


# ------------------------------------------------------------------ iFacialMocap
@pytest.mark.parametrize("sep", ["&", "-"])
def test_ifacialmocap_round_trip_and_names(sep):
    w = np.linspace(0.0, 1.0, 52)
    f = decode_ifacialmocap(encode_ifacialmocap(w, (10.0, -20.0, 5.0), (0.1, 0.2, 0.3), (1, 2, 3), (4, 5, 6),
                                                separator=sep), arrival=2.0)
    assert f.names == FACECAP_52
    np.testing.assert_allclose(f.weights, w, atol=1e-6)
    np.testing.assert_allclose(f.head, np.radians([-20.0, 10.0, 5.0]))      # (yaw, pitch, roll)
    np.testing.assert_allclose(f.eye_right, np.radians([2, 1, 3]))
    np.testing.assert_allclose(f.eye_left, np.radians([5, 4, 6]))
    np.testing.assert_allclose(f.head_position, [0.1, 0.2, 0.3])
    assert f.time == 2.0


def test_ifacialmocap_maps_any_spelling_and_ignores_unknown_names():
    f = decode_ifacialmocap(b"jawOpen-72|EyeBlinkLeft-25|cheekRaiser_L-40|=head#0,0,0,0,0,0|")
    assert f.weights[FACECAP_52.index("jawOpen")] == pytest.approx(0.72)
    assert f.weights[FACECAP_52.index("eyeBlink_L")] == pytest.approx(0.25)
    assert f.weights.sum() == pytest.approx(0.97)


@pytest.mark.parametrize("text", [b"", b"jawOpen-30|", b"=head#0,0,0,0,0,0|", b"jawOpen-x|=head#0,0,0,0,0,0|",
                                  b"jawOpen-30|=head#1,2,3|", b"jawOpen-30|=head#0,0,0,0,0,0|=head#0,0,0,0,0,0|",
                                  b"eyeBlink_L-1|eyeBlinkLeft-2|=head#0,0,0,0,0,0|", b"\xff\xfe",
                                  b"jaw Open-3|=head#0,0,0,0,0,0|", b"jawOpen-inf|=head#0,0,0,0,0,0|",
                                  b"x-1|" * 200 + b"=head#0,0,0,0,0,0|"])
def test_ifacialmocap_malformed(text):
    with pytest.raises(ShapeSpaceError) as err:
        decode_ifacialmocap(text)
    assert err.value.code == "malformed_packet"


# ------------------------------------------------------------------ Face Cap messages
def test_facecap_assembler_maps_indices_to_names_and_rotations():
    a = FaceCapAssembler()
    a.apply("/W", [FACECAP_52.index("jawOpen"), 0.5])
    a.apply("/HR", [10.0, 20.0, 30.0])
    a.apply("/HT", [1.0, 2.0, 3.0])
    a.apply("/ELR", [5.0, -6.0])
    a.apply("/ERR", [7.0, 8.0])
    a.apply("/unknown", ["anything"])
    assert not a.sweep_done
    a.apply("/W", [51, 0.0])
    assert a.sweep_done
    f = a.frame(1.5, 2.0)
    assert not a.sweep_done and f.names == FACECAP_52 and f.time == 1.5 and f.arrival == 2.0
    assert f.weights[FACECAP_52.index("jawOpen")] == 0.5
    np.testing.assert_allclose(f.head, np.radians([20, 10, 30]))
    np.testing.assert_allclose(f.eye_left, np.radians([-6, 5, 0]))
    np.testing.assert_allclose(f.head_position, [1, 2, 3])
    # a quaternion head: about y by 40° is a pure yaw
    h = math.radians(40) / 2
    a.apply("/HRQ", [0.0, math.sin(h), 0.0, math.cos(h)])
    np.testing.assert_allclose(a.frame(0, 0).head, [math.radians(40), 0, 0], atol=1e-12)


@pytest.mark.parametrize("address,args", [("/W", [52, 0.1]), ("/W", [1.5, 0.1]), ("/W", [3]), ("/HR", [1, 2]),
                                          ("/HRQ", [0, 0, 0, 0]), ("/ELR", ["a", 1]), ("/HT", [1, 2, float("nan")])])
def test_facecap_bad_messages(address, args):
    with pytest.raises(ShapeSpaceError) as err:
        FaceCapAssembler().apply(address, args)
    assert err.value.code == "malformed_packet"


def test_quaternion_to_angles_inverts_euler_matrix():
    rng = np.random.default_rng(1)
    for _ in range(50):
        ypr = rng.uniform([-3, -1.4, -3], [3, 1.4, 3])
        w, x, y, z = matrix_quaternion(euler_matrix(ypr))
        np.testing.assert_allclose(quaternion_to_yaw_pitch_roll([x, y, z, w]), ypr, atol=1e-10)


# ------------------------------------------------------------------ One-Euro filter
def test_one_euro_with_beta_zero_is_exponential_smoothing_at_min_cutoff():
    f = OneEuroFilter(min_cutoff=2.0, beta=0.0)
    x = np.random.default_rng(2).normal(size=(50, 3))
    out = [f(x[0], 0.0)]
    ref = [x[0]]
    dt = 1 / 60
    alpha = 1 / (1 + 1 / (2 * math.pi * 2.0) / dt)
    for i in range(1, 50):
        out.append(f(x[i], i * dt))
        ref.append(ref[-1] + alpha * (x[i] - ref[-1]))
    np.testing.assert_allclose(out, ref, rtol=1e-12)


def test_one_euro_removes_jitter_at_rest_and_follows_fast_motion():
    rng = np.random.default_rng(3)
    t = np.arange(240) / 60
    still = 0.5 + 0.02 * rng.normal(size=240)
    f = OneEuroFilter(min_cutoff=1.0, beta=0.5)
    smooth = np.array([f(np.array([v]), ti)[0] for v, ti in zip(still, t)])
    assert np.std(smooth[60:]) < 0.35 * np.std(still[60:])
    ramp = np.clip((t - 1.0) * 4.0, 0, 1)            # a fast move from 0 to 1 in 0.25 s
    f2, f0 = OneEuroFilter(1.0, 5.0), OneEuroFilter(1.0, 0.0)
    fast = np.array([f2(np.array([v]), ti)[0] for v, ti in zip(ramp, t)])
    slow = np.array([f0(np.array([v]), ti)[0] for v, ti in zip(ramp, t)])
    k = int(np.searchsorted(t, 1.3))
    assert abs(fast[k] - ramp[k]) < 0.5 * abs(slow[k] - ramp[k])


def test_one_euro_repeated_time_and_reset():
    f = OneEuroFilter(1.0, 0.1)
    f(np.array([0.0]), 0.0)
    a = f(np.array([1.0]), 0.1)
    assert f(np.array([5.0]), 0.1)[0] == a[0]                # repeated time: last output
    f.reset()
    assert f(np.array([5.0]), 0.2)[0] == 5.0
    with pytest.raises(ShapeSpaceError):
        OneEuroFilter(min_cutoff=0.0)


# ------------------------------------------------------------------ calibration and rotations
def test_euler_matrix_is_the_documented_composition_and_inverts():
    def ry(a):
        return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])

    def rx(a):
        return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])

    def rz(a):
        return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])

    ypr = np.array([0.3, -0.2, 0.1])
    R = euler_matrix(ypr)
    np.testing.assert_allclose(R, ry(0.3) @ rx(-0.2) @ rz(0.1), atol=1e-15)
    np.testing.assert_allclose(matrix_euler(R), ypr, atol=1e-14)


def test_calibration_makes_the_rest_frame_zero_and_keeps_full_range():
    n = 4
    rest = np.array([0.1, 0.0, 0.5, 0.97, 0.2, -0.1, 0.05, 0.0, 0.1, 0.0, 0.0, 0.0, 0.3])
    neutral = Neutral.from_vector(rest, n)
    np.testing.assert_allclose(calibrate(rest, neutral), np.r_[0, 0, 0, 0.97, np.zeros(9)], atol=1e-12)
    full = rest.copy()
    full[:3] = 1.0
    np.testing.assert_allclose(calibrate(full, neutral)[:3], 1.0)
    below = rest.copy()
    below[0] = 0.0
    assert calibrate(below, neutral)[0] == 0.0
    # head turned by 0.4 yaw from the rest pose → 0.4 yaw relative (same axis as the rest's own yaw)
    turned = rest.copy()
    turned[4:7] = matrix_euler(euler_matrix(rest[4:7]) @ euler_matrix([0.4, 0, 0]))
    np.testing.assert_allclose(calibrate(turned, neutral)[4:7], [0.4, 0, 0], atol=1e-12)
    np.testing.assert_array_equal(calibrate(rest, None), rest)


def test_head_neck_split_composes_to_the_whole_rotation():
    R = euler_matrix([0.5, -0.3, 0.2])
    for share in (0.0, 0.3, 1.0):
        A, C = rotation_power(R, share), rotation_power(R, 1 - share)
        np.testing.assert_allclose(A @ C, R, atol=1e-12)
        np.testing.assert_allclose(A @ A.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rotation_power(np.eye(3), 0.5), np.eye(3))


def test_face_frame_to_armature_and_bone_local():
    yaw = face_to_armature(euler_matrix([0.3, 0, 0]))             # yaw turns about the armature's Z (up)
    np.testing.assert_allclose(yaw @ [0, 0, 1], [0, 0, 1], atol=1e-15)
    pitch = face_to_armature(euler_matrix([0, 0.3, 0]))           # pitch about X (the side axis)
    np.testing.assert_allclose(pitch @ [1, 0, 0], [1, 0, 0], atol=1e-15)
    roll = face_to_armature(euler_matrix([0, 0, 0.3]))            # roll about −Y (forward)
    np.testing.assert_allclose(roll @ [0, 1, 0], [0, 1, 0], atol=1e-15)
    mirrored = face_to_armature(euler_matrix([0.3, 0.2, 0.1]), mirror=True)
    np.testing.assert_allclose(mirrored, face_to_armature(euler_matrix([-0.3, 0.2, -0.1])), atol=1e-14)
    # an upright bone (rest: Y along armature Z): its local rotation maps the armature-space turn back
    B = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    L = bone_local(yaw, B)
    np.testing.assert_allclose(B @ L @ B.T, yaw, atol=1e-15)
    q = matrix_quaternion(L)
    np.testing.assert_allclose(np.abs(q[1:]) / np.linalg.norm(q[1:]), [0, 1, 0], atol=1e-12)  # about bone Y


# ------------------------------------------------------------------ solvers against the offline methods
def test_copy_solver_equals_offline_copy_with_gain_offset_and_clip():
    rng = np.random.default_rng(4)
    W = rng.uniform(-0.2, 1.2, size=(30, 6))
    pairs = [(0, 2), (3, 0), (5, 4)]
    gain, offset = rng.uniform(0.5, 2, 5), rng.uniform(-0.1, 0.1, 5)
    lo, hi = np.zeros(5), np.ones(5)
    ref = np.clip(copy_weights(W, pairs, 5, gain, offset), lo, hi)
    s = CopySolver(pairs, gain, offset, lo, hi, 6)
    np.testing.assert_array_equal(np.array([s.solve(w) for w in W]), ref)
    with pytest.raises(ShapeSpaceError):
        CopySolver([], gain, offset, lo, hi, 6)
    with pytest.raises(ShapeSpaceError):
        CopySolver([(7, 0)], gain, offset, lo, hi, 6)


def test_learned_solver():
    rng = np.random.default_rng(5)
    E = rng.normal(size=(3, 4))
    s = LearnedSolver([0, 2, 5], E, np.zeros(4), np.ones(4))
    w = rng.uniform(size=6)
    np.testing.assert_allclose(s.solve(w), np.clip(w[[0, 2, 5]] @ E, 0, 1))


def test_geometric_solver_equals_offline_per_frame_fit():
    rng = np.random.default_rng(6)
    p3, n, nT, ns = 90, 7, 5, 6
    B = rng.normal(size=(p3, n))
    T = B[:, :nT] @ rng.normal(size=(nT, nT)) * 0.7 + 0.05 * rng.normal(size=(p3, nT))
    template = CopySolver([(i, i) for i in range(nT)], np.ones(nT), np.zeros(nT), np.zeros(nT), np.ones(nT), ns)
    lo, hi = np.zeros(n), np.ones(n)
    solver = GeometricSolver(template, B, T, lo, hi)
    W = rng.uniform(-0.1, 1.1, size=(40, ns))
    b0 = rng.normal(size=p3)
    positions = b0 + np.clip(W[:, :nT], 0, 1) @ T.T
    ref = fit_frames(B, b0, positions, lo, hi)
    got = np.array([solver.solve(w) for w in W])
    np.testing.assert_allclose(got, ref, atol=1e-9)
    assert (got >= lo - 1e-12).all() and (got <= hi + 1e-12).all() and solver.fallbacks == 0
    # the fallback solves the same QP
    np.testing.assert_allclose(solver._bounded_lsq(solver.K @ template.solve(W[-1])), ref[-1], atol=1e-7)
    again = GeometricSolver.from_normal_equations(template, B.T @ T, B.T @ B, lo, hi)
    np.testing.assert_allclose(again.solve(W[0]), ref[0], atol=1e-9)


# ------------------------------------------------------------------ takes at the scene rate
@pytest.mark.parametrize("rate,start", [(30.0, 20.0), (60.0, 1.0), (24.0, 0.0), (29.97, 1.0)])
def test_scene_resampler_equals_offline_resample(rate, start):
    rng = np.random.default_rng(7)
    t = 1929.13 + np.cumsum(rng.uniform(0.012, 0.021, size=200))
    W = rng.uniform(size=(200, 3))
    frames, ref = resample(t - t[0], W, rate, start)
    r = SceneResampler(rate, start)
    got = [out for ti, w in zip(t, W) for out in r.push(ti, w)]
    assert r.push(t[-5], W[-5]) == []                       # late sample ignored
    np.testing.assert_array_equal([f for f, _ in got], frames)
    np.testing.assert_allclose(np.array([v for _, v in got]), ref, atol=1e-12)
    assert r.frames_emitted == frames.size and r.start_time == t[0]


def test_names_of_all_sources_map_onto_arkit():
    assert {canonical_name(n) for n in LLF_BLENDSHAPES} == {canonical_name(n) for n in FACECAP_52}


def test_dense_box_qp_matches_the_reference_box_qp():
    from core.boxqp import solve_box_qp
    from core.live import dense_box_qp
    rng = np.random.default_rng(8)
    for _trial in range(30):
        n = int(rng.integers(2, 40))
        A = rng.normal(size=(n + 5, n))
        H = A.T @ A + 1e-3 * np.eye(n)
        g = rng.normal(size=n) * 3
        lo, hi = np.zeros(n), np.ones(n)
        lo[::5] = -np.inf
        x, ok, _ = dense_box_qp(H, g, lo, hi, rng.uniform(size=n))
        lam, Q = np.linalg.eigh(H - 1e-3 * np.eye(n))
        ref = solve_box_qp(1e-3, Q, lam + 1e-300, g, lo, hi).x
        assert ok
        np.testing.assert_allclose(x, ref, atol=1e-8)


# ------------------------------------------------------------------ issue #26: clock jumps, OSC framing, absurd values
@pytest.mark.parametrize("jump", [300.0, 600.0])
def test_a_forward_clock_jump_is_not_filled_frame_by_frame(jump):
    """Live Link Face re-syncing its timecode (or Face Cap's time tag going from 0 to the real time) used to
    key every scene frame of the jump, interpolated: 18,000 frames for 300 s, one at a time."""
    r = SceneResampler(60.0, 1.0)
    emitted = []
    for k in range(31):
        emitted += r.push(k / 60.0, [k])
    assert len(emitted) == 31 and r.next_frame == 32.0
    assert not r.is_jump(0.5 + 0.2)                       # lost packets over a few frames are still filled
    assert r.is_jump(0.5 + jump)
    with pytest.raises(ShapeSpaceError) as err:
        r.push(0.5 + jump, [1.0])
    assert err.value.code == "range" and "jumped" in str(err.value)
    assert r.frames_emitted == 31 and r.last_time == 0.5      # nothing keyed, the resampler as it was
    # a short gap is filled exactly as the offline resample fills it
    filled = r.push(0.5 + 0.1, [36.0])
    assert [f for f, _ in filled] == [32.0, 33.0, 34.0, 35.0, 36.0, 37.0]
    np.testing.assert_allclose([v[0] for _, v in filled], [31, 32, 33, 34, 35, 36])


def _osc_string(text):
    raw = text.encode() + b"\0"
    return raw + b"\0" * (-len(raw) % 4)


def _osc_message(address, *args):
    tags = "," + "".join("i" if isinstance(a, int) else "f" for a in args)
    body = b"".join(struct.pack(">i" if isinstance(a, int) else ">f", a) for a in args)
    return _osc_string(address) + _osc_string(tags) + body


def _osc_bundle(*elements, tag=1):
    return b"#bundle\0" + struct.pack(">Q", tag) + b"".join(struct.pack(">i", len(e)) + e for e in elements)


def test_osc_framing_refuses_every_truncation_and_splits_a_whole_bundle():
    msgs = [_osc_message("/HR", 1.0, 2.0, 3.0), _osc_message("/W", 24, 0.3), _osc_message("/W", 13, 0.5)]
    data = _osc_bundle(*msgs, tag=(3 << 32) + 5)
    tag, parts = osc_bundle_messages(data)
    assert tag == (3 << 32) + 5 and parts == msgs
    boundaries = {16 + sum(4 + len(m) for m in msgs[:k]): msgs[:k] for k in range(len(msgs))}
    for cut in range(len(data)):
        if cut in boundaries:          # whole elements only: valid framing, fewer messages (the assembler refuses)
            assert osc_bundle_messages(data[:cut])[1] == boundaries[cut]
            continue
        with pytest.raises(ShapeSpaceError) as err:
            osc_bundle_messages(data[:cut])
        assert err.value.code == "malformed_packet"
    # a message whose float was cut (python-osc pads it with zeros and reads 0.125 for 0.3)
    with pytest.raises(ShapeSpaceError, match="truncated"):
        check_osc_message(_osc_message("/W", 24, 0.3)[:-2])
    with pytest.raises(ShapeSpaceError, match="after its arguments"):
        check_osc_message(_osc_message("/W", 24, 0.3) + b"\0\0\0\0")


def test_deeply_nested_osc_bundles_are_refused_with_a_reason():
    data = _osc_message("/W", 0, 0.5)
    for _ in range(5000):
        data = _osc_bundle(data)
    with pytest.raises(ShapeSpaceError) as err:
        osc_bundle_messages(data)
    assert err.value.code == "malformed_packet" and f"nested more than {MAX_OSC_DEPTH}" in str(err.value)
    nested = _osc_message("/W", 0, 0.5)
    for _ in range(MAX_OSC_DEPTH - 1):
        nested = _osc_bundle(nested)
    assert osc_bundle_messages(nested)[1] == [_osc_message("/W", 0, 0.5)]


def _full_bundle_messages(weights, head=(0.0, 0.0, 0.0)):
    return [("/HR", list(head))] + [("/W", [i, float(w)]) for i, w in enumerate(weights)]


def test_facecap_bundle_is_applied_whole_or_not_at_all():
    a = FaceCapAssembler()
    first = np.linspace(0.0, 0.5, 52)
    a.apply_bundle(_full_bundle_messages(first))
    np.testing.assert_array_equal(a.weights, first)
    bad = _full_bundle_messages(np.full(52, 0.9)) + [("/HR", [1.0, 2.0])]       # the last message is malformed
    with pytest.raises(ShapeSpaceError) as err:
        a.apply_bundle(bad)
    assert err.value.code == "malformed_packet"
    np.testing.assert_array_equal(a.weights, first)                             # none of its /W applied
    with pytest.raises(ShapeSpaceError, match="carries 40 of 52"):
        a.apply_bundle(_full_bundle_messages(np.full(52, 0.9))[:41])             # cut after 40 blendshapes
    np.testing.assert_array_equal(a.weights, first)
    with pytest.raises(ShapeSpaceError, match="repeats"):
        a.apply_bundle(_full_bundle_messages(first) + [("/W", [3, 0.2])])


@pytest.mark.parametrize("channel,value,name", [(0, 3e38, "EyeBlinkLeft"), (17, -3e38, "JawOpen"),
                                               (52, 3e38, "head yaw"), (57, -1e30, "left eye roll")])
def test_llf_frame_with_absurd_values_is_refused_by_name(channel, value, name):
    values = np.zeros(61, dtype=np.float32)
    values[channel] = value
    with pytest.raises(ShapeSpaceError) as err:
        decode_llf(_hand_packet(values))
    assert err.value.code == "range" and name in str(err.value)
    values[channel] = 0.99                                # the same packet with a plausible value decodes
    assert decode_llf(_hand_packet(values)) is not None


@pytest.mark.parametrize("text", [b"jawOpen-1e306|=head#0,0,0,0,0,0|", b"jawOpen-30|=head#1e306,0,0,0,0,0|",
                                  b"jawOpen-30|=head#0,0,0,0,0,0|leftEye#0,1e306,0|"])
def test_ifacialmocap_frame_with_absurd_values_is_refused(text):
    with pytest.raises(ShapeSpaceError) as err:
        decode_ifacialmocap(text)
    assert err.value.code == "range"


@pytest.mark.parametrize("address,args", [("/W", [24, 1e308]), ("/W", [24, -101.0]), ("/HR", [1e308, 0, 0]),
                                          ("/ELR", [0, 1e308])])
def test_facecap_absurd_values_are_refused_and_not_applied(address, args):
    a = FaceCapAssembler()
    with pytest.raises(ShapeSpaceError) as err:
        a.apply(address, args)
    assert err.value.code == "range"
    assert not a.weights.any() and not a.head.any() and not a.eye_left.any()


def test_weight_limit_is_the_offline_readers():
    assert live_frames.MAX_ABS_WEIGHT is capture.MAX_ABS_WEIGHT       # one constant, not a copy
    w = np.zeros(52)
    MAX_ABS_WEIGHT = capture.MAX_ABS_WEIGHT
    w[3] = MAX_ABS_WEIGHT
    assert implausible_channel(FACECAP_52, np.concatenate([w, np.zeros(9)])) == ""
    w[3] = np.nextafter(MAX_ABS_WEIGHT, np.inf)
    assert FACECAP_52[3] in implausible_channel(FACECAP_52, np.concatenate([w, np.zeros(9)]))


def test_calibrating_on_an_absurd_rest_face_is_refused():
    """A 3e38 rest face made every later frame read 1.0."""
    v = np.zeros(61)
    v[5] = -3e38
    with pytest.raises(ShapeSpaceError) as err:
        Neutral.from_vector(v, 52)
    assert err.value.code == "range" and "channel 5" in str(err.value)
    v[5] = 0.2
    assert Neutral.from_vector(v, 52).weights[5] == 0.2
