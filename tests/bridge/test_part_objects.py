"""Transfer Shapes onto a head whose eyes and teeth are objects of their own (issue #22 §1), as Ready Player Me
ships them: the part objects named by the target's *Parts* collection are transferred with the head and get
shape keys of the same names, in their own object space; checked through Blender's evaluation.

Source: Ready Player Me's ``Wolf3D_Head`` with its ARKit keys; target: copies of the head, its eyes and its teeth
with every key removed (``_landmark_pairs`` places the landmarks by position, as on the Face Cap cases).
"""
import numpy as np
import pytest

from blender_support import blend_fingerprint, bpy, evaluated, import_file
from shapespace.bridge import authoring, part_objects, shapekeys
from shapespace.core.result import ShapeSpaceError, Status
from support import shared
from test_authoring_transfer import _landmark_pairs, _place_landmarks

PARTS = ("EyeLeft", "EyeRight", "Wolf3D_Teeth")


def _copy(name, suffix):
    ob = bpy.data.objects[name]
    new = ob.copy()
    new.data = ob.data.copy()
    new.name = f"{name}{suffix}"
    bpy.context.scene.collection.objects.link(new)
    new.shape_key_clear()
    return new


def _rpm_with_part_objects():
    import_file(shared("rpm_brunette", "brunette-t.glb"))
    src = bpy.data.objects["Wolf3D_Head"]
    tgt = _copy("Wolf3D_Head", ".target")
    coll = bpy.data.collections.new("TargetParts")
    bpy.context.scene.collection.children.link(coll)
    for name in PARTS:
        coll.objects.link(_copy(name, ".target"))
    tgt.shapespace_authoring.parts_collection = coll
    sv, tv = _landmark_pairs(src, tgt, (np.eye(3), 1.0, np.zeros(3)))
    _place_landmarks(src, tgt, sv, tv)
    return src, tgt


def _world(ob, co):
    M = np.array(ob.matrix_world)
    return co @ M[:3, :3].T + M[:3, 3]


def _values(ob, **values):
    names = shapekeys.slider_names(ob)
    shapekeys.write_slider_values(ob, names, [values.get(n, 0.0) for n in names])
    return evaluated(ob)


def _rigid_error(before, after):
    d0 = np.linalg.norm(before[:, None] - before[None], axis=2)
    d1 = np.linalg.norm(after[:, None] - after[None], axis=2)
    return float(np.abs(d1 - d0).max())


def test_part_objects_get_keys_of_the_same_names_and_move_as_parts(registered):
    src, tgt = _rpm_with_part_objects()
    rep = authoring.transfer_shapes(src, tgt, unmatched_parts="move",
                                    parts=part_objects.meshes_of(tgt.shapespace_authoring.parts_collection, tgt))
    assert [p["object"] for p in rep.part_objects] == sorted(f"{n}.target" for n in PARTS)
    for p in rep.part_objects:
        ob = bpy.data.objects[p["object"]]
        assert p["created"] == rep.created
        assert [kb.name for kb in ob.data.shape_keys.key_blocks][1:] == rep.created
    size = float(np.ptp(_world(tgt, evaluated(tgt))))
    left, right = bpy.data.objects["EyeLeft.target"], bpy.data.objects["EyeRight.target"]
    rest_l, rest_r = _world(left, evaluated(left)), _world(right, evaluated(right))
    look_l, look_r = _world(left, _values(left, eyeLookUpLeft=1.0)), _world(right, _values(right, eyeLookUpLeft=1.0))
    assert np.abs(look_l - rest_l).max() > 1e-3 * size                     # the left eye turns …
    assert _rigid_error(rest_l, look_l) < 1e-5 * size                      # … rigidly, in world space
    assert np.abs(look_r - rest_r).max() < 1e-6 * size                     # the right eye stays
    up = np.array(tgt.matrix_world)[:3, 2]                                 # Ready Player Me: z up in the world
    front = rest_l[np.argmax(rest_l @ -np.array(tgt.matrix_world)[:3, 1])]  # the pupil (−y is forward)
    moved = look_l[np.argmax(rest_l @ -np.array(tgt.matrix_world)[:3, 1])] - front
    assert moved @ up > 0                                                  # up, as eyeLookUp says
    rest = _world(tgt, _values(tgt))
    blink = _world(tgt, _values(tgt, eyeBlinkLeft=1.0)) - rest
    assert np.abs(blink).max() > 1e-3 * size


