"""Sidebar panels: every panel's ``poll`` and ``draw`` run against real data, and every property and
operator they name — and every operator property they set — exists in Blender's RNA.

Panels only draw in a window redraw, which the headless ``bpy`` module cannot run; ``draw`` is called
here with a recording layout whose ``prop``/``operator``/``template_list`` check their arguments against
the real RNA definitions (so a renamed property or a typo fails here, not in the artist's sidebar)."""
import os

import bpy
import pytest

from blender_support import draw_panel, import_file
from support import ASSETS

PANELS = ("SHAPESPACE_PT_rig", "SHAPESPACE_PT_direct", "SHAPESPACE_PT_correctives", "SHAPESPACE_PT_retarget",
          "SHAPESPACE_PT_face_space")


def _draw_all(context):
    from shapespace.panels import classes
    drawn = {}
    for cls in classes:
        if cls.__name__ not in PANELS or (hasattr(cls, "poll") and not cls.poll(context)):
            continue
        drawn[cls.__name__] = draw_panel(cls, context, bl_idname=cls.__name__).log
    return drawn


def test_panels_on_a_face_rig(registered):
    import_file(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    ob = bpy.data.objects["FBHead"]
    bpy.context.view_layer.objects.active = ob
    st = ob.shapespace_retarget
    for kind in ("CSV", "ACTION", "MESH"):
        st.source_kind = kind
        drawn = _draw_all(bpy.context)
        assert {"SHAPESPACE_PT_rig", "SHAPESPACE_PT_direct", "SHAPESPACE_PT_retarget"} <= set(drawn)
        assert ("operator", "shapespace.retarget") in drawn["SHAPESPACE_PT_retarget"]
    assert bpy.ops.shapespace.set_mapping(source="JawOpen", target="MouthClose", gain=0.5) == {"FINISHED"}
    log = _draw_all(bpy.context)["SHAPESPACE_PT_retarget"]
    assert any(kind == "label" and text.startswith("JawOpen → MouthClose") for kind, text in log)
    csv = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
    assert bpy.ops.shapespace.retarget(filepath=csv, method="perframe", key_tolerance=0.01) == {"FINISHED"}
    log = _draw_all(bpy.context)["SHAPESPACE_PT_retarget"]
    assert ("operator", "shapespace.discard_retarget") in log
    assert any(kind == "label" and "% of the keys kept" in text for kind, text in log)
    assert bpy.ops.shapespace.remove_mapping(source="JawOpen") == {"FINISHED"}
    # face space: before and after analysis, prior and flagged frames
    assert "SHAPESPACE_PT_face_space" in _draw_all(bpy.context)
    with pytest.raises(RuntimeError, match="no mapping override for 'JawOpen'"):
        bpy.ops.shapespace.remove_mapping(source="JawOpen")


def test_panels_on_a_skinned_character(registered):
    import_file(os.path.join(ASSETS, "cesium_man", "CesiumMan.glb"))
    ob = next(o for o in bpy.data.objects if o.type == "MESH")
    bpy.context.view_layer.objects.active = ob
    drawn = _draw_all(bpy.context)
    assert "SHAPESPACE_PT_correctives" in drawn
    assert ("operator", "shapespace.psd_add_example") in drawn["SHAPESPACE_PT_correctives"]


def test_correctives_panel_says_when_an_appended_old_pose_space_uses_skin_weighted(registered, tmp_path):
    """A pose space appended from a 0.1.0 file has no stored distance (no load handler ran): the property shows
    the new default (Blended) but the pose space uses Skin Weighted, and the panel says so until it is stored."""
    blend = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data", "shapespace_0_1_0.blend")
    with bpy.data.libraries.load(blend, link=False) as (_src, dst):
        dst.objects = ["Limb", "Armature"]
    for o in dst.objects:
        bpy.context.scene.collection.objects.link(o)
    ob = bpy.data.objects["Limb"]
    bpy.context.view_layer.objects.active = ob
    ob.shapespace_psd.method = "WPSD"
    note = ("label", "Uses Skin Weighted: this pose space was made before ShapeSpace 0.2.0")
    assert note in _draw_all(bpy.context)["SHAPESPACE_PT_correctives"]
    assert bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "appended.blend")) == {"FINISHED"}
    assert ob.shapespace_psd.wpsd_distance == "SKIN"                  # stored on save
    assert note not in _draw_all(bpy.context)["SHAPESPACE_PT_correctives"]


def test_direct_manipulation_panel_on_a_bone_driven_face_without_shape_keys(registered):
    """A face driven only by bones (its control set stored) gets the Pin tool's settings: mode, α, the Learned
    prior's action and range, Symmetric — not the shape-key solve's (μ, PCA form, snapping, Solve Pins)."""
    from shapespace.bridge import rig as brig
    from shapespace.bridge.rig import stored
    bpy.ops.mesh.primitive_uv_sphere_add()
    face = bpy.context.active_object
    arm = bpy.data.objects.new("Bones", bpy.data.armatures.new("Bones"))
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    bone = arm.data.edit_bones.new("jaw")
    bone.head, bone.tail = (0.0, 0.0, 0.0), (0.0, -1.0, 0.0)
    bpy.ops.object.mode_set(mode="OBJECT")
    face.modifiers.new("Armature", "ARMATURE").object = arm
    face.vertex_groups.new(name="jaw").add(list(range(len(face.data.vertices))), 1.0, "REPLACE")
    stored.add_entries_of(face, arm.name, [brig.bone_channel(arm, "jaw", "rotation", 0)])
    bpy.context.view_layer.objects.active = face
    assert face.data.shape_keys is None
    face.shapespace.mode = "LEARNED"
    log = _draw_all(bpy.context)["SHAPESPACE_PT_direct"]
    props = {name for kind, name in log if kind == "prop"}
    ops = {name for kind, name in log if kind == "operator"}
    assert {"mode", "alpha", "prior_action", "prior_start", "prior_end", "symmetric"} <= props
    assert not props & {"mu", "prior_form", "snap"}
    assert "shapespace.solve_pins" not in ops and "shapespace.add_inbetween" not in ops
