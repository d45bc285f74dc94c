"""Keyframe sampling (CONSTANT / LINEAR) and frame-rate conversion."""
import numpy as np
import pytest

from core.animation import CONSTANT, LINEAR, frames_to_seconds, sample_keys, seconds_to_frames
from core.result import ShapeSpaceError

KF = np.array([1.0, 1.14, 2.39, 4.0, 7.5, 8.25])
KV = np.array([0.0, 0.8, -0.3, 0.25, 1.0, 0.6])


def reference_sample(kf, kv, modes, t, extrapolate_linear=False):
    """Scalar, loop-based reference following Blender's F-Curve rules."""
    if t < kf[0]:
        if extrapolate_linear and len(kf) > 1 and modes[0] == LINEAR:
            return kv[0] + (kv[1] - kv[0]) / (kf[1] - kf[0]) * (t - kf[0])
        return kv[0]
    if t > kf[-1]:
        # Blender (fcurve_eval_keyframes_extrapolate) looks at the *last key's* interpolation
        if extrapolate_linear and len(kf) > 1 and modes[-1] == LINEAR:
            return kv[-1] + (kv[-1] - kv[-2]) / (kf[-1] - kf[-2]) * (t - kf[-1])
        return kv[-1]
    for i in range(len(kf) - 1):
        if kf[i] <= t <= kf[i + 1]:
            if t == kf[i + 1]:
                return kv[i + 1]
            if modes[i] == CONSTANT:
                return kv[i]
            return kv[i] + (kv[i + 1] - kv[i]) * (t - kf[i]) / (kf[i + 1] - kf[i])
    return kv[-1]


def test_linear_equals_numpy_interp_inside_range():
    t = np.linspace(1.0, 8.25, 301)
    out = sample_keys(KF, KV, np.full(6, LINEAR), t)
    np.testing.assert_allclose(out, np.interp(t, KF, KV), atol=1e-12)


def test_linear_at_keys_returns_key_values():
    np.testing.assert_allclose(sample_keys(KF, KV, np.full(6, LINEAR), KF), KV, atol=1e-12)
    np.testing.assert_array_equal(sample_keys(KF, KV, np.full(6, CONSTANT), KF), KV)


def test_constant_holds_left_value_and_jumps_at_next_key():
    kf, kv = [0.0, 10.0, 20.0], [1.0, 5.0, -2.0]
    t = np.array([0.0, 0.001, 5.0, 9.999999, 10.0, 10.5, 19.99, 20.0])
    out = sample_keys(kf, kv, [CONSTANT] * 3, t)
    np.testing.assert_array_equal(out, [1.0, 1.0, 1.0, 1.0, 5.0, 5.0, 5.0, -2.0])


def test_mixed_interpolation_per_segment():
    modes = np.array([LINEAR, CONSTANT, LINEAR, CONSTANT, LINEAR, LINEAR])
    t = np.linspace(1.0, 8.25, 500)
    out = sample_keys(KF, KV, modes, t)
    expected = np.array([reference_sample(KF, KV, modes, ti) for ti in t])
    np.testing.assert_allclose(out, expected, atol=1e-12)
    # explicit spot checks: inside a CONSTANT segment (key 1 -> 2) the value is KV[1]
    np.testing.assert_array_equal(sample_keys(KF, KV, modes, [1.5, 2.0, 2.389]), [0.8, 0.8, 0.8])
    # inside a LINEAR segment (key 2 -> 3): numpy.interp on that segment
    np.testing.assert_allclose(sample_keys(KF, KV, modes, [3.0]), np.interp([3.0], KF[2:4], KV[2:4]), atol=1e-12)


def test_fractional_keys_and_fractional_samples():
    kf = np.array([1.14, 2.39, 3.64, 4.89])          # e.g. 30 fps capture on a 24 fps timeline
    kv = np.array([0.1, 0.9, 0.4, 0.0])
    t = np.array([1.14, 1.5, 2.0, 2.39, 2.4, 3.1415, 4.5, 4.89])
    out = sample_keys(kf, kv, [LINEAR] * 4, t)
    np.testing.assert_allclose(out, np.interp(t, kf, kv), atol=1e-12)
    # hand value: halfway between 1.14 and 2.39 is 1.765 -> 0.5
    np.testing.assert_allclose(sample_keys(kf, kv, [LINEAR] * 4, [1.765]), [0.5], atol=1e-12)
    const = sample_keys(kf, kv, [CONSTANT] * 4, t)
    np.testing.assert_array_equal(const, [0.1, 0.1, 0.1, 0.9, 0.9, 0.9, 0.4, 0.0])


@pytest.mark.parametrize("mode", [CONSTANT, LINEAR])
def test_constant_extrapolation_outside(mode):
    t = np.array([-100.0, 0.0, 0.999, 8.2500001, 9.0, 1e6])
    out = sample_keys(KF, KV, np.full(6, mode), t)
    np.testing.assert_array_equal(out, [0.0, 0.0, 0.0, 0.6, 0.6, 0.6])


