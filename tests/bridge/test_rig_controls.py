"""Issue #25 item 5: control sets stored on the face, proposed from what deforms it, edited, mirrored.

Ground truth is Blender's evaluation: a proposed channel, moved alone, changes the distances between the face's
evaluated vertices (it deforms the face, not just carries it); a channel left out does not.  Stored sets survive
save and reopen exactly, damage is named by Check Rig, undo restores, and the operators work in Object and Pose
Mode and refuse Edit Mode by name.
"""
import json

import numpy as np
import pytest

import rigs
from blender_support import OPERATOR_CALLS, bpy, classify_operator_call, draw_panel
from shapespace.bridge import inventory
from shapespace.bridge.rig import bind, control_set, proposal, stored
from shapespace.core.rig.controls import ChannelKind
from support import shared

BUILDERS = {"hybrid": rigs.hybrid_rig, "driver": rigs.driver_rig, "rigify": rigs.rigify_rig}
CONTROL_OPS = ("propose_controls", "add_control_bones", "add_control_property", "remove_control", "toggle_control",
               "set_control_bounds", "clear_controls", "mirror_controls")
#: A channel deforms the face when some vertex pair's distance changes by more than this fraction of the diagonal.
DEFORM_TOL = 1e-5


def _head():
    return shared(*rigs.FACECAP.split("/"))


def _activate(ob, mode="OBJECT", *also):
    if bpy.context.object is not None and bpy.context.object.mode != "OBJECT":
        bpy.ops.object.mode_set(mode="OBJECT")
    bpy.ops.object.select_all(action="DESELECT")
    for o in (ob, *also):
        o.select_set(True)
    bpy.context.view_layer.objects.active = ob
    if mode != "OBJECT":
        bpy.ops.object.mode_set(mode=mode)


def _select_bones(arm, names) -> None:
    """Select exactly ``names`` in Pose Mode (5.0 keeps the selection on the pose bone, 4.2 on the bone)."""
    for pb in arm.pose.bones:
        (pb if hasattr(pb, "select") else pb.bone).select = pb.name in names


def _pair_change(rig, channel, rng_pairs) -> float:
    """How much moving ``channel`` alone (a quarter of its range, or 0.1, inside its bounds) changes the distances
    between vertex pairs of the evaluated face, as a fraction of the diagonal (Blender's evaluation, no probe)."""
    b = bind(control_set([channel]))[0]
    raw, c = b.raw(), b.get()
    span = channel.hi - channel.lo
    delta = 0.25 * span if np.isfinite(span) else 0.1
    rest = rig.world_points()
    worst = 0.0
    for v in (min(c + delta, channel.hi), max(c - delta, channel.lo)):
        if v == c:
            continue
        b.set(v)
        moved = rig.world_points()
        i, j = rng_pairs
        d0 = np.linalg.norm(rest[i] - rest[j], axis=1)
        d1 = np.linalg.norm(moved[i] - moved[j], axis=1)
        worst = max(worst, float(np.abs(d1 - d0).max()))
    b.set_raw(raw)
    bpy.context.view_layer.update()
    return worst / rigs.diagonal(rest)


@pytest.mark.parametrize("name", [pytest.param(n, marks=[pytest.mark.rigify] if n == "rigify" else [])
                                  for n in sorted(BUILDERS)])
def test_propose_finds_the_channels_that_move_the_face_and_none_that_do_not(registered, name):
    rig = BUILDERS[name](_head())
    _activate(rig.mesh)
    assert bpy.ops.shapespace.propose_controls() == {"FINISHED"}
    armature, entries = stored.read(rig.mesh)
    assert armature == rig.armature.name
    labels = [e.label for e in entries]
    assert {ch.name for ch in rig.controls.channels} <= set(labels)          # every control of the test rig
    report, chans = proposal.propose(rig.mesh, rig.armature)                   # same answer, report by name
    assert [c.name for c in chans] == labels
    rng = np.random.default_rng(5)
    n = len(rig.mesh.data.vertices)
    pairs = (rng.integers(n, size=4000), rng.integers(n, size=4000))
    sample = chans if len(chans) <= 60 else [chans[i] for i in rng.choice(len(chans), 60, replace=False)]
    for ch in sample:                                                           # each proposed channel deforms
        assert _pair_change(rig, ch, pairs) > DEFORM_TOL, ch.name
    cand, locked, held = proposal.candidates(rig.mesh, rig.armature)
    inert = [c for c in cand if c.name in report.skipped["inert"]]
    assert inert
    sample = inert if len(inert) <= 40 else [inert[i] for i in rng.choice(len(inert), 40, replace=False)]
    for ch in sample:                                                           # each left-out channel does not
        assert _pair_change(rig, ch, pairs) <= 10 * DEFORM_TOL, ch.name
    assert report.skipped["locked"] == locked and locked
    if name == "driver":                       # driven sliders are overridden by their drivers: never proposed
        assert {"key jawOpen", "key mouthSmile_L", "key eyeBlink_L"} <= set(report.skipped["inert"])
        assert {"ctl_jaw location X", "ctl_brow rotation Y"} <= set(locked)
    if name == "hybrid":
        assert "jaw rotation Y" in locked
    if name == "rigify":                       # root and torso carry the head without deforming it
        assert {"root rotation X", "root location Z"} <= set(report.skipped["inert"])


