"""Update Correctives and the live preview at 30 fps (#16 Build 4/5): the trained model is cached with a
fingerprint of its inputs (a corrective edited directly, a method or distance-option change retrain), weighted
PSD's float32 evaluation equals the float64 model through Blender's evaluation, and the blended distance is
stored per object (old files: the skin-weighted distance)."""
import importlib

import numpy as np
import pytest

from blender_support import blend_fingerprint, bpy, evaluated, import_file
from shapespace.bridge import posespace, skin
from shapespace.core.blendshape import bounding_box_diagonal
from shapespace.core.posespace.pairs import bone_pairs
from shapespace.core.posespace.psd import skin_group_inputs, train_psd
from shapespace.ui import posespace_preview
from support import shared

preview_module = importlib.import_module("shapespace.bridge.posespace.preview")
QUATS = [(0.9, 0.3, 0.2, 0.1), (0.9, -0.3, 0.1, 0.2), (0.8, 0.1, -0.5, 0.3), (0.95, 0.0, 0.3, -0.1)]


def _rig():
    """CesiumMan with three posed bones, four examples with smooth correctives written into their keys."""
    posespace_preview.CACHE.clear()
    posespace.forget_models()
    import_file(shared("cesium_man", "CesiumMan.glb"))
    ob = bpy.data.objects["Cesium_Man"]
    arm = bpy.data.objects["Armature"]
    arm.animation_data.action = None
    bones = [arm.pose.bones[i] for i in (4, 5, 6)]
    for pb in arm.pose.bones:
        pb.rotation_mode = "QUATERNION"
    bpy.context.view_layer.objects.active = ob
    co = np.empty(3 * len(ob.data.vertices), dtype=np.float32)
    ob.data.vertices.foreach_get("co", co)
    rest = co.reshape(-1, 3)
    size = bounding_box_diagonal(rest)
    for k, q in enumerate(QUATS):
        for j, pb in enumerate(bones):
            pb.rotation_quaternion = q if j == k % 3 else (1, 0, 0, 0)
        bpy.context.view_layer.update()
        name = posespace.add_example(ob, make_sculpt_copy=False)
        kb = ob.data.shape_keys.key_blocks[name]
        disp = 0.01 * size * np.sin(rest * (3.0 + k) / size + k)
        kb.points.foreach_set("co", (rest + disp).astype(np.float32).ravel())
    ob.data.update()
    for pb in bones:
        pb.rotation_quaternion = (0.92, 0.2, 0.25, 0.1)
    bpy.context.view_layer.update()
    return ob, arm, rest.astype(np.float64), size


def _reference(ob, blend=None):
    """The float64 weighted-PSD model trained in the core from the mesh's own data (bone parents and rest
    matrices read here from the armature's bones)."""
    st = ob.shapespace_psd
    rs = posespace.readers(ob)
    d = skin.read_skinning(ob).deformers[0]
    kw = skin_group_inputs(rs, d.bone_names, d.weights.bone_index, d.weights.weight)
    if blend in ("auto", "pairs"):
        bones = list(bpy.data.objects["Armature"].data.bones)
        parents = [bones.index(b.parent) if b.parent else -1 for b in bones]
        rest = np.array([np.array(b.matrix_local) for b in bones])
        kw["pairs"] = bone_pairs(rs, [b.name for b in bones], rest, parents, kw["vertex_groups"],
                                 kw["vertex_weights"])
    X = np.array([posespace.interpolation_pose(ex) for ex in st.examples])
    D = posespace.example_correctives(ob, list(st.examples))
    return train_psd(X, D, "wpsd", blend=blend, **kw)


def _corrected_rest(ob):
    """The mesh before the Armature modifier, as Blender evaluates it (modifiers after the keys off)."""
    mods = [m for m in ob.modifiers if m.type == "ARMATURE"]
    for m in mods:
        m.show_viewport = False
    try:
        return evaluated(ob)
    finally:
        for m in mods:
            m.show_viewport = True


@pytest.mark.parametrize("distance,blend", [("SKIN", None), ("BLEND", "auto"), ("PAIRS", "pairs")])
def test_update_equals_the_float64_model_through_blender(registered, distance, blend):
    ob, arm, rest, size = _rig()
    st = ob.shapespace_psd
    st.method = "WPSD"
    st.wpsd_distance = distance
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    ref = _reference(ob, blend)
    want = rest + ref.evaluate(posespace.read_pose(ob))
    got = _corrected_rest(ob)
    assert np.abs(got - want).max() <= 1e-6 * size
    deformer = posespace.cached_model(ob)[0]
    if blend is None:
        assert deformer.blend is None and deformer.pairs is None
    elif blend == "auto":                    # leave-one-out left the skin-weighted distance somewhere
        assert deformer.blend is not None or deformer.pairs is not None
    else:
        assert deformer.pairs.n_pairs >= 2 and np.all(deformer.pair_share == 1.0)


