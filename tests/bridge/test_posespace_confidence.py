"""Pose-space confidence in Blender (bridge.posespace.confidence, thesis 9.1–9.2)."""
import os

from blender_support import bpy, import_file
from shapespace.bridge import posespace
from support import ASSETS


# --------------------------------------------------------------------------- pose-space confidence
def test_pose_space_confidence_is_zero_at_examples_and_grows_between(registered):
    import_file(os.path.join(ASSETS, "cesium_man", "CesiumMan.glb"))
    ob = next(o for o in bpy.data.objects if o.type == "MESH")
    arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    bpy.context.view_layer.objects.active = ob
    bone = next(b for b in arm.pose.bones if "arm" in b.name.lower() or "elbow" in b.name.lower())
    bone.rotation_mode = "XYZ"
    for angle in (1.2, 0.0):
        bone.rotation_euler = (angle, 0.0, 0.0)
        bpy.context.view_layer.update()
        assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
    bone.rotation_euler = (0.0, 0.0, 0.0)
    bpy.context.view_layer.update()
    assert bpy.ops.shapespace.psd_confidence(heat_map=True) == {"FINISHED"}
    at_example = ob.shapespace_face.confidence
    bone.rotation_euler = (0.6, 0.0, 0.0)
    bpy.context.view_layer.update()
    assert bpy.ops.shapespace.psd_confidence(heat_map=True) == {"FINISHED"}
    between = ob.shapespace_face.confidence
    assert at_example < 1e-6 < between < 1.0
    attr = ob.data.color_attributes[posespace.CONFIDENCE_ATTRIBUTE]
    assert len(attr.data) == len(ob.data.vertices)
