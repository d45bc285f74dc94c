"""Live capture through real loopback sockets: Live Link Face v6, Face Cap OSC and iFacialMocap replays of the
shipped recording onto FBHead, recorded takes equal to the offline ``copy`` retarget, bad and reordered
packets, a busy port, a silent source, Stop / unregister / file load while packets arrive, undo, save.

Also (issue #26): a forward jump of the source clock while recording (not filled frame by frame), Face Cap bundles
decoded whole or refused whole (every truncation of a real bundle, a malformed message at the end, bundles nested
without bound), and absurd but finite values refused and counted in the panel's status.

Only 127.0.0.1; every loop has a deadline (live_support.drive)."""
import os
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import live_replay
from blender_support import SS, bpy, draw_panel, import_file
from live_support import CSV, HOST, configure, drive, frames_received, halt, raw_sender, replay_and_drain, sender
from shapespace.bridge import actions, manipulation, retarget
from shapespace.bridge.live import recording, session
from shapespace.bridge.live.facecap import facecap_decoder
from shapespace.bridge.manipulation import cache
from shapespace.core.live import FACECAP_52, LLF_CURVES, encode_llf
from shapespace.core.result import ShapeSpaceError
from support import ASSETS, ROOT

BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")


def _fbhead():
    import_file(BLEND)
    scene = bpy.context.scene
    scene.frame_current = scene.frame_start
    ob = bpy.data.objects["FBHead"]
    bpy.context.view_layer.objects.active = ob
    return ob


def _take_curves(ob, take):
    return actions.shape_key_curves(ob, bpy.data.actions[take])


def _assert_take_equals_offline_copy(ob, take):
    rep = retarget.retarget(ob, CSV, "copy")
    offline = _take_curves(ob, rep.action)
    live = _take_curves(ob, take)
    assert set(live) == set(offline) and len(offline) == 51
    worst = 0.0
    for name, fc in offline.items():
        x, y, _ = actions.read_curve(fc)
        lx, ly, interp = actions.read_curve(live[name])
        np.testing.assert_array_equal(lx, x)
        assert set(interp) == {"LINEAR"}
        worst = max(worst, float(np.abs(ly - y).max()))
    assert worst <= 1e-6, worst                                  # float32 precision
    return worst


def _stop_all():
    if session.RUNTIME.session is not None:
        session.stop()


@pytest.fixture(autouse=True)
def _no_session_left():
    yield
    _stop_all()
    assert session.RUNTIME.session is None and not bpy.app.timers.is_registered(session._timer)


