"""Issue #26, live capture: a forward jump of the source clock while recording (not filled frame by frame),
Face Cap bundles decoded whole or refused whole (every truncation of a real bundle, a malformed message at
the end, bundles nested without bound), and absurd but finite values refused and counted in the panel's status.

Only 127.0.0.1; every loop has a deadline (live_support.drive)."""
import os
import struct

import numpy as np
import pytest

from blender_support import bpy, import_file
from live_support import CSV, configure, drive, frames_received, raw_sender
from shapespace.bridge import actions, manipulation
from shapespace.bridge.live import recording, session
from shapespace.bridge.live.facecap import facecap_decoder
from shapespace.bridge.manipulation import cache
from shapespace.core.live import FACECAP_52, LLF_CURVES, encode_llf
from shapespace.core.result import ShapeSpaceError
from support import ASSETS

import live_replay

BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")


def _fbhead():
    import_file(BLEND)
    scene = bpy.context.scene
    scene.frame_current = scene.frame_start
    ob = bpy.data.objects["FBHead"]
    bpy.context.view_layer.objects.active = ob
    return ob


@pytest.fixture(autouse=True)
def _no_session_left():
    yield
    if session.RUNTIME.session is not None:
        session.stop()
    assert session.RUNTIME.session is None and not bpy.app.timers.is_registered(session._timer)


# ------------------------------------------------------------------ item 1: a clock jump while recording
@pytest.mark.parametrize("jump_seconds", [300, 600])
def test_a_clock_jump_while_recording_starts_a_new_take_without_keying_the_gap(registered, jump_seconds):
    """Live Link Face re-syncing its timecode mid-take used to key every frame of the jump (interpolated junk:
    18,000 frames for 300 s at 60 fps, on the main thread); now the take ends and the next one goes on."""
    ob = _fbhead()
    port = configure(ob)
    session.start(bpy.context.scene, ob)
    session.record(bpy.context.scene, "Take")
    rate = bpy.context.scene.render.fps / bpy.context.scene.render.fps_base
    rows = live_replay.read_rows(CSV)[2]
    before = [encode_llf(rows[k], 1000 + k) for k in range(30)]
    after = [encode_llf(rows[30 + k], 1000 + 60 * jump_seconds + k) for k in range(30)]
    raw_sender(before, port)
    assert drive(lambda: frames_received() >= 30, seconds=10)
    session.tick()
    raw_sender(after, port)
    assert drive(lambda: frames_received() >= 60, seconds=10)
    session.tick()
    st = session.status()
    assert st.recording and "jumped" in st.message
    take, _ = session.stop_recording()
    assert recording.takes() == ["Take 1", "Take 2"] and take == "Take 2"
    keyed = {}
    for name in recording.takes():
        info = recording.take_info(bpy.data.actions[name])
        curve = actions.shape_key_curves(ob, bpy.data.actions[name])["JawOpen"]
        keyed[name] = actions.read_curve(curve)[0]
        assert info["complete"] and info["frames"] == keyed[name].size
    # 30 packets at 60 fps are 0.483 s: 15 scene frames at 30 fps each side of the jump, nothing in between
    n = int(np.floor(29 / 60 * rate + 1e-9)) + 1
    start = bpy.context.scene.frame_current
    np.testing.assert_array_equal(keyed["Take 1"], start + np.arange(n))
    np.testing.assert_array_equal(keyed["Take 2"], start + n + np.arange(n))
    info2 = recording.take_info(bpy.data.actions["Take 2"])
    assert info2["start_seconds"] == pytest.approx((1000 + 60 * jump_seconds + 0.25) / 60.0, abs=1e-6) or \
        info2["start_seconds"] == pytest.approx((1000 + 60 * jump_seconds) / 60.0, abs=1e-6)
    assert actions.active_action(ob.data.shape_keys).name == "Take 2"      # the last take plays


# ------------------------------------------------------------------ items 4, 5, 8: Face Cap bundles whole
def _osc_element(message: bytes) -> bytes:
    return struct.pack(">i", len(message)) + message


def _single(address: str, *args) -> bytes:
    """An OSC message (floats beyond float32 sent as doubles, as an OSC sender may)."""
    from pythonosc import osc_message_builder
    b = osc_message_builder.OscMessageBuilder(address)
    for a in args:
        b.add_arg(a, "d" if isinstance(a, float) and abs(a) > 3.4e38 else None)
    return b.build().dgram


def test_every_truncation_of_a_real_facecap_bundle_is_refused_and_nothing_of_it_applied():
    """Cut at byte 53, 80, 116 or 134 a bundle used to be accepted: the cut float read 0.125 for 0.3 and the
    channels after it kept the previous bundle's values."""
    decode = facecap_decoder()
    packets = live_replay.facecap_packets(CSV)
    (first,) = decode(packets[0][1], 1.0)
    second = packets[1][1]
    accepted = []
    for cut in range(len(second)):
        try:
            decode(second[:cut], 2.0)
        except ShapeSpaceError as exc:
            assert exc.code == "malformed_packet", (cut, str(exc))
        else:
            accepted.append(cut)
    assert accepted == []
    # nothing of the refused bundles was kept: a lone /W 51 completes a sweep over the first bundle's values
    (sweep,) = decode(_single("/W", 51, 0.5), 3.0)
    np.testing.assert_array_equal(sweep.weights[:51], first.weights[:51])
    (whole,) = decode(second, 4.0)                       # the whole bundle still decodes, to its own values
    row = np.array(live_replay.read_rows(CSV)[2][1], dtype=np.float32)
    jaw = FACECAP_52.index("jawOpen")
    assert whole.weights[jaw] == row[LLF_CURVES.index("JawOpen")]


