"""Retarget hardening (#10): nothing is lost, every failure leaves the file as before, messages name the culprit.

Outcomes are read back from Blender itself (the action the Key plays, its F-Curves evaluated by Blender, the
actions that survive saving and reopening the file).
"""
import json
import os

import numpy as np
import pytest

from support import ASSETS
from blender_support import blend_fingerprint, bpy, import_file
from shapespace.bridge import actions, retarget, shapekeys
from shapespace.core.result import ShapeSpaceError
from shapespace.core.retarget.capture import read_live_link_csv, resample

CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")
FACECAP = os.path.join(ASSETS, "facecap", "facecap_decoded.glb")


def _fbhead_with_artist_action():
    """FBHead playing the artist's hand-keyed jaw (an action without a fake user)."""
    import_file(BLEND)
    ob = bpy.data.objects["FBHead"]
    bpy.context.view_layer.objects.active = ob
    key = ob.data.shape_keys
    for f, v in ((1, 0.0), (10, 0.8), (20, 0.1)):
        key.key_blocks["JawOpen"].value = v
        key.key_blocks["JawOpen"].keyframe_insert("value", frame=f)
    key.animation_data.action.name = "ArtistJaw"
    key.key_blocks["JawOpen"].value = 0.0
    return ob, key, bpy.data.actions["ArtistJaw"]


def _state(key):
    """What a failed retarget must leave exactly as it was."""
    ad = key.animation_data
    return (blend_fingerprint(), ad.action.name if ad and ad.action else None,
            getattr(ad, "action_slot", None) and ad.action_slot.identifier,
            sorted((a.name, a.users, a.use_fake_user) for a in bpy.data.actions),
            retarget.LAST_PROP in key, key.get(retarget.MAPPING_PROP))


def _save_and_reopen(tmp_path, name="shot.blend"):
    path = str(tmp_path / name)
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    ob = bpy.data.objects["FBHead"]
    bpy.context.view_layer.objects.active = ob
    return ob, ob.data.shape_keys


# ----------------------------------------------------------------------------------------- r01
@pytest.mark.parametrize("failure", [ShapeSpaceError("disk on fire", "invalid"), RuntimeError("Blender said no")])
def test_failure_while_writing_keys_leaves_the_file_as_before(monkeypatch, tmp_path, failure):
    ob, key, artist = _fbhead_with_artist_action()
    before = _state(key)
    write_curve = actions.write_curve
    calls = []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 20:                       # half-way through the curves
            raise failure
        return write_curve(*args, **kwargs)

    monkeypatch.setattr(actions, "write_curve", failing)
    with pytest.raises(type(failure)):
        retarget.retarget(ob, CSV, "copy")
    assert len(calls) == 20
    assert _state(key) == before
    ob, key = _save_and_reopen(tmp_path)
    assert key.animation_data.action.name == "ArtistJaw" and sorted(bpy.data.actions.keys()) == ["ArtistJaw"]


