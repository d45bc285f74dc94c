"""Head, neck and eyes offline (issue #24): a recording's head and eye channels key the chosen bones exactly as
live capture drives them.

The take is the shared Live Link Face recording with a synthetic head motion (its own head columns are 0),
written as a CSV by ``tools/capture_files.py``.  Checked against Blender's own evaluation of the keyed
armature (the posed bones' armature-space rotations equal the face rotation ``R_y(yaw) R_x(pitch)
R_z(roll)`` carried onto Blender's axes, built here with mathutils), and against the live session's path
(the same rows sent as Live Link Face packets through the live pipeline and scene resampler).
"""
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from mathutils import Matrix

from blender_support import bpy, import_file
from capture_files import load_llf_take, write_llf_csv
from shapespace.bridge import actions, retarget
from shapespace.bridge.live.rig import Pipeline
from shapespace.core.live import CopySolver, SceneResampler, decode_llf, encode_llf
from shapespace.core.result import ShapeSpaceError
from support import ASSETS, ROOT

BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")
CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
C = Matrix(((1, 0, 0), (0, 0, -1), (0, 1, 0)))          # face frame → Blender armature axes
MODES = {"neck": "XYZ", "head": "QUATERNION", "eye.L": "YXZ", "eye.R": "AXIS_ANGLE"}


def face_rotation(ypr):
    yaw, pitch, roll = (float(v) for v in ypr)
    return C @ Matrix.Rotation(yaw, 3, "Y") @ Matrix.Rotation(pitch, 3, "X") @ Matrix.Rotation(roll, 3, "Z") \
        @ C.transposed()


def make_rig():
    """An armature: neck → head → eyes, with tilted rest orientations and rolls, one rotation mode each."""
    data = bpy.data.armatures.new("Rig")
    arm = bpy.data.objects.new("Rig", data)
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    spec = {"neck": ((0, 0, 1.4), (0, 0.02, 1.55), 0.1, None), "head": ((0, 0.02, 1.55), (0, -0.01, 1.8), -0.2, "neck"),
            "eye.L": ((0.03, -0.08, 1.65), (0.03, -0.1, 1.65), 0.3, "head"),
            "eye.R": ((-0.03, -0.08, 1.65), (-0.04, -0.1, 1.66), 0.0, "head")}
    for name, (head, tail, roll, parent) in spec.items():
        eb = data.edit_bones.new(name)
        eb.head, eb.tail, eb.roll = head, tail, roll
        if parent:
            eb.parent = data.edit_bones[parent]
    bpy.ops.object.mode_set(mode="OBJECT")
    for name, mode in MODES.items():
        arm.pose.bones[name].rotation_mode = mode
    return arm


def delta(arm, name):
    """A posed bone's armature-space rotation relative to its rest (Blender's evaluation)."""
    pb = arm.pose.bones[name]
    return pb.matrix.to_3x3().normalized() @ pb.bone.matrix_local.to_3x3().normalized().inverted()


@pytest.fixture
def scene_with_take(tmp_path):
    import_file(BLEND)
    take = load_llf_take(CSV)
    path = tmp_path / "take.csv"
    path.write_text(write_llf_csv(take), encoding="utf-8")
    return bpy.data.objects["FBHead"], make_rig(), str(path), take


def bones_setting(**kw):
    return retarget.HeadEyeBones("Rig", head="head", neck="neck", eye_left="eye.L", eye_right="eye.R", **kw)