def test_a_bundle_refused_as_malformed_applies_none_of_its_weights():
    decode = facecap_decoder()
    packets = live_replay.facecap_packets(CSV)
    (first,) = decode(packets[0][1], 1.0)
    bad = packets[1][1] + _osc_element(_single("/HR", 1.0, 2.0))          # every /W valid, then a bad /HR
    with pytest.raises(ShapeSpaceError) as err:
        decode(bad, 2.0)
    assert err.value.code == "malformed_packet" and "/HR" in str(err.value)
    (sweep,) = decode(_single("/W", 51, 0.5), 3.0)
    np.testing.assert_array_equal(sweep.weights[:51], first.weights[:51])
    np.testing.assert_array_equal(sweep.head, first.head)


def test_a_deeply_nested_bundle_is_refused_with_a_reason():
    data = _single("/W", 0, 0.5)
    for _ in range(3000):
        data = b"#bundle\0" + struct.pack(">Q", 1) + _osc_element(data)
    with pytest.raises(ShapeSpaceError) as err:
        facecap_decoder()(data, 1.0)
    assert err.value.code == "malformed_packet" and "nested more than" in str(err.value)
    assert "Recursion" not in str(err.value)


# ------------------------------------------------------------------ item 7: absurd values refused and counted
def test_absurd_values_are_refused_and_counted_in_the_status(registered):
    ob = _fbhead()
    port = configure(ob)
    session.start(bpy.context.scene, ob)
    rows = live_replay.read_rows(CSV)[2]
    absurd = np.array(rows[0], dtype=np.float64)
    absurd[LLF_CURVES.index("JawOpen")] = -3e38
    head = np.array(rows[0], dtype=np.float64)
    head[LLF_CURVES.index("HeadPitch")] = 3e38
    raw_sender([encode_llf(absurd, 1000), encode_llf(head, 1001), encode_llf(rows[2], 1002)], port)
    assert drive(lambda: frames_received() >= 1 and session.status().implausible >= 2, seconds=10)
    session.tick()
    st = session.status()
    assert st.frames == 1 and st.implausible == 2 and st.malformed == 0
    assert "head pitch" in st.error
    # the rig shows the one plausible frame, never a clipped absurd value
    jaw = ob.data.shape_keys.key_blocks["JawOpen"].value
    assert jaw == pytest.approx(rows[2][LLF_CURVES.index("JawOpen")], abs=1e-6)
    # calibrating takes the last plausible frame (an absurd one never became the rest face)
    session.calibrate()
    np.testing.assert_allclose(session.RUNTIME.session.pipeline.neutral.weights,
                               np.asarray(rows[2][:52], dtype=np.float32), atol=1e-7)


def test_facecap_absurd_weight_is_refused_and_not_applied():
    decode = facecap_decoder()
    packets = live_replay.facecap_packets(CSV)
    (first,) = decode(packets[0][1], 1.0)
    with pytest.raises(ShapeSpaceError) as err:
        decode(_single("/W", 24, 1e308), 2.0)
    assert err.value.code == "range" and "jawOpen" in str(err.value)
    (sweep,) = decode(_single("/W", 51, 0.5), 3.0)
    np.testing.assert_array_equal(sweep.weights[:51], first.weights[:51])


# ------------------------------------------------------------------ item 14: live frames and the rig cache
def test_live_frames_never_read_or_verify_the_rig_cache(registered):
    """Live writes the sliders every frame without touching the drag's rig cache: no read and no checksum per
    frame; the next use of the cache after live frames costs one checksum (the writes are not the cache's
    own evaluated updates), never a read."""
    rigs = manipulation.RIGS
    ob = _fbhead()
    port = configure(ob)
    manipulation.rig_model(ob)
    reads, checks = rigs.reads, rigs.verifications
    session.start(bpy.context.scene, ob)
    raw_sender([d for _, d in live_replay.llf_packets(CSV)[:40]], port)
    assert drive(lambda: frames_received() >= 40, seconds=10)
    session.tick()
    assert session.RUNTIME.session.applied >= 1
    assert (rigs.reads, rigs.verifications) == (reads, checks)
    session.stop()
    model = manipulation.rig_model(ob)
    assert rigs.reads == reads and rigs.verifications <= checks + 1
    assert rigs.verifications == checks + 1 or not cache.EDITS_REPORTED or not rigs.tracking
    jaw = ob.data.shape_keys.key_blocks["JawOpen"].value
    assert model.values[model.index("JawOpen")] == pytest.approx(jaw)
