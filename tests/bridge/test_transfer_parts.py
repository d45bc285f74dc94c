"""Transfer Shapes ▸ Parts (issue #22 §1): the target's facial parts listed in the panel, the kinds the user sets
there, and part objects their rig moves by itself kept still — checked through Blender's evaluation.

Cases: Face Cap's own file (its eyes turn by their ``grp_eye*`` parents' animated rotation, its teeth do not
move); Ready Player Me's head, eyes and teeth copied as a keyless target with part objects
(``test_part_objects``), an eye's rotation then animated as a rig would.
"""
import time

import bmesh
import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from blender_support import RecordingLayout, blend_fingerprint, bpy, draw_panel, esc_mid_way, evaluated, import_file
from shapespace.bridge import actions, authoring, part_objects
from shapespace.bridge.authoring.reading import read_target
from shapespace.core.progress import Cancelled
from shapespace.core.result import ShapeSpaceError
from shapespace.panels.authoring import SHAPESPACE_PT_transfer_shapes as Panel
from shapespace.panels.authoring import SHAPESPACE_UL_transfer_parts as PartsList
from support import shared
from test_part_objects import _rpm_with_part_objects, _values


def _face_cap():
    import_file(shared("facecap", "facecap_decoded.glb"))
    face = bpy.data.objects["Mesh_2"]
    coll = bpy.data.collections.new("FaceCapParts")
    bpy.context.scene.collection.children.link(coll)
    for name in ("Mesh_0", "Mesh_1", "Mesh_3"):
        coll.objects.link(bpy.data.objects[name])
    face.shapespace_authoring.parts_collection = coll
    bpy.context.view_layer.objects.active = face
    return face


def _rows(ob):
    return {(r.object, r.vertex): r for r in ob.shapespace_authoring.parts}


def _parts_of(ob):
    return part_objects.meshes_of(ob.shapespace_authoring.parts_collection, ob)


def _transfer(src, tgt):
    return authoring.transfer_shapes(src, tgt, unmatched_parts="move", existing="overwrite", parts=_parts_of(tgt),
                                     examples=authoring.stored_examples(tgt))


def test_face_caps_eyes_turn_by_their_rig_and_are_found_still_its_teeth_are_not(registered):
    face = _face_cap()
    for name, rig in (("Mesh_0", "grp_eyeLeft"), ("Mesh_1", "grp_eyeRight")):
        assert authoring.moved_by_rig(bpy.data.objects[name], face) == \
            f"the rotation_quaternion of {rig!r} is animated"
    assert authoring.moved_by_rig(bpy.data.objects["Mesh_3"], face) == ""        # under the head's own parent
    assert bpy.ops.shapespace.find_transfer_parts() == {"FINISHED"}
    rows = _rows(face)
    for name in ("Mesh_0", "Mesh_1"):
        eye = [r for (o, _), r in rows.items() if o == name]
        assert eye and all(r.used == "still" and r.kind == "auto" and "moved by its rig" in r.reason for r in eye)
    teeth = [r for (o, _), r in rows.items() if o == "Mesh_3"]
    assert teeth and {r.used for r in teeth} == {"skull"}
    assert sum(r.vertices for r in rows.values() if r.object) == sum(
        len(bpy.data.objects[n].data.vertices) for n in ("Mesh_0", "Mesh_1", "Mesh_3"))
    layout = draw_panel(Panel)
    assert "Parts: 36, 1 unsure" in layout.labels and ("list", "parts") in layout.log
    row = RecordingLayout()                                                   # one row of the list as drawn
    PartsList.draw_item(None, bpy.context, row, face.shapespace_authoring, rows[("Mesh_0", 0)], 0, None, "", 0)
    assert row.labels == ["Mesh_0 #0 (216)", "still"] and ("prop", "kind") in row.log