def test_head_neck_eyes_keyed_as_blender_evaluates_them(scene_with_take):
    ob, arm, path, take = scene_with_take
    scene = bpy.context.scene
    rep = retarget.retarget(ob, path, "copy", bones=bones_setting(neck_share=0.4))
    assert rep["bones"] == ["head", "neck", "eye.L", "eye.R"]
    assert not [i for i in rep.issues if "not used" in i.message]
    action = bpy.data.actions[rep["bones_action"]]
    assert actions.active_action(arm) == action
    if actions.LAYERED:
        assert rep["bones_action"] == rep["action"]                   # one action: a slot each
    _, t, _, rot = take
    rate = scene.render.fps / scene.render.fps_base
    for frame in (scene.frame_start, scene.frame_start + 7, scene.frame_start + 60, scene.frame_start + 150):
        scene.frame_set(frame)
        s = (frame - scene.frame_start) / rate
        ypr = [np.interp(s, t, rot[:, k]) for k in range(9)]
        head = face_rotation(ypr[0:3])
        got = delta(arm, "head")                                     # neck then head: the whole rotation
        assert max(abs(a - b) for ra, rb in zip(got, head) for a, b in zip(ra, rb)) < 1e-4
        neck = delta(arm, "neck")
        angle = neck.to_quaternion().angle
        assert angle == pytest.approx(0.4 * head.to_quaternion().angle, abs=1e-4)   # the neck's share
        for eye, cols in (("eye.L", slice(3, 6)), ("eye.R", slice(6, 9))):
            expected = head @ face_rotation(ypr[cols])                # eyes turn relative to the head
            got = delta(arm, eye)
            assert max(abs(a - b) for ra, rb in zip(got, expected) for a, b in zip(ra, rb)) < 1e-4, eye


def test_offline_bone_curves_equal_the_live_path_for_the_same_packets(scene_with_take):
    ob, arm, path, take = scene_with_take
    scene = bpy.context.scene
    rep = retarget.retarget(ob, path, "copy", bones=bones_setting())
    plan_bones = retarget.bone_specs(arm, "head", "neck", "eye.L", "eye.R", 0.3)
    solver = CopySolver([(0, 0)], np.ones(1), np.zeros(1), np.zeros(1), np.ones(1), 52)
    live = Pipeline(ob.name, ["EyeBlinkLeft"], solver, 52, "COPY", arm.name, plan_bones)
    resampler = SceneResampler(scene.render.fps / scene.render.fps_base, scene.frame_start)
    _, t, _, rot = take
    expected = {}
    for k in range(t.size):
        milli = int(round(t[k] * 60000.0))                         # the CSV's own timecode, as a packet
        frame, sub = divmod(milli, 1000)
        packet = encode_llf(np.concatenate([np.zeros(52), rot[k]]), frame, sub / 1000.0)
        f = decode_llf(packet)
        for scene_frame, v in resampler.push(f.time, f.vector()):
            expected[scene_frame] = live.solve(v)[1]
    curves = {(fc.data_path, fc.array_index): fc for fc in actions.fcurves(bpy.data.actions[rep["bones_action"]],
                                                                         arm)}
    worst = 0.0
    for b in plan_bones:
        prop, count = b.channel
        for i in range(count):
            x, y = actions.read_curve(curves[(actions.bone_path(b.name, prop), i)])[:2]
            ref = np.array([expected[fr][b.name][i] for fr in x])
            worst = max(worst, float(np.abs(y - ref).max()))
    assert worst < 1e-6


def test_unused_head_eye_channels_are_named(scene_with_take):
    ob, arm, path, _ = scene_with_take
    rep = retarget.retarget(ob, path, "copy")
    assert any("HeadYaw" in m and "RightEyeRoll" in m and "not used" in m for m in (i.message for i in rep.issues))
    assert "bones" not in rep
    rep = retarget.retarget(ob, path, "copy", bones=retarget.HeadEyeBones("Rig", head="head"))
    unused = [i.message for i in rep.issues if "not used" in i.message]
    assert unused and "LeftEyeYaw" in unused[0] and "HeadYaw" not in unused[0]


def test_missing_bone_refused_and_nothing_written(scene_with_take):
    ob, arm, path, _ = scene_with_take
    before = set(bpy.data.actions.keys())
    with pytest.raises(ShapeSpaceError) as exc:
        retarget.retarget(ob, path, "copy", bones=retarget.HeadEyeBones("Rig", head="Head_missing"))
    assert exc.value.code == "missing_bone" and "Head_missing" in str(exc.value)
    assert set(bpy.data.actions.keys()) == before and actions.active_action(arm) is None