def _stored_text(ob):
    return ob.get(stored.PROP)


def test_store_save_reopen_gives_the_same_control_set(registered, tmp_path):
    rig = rigs.hybrid_rig(_head())
    face, arm = rig.mesh, rig.armature
    _activate(arm, "POSE", face)
    _select_bones(arm, ("jaw",))
    assert bpy.ops.shapespace.add_control_bones() == {"FINISHED"}
    _activate(face)
    assert bpy.ops.shapespace.add_control_property(data_path='data.shape_keys.key_blocks["eyeBlink_L"].value',
                                                   object_name=face.name) == {"FINISHED"}
    _, entries = stored.read(face)
    labels = [e.label for e in entries]
    assert labels == ["jaw rotation X", "jaw rotation Z", "jaw location X", "jaw location Y", "jaw location Z",
                      "key eyeBlink_L"]                                      # rotation Y is locked
    assert bpy.ops.shapespace.set_control_bounds(index=0, use_min=True, min=-0.1, use_max=False) == {"FINISHED"}
    assert bpy.ops.shapespace.toggle_control(index=2, enabled=False) == {"FINISHED"}
    before = stored.read(face)
    controls = stored.control_set(face)
    assert controls.names == [n for n in labels if n != "jaw location X"]
    # override (a float operator property: float32) + Limit Rotation
    assert controls.channels[0].lo == pytest.approx(-0.1, rel=1e-6)
    assert controls.channels[0].hi == pytest.approx(0.35, rel=1e-6)
    path = str(tmp_path / "controls.blend")
    assert bpy.ops.wm.save_as_mainfile(filepath=path) == {"FINISHED"}
    text, name = _stored_text(face), face.name
    assert bpy.ops.wm.open_mainfile(filepath=path) == {"FINISHED"}
    face = bpy.data.objects[name]
    assert _stored_text(face) == text
    assert stored.read(face) == before
    assert stored.control_set(face) == controls
    assert json.loads(text)["schema_version"] == 1


def test_a_damaged_channel_is_named_by_check_rig_and_nothing_breaks(registered):
    rig = rigs.hybrid_rig(_head())
    face = rig.mesh
    _activate(face)
    assert bpy.ops.shapespace.propose_controls() == {"FINISHED"}
    data = json.loads(_stored_text(face))
    data["channels"][3]["kind"] = "twist"
    face[stored.PROP] = json.dumps(data)
    found = [i for i in inventory.check_object(face) if i.code == "corrupt_metadata"]
    assert len(found) == 1, found
    msg = found[0].message
    assert "shapespace_controls" in msg and face.name in msg and "channel 3" in msg and "\n" not in msg
    with pytest.raises(RuntimeError, match="damaged ShapeSpace data in Object .* ▸ shapespace_controls: channel 3"):
        bpy.ops.shapespace.check_rig()
    log = draw_panel(_panel(), bpy.context, strict=False)
    assert any("channel 3" in t for t in log.labels)
    for op in CONTROL_OPS:
        _activate(face)
        outcome, message = classify_operator_call(op, OPERATOR_CALLS[op])
        assert outcome in ("refused", "cancelled", "finished"), (op, outcome, message)
        if op != "clear_controls":
            assert outcome != "finished" or _stored_text(face) == json.dumps(data), op
    assert stored.PROP not in face or _stored_text(face) == json.dumps(data)


def _panel():
    from shapespace.panels.controls import SHAPESPACE_PT_controls
    return SHAPESPACE_PT_controls