def test_a_part_object_in_edit_mode_or_moved_mid_way_is_refused_and_nothing_written(registered):
    src, tgt = _rpm_with_part_objects()
    teeth = bpy.data.objects["Wolf3D_Teeth.target"]
    parts = part_objects.meshes_of(tgt.shapespace_authoring.parts_collection, tgt)
    plan = authoring.read_transfer(src, tgt, unmatched_parts="move", parts=parts)
    outcome = authoring.compute_transfer(plan)
    teeth.location.x += 0.01                                               # moved while it computed
    bpy.context.view_layer.update()
    before = blend_fingerprint()
    with pytest.raises(ShapeSpaceError, match="changed while the transfer computed"):
        authoring.write_transfer(outcome)
    assert blend_fingerprint() == before
    teeth.location.x -= 0.01
    outcome = authoring.compute_transfer(authoring.read_transfer(src, tgt, unmatched_parts="move", parts=parts))
    teeth.data.vertices[0].co.z += 0.001                                 # its own shape edited while it computed
    before = blend_fingerprint()
    with pytest.raises(ShapeSpaceError, match="changed while the transfer computed"):
        authoring.write_transfer(outcome)
    assert blend_fingerprint() == before
    bpy.ops.object.select_all(action="DESELECT")
    teeth.select_set(True)
    bpy.context.view_layer.objects.active = teeth
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        with pytest.raises(ShapeSpaceError, match="part object 'Wolf3D_Teeth.target' is in Edit Mode"):
            authoring.read_transfer(src, tgt, unmatched_parts="move", parts=parts)
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")


def test_command_line_parts_collection(registered, tmp_path):
    """``transfer --parts-collection NAME``: the collection's meshes are transferred as parts and listed in the
    JSON report; a collection that does not exist is refused by name (exit 1, nothing saved)."""
    import json

    from test_authoring_transfer import _cli
    src, tgt = _rpm_with_part_objects()
    tgt.shapespace_authoring.parts_collection = None                    # the command line names it
    path = str(tmp_path / "avatar.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    common = ("-b", path, "--command", "shapespace", "transfer", "--source-rig", "Wolf3D_Head",
              "--object", "Wolf3D_Head.target", "--dry-run")
    code, stdout, stderr = _cli(*common, "--parts-collection", "TargetParts")
    assert stdout.strip(), stderr
    rep = json.loads(stdout)
    assert [p["object"] for p in rep["part_objects"]] == sorted(f"{n}.target" for n in PARTS), stderr
    assert all(p["created"] == rep["created"] for p in rep["part_objects"])
    assert code == (0 if rep["status"] == "ok" and rep["registration_status"] != "not_converged" else 1)
    code, stdout, stderr = _cli(*common, "--parts-collection", "NoSuch")
    assert code == 1 and stdout == "" and "--parts-collection: no collection named 'NoSuch'" in stderr


def test_the_panel_shows_the_last_transfers_checks_and_names_a_damaged_verdict(registered):
    """After a transfer the Transfer Shapes panel shows its verdict (status, failed keys, parts); a damaged
    stored verdict is one line in the panel (no exception) and Check Rig's damage list names it."""
    from blender_support import RecordingLayout as Layout
    from shapespace.bridge import storage
    from shapespace.panels.authoring import SHAPESPACE_PT_transfer_shapes as Panel

    def labels():
        log = []
        Panel.draw(type("PanelCall", (), {"layout": Layout(log)})(), bpy.context)
        return [text for kind, text in log if kind == "label"]

    src, tgt = _rpm_with_part_objects()
    rep = authoring.transfer_shapes(src, tgt, unmatched_parts="move",
                                    parts=part_objects.meshes_of(tgt.shapespace_authoring.parts_collection, tgt))
    bpy.context.view_layer.objects.active = tgt
    drawn = labels()
    failed = [k["name"] for k in rep.keys if k["failed"]]
    head = ("every key passed its checks" if rep.status == Status.OK else f"{len(failed)} keys failed a check")
    assert f"Last transfer from Wolf3D_Head: {head}" in drawn
    assert any(text.startswith("Parts: ") and "eye" in text for text in drawn)
    assert all(any(text.startswith(f"{name}: ") for text in drawn) for name in failed[:12])
    tgt.data.shape_keys[authoring.LAST_PROP] = "{not json"
    assert any(text.startswith("damaged ShapeSpace data") and authoring.LAST_PROP in text for text in labels())
    assert any(authoring.LAST_PROP in issue.message for issue in storage.damaged_blobs(tgt))