def test_bone_keys_reduced_like_the_weights(scene_with_take):
    ob, arm, path, _ = scene_with_take
    dense = retarget.retarget(ob, path, "copy", bones=bones_setting(), action_name="dense")
    reduced = retarget.retarget(ob, path, "copy", bones=bones_setting(), action_name="reduced", key_tolerance=0.01)
    count = lambda rep: sum(len(fc.keyframe_points) for fc in  # noqa: E731
                            actions.fcurves(bpy.data.actions[rep["bones_action"]], arm))
    assert count(reduced) < 0.5 * count(dense)
    scene = bpy.context.scene
    for frame in range(scene.frame_start, scene.frame_start + 150, 13):
        scene.frame_set(frame)
        head_reduced = delta(arm, "head")
        actions.assign_action(arm, bpy.data.actions[dense["bones_action"]])
        scene.frame_set(frame)
        head_dense = delta(arm, "head")
        actions.assign_action(arm, bpy.data.actions[reduced["bones_action"]])
        assert max(abs(a - b) for ra, rb in zip(head_reduced, head_dense) for a, b in zip(ra, rb)) < 0.05


def test_operator_keys_the_bones(registered, scene_with_take):
    ob, arm, path, _ = scene_with_take
    bpy.context.view_layer.objects.active = ob
    assert bpy.ops.shapespace.retarget(filepath=path, method="copy", armature="Rig", head_bone="head",
                                       eye_left_bone="eye.L", eye_right_bone="eye.R") == {"FINISHED"}
    keyed = {fc.data_path for fc in actions.fcurves(actions.active_action(arm), arm)}
    paths = {"QUATERNION": "rotation_quaternion", "AXIS_ANGLE": "rotation_axis_angle"}
    assert keyed == {actions.bone_path(b, paths.get(arm.pose.bones[b].rotation_mode, "rotation_euler"))
                     for b in ("head", "eye.L", "eye.R")}
    with pytest.raises(RuntimeError, match="has no bone 'nope'"):
        bpy.ops.shapespace.retarget(filepath=path, method="copy", armature="Rig", head_bone="nope")