def test_an_eye_its_rig_turns_gets_still_keys_the_other_turns_and_a_set_kind_wins(registered):
    src, tgt = _rpm_with_part_objects()
    left, right = bpy.data.objects["EyeLeft.target"], bpy.data.objects["EyeRight.target"]
    left.rotation_euler = (0.0, 0.0, 0.0)
    left.keyframe_insert("rotation_euler", frame=1)
    left.rotation_euler = (0.0, 0.0, 0.3)
    left.keyframe_insert("rotation_euler", frame=20)
    bpy.context.scene.frame_set(1)
    assert authoring.moved_by_rig(left, tgt) == "the rotation_euler of 'EyeLeft.target' is animated"
    rep = _transfer(src, tgt)
    rest_l, rest_r = _values(left), _values(right)
    size = float(np.ptp(evaluated(tgt)))
    assert np.abs(_values(left, eyeLookUpLeft=1.0) - rest_l).max() < 1e-7 * size      # its rig turns it
    assert np.abs(_values(right, eyeLookUpRight=1.0) - rest_r).max() > 1e-3 * size    # this one, the keys
    said = [p for p in rep.parts if p["object"] == "EyeLeft.target"]
    assert said and all(p["kind"] == "still" and "moved by its rig" in p["reason"] for p in said)
    rows = [r for r in tgt.shapespace_authoring.parts if r.object == "EyeLeft.target"]
    assert rows and all(r.used == "still" for r in rows)
    for r in rows:                                                            # the user says: turn it anyway
        r.kind = "eye"
    _transfer(src, tgt)
    rest_l = _values(left)
    assert np.abs(_values(left, eyeLookUpLeft=1.0) - rest_l).max() > 1e-3 * size
    rows = [r for r in tgt.shapespace_authoring.parts if r.object == "EyeLeft.target"]
    assert all(r.kind == "eye" and r.used == "eye" and r.reason == "set by the user" for r in rows)


def test_a_kind_set_in_the_list_moves_the_part_so_and_survives_find_parts(registered):
    src, tgt = _rpm_with_part_objects()
    ob = bpy.data.objects["Wolf3D_Teeth.target"]
    _transfer(src, tgt)                                                       # as proposed: the jaw moves them
    size = float(np.ptp(evaluated(tgt)))
    assert np.abs(_values(ob, jawOpen=1.0) - _values(ob)).max() > 1e-3 * size
    bpy.context.view_layer.objects.active = tgt
    assert bpy.ops.shapespace.find_transfer_parts() == {"FINISHED"}
    teeth = [r for r in tgt.shapespace_authoring.parts if r.object == "Wolf3D_Teeth.target"]
    assert teeth
    for r in teeth:
        r.kind = "still"
    assert bpy.ops.shapespace.find_transfer_parts() == {"FINISHED"}            # found again: the choice stays
    assert all(r.kind == "still" and r.used == "still" for r in tgt.shapespace_authoring.parts
               if r.object == "Wolf3D_Teeth.target")
    _transfer(src, tgt)
    rest = _values(ob)
    for name in ("jawOpen", "mouthSmileLeft", "jawLeft"):
        assert np.abs(_values(ob, **{name: 1.0}) - rest).max() == 0.0


def test_a_set_row_whose_part_is_gone_is_refused_by_name_and_nothing_is_written(registered):
    src, tgt = _rpm_with_part_objects()
    bpy.context.view_layer.objects.active = tgt
    assert bpy.ops.shapespace.find_transfer_parts() == {"FINISHED"}
    row = next(r for r in tgt.shapespace_authoring.parts if r.object == "Wolf3D_Teeth.target")
    row.kind = "jaw"
    tgt.shapespace_authoring.parts_collection.objects.unlink(bpy.data.objects["Wolf3D_Teeth.target"])
    before = blend_fingerprint()
    with pytest.raises(ShapeSpaceError, match=r"part 'Wolf3D_Teeth.target' vertex \d+ \(set to 'jaw'\) is no "
                                              r"longer a part of this transfer"):
        _transfer(src, tgt)
    assert blend_fingerprint() == before
    assert authoring.find_parts(tgt, _parts_of(tgt)) > 0                      # found again: the row stays, gone
    gone = [r for r in tgt.shapespace_authoring.parts if r.object == "Wolf3D_Teeth.target"]
    assert [(r.kind, r.used) for r in gone] == [("jaw", "")]
    with pytest.raises(ShapeSpaceError, match="Find Parts again, or set the row to Auto"):
        _transfer(src, tgt)
    gone[0].kind = "auto"                                                     # an Auto row is simply refreshed
    assert authoring.find_parts(tgt, _parts_of(tgt)) > 0
    assert not any(r.object == "Wolf3D_Teeth.target" for r in tgt.shapespace_authoring.parts)


