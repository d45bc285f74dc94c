"""Retarget panel route onto a face's stored control set (issue #25 item 3 in the UI): the Live Link Face take onto the
hybrid rig, per frame, with progress, Esc and key reduction.

As in ``test_retarget_progress_cancel.py`` the modal path is driven step by step through the bridge job functions its
handler calls (``bridge.rig.steps``: the timer is ``job.step()``, Esc is ``job.cancel()``); the scripted operator call
is the synchronous path.  Ground truth is Blender's evaluation of the keyed actions: the take retarget in one go by
the CLI's entry point (:func:`bridge.rig.retarget_capture_onto_rig`) and the panel's route give the same surfaces.
"""
import numpy as np
import pytest

import rigs
from blender_support import blend_fingerprint, bpy, draw_panel
from shapespace.bridge import actions
from shapespace.bridge import rig as brig
from shapespace.bridge.rig import last_take, steps, stored
from shapespace.core.progress import Cancelled
from support import shared
from test_rig import _assert_same_state, _state


def _csv():
    return shared("llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")


def _face():
    rig = rigs.hybrid_rig(shared(*rigs.FACECAP.split("/")))
    stored.add_entries_of(rig.mesh, rig.armature.name, rig.controls.channels)
    bpy.ops.object.select_all(action="DESELECT")
    rig.mesh.select_set(True)
    bpy.context.view_layer.objects.active = rig.mesh
    return rig


def _surfaces(rig, frames):
    out = []
    for f in frames:
        bpy.context.scene.frame_set(int(f))
        out.append(rig.world_points())
    return np.stack(out)


def test_panel_route_keys_the_take_on_the_armature_as_the_one_shot_route_does(registered):
    rig = _face()
    job = steps.start_retarget(rig.mesh, stored.control_set(rig.mesh), _csv(), action_name="panel")
    while not job.step(0.0):                                                   # the modal timer ticks
        pass
    assert job.reported == sorted(job.reported) and len(job.reported) >= 5 and job.fraction == 1.0
    rep = steps.finish_retarget(job, rig.mesh, _csv(), key_tolerance=0.0)
    assert rep.mapped_channels == 52 and "jaw rotation X" in rep.keyed_channels
    assert {a["id"] for a in rep.actions} == {"OBJECT", "KEY"}
    arm_action = actions.active_action(rig.armature)
    assert arm_action is not None and arm_action.name.startswith("panel")        # on the armature's action
    first, last = rep.frame_range
    frames = np.unique(np.linspace(first, last, 9).round())
    diag = rigs.diagonal(rig.world_points())
    panel = _surfaces(rig, frames)
    assert last_take.summary_of(rig.mesh).startswith(", ".join(a["action"] for a in rep.actions))
    brig.restore_previous(rep, stored.control_set(rig.mesh))                   # back to before, then in one go
    one = brig.retarget_capture_onto_rig(rig.mesh, stored.control_set(rig.mesh), _csv(), action_name="one")
    assert rep.frames == one.frames and rep.keyed_channels == one.keyed_channels
    assert rep.rms <= 1.05 * one.rms + 1e-6 * diag
    shot = _surfaces(rig, frames)
    assert np.abs(panel - shot).max() <= 1e-3 * diag                           # the same motion, as Blender draws


