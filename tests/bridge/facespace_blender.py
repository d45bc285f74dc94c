"""Rigs, damage and operator runs shared by the Blender tests of bridge.facespace."""
import os

import numpy as np

from blender_support import bpy, classify_operator_call, draw_panel, import_file, sphere_rig
from shapespace.bridge import actions, shapekeys
from support import ASSETS

FACECAP = os.path.join(ASSETS, "facecap", "facecap_decoded.glb")


def facecap(with_animation=True):
    import_file(FACECAP)
    ob = bpy.data.objects["Mesh_2"]
    bpy.context.view_layer.objects.active = ob
    if not with_animation:
        ob.data.shape_keys.animation_data.action = None
    return ob


def set_sliders(ob, names, w):
    shapekeys.write_slider_values(ob, names, w)


def facecap_action(ob):
    return next(a for a in bpy.data.actions if actions.shape_key_curves(ob, a))


def face_sphere(keys=3, lo=0.0, hi=1.0, animated=True, name="Face"):
    ob = sphere_rig(keys, name)
    for k in range(keys):
        kb = ob.data.shape_keys.key_blocks[f"K{k}"]
        kb.slider_min, kb.slider_max = lo, hi
    if animated:
        for f in range(1, 31):
            for k, kb in enumerate(ob.data.shape_keys.key_blocks[1:]):
                kb.value = 0.5 + 0.45 * np.sin(0.3 * f + k)
                kb.keyframe_insert("value", frame=f)
        bpy.context.scene.frame_set(1)         # slider values = the animation's (what any update shows)
    bpy.context.view_layer.objects.active = ob
    ob.select_set(True)
    return ob


def run_on_face(op_name, **kwargs):
    """Run an operator; returns (outcome, message) by the reliability suites' rule (no traceback, file kept)."""
    bpy.context.view_layer.objects.active = bpy.data.objects["Face"]
    return classify_operator_call(op_name, kwargs)


def key_curve(ob, name):
    return actions.shape_key_curves(ob)[name]


def damage_keyframe(ob, name="K1", frame=10, value=float("nan")):
    fc = key_curve(ob, name)
    kp = next(kp for kp in fc.keyframe_points if round(kp.co[0]) == frame)
    kp.co = (kp.co[0], value)
    fc.update()
    bpy.context.scene.frame_set(1)


# --------------------------------------------------------------------------- damaged face-space metadata
def draw_face_panel():
    from shapespace.panels.facespace import SHAPESPACE_PT_face_space
    return draw_panel(SHAPESPACE_PT_face_space, strict=False).labels