def test_llf_replay_from_another_process_records_the_offline_copy(registered):
    ob = _fbhead()
    port = configure(ob)
    assert bpy.ops.shapespace.live_start() == {"FINISHED"}
    assert bpy.app.timers.is_registered(session._timer)
    assert bpy.ops.shapespace.live_record() == {"FINISHED"}
    proc = subprocess.Popen([sys.executable, os.path.join(ROOT, "tools", "live_replay.py"), CSV, "--port", str(port),
                             "--host", HOST], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert drive(lambda: proc.poll() is not None and frames_received() >= 328, seconds=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=10)
    session.tick()
    st = session.status()
    assert st.frames == 328 and st.malformed == 0 and st.late == 0
    assert st.dropped == 1              # the recording itself skips one 60 fps timecode frame
    assert st.recording and st.take_frames == 164
    assert st.work_ms_p50 < 5 and st.packets_per_second > 0
    # the rig shows the last packet, copied by name (the packet order is not the CSV's)
    last = np.array(live_replay.read_rows(CSV)[2][-1])
    jaw = ob.data.shape_keys.key_blocks["JawLeft"].value
    assert jaw == pytest.approx(last[LLF_CURVES.index("JawLeft")], abs=1e-6)
    assert bpy.ops.shapespace.live_stop_recording() == {"FINISHED"}
    take = recording.takes()[0]
    info = recording.take_info(bpy.data.actions[take])
    assert info["complete"] and info["frames"] == 164 and info["source"] == "Live Link Face"
    assert info["start_timecode"] == "00:32:09:07.867" and info["scene_fps"] == 30.0
    assert bpy.data.actions[take].use_fake_user
    assert actions.active_action(ob.data.shape_keys).name == take          # the rig plays the take
    _assert_take_equals_offline_copy(ob, take)
    assert bpy.ops.shapespace.live_stop() == {"FINISHED"}


def test_facecap_osc_replay_records_the_offline_copy(registered):
    ob = _fbhead()
    port = configure(ob, source="FACECAP")
    bpy.context.scene.shapespace_live.port = port
    assert bpy.ops.shapespace.live_start() == {"FINISHED"}
    assert bpy.ops.shapespace.live_record() == {"FINISHED"}
    assert replay_and_drain(live_replay.facecap_packets(CSV), port)
    assert session.status().frames == 328
    take, _ = session.stop_recording()
    _assert_take_equals_offline_copy(ob, take)


def test_ifacialmocap_replay_drives_the_rig(registered):
    ob = _fbhead()
    port = configure(ob, source="IFACIALMOCAP")
    bpy.context.scene.shapespace_live.port = port
    session.start(bpy.context.scene, ob)
    packets = live_replay.ifacialmocap_packets(CSV)[:60]
    assert replay_and_drain(packets, port, rate=240)
    last = np.array(live_replay.read_rows(CSV)[2][59])
    for name in ("JawOpen", "EyeBlinkLeft", "MouthSmileRight"):
        assert ob.data.shape_keys.key_blocks[name].value == pytest.approx(last[LLF_CURVES.index(name)], abs=1e-5)


def test_malformed_duplicated_and_reordered_packets(registered):
    ob = _fbhead()
    port = configure(ob)
    session.start(bpy.context.scene, ob)
    good = live_replay.llf_packets(CSV)[:40]
    junk = [b"", good[0][1][:50], bytes([5]) + good[0][1][1:], encode_llf(np.zeros(52), 10, count=52),
            os.urandom(300), bytes(65_000), b"\x06" + os.urandom(200)]
    stream = []
    for k, (_, d) in enumerate(good):
        stream.append(d)
        if k % 10 == 3:
            stream.append(d)                                      # duplicated
        if k % 10 == 6:
            stream.append(good[k - 2][1])                         # reordered (an older frame, late)
        if k % 10 == 8:
            stream.append(junk[(k // 10) % len(junk)])
    stream += junk
    raw_sender(stream, port)
    assert drive(lambda: session.status().malformed >= 4 + len(junk) and frames_received() >= 40, seconds=10)
    session.tick()
    st = session.status()
    assert st.frames == 40 and st.late == 8 and st.malformed == 4 + len(junk)
    assert st.running and session.RUNTIME.session.receiver.alive
    last = np.array(live_replay.read_rows(CSV)[2][39])
    assert ob.data.shape_keys.key_blocks["JawOpen"].value == pytest.approx(last[LLF_CURVES.index("JawOpen")],
                                                                          abs=1e-6)


def test_port_in_use_is_a_clear_message(registered):
    import socket
    ob = _fbhead()
    port = configure(ob)
    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    blocker.bind((HOST, port))
    try:
        with pytest.raises(RuntimeError, match=f"UDP port {port} on {HOST} is already in use"):
            bpy.ops.shapespace.live_start()
        assert session.RUNTIME.session is None and not bpy.app.timers.is_registered(session._timer)
    finally:
        blocker.close()
    assert bpy.ops.shapespace.live_start() == {"FINISHED"}


def test_source_that_stops_sending_shows_it_and_nothing_hangs(registered):
    ob = _fbhead()
    port = configure(ob)
    session.start(bpy.context.scene, ob)
    assert "waiting for Live Link Face" in session.status().message
    raw_sender([d for _, d in live_replay.llf_packets(CSV)[:5]], port)
    assert drive(lambda: frames_received() == 5, seconds=5)
    session.tick()
    assert session.status().message.startswith("receiving")
    slowest = 0.0
    end = time.monotonic() + 1.4
    while time.monotonic() < end:
        t = time.perf_counter()
        session.tick()
        slowest = max(slowest, time.perf_counter() - t)
        time.sleep(0.004)
    st = session.status()
    assert "stopped sending" in st.message and st.last_frame_age > 1.0 and st.packets_per_second == 0
    assert slowest < 0.05
    receiver = session.RUNTIME.session.receiver
    t = time.perf_counter()
    assert bpy.ops.shapespace.live_stop() == {"FINISHED"}
    assert time.perf_counter() - t < 1.0 and not receiver.alive and receiver.sock.fileno() == -1


def _running_take_with_packets_arriving(ob):
    port = configure(ob)
    session.start(bpy.context.scene, ob)
    take = session.record(bpy.context.scene, "Cut")
    th = sender(live_replay.llf_packets(CSV, loops=3), port, rate=120, seconds=8)
    assert drive(lambda: session.status().take_frames > 20, seconds=10)
    return take, th, session.RUNTIME.session.receiver


def test_stop_while_packets_arrive_keeps_the_take(registered):
    ob = _fbhead()
    take, th, receiver = _running_take_with_packets_arriving(ob)
    assert bpy.ops.shapespace.live_stop() == {"FINISHED"}
    assert not receiver.alive and receiver.sock.fileno() == -1
    assert not bpy.app.timers.is_registered(session._timer)
    info = recording.take_info(bpy.data.actions[take])
    assert info["complete"] and info["frames"] > 20
    assert len(_take_curves(ob, take)["JawOpen"].keyframe_points) == info["frames"]
    halt(th)


def test_unregister_while_packets_arrive_stops_everything(registered):
    ob = _fbhead()
    take, th, receiver = _running_take_with_packets_arriving(ob)
    threads_before = {t.name for t in threading.enumerate()}
    assert any(n.startswith("ShapeSpace live") for n in threads_before)
    SS.unregister()
    try:
        assert session.RUNTIME.session is None and not receiver.alive and receiver.sock.fileno() == -1
        assert not bpy.app.timers.is_registered(session._timer)
        assert session._before_load not in bpy.app.handlers.load_pre
        assert not any(t.name.startswith("ShapeSpace live") for t in threading.enumerate())
        assert "disabled" in session.RUNTIME.message
        action = bpy.data.actions[take]                               # the take so far is kept
        assert len(actions.shape_key_curves(ob, action)["JawOpen"].keyframe_points) > 20
    finally:
        SS.register()
    halt(th)


def test_opening_another_file_stops_the_receiver(registered):
    ob = _fbhead()
    _, th, receiver = _running_take_with_packets_arriving(ob)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert session.RUNTIME.session is None and not receiver.alive
    assert not bpy.app.timers.is_registered(session._timer)
    halt(th)


def test_deleted_target_stops_the_timer_with_a_message(registered):
    ob = _fbhead()
    port = configure(ob)
    session.start(bpy.context.scene, ob)
    bpy.data.objects.remove(ob)
    sender(live_replay.llf_packets(CSV)[:30], port, rate=240)
    assert drive(lambda: session.RUNTIME.session is None, seconds=5)
    assert "'FBHead' was deleted" in session.status().message
    assert not bpy.app.timers.is_registered(session._timer)


def test_a_take_interrupted_by_saving_and_closing_is_in_the_file(registered, tmp_path):
    ob = _fbhead()
    take, th, _ = _running_take_with_packets_arriving(ob)
    path = str(tmp_path / "mid_take.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)                  # "Blender closed mid-take" after a save
    keys_saved = len(_take_curves(ob, take)["JawOpen"].keyframe_points)
    _stop_all()
    halt(th)
    bpy.ops.wm.open_mainfile(filepath=path)
    action = bpy.data.actions[take]
    info = recording.take_info(action)
    assert not info["complete"] and action.use_fake_user
    assert len(actions.shape_key_curves(bpy.data.objects["FBHead"], action)["JawOpen"].keyframe_points) == keys_saved


def test_undo_after_a_recording(registered):
    ob = _fbhead()
    port = configure(ob)
    assert bpy.ops.shapespace.live_start() == {"FINISHED"}
    bpy.ops.ed.undo_push(message="start")
    assert bpy.ops.shapespace.live_record() == {"FINISHED"}
    bpy.ops.ed.undo_push(message="record")
    assert replay_and_drain(live_replay.llf_packets(CSV)[:90], port, rate=240)
    assert bpy.ops.shapespace.live_stop_recording() == {"FINISHED"}
    bpy.ops.ed.undo_push(message="stop recording")
    take = recording.takes()[0]
    frames = recording.take_info(bpy.data.actions[take])["frames"]
    bpy.ops.ed.undo()
    bpy.ops.ed.undo()
    assert take not in bpy.data.actions                        # back to before Record
    session.tick()                                            # the live session survives undo
    assert session.RUNTIME.session is not None
    bpy.ops.ed.redo()
    bpy.ops.ed.redo()
    assert recording.take_info(bpy.data.actions[take])["frames"] == frames
    raw_sender([d for _, d in live_replay.llf_packets(CSV)[100:110]], port)
    assert drive(lambda: frames_received() >= 100, seconds=5)
    session.tick()
    assert session.RUNTIME.session is not None and bpy.data.objects["FBHead"].data.shape_keys is not None


def test_calibrate_makes_the_rest_face_zero(registered):
    ob = _fbhead()
    port = configure(ob)
    assert bpy.ops.shapespace.live_start() == {"FINISHED"}
    with pytest.raises(RuntimeError, match="no frame has been received yet"):
        bpy.ops.shapespace.live_calibrate()
    packets = live_replay.llf_packets(CSV)
    raw_sender([packets[0][1]], port)
    assert drive(lambda: frames_received() == 1, seconds=5)
    session.tick()
    assert ob.data.shape_keys.key_blocks["MouthClose"].value > 0.05
    assert bpy.ops.shapespace.live_calibrate() == {"FINISHED"}
    raw_sender([encode_llf(live_replay.read_rows(CSV)[2][0], packets[0][1] and 10**7)], port)
    assert drive(lambda: frames_received() == 2, seconds=5)
    session.tick()
    values = [kb.value for kb in ob.data.shape_keys.key_blocks[1:]]
    assert max(values) == pytest.approx(0.0, abs=1e-6) and session.status().calibrated


def test_take_list_play_and_remove(registered):
    ob = _fbhead()
    port = configure(ob)
    session.start(bpy.context.scene, ob)
    for _ in range(2):
        session.record(bpy.context.scene, "Take")
        assert replay_and_drain(live_replay.llf_packets(CSV, subject="s")[:20], port, rate=240)
        session.stop_recording()
        session.RUNTIME.session.mailbox._last_time = None          # the same frames again, as a new take
    assert recording.takes() == ["Take 1", "Take 2"]
    assert bpy.ops.shapespace.live_play_take(take="Take 1") == {"FINISHED"}
    assert actions.active_action(ob.data.shape_keys).name == "Take 1"
    assert bpy.ops.shapespace.live_remove_take(take="Take 2") == {"FINISHED"}
    assert recording.takes() == ["Take 1"]
    with pytest.raises(RuntimeError, match="no live take named 'Nope'"):
        bpy.ops.shapespace.live_play_take(take="Nope")


def test_clean_on_stop_keeps_the_raw_take(registered):
    ob = _fbhead()
    port = configure(ob, clean_spacetime=True, clean_tolerance=0.01)
    assert bpy.ops.shapespace.live_start() == {"FINISHED"}
    assert bpy.ops.shapespace.live_record() == {"FINISHED"}
    assert replay_and_drain(live_replay.llf_packets(CSV), port, rate=240)
    assert bpy.ops.shapespace.live_stop_recording() == {"FINISHED"}
    take = recording.takes()[0]
    info = recording.take_info(bpy.data.actions[take])
    clean = bpy.data.actions[info["clean_action"]]
    assert actions.active_action(ob.data.shape_keys) == clean and clean.use_fake_user
    raw = _take_curves(ob, take)["JawOpen"]
    reduced = actions.shape_key_curves(ob, clean)["JawOpen"]
    assert len(reduced.keyframe_points) < len(raw.keyframe_points) == info["frames"]
    x, y, _ = actions.read_curve(raw)
    assert np.abs(np.array([reduced.evaluate(f) for f in x]) - y).max() < 0.03


def test_live_panel_draws_in_every_state(registered):
    from shapespace.panels.live import SHAPESPACE_PT_live

    def draw():
        return draw_panel(SHAPESPACE_PT_live, strict=False, bl_idname="SHAPESPACE_PT_live").labels

    ob = _fbhead()
    assert "stopped" in draw()
    port = configure(ob, method="SOLVE")
    draw()
    bpy.context.scene.shapespace_live.method = "COPY"
    session.start(bpy.context.scene, ob)
    session.record(bpy.context.scene)
    assert replay_and_drain(live_replay.llf_packets(CSV)[:30], port, rate=240)
    log = draw()
    assert any("packets/s" in t for t in log) and any(t.startswith("recording Take 1") for t in log)


def test_listening_beyond_this_computer_respects_online_access(registered):
    ob = _fbhead()
    configure(ob)
    st = bpy.context.scene.shapespace_live
    st.address = "0.0.0.0"
    if bpy.app.online_access:
        pytest.skip("online access is allowed in this Blender")
    with pytest.raises(RuntimeError, match="Allow Online Access"):
        bpy.ops.shapespace.live_start()
    assert session.RUNTIME.session is None


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
    frame; the next use of the cache after live frames costs no checksum either (they are ShapeSpace's own
    writes, evaluated as such) and never a read."""
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
    assert rigs.verifications == checks or not cache.EDITS_REPORTED or not rigs.tracking
    jaw = ob.data.shape_keys.key_blocks["JawOpen"].value
    assert model.values[model.index("JawOpen")] == pytest.approx(jaw)


def test_live_frames_on_a_cached_rig_are_shapespace_own_writes(registered):
    """Item 14 (the mechanism): live frames are ShapeSpace's own slider writes, so on a rig the drag's cache
    holds they must not be taken for outside edits — no checksum of every key coordinate at the next drag or
    Solve Pins use (16 ms on a 105k-vertex face), and the cached model carries the sliders the frames wrote.
    A key coordinate a script edits between frames is still seen (the cache reads the rig again)."""
    rigs = manipulation.RIGS
    ob = _fbhead()
    port = configure(ob)
    manipulation.rig_model(ob)
    bpy.context.evaluated_depsgraph_get()
    reads, checks = rigs.reads, rigs.verifications
    session.start(bpy.context.scene, ob)
    try:
        raw_sender([d for _, d in live_replay.llf_packets(CSV)[:40]], port)
        assert drive(lambda: frames_received() >= 40, seconds=10)
        session.tick()
        assert session.RUNTIME.session.applied >= 1
        bpy.context.evaluated_depsgraph_get()                   # the viewport's redraw after the frames
        model = manipulation.rig_model(ob)
        assert rigs.reads == reads
        if cache.EDITS_REPORTED and rigs.tracking:
            assert rigs.verifications == checks              # was checks + 1: live writes taken as outside edits
        jaw = ob.data.shape_keys.key_blocks["JawOpen"].value
        assert jaw != 0.0 and model.values[model.index("JawOpen")] == pytest.approx(jaw)
        # an outside edit of a key's coordinates between two frames is still seen
        kb = ob.data.shape_keys.key_blocks["JawOpen"]
        co = np.empty(3 * len(ob.data.vertices), np.float32)
        kb.points.foreach_get("co", co)
        co[:3] += 0.25
        kb.points.foreach_set("co", co)
        raw_sender([d for _, d in live_replay.llf_packets(CSV)[40:60]], port)
        assert drive(lambda: frames_received() >= 60, seconds=10)
        session.tick()
        model = manipulation.rig_model(ob)
        base = ob.data.shape_keys.reference_key.data[0].co
        np.testing.assert_allclose(model.deltas[model.index("JawOpen")][0], np.array(co[:3]) - np.array(base),
                                   atol=1e-5)
    finally:
        session.stop()