def test_key_reduction_keeps_the_surface_within_the_tolerance(registered):
    rig = _face()
    tol = 2e-4
    assert bpy.ops.shapespace.retarget_controls(filepath=_csv(), key_tolerance=0.0) == {"FINISHED"}
    arm_dense = actions.active_action(rig.armature)
    dense_keys = sum(len(fc.keyframe_points) for fc in actions.action_fcurves(arm_dense))
    first, last = int(arm_dense.frame_range[0]), int(arm_dense.frame_range[1])
    frames = np.arange(first, last + 1, 7)
    dense = _surfaces(rig, frames)
    assert bpy.ops.shapespace.retarget_controls(filepath=_csv(), key_tolerance=tol) == {"FINISHED"}
    arm_sparse = actions.active_action(rig.armature)
    assert arm_sparse != arm_dense
    sparse_keys = sum(len(fc.keyframe_points) for fc in actions.action_fcurves(arm_sparse))
    assert sparse_keys < 0.5 * dense_keys
    keyed = [fc for fc in actions.action_fcurves(arm_sparse)] + \
        [fc for fc in actions.action_fcurves(actions.active_action(rig.mesh.data.shape_keys))]
    # each keyed curve stays within the tolerance in surface units (write_take): their sum bounds the surface
    assert np.linalg.norm(_surfaces(rig, frames) - dense, axis=-1).max() <= 1.01 * tol * len(keyed)
    assert "% of the keys kept" in last_take.summary_of(rig.mesh)


def test_esc_mid_way_leaves_rig_and_file_exactly_as_before(registered):
    rig = _face()
    bpy.context.scene.frame_current = 4
    before, fingerprint = _state(rig), blend_fingerprint()
    job = steps.start_retarget(rig.mesh, stored.control_set(rig.mesh), _csv())
    while job.fraction < 0.4:
        assert not job.step(0.0)
    job.cancel()                                                               # Esc
    with pytest.raises(Cancelled):
        steps.finish_retarget(job, rig.mesh, _csv())
    _assert_same_state(before, _state(rig))
    assert blend_fingerprint() == fingerprint and not last_take.has_result(rig.mesh)
    assert bpy.context.scene.frame_current == 4


def test_panel_offers_the_route_and_the_operator_names_what_is_missing(registered):
    from shapespace.panels.retarget import SHAPESPACE_PT_retarget
    rig = _face()
    st = rig.mesh.shapespace_retarget
    st.target, st.csv_path = "CONTROLS", _csv()
    log = draw_panel(SHAPESPACE_PT_retarget, bpy.context)
    assert ("operator", "shapespace.retarget_controls") in log.log
    assert any("per frame" in t and "space-time" in t for t in log.labels)
    assert ("operator", "shapespace.retarget") not in log.log
    assert ("operator", "shapespace.discard_retarget") not in log.log          # nothing to discard yet
    stored.clear(rig.mesh)
    with pytest.raises(RuntimeError, match="has no control set"):
        bpy.ops.shapespace.retarget_controls(filepath=_csv())


def _played(rig):
    return (actions.active_action(rig.armature), actions.active_action(rig.mesh.data.shape_keys))


def test_discard_result_gives_every_datablock_its_action_and_every_channel_its_value(registered):
    from shapespace.panels.retarget import SHAPESPACE_PT_retarget
    rig = _face()
    first = bpy.data.actions.new("artist bones")
    actions.assign_action(rig.armature, first)                                 # the armature played an action
    frames = [1, 40, 90]
    before_state, before_played = _state(rig), _played(rig)
    before_surface = _surfaces(rig, frames)
    assert bpy.ops.shapespace.retarget_controls(filepath=_csv()) == {"FINISHED"}
    made = [a.name for a in _played(rig) if a is not None]
    assert _played(rig) != before_played and last_take.has_result(rig.mesh)
    st = rig.mesh.shapespace_retarget
    st.target, st.csv_path = "CONTROLS", _csv()
    assert ("operator", "shapespace.discard_retarget") in draw_panel(SHAPESPACE_PT_retarget, bpy.context).log
    assert bpy.ops.shapespace.discard_retarget() == {"FINISHED"}
    assert _played(rig) == before_played and not last_take.has_result(rig.mesh)
    assert all(name not in bpy.data.actions for name in made)                  # the take's actions are deleted
    bpy.context.scene.frame_set(1)
    _assert_same_state(before_state, _state(rig))
    diag = rigs.diagonal(rig.world_points())
    assert np.abs(_surfaces(rig, frames) - before_surface).max() <= 1e-6 * diag   # as Blender evaluates it
    with pytest.raises(RuntimeError, match="Nothing retargeted"):
        bpy.ops.shapespace.discard_retarget()