@pytest.mark.rigify
def test_mirror_controls_on_rigify_face_bones(registered):
    rig = rigs.rigify_rig(_head())
    face, arm = rig.mesh, rig.armature
    left = ("lips.L", "brow.T.L.002", "lid.T.L.002", "jaw_master")
    _activate(arm, "POSE", face)
    _select_bones(arm, left)
    assert bpy.ops.shapespace.add_control_bones() == {"FINISHED"}
    _, entries = stored.read(face)
    i = next(k for k, e in enumerate(entries) if e.label == "lips.L location X")
    assert bpy.ops.shapespace.set_control_bounds(index=i, use_min=True, min=-0.02, use_max=True,
                                                 max=0.05) == {"FINISHED"}
    _, entries = stored.read(face)
    assert bpy.ops.shapespace.mirror_controls() == {"FINISHED"}
    _, mirrored = stored.read(face)
    assert mirrored[:len(entries)] == entries
    added = mirrored[len(entries):]
    expected = {e.label.replace(".L", ".R") for e in entries if ".L" in e.owner}
    assert {e.label for e in added} == expected
    by_label = {e.label: e for e in added}
    assert (by_label["lips.R location X"].lo, by_label["lips.R location X"].hi) == pytest.approx((-0.05, 0.02),
                                                                                                 rel=1e-6)
    # the mirrored channels are the rig's: moving lips.R X by +v moves the face as lips.L X by -v, mirrored in x
    controls = stored.control_set(face)
    assert {c.name for c in controls.channels} >= expected
    assert bpy.ops.shapespace.mirror_controls() == {"FINISHED"}                    # nothing left to add
    assert len(stored.read(face)[1]) == len(mirrored)
    # a sided channel without a mirror is refused by name, nothing written
    arm["smile_L"] = 0.0
    arm.id_properties_ui("smile_L").update(soft_min=0.0, soft_max=1.0)
    assert bpy.ops.shapespace.add_control_property(data_path='["smile_L"]') == {"FINISHED"}
    text = _stored_text(face)
    with pytest.raises(RuntimeError, match=r"channel 'rig\[smile_L\]' has no mirror 'rig\[smile_R\]'"):
        bpy.ops.shapespace.mirror_controls()
    assert _stored_text(face) == text


@pytest.mark.rigify
def test_mirrored_rigify_channel_moves_the_face_as_the_mirror_image(registered):
    rig = rigs.rigify_rig(_head())
    face, arm = rig.mesh, rig.armature
    _activate(face)
    stored.write(face, arm.name, [stored.entry_of(rig.controls.channels[rig.controls.index("lips.L location X")])])
    assert bpy.ops.shapespace.mirror_controls() == {"FINISHED"}
    controls = stored.control_set(face)
    rest = rig.world_points()
    moved = []
    for i, v in ((0, 0.04), (1, -0.04)):                      # lips.L X = +v and lips.R X = −v (flipped pose)
        c = np.zeros(2)
        c[i] = v
        b = bind(controls)
        b[i].set(v)
        bpy.context.view_layer.update()
        moved.append(rig.world_points() - rest)
        b[i].set(0.0)
        bpy.context.view_layer.update()
    # the displacement fields are mirror images: the largest motions match in size and sit on opposite sides
    left, right = moved
    assert np.isclose(np.linalg.norm(left, axis=1).max(), np.linalg.norm(right, axis=1).max(), rtol=0.2)
    cl = rest[np.argmax(np.linalg.norm(left, axis=1))]
    cr = rest[np.argmax(np.linalg.norm(right, axis=1))]
    centre = 0.5 * (rest[:, 0].max() + rest[:, 0].min())
    assert (cl[0] - centre) * (cr[0] - centre) < 0


def test_undo_restores_the_control_set(registered):
    rig = rigs.hybrid_rig(_head())
    name = rig.mesh.name
    _activate(rig.mesh)
    bpy.ops.ed.undo_push(message="start")
    assert bpy.ops.shapespace.propose_controls() == {"FINISHED"}
    bpy.ops.ed.undo_push(message="propose")
    n = len(stored.read(bpy.data.objects[name])[1])
    assert bpy.ops.shapespace.remove_control(index=0) == {"FINISHED"}
    bpy.ops.ed.undo_push(message="remove")
    assert len(stored.read(bpy.data.objects[name])[1]) == n - 1
    bpy.ops.ed.undo()
    assert len(stored.read(bpy.data.objects[name])[1]) == n
    bpy.ops.ed.undo()
    assert stored.PROP not in bpy.data.objects[name]