def test_bone_pairs_without_a_shared_pair_is_refused_by_name(registered):
    """Only one of the pose space's bones keeps skin weights: no vertex has two read bones, so Bone Pairs has
    nothing to measure; Update Correctives says so, returns CANCELLED and leaves the file as it was."""
    ob, arm, rest, size = _rig()
    read = [r.source for r in ob.shapespace_psd.readers if r.kind == "ROTATION"]
    assert len(read) >= 2
    for name in read[1:]:
        ob.vertex_groups.remove(ob.vertex_groups[name])
    st = ob.shapespace_psd
    st.method = "WPSD"
    st.wpsd_distance = "PAIRS"
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="Bone Pairs distance of 'Cesium_Man' has no pair"):
        bpy.ops.shapespace.psd_update()
    assert blend_fingerprint() == before
    st.wpsd_distance = "BLEND"                     # the automatic choice falls back to the other distances
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    assert posespace.cached_model(ob)[0].pairs is None


def test_a_corrective_edited_directly_is_seen_by_the_next_update(registered):
    ob, arm, rest, size = _rig()
    st = ob.shapespace_psd
    st.method = "WPSD"
    st.wpsd_distance = "SKIN"                                     # the reference below is skin-weighted
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    first = posespace.cached_model(ob)[0]
    assert posespace.cached_model(ob)[0] is first              # nothing changed: the same model
    kb = ob.data.shape_keys.key_blocks[st.examples[1].name]
    co = np.empty(3 * len(kb.points), dtype=np.float32)
    kb.points.foreach_get("co", co)
    co[::3] += 0.02 * size                                       # a sculpt on the key itself (no revision bump)
    kb.points.foreach_set("co", co)
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    assert posespace.cached_model(ob)[0] is not first
    want = rest + _reference(ob).evaluate(posespace.read_pose(ob))
    assert np.abs(_corrected_rest(ob) - want).max() <= 1e-6 * size


def test_method_and_distance_changes_retrain_update_and_live_preview(registered):
    ob, arm, rest, size = _rig()
    st = ob.shapespace_psd
    st.method = "WPSD"
    st.wpsd_distance = "SKIN"                                     # new pose spaces start Blended (0.2.0)
    st.live_preview = True
    bpy.context.view_layer.update()
    assert posespace_preview.refresh(ob) in (True, False)
    skin_model = posespace.cached_model(ob)[0]
    st.wpsd_distance = "BLEND"
    blend_model = posespace.cached_model(ob)[0]
    assert blend_model is not skin_model and blend_model.diagnostics.get("blend_regions") is not None
    arm.pose.bones[5].rotation_quaternion = (0.9, 0.1, 0.3, 0.2)
    bpy.context.view_layer.update()                               # the handler previews with the blended model
    want = rest + _reference(ob, "auto").evaluate(posespace.read_pose(ob))
    st.live_preview = False
    assert np.abs(_corrected_rest(ob) - want).max() <= 1e-6 * size
    st.method = "PSD"
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    assert posespace.cached_model(ob)[0].method == "psd"


def test_old_files_use_the_skin_weighted_distance(registered):
    bpy.ops.wm.open_mainfile(filepath=shared_fixture())
    with_examples = [o for o in bpy.data.objects if o.type == "MESH" and len(o.shapespace_psd.examples)]
    assert with_examples
    assert all(o.shapespace_psd.wpsd_distance == "SKIN" for o in with_examples)


def test_new_pose_spaces_default_to_the_blended_distance_and_keep_it(registered, tmp_path):
    """Issue #26 item 18: a pose space made now is Blended, stored explicitly from its first example on (a
    later change of the default cannot change it), through save and reopen; Update trains the blended model."""
    ob, arm, rest, size = _rig()
    st = ob.shapespace_psd
    assert st.wpsd_distance == "BLEND" and st.is_property_set("wpsd_distance")
    st.method = "WPSD"
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    want = rest + _reference(ob, "auto").evaluate(posespace.read_pose(ob))
    assert np.abs(_corrected_rest(ob) - want).max() <= 1e-6 * size
    path = str(tmp_path / "new.blend")
    assert bpy.ops.wm.save_as_mainfile(filepath=path) == {"FINISHED"}
    assert bpy.ops.wm.open_mainfile(filepath=path) == {"FINISHED"}
    st = bpy.data.objects["Cesium_Man"].shapespace_psd
    assert st.wpsd_distance == "BLEND" and st.is_property_set("wpsd_distance")


def shared_fixture():
    import os
    return os.path.join(os.path.dirname(os.path.dirname(__file__)), "data", "shapespace_0_1_0.blend")