def test_cli_head_neck_eye_options(scene_with_take, tmp_path):
    ob, arm, path, _ = scene_with_take
    blend = tmp_path / "rig.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    run_cli = os.path.join(ROOT, "tools", "run_cli.py")
    common = [sys.executable, run_cli, str(blend), "--", "retarget", "--source", path, "--method", "copy",
              "--object", "FBHead", "--dry-run"]
    proc = subprocess.run(common + ["--head-bone", "head", "--neck-bone", "neck", "--eye-bones", "eye.L", "eye.R"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout[proc.stdout.index("{"):])["results"][0]
    assert rep["bones"] == ["head", "neck", "eye.L", "eye.R"] and rep["bones_action"]
    proc = subprocess.run(common, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "HeadYaw, HeadPitch, HeadRoll, LeftEyeYaw" in proc.stderr and "not used" in proc.stderr
    proc = subprocess.run(common + ["--head-bone", "head", "--neck-share", "2"], capture_output=True, text=True,
                          timeout=300)
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("shapespace: error:")]
    assert proc.returncode == 2 and errors == ["shapespace: error: --neck-share must lie in [0, 1], got 2"]


def test_calibration_rest_frame_becomes_the_rest_pose(scene_with_take):
    """As live *Calibrate*: the chosen frame's head and eye pose is the rest (R' = R₀ᵀ R)."""
    ob, arm, path, take = scene_with_take
    scene = bpy.context.scene
    rest = scene.frame_start + 40
    retarget.retarget(ob, path, "copy", bones=bones_setting(rest_frame=rest))
    _, t, _, rot = take
    rate = scene.render.fps / scene.render.fps_base
    ypr = lambda frame: [np.interp((frame - scene.frame_start) / rate, t, rot[:, k]) for k in range(3)]  # noqa: E731
    scene.frame_set(rest)
    assert delta(arm, "head").to_quaternion().angle < 1e-5
    frame = scene.frame_start + 90
    scene.frame_set(frame)
    expected = face_rotation(ypr(rest)).transposed() @ face_rotation(ypr(frame))    # C R₀ᵀ R Cᵀ
    got = delta(arm, "head")
    assert max(abs(a - b) for ra, rb in zip(got, expected) for a, b in zip(ra, rb)) < 1e-4


def test_discard_result_gives_the_armature_back_what_it_played(scene_with_take):
    """Discard Result after a retarget that keyed the bones: the armature plays its own action again (with its
    fake-user flag as it was), the bone keys are gone from the file, and a poll of Blender's evaluation shows
    the bones back in that action's pose; refused, changing nothing, when the armature plays something else."""
    ob, arm, path, _ = scene_with_take
    own = bpy.data.actions.new("ArmOwn")
    actions.assign_action(arm, own)
    actions.write_curve(arm, 'pose.bones["head"].rotation_quaternion', np.array([1.0, 2.0]),
                        np.array([0.9, 0.8]), index=0, group="head")
    rep = retarget.retarget(ob, path, "copy", bones=bones_setting())
    assert arm.animation_data.action.name == rep.bones_action != "ArmOwn"
    other = bpy.data.actions.new("Elsewhere")
    arm.animation_data.action = other
    with pytest.raises(ShapeSpaceError, match="plays 'Elsewhere', not the retarget's bone keys"):
        retarget.discard_last(ob)
    assert retarget.has_result(ob) and ob.data.shape_keys.animation_data.action.name == rep.action
    arm.animation_data.action = bpy.data.actions[rep.bones_action]
    retarget.discard_last(ob)
    assert arm.animation_data.action == own and not own.use_fake_user
    assert rep.bones_action not in bpy.data.actions and rep.action not in bpy.data.actions
    bpy.context.scene.frame_set(1)
    assert abs(arm.pose.bones["head"].rotation_quaternion[0] - 0.9) < 1e-6


def test_cli_uses_the_bones_stored_on_the_rig(registered, scene_with_take, tmp_path):
    """Without a bone option the CLI (and so a farm job) keys the head / neck / eye bones stored on the target
    mesh (Retarget panel ▸ Head & Eyes), as the panel's operator does; options given replace them."""
    ob, arm, path, _ = scene_with_take
    st = ob.shapespace_retarget
    st.armature, st.head_bone, st.neck_bone, st.eye_left_bone, st.eye_right_bone = arm, "head", "neck", "eye.L", ""
    blend = tmp_path / "rig.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    run_cli = os.path.join(ROOT, "tools", "run_cli.py")
    common = [sys.executable, run_cli, str(blend), "--", "retarget", "--source", path, "--method", "copy",
              "--object", "FBHead", "--dry-run"]
    for extra, bones in (([], ["head", "neck", "eye.L"]), (["--eye-bones", "eye.L", "eye.R"], ["eye.L", "eye.R"])):
        proc = subprocess.run(common + extra, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        rep = json.loads(proc.stdout[proc.stdout.index("{"):])["results"][0]
        assert rep.get("bones") == bones and rep["bones_action"], proc.stderr[-2000:]


def test_calibrate_from_the_operator_and_stored_on_the_rig_for_the_cli(registered, scene_with_take, tmp_path):
    """*Calibrate* at a rest frame from the operator, and stored on the rig for the CLI (or --calibrate-frame):
    the rest frame's head and eye pose becomes the rest pose, as the bridge's ``rest_frame`` makes it."""
    ob, arm, path, _ = scene_with_take
    scene = bpy.context.scene
    rest, other = scene.frame_start + 40, scene.frame_start + 90
    bpy.context.view_layer.objects.active = ob
    assert bpy.ops.shapespace.retarget(filepath=path, method="copy", armature="Rig", head_bone="head",
                                       eye_left_bone="eye.L", calibrate=True, rest_frame=rest) == {"FINISHED"}
    for name in ("head", "eye.L"):
        scene.frame_set(rest)
        assert delta(arm, name).to_quaternion().angle < 1e-5
        scene.frame_set(other)
        assert delta(arm, name).to_quaternion().angle > 1e-3
    st = ob.shapespace_retarget
    st.armature, st.head_bone, st.calibrate, st.rest_frame = arm, "head", True, rest
    blend, out = tmp_path / "rig.blend", tmp_path / "out.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    run_cli = os.path.join(ROOT, "tools", "run_cli.py")
    for extra, at in (([], rest), (["--head-bone", "head", "--calibrate-frame", str(other)], other)):
        proc = subprocess.run([sys.executable, run_cli, str(blend), "--", "retarget", "--source", path, "--method",
                               "copy", "--object", "FBHead", "--out", str(out), "--overwrite", *extra],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        bpy.ops.wm.open_mainfile(filepath=str(out))
        rig, scene = bpy.data.objects["Rig"], bpy.context.scene
        scene.frame_set(at)
        assert delta(rig, "head").to_quaternion().angle < 1e-5
        scene.frame_set(rest + other - at)
        assert delta(rig, "head").to_quaternion().angle > 1e-3