def test_the_targets_own_parts_are_listed_under_no_name_and_survive_renaming_it(registered):
    face = _face_cap()
    face.shapespace_authoring.parts_collection = None                          # the head alone
    assert authoring.find_parts(face) == 16                                   # Face Cap: 17 parts, the skin one
    rows = face.shapespace_authoring.parts
    assert all(r.object == "" for r in rows)
    inner = next(r for r in rows if r.used == "jaw")
    inner.kind = "still"
    face.name = "Head"
    kinds = authoring.part_kinds(face, read_target(face))
    assert kinds == {inner.vertex: ("still", "set by the user")}
    row = RecordingLayout()
    PartsList.draw_item(None, bpy.context, row, face.shapespace_authoring, inner, 0, None, "", 0)
    assert row.labels[0] == f"Head #{inner.vertex} ({inner.vertices})"


def test_select_part_selects_exactly_one_connected_piece(registered):
    face = _face_cap()
    assert bpy.ops.shapespace.find_transfer_parts() == {"FINISHED"}
    st = face.shapespace_authoring
    st.active_part = next(i for i, r in enumerate(st.parts) if r.object == "Mesh_3")
    row = st.parts[st.active_part]
    assert bpy.ops.shapespace.select_transfer_part() == {"FINISHED"}
    me = bpy.data.objects["Mesh_3"].data
    sel = np.zeros(len(me.vertices), dtype=bool)
    me.vertices.foreach_get("select", sel)
    ev = np.zeros(len(me.edges) * 2, dtype=np.int64)
    me.edges.foreach_get("vertices", ev)
    ev = ev.reshape(-1, 2)
    graph = coo_matrix((np.ones(len(ev)), (ev[:, 0], ev[:, 1])), shape=(len(me.vertices),) * 2)
    _, comp = connected_components(graph, directed=False)                     # SciPy's own components
    np.testing.assert_array_equal(sel, comp == comp[row.vertex])
    assert sel.sum() == row.vertices and np.flatnonzero(sel)[0] == row.vertex