def test_operators_work_in_object_and_pose_mode_and_refuse_edit_mode_by_name(registered):
    rig = rigs.driver_rig(_head())
    face, arm = rig.mesh, rig.armature
    _activate(arm, "POSE", face)                              # Pose Mode: the face is the selected mesh
    _select_bones(arm, ("ctl_jaw", "ctl_brow"))
    assert bpy.ops.shapespace.add_control_bones() == {"FINISHED"}
    assert [e.label for e in stored.read(face)[1]] == ["ctl_jaw rotation X", "ctl_jaw rotation Y",
                                                       "ctl_jaw rotation Z", "ctl_jaw location Y",
                                                       "ctl_brow rotation X", "ctl_brow location X",
                                                       "ctl_brow location Y", "ctl_brow location Z"]
    assert bpy.ops.shapespace.add_control_property(data_path='["blink"]') == {"FINISHED"}
    assert stored.read(face)[1][-1].kind == ChannelKind.PROPERTY
    assert bpy.ops.shapespace.remove_control(index=0) == {"FINISHED"}
    log = draw_panel(_panel(), bpy.context)
    assert ("operator", "shapespace.toggle_control") in log.log and any("8 channels" in t for t in log.labels)
    _activate(arm, "POSE")                                    # face not selected: found through its stored set
    assert bpy.ops.shapespace.propose_controls() == {"FINISHED"}
    assert {"ctl_jaw location Y", "Controls[blink]"} <= {e.label for e in stored.read(face)[1]}
    _activate(face)                                           # Object Mode on the face
    assert bpy.ops.shapespace.clear_controls() == {"FINISHED"} and stored.PROP not in face
    assert bpy.ops.shapespace.propose_controls() == {"FINISHED"}
    text = _stored_text(face)
    for ob in (arm, face):                                    # Edit Mode refused by name, nothing written
        _activate(ob, "EDIT", *(() if ob is face else (face,)))
        for op in CONTROL_OPS:
            outcome, message = classify_operator_call(op, OPERATOR_CALLS[op])
            assert outcome == "refused", (op, outcome, message)
            if op != "add_control_bones":
                assert f"'{ob.name}' is in Edit Mode" in message, (op, message)
        assert _stored_text(face) == text
        bpy.ops.object.mode_set(mode="OBJECT")


def test_propose_reports_progress_and_a_cancel_leaves_rig_and_file_as_they_were(registered):
    from shapespace.core.progress import Cancelled
    rig = rigs.hybrid_rig(_head())
    seen = []
    report, chans = proposal.propose(rig.mesh, rig.armature, progress=seen.append)
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(seen) == len(proposal.candidates(rig.mesh,
                                                                                             rig.armature)[0])
    before = (rig.world_points(), [tuple(pb.rotation_euler) for pb in rig.armature.pose.bones],
              [kb.value for kb in rig.mesh.data.shape_keys.key_blocks])

    def stop(fraction):
        if fraction > 0.5:
            raise Cancelled()
    with pytest.raises(Cancelled):
        proposal.propose_and_store(rig.mesh, rig.armature, progress=stop)
    after = (rig.world_points(), [tuple(pb.rotation_euler) for pb in rig.armature.pose.bones],
             [kb.value for kb in rig.mesh.data.shape_keys.key_blocks])
    np.testing.assert_array_equal(before[0], after[0])
    assert before[1:] == after[1:] and stored.PROP not in rig.mesh


def test_add_property_refuses_what_is_not_a_channel_by_name(registered):
    rig = rigs.driver_rig(_head())
    _activate(rig.mesh)
    cases = {'pose.bones["ctl_jaw"].location': "is not a custom property",
             '["nope"]': "has no custom property 'nope'",
             'data.shape_keys.key_blocks["nope"].value': "has no shape-key slider 'nope'"}
    for path, said in cases.items():
        with pytest.raises(RuntimeError, match=said):
            bpy.ops.shapespace.add_control_property(data_path=path, object_name=rig.mesh.name
                                                    if "shape_keys" in path else rig.armature.name)
    assert stored.PROP not in rig.mesh
    assert bpy.ops.shapespace.add_control_property(data_path='["blink"]', object_name="Controls") == {"FINISHED"}
    with pytest.raises(RuntimeError, match=r"channel 'Controls\[blink\]' is already in the control set"):
        bpy.ops.shapespace.add_control_property(data_path='["blink"]', object_name="Controls")
    with pytest.raises(RuntimeError, match="no object 'Missing'"):
        bpy.ops.shapespace.add_control_property(data_path='["blink"]', object_name="Missing")


@pytest.mark.parametrize("name", ["hybrid", "driver"])
def test_a_stored_control_set_reads_back_as_the_rigs_own_channels(registered, name):
    """Channel → stored entry → channel is exact (path, axis, bounds, lock, rotation mode), so a solve on the stored
    set is the solve on the rig's control set (tests/bridge/test_rig.py)."""
    rig = BUILDERS[name](_head())
    entries = [stored.entry_of(ch) for ch in rig.controls.channels]
    stored.write(rig.mesh, rig.armature.name, entries)
    assert stored.control_set(rig.mesh) == rig.controls
    stored.set_enabled(rig.mesh, 0, False)
    assert stored.control_set(rig.mesh).channels == rig.controls.channels[1:]
    assert stored.control_set(rig.mesh, enabled_only=False) == rig.controls