def _write_text(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _csv_with_cell(tmp_path, row, column, value):
    lines = open(CSV).read().splitlines()
    header = lines[0].split(",")
    cells = lines[row].split(",")
    cells[header.index(column)] = value
    lines[row] = ",".join(cells)
    return _write_text(tmp_path, "damaged.csv", "\n".join(lines) + "\n")


@pytest.mark.parametrize("case", ["stored_nan_gain", "lam_nan", "huge_cell", "nan_action_key", "tolerance_nan",
                                  "tolerance_negative"])
def test_bad_values_are_refused_before_anything_is_written(tmp_path, case):
    ob, key, artist = _fbhead_with_artist_action()
    kwargs, source, method, match = {}, CSV, "copy", None
    if case == "stored_nan_gain":        # a blob written by 0.1.0 (json.dumps allowed NaN)
        key[retarget.MAPPING_PROP] = json.dumps({"JawOpen": {"target": "JawOpen", "gain": float("nan"),
                                                             "offset": 0.0}})
        match = "mapping of 'JawOpen' has a non-finite or out-of-range gain"
    elif case == "lam_nan":
        kwargs, method, match = {"lam": float("nan")}, "spacetime", "lam must be finite"
    elif case == "huge_cell":
        source, method = _csv_with_cell(tmp_path, 5, "JawOpen", "1e308"), "perframe"
        match = "line 6, column 'JawOpen': 1e308"
    elif case == "nan_action_key":
        source, method = bpy.data.actions.new("NaNTake"), "spacetime"
        actions.assign_action(key, source)
        for name, v in (("JawOpen", 0.5), ("EyeBlinkLeft", 0.2)):
            fc = actions.write_curve(key, actions.shape_key_path(name), [1.0, 2.0, 3.0, 4.0], [0.0, v, v, 0.0])
        fc.keyframe_points[2].co = (3.0, float("nan"))                  # a damaged key (as imported)
        actions.assign_action(key, artist)
        source.use_fake_user = True
        match = "the curve of 'EyeBlinkLeft' is NaN or infinite at frame 2"
    elif case == "tolerance_nan":
        kwargs, match = {"key_tolerance": float("nan")}, "key tolerance must be finite"
    else:
        kwargs, match = {"key_tolerance": -1.0}, "key tolerance must be ≥ 0"
    before = _state(key)
    with pytest.raises(ShapeSpaceError, match=match):
        retarget.retarget(ob, source, method, **kwargs)
    assert _state(key) == before


def test_set_mapping_refuses_a_non_finite_gain_or_offset(registered):
    ob, key, _ = _fbhead_with_artist_action()
    assert bpy.ops.shapespace.set_mapping(source="JawOpen", target="JawOpen", gain=0.5) == {"FINISHED"}
    stored = key[retarget.MAPPING_PROP]
    for kwargs in ({"gain": float("nan")}, {"offset": float("inf")}, {"gain": 1e30}):
        with pytest.raises(RuntimeError, match="must be a finite number|must lie within ±100"):
            bpy.ops.shapespace.set_mapping(source="JawOpen", target="JawOpen", **kwargs)
    assert key[retarget.MAPPING_PROP] == stored


# ----------------------------------------------------------------------------------------- r03
def test_previous_action_survives_saving_and_discard_after_reopening_restores_it(registered, tmp_path):
    ob, key, artist = _fbhead_with_artist_action()
    assert bpy.ops.shapespace.retarget(filepath=CSV, method="copy") == {"FINISHED"}
    result = key.animation_data.action.name
    assert result != "ArtistJaw"
    ob, key = _save_and_reopen(tmp_path)
    assert {"ArtistJaw", result} <= set(bpy.data.actions.keys())
    assert key.animation_data.action.name == result
    assert bpy.ops.shapespace.discard_retarget() == {"FINISHED"}
    assert key.animation_data.action.name == "ArtistJaw"
    assert not bpy.data.actions["ArtistJaw"].use_fake_user          # as it was before the retarget
    assert result not in bpy.data.actions
    ob, key = _save_and_reopen(tmp_path, "again.blend")
    assert key.animation_data.action.name == "ArtistJaw"
    bpy.context.scene.frame_set(10)
    assert key.key_blocks["JawOpen"].value == pytest.approx(0.8, abs=1e-6)   # Blender plays the artist's keys


def test_discard_only_ever_restores(registered):
    ob, key, artist = _fbhead_with_artist_action()
    rep = retarget.retarget(ob, CSV, "copy")
    other = bpy.data.actions.new("SomethingElse")
    other.use_fake_user = True
    key.animation_data.action = other                             # the artist moved on
    with pytest.raises(RuntimeError, match="plays 'SomethingElse', not the retarget result"):
        bpy.ops.shapespace.discard_retarget()
    assert key.animation_data.action == other and rep.action in bpy.data.actions
    key.animation_data.action = bpy.data.actions[rep.action]
    bpy.data.actions.remove(artist)                               # the action to restore is gone (0.1.0 files)
    with pytest.raises(RuntimeError, match="'ArtistJaw' that .* replaced is no longer in the file"):
        bpy.ops.shapespace.discard_retarget()
    assert key.animation_data.action.name == rep.action and retarget.has_result(ob)


# ----------------------------------------------------------------------------------------- r04 (in process)
def test_every_result_of_a_batch_survives_saving(tmp_path):
    ob, key, artist = _fbhead_with_artist_action()
    names = [retarget.retarget(ob, CSV, "copy", action_name=f"take{k}").action for k in range(3)]
    ob, key = _save_and_reopen(tmp_path)
    assert set(names) | {"ArtistJaw"} == set(bpy.data.actions.keys())
    for name in names:
        curves = actions.shape_key_curves(ob, bpy.data.actions[name])
        assert len(curves) == 51 and bpy.data.actions[name].use_fake_user


# ----------------------------------------------------------------------------------------- r11
def test_stale_mapping_override_is_reported_and_the_channel_matched_by_name(registered):
    ob, key, _ = _fbhead_with_artist_action()
    assert bpy.ops.shapespace.set_mapping(source="JawOpen", target="MouthClose") == {"FINISHED"}
    ob.shape_key_remove(key.key_blocks["MouthClose"])             # the artist deletes that key later
    rep = retarget.retarget(ob, CSV, "copy")
    assert any("JawOpen → MouthClose names no shape key" in m and "matched by name to JawOpen" in m
               for m in rep.issues)
    stream = read_live_link_csv(CSV)
    scene = bpy.context.scene
    frames, w = resample(stream.times, stream.weights, scene.render.fps, scene.frame_start)
    fc = actions.shape_key_curves(ob, bpy.data.actions[rep.action])["JawOpen"]
    got = np.array([fc.evaluate(f) for f in frames])
    np.testing.assert_allclose(got, np.clip(w[:, stream.names.index("JawOpen")], 0, 1), atol=1e-6)
    # no key to match by name either: the channel is named as not retargeted
    ob.shape_key_remove(key.key_blocks["JawOpen"])
    rep = retarget.retarget(ob, CSV, "copy")
    assert any("JawOpen is not retargeted" in m for m in rep.issues)


# ----------------------------------------------------------------------------------------- r20
def test_nan_rig_retarget_names_the_key_and_keeps_the_action(registered):
    ob, key, artist = _fbhead_with_artist_action()
    kb = key.key_blocks["MouthSmileLeft"]
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    co[30] = np.nan
    kb.data.foreach_set("co", co)
    n = len(bpy.data.actions)
    for method in ("spacetime", "perframe", "copy"):
        with pytest.raises(RuntimeError, match="'MouthSmileLeft'.*non-finite coordinate"):
            bpy.ops.shapespace.retarget(filepath=CSV, method=method)
        assert key.animation_data.action == artist and len(bpy.data.actions) == n


# ----------------------------------------------------------------------------------------- empty keys
def test_solvers_leave_sliders_of_empty_keys_at_the_copied_value():
    """facecap's tongueOut moves no vertex: perframe and space-time key it as copy does (clipped source);
    a mesh performance keys it at rest (0)."""
    import_file(FACECAP)
    ob = bpy.data.objects["Mesh_2"]
    key = ob.data.shape_keys
    capture = actions.active_action(key)
    model = shapekeys.read_blendshape_model(ob)
    tongue = model.names.index("tongueOut")
    assert np.abs(model.deltas[tongue]).max() == 0
    names, frames, src, _ = retarget.read_source(capture, bpy.context.scene)
    want = np.clip(src[:, names.index("tongueOut")], 0, 1)
    assert np.ptp(want) > 0.02                                     # the capture moves it
    key.animation_data.action = None
    for method in ("perframe", "spacetime", "copy"):
        rep = retarget.retarget(ob, capture, method)
        fc = actions.shape_key_curves(ob, bpy.data.actions[rep.action])["tongueOut"]
        got = np.array([fc.evaluate(f) for f in frames])
        np.testing.assert_allclose(got, want, atol=1e-6, err_msg=method)


def test_mesh_performance_leaves_sliders_of_empty_keys_at_rest():
    import_file(FACECAP)
    src = bpy.data.objects["Mesh_2"]
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 40, 60
    me = src.data.copy()
    dst = bpy.data.objects.new("Target", me)
    scene.collection.objects.link(dst)
    dst.data.shape_keys.animation_data_clear() if dst.data.shape_keys.animation_data else None
    rep = retarget.retarget_dense(dst, src, "spacetime")
    fc = actions.shape_key_curves(dst, bpy.data.actions[rep.action])["tongueOut"]
    assert max(abs(fc.evaluate(f)) for f in range(40, 61)) == 0.0


# ----------------------------------------------------------------------------------------- r09 / r15 / r28
def test_bad_takes_are_refused_naming_file_and_line(tmp_path):
    ob, key, artist = _fbhead_with_artist_action()
    before = _state(key)
    bad_hour = _csv_with_cell(tmp_path, 6, "Timecode", "25:32:09:07.000")
    with pytest.raises(ShapeSpaceError, match=f"^{bad_hour}: line 7: timecode '25:32:09:07.000' is out of range"):
        retarget.retarget(ob, bad_hour, "copy")
    folder = tmp_path / "dir.csv"
    folder.mkdir()
    with pytest.raises(ShapeSpaceError, match="is a directory, not a CSV file"):
        retarget.retarget(ob, str(folder), "copy")
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    with pytest.raises(ShapeSpaceError, match="not a regular file"):
        retarget.retarget(ob, str(fifo), "copy")
    short = _write_text(tmp_path, "short.csv", "Timecode,JawOpen\n" + "".join(
        f"00:00:00:00.{k}00,0.{k}\n" for k in range(3)))
    with pytest.raises(ShapeSpaceError, match="1 frame.* at 30 fps; at least 3 are needed"):
        retarget.retarget(ob, short, "copy")
    assert _state(key) == before


def test_take_across_midnight_is_retargeted_with_its_real_length(tmp_path):
    ob, key, _ = _fbhead_with_artist_action()
    lines = open(CSV).read().splitlines()
    rows = [ln.split(",") for ln in lines[1:]]
    for k, r in enumerate(rows):                  # the same take started 2.5 s before midnight
        t = (86400 - 2.5 + k / 60.0) % 86400
        h, rem = divmod(t, 3600)
        m, rem = divmod(rem, 60)
        s = int(rem)
        r[0] = f"{int(h):02d}:{int(m):02d}:{s:02d}:{(rem - s) * 60:06.3f}"
    path = _write_text(tmp_path, "midnight.csv", "\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    rep = retarget.retarget(ob, path, "copy")
    assert rep.frames == int(np.floor((len(rows) - 1) / 60.0 * 30 + 1e-9)) + 1
    assert any("crosses midnight" in m for m in rep.issues)