def test_linear_extrapolation_all_linear():
    t = np.array([-2.0, 0.0, 0.5, 9.0, 20.0])
    out = sample_keys(KF, KV, np.full(6, LINEAR), t, extrapolate_linear=True)
    s0 = (KV[1] - KV[0]) / (KF[1] - KF[0])
    s1 = (KV[-1] - KV[-2]) / (KF[-1] - KF[-2])
    expected = [KV[0] + s0 * (ti - KF[0]) if ti < KF[0] else KV[-1] + s1 * (ti - KF[-1]) for ti in t]
    np.testing.assert_allclose(out, expected, atol=1e-12)
    # inside the range the flag changes nothing
    inside = np.linspace(1, 8.25, 50)
    np.testing.assert_array_equal(sample_keys(KF, KV, np.full(6, LINEAR), inside, extrapolate_linear=True),
                                  sample_keys(KF, KV, np.full(6, LINEAR), inside))


def test_linear_extrapolation_with_constant_first_key_holds_before_range():
    modes = [CONSTANT, LINEAR, LINEAR, LINEAR, LINEAR, LINEAR]
    out = sample_keys(KF, KV, modes, [-5.0, 0.5], extrapolate_linear=True)
    np.testing.assert_array_equal(out, [KV[0], KV[0]])


@pytest.mark.parametrize("last_two", [(CONSTANT, LINEAR), (LINEAR, CONSTANT)])
def test_linear_extrapolation_after_range_follows_last_key_interpolation(last_two):
    modes = [LINEAR, LINEAR, LINEAR, LINEAR, *last_two]
    t = np.array([9.0, 12.0])
    out = sample_keys(KF, KV, modes, t, extrapolate_linear=True)
    expected = [reference_sample(KF, KV, modes, ti, extrapolate_linear=True) for ti in t]
    np.testing.assert_allclose(out, expected, atol=1e-12)


@pytest.mark.parametrize("extrap", [False, True])
def test_single_key_is_constant(extrap):
    out = sample_keys([3.3], [0.42], [LINEAR], [-1.0, 3.3, 10.0], extrapolate_linear=extrap)
    np.testing.assert_array_equal(out, [0.42, 0.42, 0.42])


def test_two_keys_and_output_shape():
    out = sample_keys([0.0, 2.0], [1.0, 3.0], [LINEAR, LINEAR], np.array([[0.5, 1.0], [1.5, 2.0]]))
    assert out.shape == (2, 2)
    np.testing.assert_allclose(out, [[1.5, 2.0], [2.5, 3.0]], atol=1e-15)


@pytest.mark.parametrize("kf,kv,modes,code", [
    ([0.0, 2.0, 1.0], [0, 1, 2], [1, 1, 1], "unsorted"),
    ([0.0, 1.0, 1.0], [0, 1, 2], [1, 1, 1], "unsorted"),
    ([0.0, 1.0], [0, 1, 2], [1, 1], "shape"),
    ([0.0, 1.0], [0, 1], [1], "shape"),
    ([[0.0, 1.0]], [[0, 1]], [[1, 1]], "shape"),
    ([], [], [], "empty_curve"),
])
def test_sample_keys_errors(kf, kv, modes, code):
    with pytest.raises(ShapeSpaceError) as exc:
        sample_keys(kf, kv, modes, [0.5])
    assert exc.value.code == code


# ----------------------------------------------------------- frame rates
@pytest.mark.parametrize("fps,fps_base,offset", [(24, 1, 0), (24, 1, 1), (30, 1.001, 0), (60, 1, 0), (25, 1, 100)])
def test_seconds_frames_round_trip(fps, fps_base, offset):
    secs = np.linspace(0, 17.3, 97)
    frames = seconds_to_frames(secs, fps, fps_base, offset)
    np.testing.assert_allclose(frames, secs * fps / fps_base + offset, rtol=1e-14, atol=1e-9)
    np.testing.assert_allclose(frames_to_seconds(frames, fps, fps_base, offset), secs, atol=1e-12)


def test_half_second_at_24_fps_with_offset_is_frame_13():
    assert float(seconds_to_frames(0.5, 24, frame_offset=1)) == pytest.approx(13.0)
    assert float(frames_to_seconds(13, 24, frame_offset=1)) == pytest.approx(0.5)


def test_60fps_timecode_to_24fps_frames():
    cap_frames = np.arange(0, 121)                       # two seconds of 60 fps capture
    secs = frames_to_seconds(cap_frames, 60)
    scene = seconds_to_frames(secs, 24, frame_offset=1)
    np.testing.assert_allclose(scene, 1 + cap_frames * 24 / 60, atol=1e-12)
    assert scene[30] == pytest.approx(13.0)              # 0.5 s
    assert scene[120] == pytest.approx(49.0)             # 2 s
    # ntsc: 29.97 = 30000/1001 -> fps=30, fps_base=1.001
    assert float(frames_to_seconds(30, 30, 1.001)) == pytest.approx(1.001)


@pytest.mark.parametrize("fn", [frames_to_seconds, seconds_to_frames])
@pytest.mark.parametrize("fps,fps_base", [(0, 1), (-24, 1), (24, 0), (24, -1)])
def test_non_positive_fps_is_an_error(fn, fps, fps_base):
    with pytest.raises(ShapeSpaceError) as exc:
        fn([1.0], fps, fps_base)
    assert exc.value.code == "fps"
    assert "fps" in str(exc.value)
