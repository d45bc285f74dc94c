"""Keyframes on both action APIs, sampling at fractional frames, and transforms."""
import numpy as np

from blender_support import bpy, evaluated, import_file, rel_error
from shapespace.bridge import actions, meshes, shapekeys
from shapespace.core import names as ss_names
from support import shared


def _facecap():
    import_file(shared("facecap", "facecap_decoded.glb"))
    return bpy.data.objects["Mesh_2"]


def test_api_flavour_matches_blender_version():
    assert actions.LAYERED == (bpy.app.version >= (4, 4, 0))
    if bpy.app.version >= (5, 0, 0):
        assert "fcurves" not in bpy.types.Action.bl_rna.properties


def test_facecap_curves_sampled_at_fractional_frames_match_blender():
    ob = _facecap()
    curves = actions.shape_key_curves(ob)
    assert len(curves) == 52
    fc = curves["jawOpen"]
    kx, _, _ = actions.read_curve(fc)
    assert np.any(np.abs(kx - np.round(kx)) > 1e-3), "facecap keys sit on fractional frames"
    frames = np.linspace(kx[0] - 5, kx[-1] + 5, 97)  # includes both extrapolation ends
    for name in ("jawOpen", "eyeBlink_L", "mouthSmile_R"):
        ours = actions.sample_curve(curves[name], frames)
        ref = np.array([curves[name].evaluate(f) for f in frames])
        # Blender evaluates in float32: frame times near 270 are quantised to ~1.5e-5 frames,
        # which moves a weight with slope ~0.1/frame by ~1.5e-6.
        np.testing.assert_allclose(ours, ref, atol=1e-5)


def test_sampled_weights_drive_the_same_mesh_as_blender_at_subframes():
    ob = _facecap()
    model = shapekeys.read_blendshape_model(ob)
    scene = bpy.context.scene
    for frame, sub in ((37, 0.25), (120, 0.6), (200, 0.0)):
        scene.frame_set(frame, subframe=sub)
        w = actions.sample_shape_keys(ob, model.names, [frame + sub])[0]
        assert rel_error(model.evaluate(w), evaluated(ob)) < 1e-5


def test_write_curve_and_read_back_on_current_api():
    ob = _facecap()
    key = ob.data.shape_keys
    names = ["jawOpen", "eyeBlink_L"]
    frames = np.array([1.0, 2.5, 10.0, 11.0])
    values = np.array([[0.0, 0.1], [0.5, 0.2], [1.0, 0.9], [0.2, 0.0]])
    action = actions.key_shape_values(ob, names, frames, values, action_name="Retargeted")
    assert actions.active_action(key) == action
    if actions.LAYERED:
        assert key.animation_data.action_slot is not None
    curves = actions.shape_key_curves(ob)
    assert set(curves) == set(names)
    for j, n in enumerate(names):
        kx, ky, interp = actions.read_curve(curves[n])
        np.testing.assert_allclose(kx, frames, atol=1e-6)
        np.testing.assert_allclose(ky, values[:, j], atol=1e-6)
        assert set(interp) == {"LINEAR"}
    # Blender's own evaluation of what we wrote, at a fractional frame
    bpy.context.scene.frame_set(2, subframe=0.0)
    expected = 0.0 + (0.5 - 0.0) * (2.0 - 1.0) / 1.5
    assert abs(key.key_blocks["jawOpen"].value - expected) < 1e-6


def test_insert_key_keeps_other_keys_and_bone_channels():
    import_file(shared("cesium_man", "CesiumMan.glb"))
    arm = bpy.data.objects["Armature"]
    bone = arm.pose.bones[2].name
    path = actions.bone_path(bone, "rotation_quaternion")
    before = len(actions.fcurves(actions.active_action(arm), arm))
    actions.insert_key(arm, path, 500.0, 0.25, index=1)
    fcs = [fc for fc in actions.fcurves(actions.active_action(arm), arm) if fc.data_path == path]
    assert len(fcs) == 4  # w, x, y, z of that bone
    fc = next(fc for fc in fcs if fc.array_index == 1)
    kx, ky, _ = actions.read_curve(fc)
    assert kx[-1] == 500.0 and abs(ky[-1] - 0.25) < 1e-7 and kx.size > 1
    assert len(actions.fcurves(actions.active_action(arm), arm)) == before


def test_key_sliders_operator_keys_every_slider(registered):
    import_file(shared("llf_fbhead", "Live_Link_Face.blend"))
    ob = bpy.data.objects["FBHead"]
    bpy.context.view_layer.objects.active = ob
    names = shapekeys.slider_names(ob)
    rng = np.random.default_rng(0)
    vals = rng.uniform(0, 1, len(names))
    shapekeys.write_slider_values(ob, names, vals)
    bpy.context.scene.frame_set(42)
    assert bpy.ops.shapespace.key_sliders() == {"FINISHED"}
    curves = actions.shape_key_curves(ob)
    assert len(curves) == len(names) == 51
    for n, v in zip(names, vals):
        assert abs(curves[n].evaluate(42.0) - v) < 1e-6


def test_world_local_roundtrip_under_scaled_parents_matches_blender_apply():
    """facecap's head: int16-range local units under a ~2e-4 parent scale."""
    ob = _facecap()
    local = meshes.vertex_positions(ob.data).astype(np.float64)
    assert np.abs(local).max() > 1000
    world = meshes.to_world(ob, local)
    np.testing.assert_allclose(meshes.to_local(ob, world), local, rtol=0, atol=1e-6 * np.abs(local).max())
    # Independent: let Blender bake the parent chain into the vertices.
    dup = ob.copy()
    dup.data = ob.data.copy()
    dup.shape_key_clear()
    bpy.context.scene.collection.objects.link(dup)
    bpy.ops.object.select_all(action="DESELECT")
    dup.select_set(True)
    bpy.context.view_layer.objects.active = dup
    bpy.ops.object.parent_clear(type="CLEAR_KEEP_TRANSFORM")
    bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
    baked = meshes.vertex_positions(dup.data).astype(np.float64)
    assert rel_error(world, baked) < 1e-5


def test_arkit_names_match_across_shared_conventions():
    import_file(shared("llf_fbhead", "Live_Link_Face.blend"))
    llf = shapekeys.slider_names(bpy.data.objects["FBHead"])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    fc_names = shapekeys.slider_names(_facecap())
    mapping, unmatched_src, unmatched_tgt = ss_names.match_channels(llf, fc_names)
    assert len(mapping) == 51 and not unmatched_src
    assert mapping["EyeBlinkLeft"] == "eyeBlink_L" and mapping["JawOpen"] == "jawOpen"
    assert unmatched_tgt == ["tongueOut"]