def test_discard_result_is_refused_by_name_when_the_rig_changed_and_changes_nothing(registered):
    rig = _face()
    assert bpy.ops.shapespace.retarget_controls(filepath=_csv()) == {"FINISHED"}
    take_bones = actions.active_action(rig.armature)
    other = bpy.data.actions.new("artist's edit")
    actions.assign_action(rig.armature, other)                                 # the artist moved on
    fingerprint = blend_fingerprint()
    with pytest.raises(RuntimeError, match="no longer plays the take's action"):
        bpy.ops.shapespace.discard_retarget()
    assert blend_fingerprint() == fingerprint and last_take.has_result(rig.mesh)
    actions.assign_action(rig.armature, take_bones)
    stored.set_enabled(rig.mesh, 0, False)                      # a channel disabled since
    fingerprint = blend_fingerprint()
    with pytest.raises(RuntimeError, match="control set changed since the retarget"):
        bpy.ops.shapespace.discard_retarget()
    assert blend_fingerprint() == fingerprint


def test_each_result_has_its_own_discard_and_auto_is_refused_when_both_are_remembered(registered):
    from shapespace.bridge import retarget
    from shapespace.panels.retarget import SHAPESPACE_PT_retarget
    rig = _face()
    assert bpy.ops.shapespace.retarget_controls(filepath=_csv()) == {"FINISHED"}
    bones_take = actions.active_action(rig.armature)
    assert bpy.ops.shapespace.retarget(filepath=_csv(), method="copy") == {"FINISHED"}   # then onto the shape keys
    assert last_take.has_result(rig.mesh) and retarget.has_result(rig.mesh)
    fingerprint = blend_fingerprint()
    with pytest.raises(RuntimeError, match="choose which"):
        bpy.ops.shapespace.discard_retarget()                                  # a script must say which
    assert blend_fingerprint() == fingerprint
    st = rig.mesh.shapespace_retarget
    st.csv_path = _csv()
    buttons = [("SHAPE_KEYS", "SHAPE_KEYS"), ("CONTROLS", "CONTROLS")]
    for target, result in buttons:                                             # each box's button names its result
        st.target = target
        log = draw_panel(SHAPESPACE_PT_retarget, bpy.context)
        discard = [p for kind, p in log.log if kind == "operator_props" and p._idname == "shapespace.discard_retarget"]
        assert [p.result for p in discard] == [result]
    shape_key_take = actions.active_action(rig.mesh.data.shape_keys).name
    assert bpy.ops.shapespace.discard_retarget(result="SHAPE_KEYS") == {"FINISHED"}
    assert not retarget.has_result(rig.mesh) and last_take.has_result(rig.mesh)
    assert shape_key_take not in bpy.data.actions
    assert actions.active_action(rig.armature) == bones_take                   # the rig take is left alone


def test_a_take_whose_result_cannot_be_remembered_is_given_back(registered, monkeypatch):
    rig = _face()
    before_played = _played(rig)
    n_actions = len(bpy.data.actions)

    def broken(*_args, **_kw):
        raise OSError("disk full")                                             # stands for any failure to store
    monkeypatch.setattr(last_take, "remember", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        bpy.ops.shapespace.retarget_controls(filepath=_csv())
    assert _played(rig) == before_played and len(bpy.data.actions) == n_actions
    assert not last_take.has_result(rig.mesh)


def test_discard_keeps_a_take_action_something_else_plays_now(registered):
    rig = _face()
    assert bpy.ops.shapespace.retarget_controls(filepath=_csv()) == {"FINISHED"}
    bones_take = actions.active_action(rig.armature)
    other = bpy.data.objects.new("Other", None)
    bpy.context.scene.collection.objects.link(other)
    other.animation_data_create().action = bones_take                          # the artist reuses the take
    assert bpy.ops.shapespace.discard_retarget() == {"FINISHED"}
    assert bones_take.name in bpy.data.actions and other.animation_data.action == bones_take