def _head_with_boxes():
    """A sphere 'head' and two loose boxes of 8 vertices each (sizes 0.1 and 0.2) in one mesh."""
    me = bpy.data.meshes.new("Head")
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=32, v_segments=16, radius=1.0)
    for centre, size in (((0.3, -0.8, 0.3), 0.1), ((0.0, -0.6, -0.4), 0.2)):
        made = bmesh.ops.create_cube(bm, size=size)
        bmesh.ops.translate(bm, vec=centre, verts=made["verts"])
    bm.to_mesh(me)
    bm.free()
    ob = bpy.data.objects.new("Head", me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def test_a_set_row_whose_index_another_part_took_after_an_edit_is_refused_not_moved_onto_it(registered):
    ob = _head_with_boxes()
    assert authoring.find_parts(ob) == 2
    small, big = sorted(ob.shapespace_authoring.parts, key=lambda r: r.vertex)
    small.kind = "still"
    shift = big.vertex - small.vertex                                  # delete that many skin vertices: the big
    bm = bmesh.new()                                                   # box's lowest index becomes the small's
    bm.from_mesh(ob.data)
    bm.verts.ensure_lookup_table()
    bmesh.ops.delete(bm, geom=[bm.verts[i] for i in range(shift)], context="VERTS")
    bm.to_mesh(ob.data)
    bm.free()
    with pytest.raises(ShapeSpaceError, match=rf"part 'Head' vertex {small.vertex} \(set to 'still'\) is no longer"):
        authoring.part_kinds(ob, read_target(ob))
    assert authoring.find_parts(ob) == 2                                 # found again: the choice is not carried
    rows = ob.shapespace_authoring.parts                                # onto the other box; its row stays, gone
    assert sorted((r.kind, r.used != "") for r in rows) == [("auto", True), ("auto", True), ("still", False)]


@pytest.mark.skipif(not actions.LAYERED, reason="one action with several objects' slots: Blender 4.4+")
def test_an_nla_strip_is_read_through_its_own_slot_of_a_shared_action(registered):
    head = _head_with_boxes()
    parts = []
    act = bpy.data.actions.new("Take")
    layer = act.layers.new("Layer")
    strip = layer.strips.new(type="KEYFRAME")
    for name, turn in (("Still", 0.0), ("Turning", 0.5)):                 # the first slot keeps still
        ob = bpy.data.objects.new(name, bpy.data.meshes.new(name))
        bpy.context.scene.collection.objects.link(ob)
        slot = act.slots.new(id_type="OBJECT", name=name)
        fc = strip.channelbag(slot, ensure=True).fcurves.new("rotation_euler", index=2)
        fc.keyframe_points.insert(1, 0.0)
        fc.keyframe_points.insert(20, turn)
        track = ob.animation_data_create().nla_tracks.new()
        track.strips.new("Take", 1, act).action_slot = slot
        track.mute = True
        parts.append(ob)
    assert authoring.moved_by_rig(parts[0], head) == ""
    assert authoring.moved_by_rig(parts[1], head) == "the rotation_euler of 'Turning' is animated"


def test_a_constraint_to_the_face_itself_does_not_count_as_its_rig_moving_a_part(registered):
    head = _head_with_boxes()
    eye = bpy.data.objects.new("Eye", bpy.data.meshes.new("Eye"))
    aim = bpy.data.objects.new("Aim", None)
    for ob in (eye, aim):
        bpy.context.scene.collection.objects.link(ob)
    con = eye.constraints.new("CHILD_OF")
    con.target = head
    assert authoring.moved_by_rig(eye, head) == ""
    track = eye.constraints.new("DAMPED_TRACK")
    track.target = aim
    assert authoring.moved_by_rig(eye, head) == "'Eye' has a Damped Track constraint"


def test_a_kind_changed_while_the_transfer_computes_stops_the_write_finding_parts_does_not(registered):
    src, tgt = _rpm_with_part_objects()
    assert authoring.find_parts(tgt, _parts_of(tgt)) > 0
    plan = authoring.read_transfer(src, tgt, unmatched_parts="move", parts=_parts_of(tgt))
    outcome = authoring.compute_transfer(plan)
    assert authoring.find_parts(tgt, _parts_of(tgt)) > 0                  # the list refreshed: kinds unchanged
    row = next(r for r in tgt.shapespace_authoring.parts if r.object == "Wolf3D_Teeth.target")
    row.kind = "still"                                                    # … and now one changed
    before = blend_fingerprint()
    with pytest.raises(ShapeSpaceError, match="the kinds of the parts of 'Wolf3D_Head.target' changed"):
        authoring.write_transfer(outcome)
    assert blend_fingerprint() == before
    row.kind = "auto"
    assert authoring.write_transfer(outcome).created


def _listed(ob):
    return [(r.object, r.vertex, r.vertices, round(r.size, 6), r.kind, r.used, r.reason, r.unsure)
            for r in ob.shapespace_authoring.parts]


def test_find_parts_as_a_job_lists_what_the_direct_call_does_esc_and_an_edit_leave_the_list(registered):
    """The panel's Find Parts computes in a worker (progress, Esc): ICT FaceKit's 55 parts.  Esc mid-way leaves the
    list and the file as they were; run to its end, the job lists exactly what the direct call lists, with the
    kind the user set kept; a target edited while it computed is refused by name and the list is kept."""
    import_file(shared("ict_facekit", "ict_facekit_expressions.glb"))
    ob = bpy.data.objects["ICTFace"]
    assert authoring.find_parts(ob) == 55
    ob.shapespace_authoring.parts[3].kind = "still"                      # the user's choice
    before, listed = blend_fingerprint(), _listed(ob)
    job = authoring.start_find_parts_job(authoring.read_find_parts(ob))
    assert esc_mid_way(job, 0.1, 60)
    with pytest.raises(Cancelled):
        authoring.finish_find_parts_job(job)
    assert blend_fingerprint() == before and _listed(ob) == listed
    job = authoring.start_find_parts_job(authoring.read_find_parts(ob))
    while not job.done:                                                  # the modal timer ticks
        time.sleep(0.01)
    assert authoring.finish_find_parts_job(job) == 55
    assert all(b >= a for a, b in zip(job.reported, job.reported[1:])) and job.reported[-1] == 1.0
    assert len(job.reported) > 55                                        # a step per part at least
    via_job = _listed(ob)
    assert via_job[3][4] == "still" and via_job[3][5] == "still"
    assert authoring.find_parts(ob) == 55 and _listed(ob) == via_job
    job = authoring.start_find_parts_job(authoring.read_find_parts(ob))
    assert job.wait(60)
    ob.data.shape_keys.reference_key.data[0].co.x += 0.01                # the artist edits the head meanwhile
    before = blend_fingerprint()
    with pytest.raises(ShapeSpaceError, match="'ICTFace' or its Part Objects changed while Find Parts computed"):
        authoring.finish_find_parts_job(job)
    assert blend_fingerprint() == before and _listed(ob) == via_job


def test_find_parts_invoked_without_a_window_runs_in_one_go(registered):
    face = _face_cap()
    assert bpy.ops.shapespace.find_transfer_parts("INVOKE_DEFAULT") == {"FINISHED"}
    direct = _listed(face)
    face.shapespace_authoring.parts.clear()
    assert authoring.find_parts(face, _parts_of(face)) == len(direct) > 0
    assert _listed(face) == direct


def _edit_a_part_objects_shape(face):
    eye = bpy.data.objects["Mesh_0"]
    points = eye.data.shape_keys.reference_key.data if eye.data.shape_keys else eye.data.vertices
    points[0].co.z += 0.001


def _join_two_parts_by_a_face(face):
    """One triangle joining the skin to an eye-lash piece, no vertex added (the counts and positions stay)."""
    me = face.data
    row = next(r for r in face.shapespace_authoring.parts if r.object == "")
    bm = bmesh.new()
    bm.from_mesh(me)
    bm.verts.ensure_lookup_table()
    bm.faces.new([bm.verts[0], bm.verts[1], bm.verts[row.vertex]])
    bm.to_mesh(me)
    bm.free()


def _unlink_a_part_object(face):
    face.shapespace_authoring.parts_collection.objects.unlink(bpy.data.objects["Mesh_3"])


@pytest.mark.parametrize("edit", [_edit_a_part_objects_shape, _join_two_parts_by_a_face, _unlink_a_part_object],
                         ids=["part_object_shape", "target_faces", "part_objects_collection"])
def test_find_parts_refuses_what_changed_while_it_computed_and_keeps_the_list(registered, edit):
    face = _face_cap()
    parts = _parts_of(face)
    assert authoring.find_parts(face, parts) > 0
    listed = _listed(face)
    job = authoring.start_find_parts_job(authoring.read_find_parts(face, parts))
    assert job.wait(60)
    edit(face)
    before = blend_fingerprint()
    with pytest.raises(ShapeSpaceError, match="'Mesh_2' or its Part Objects changed while Find Parts computed"):
        authoring.finish_find_parts_job(job)
    assert blend_fingerprint() == before and _listed(face) == listed
