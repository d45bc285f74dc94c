"""Core blendshape evaluation equals Blender's evaluated mesh on every shared face asset."""
import numpy as np
import pytest

from blender_support import bpy, evaluated, import_file, rel_error
from shapespace.bridge import shapekeys
from shapespace.core.blendshape import diagnose_model
from support import shared

TOL = 1e-5  # of the bounding-box diagonal (issue #2)


def _face_objects():
    return [ob for ob in bpy.data.objects if ob.type == "MESH" and ob.data.shape_keys]


def _check_random_settings(obj, rng, trials=4):
    model = shapekeys.read_blendshape_model(obj)
    worst = 0.0
    for _ in range(trials):
        w = rng.uniform(-0.3, 1.3, model.n_targets)  # includes out-of-range values Blender clamps
        shapekeys.write_slider_values(obj, model.names, w)
        ours = model.evaluate(w)
        worst = max(worst, rel_error(ours, evaluated(obj)))
    return model, worst


@pytest.mark.parametrize("asset", [
    ("facecap", "facecap_decoded.glb"),
    ("ict_facekit", "ict_facekit_expressions.glb"),
    ("robot_expressive", "RobotExpressive.glb"),
    ("rpm_brunette", "brunette-t.glb"),
])
def test_gltf_faces_match_blender(asset):
    import_file(shared(*asset))
    rng = np.random.default_rng(1)
    faces = _face_objects()
    assert faces
    for ob in faces:
        # Evaluate the mesh alone: modifiers (armature) are not part of the blendshape model.
        for m in ob.modifiers:
            m.show_viewport = False
        model, err = _check_random_settings(ob, rng)
        assert err < TOL, f"{ob.name}: {err:.3g}"
        assert model.n_vertices == len(ob.data.vertices)


def test_fbhead_blend_matches_blender():
    import_file(shared("llf_fbhead", "Live_Link_Face.blend"))
    ob = bpy.data.objects["FBHead"]
    model, err = _check_random_settings(ob, np.random.default_rng(2))
    assert model.n_targets == 51
    assert err < TOL


def test_facecap_reads_expected_rig():
    import_file(shared("facecap", "facecap_decoded.glb"))
    ob = bpy.data.objects["Mesh_2"]
    model = shapekeys.read_blendshape_model(ob)
    assert (model.n_vertices, model.n_targets) == (2694, 52)
    diag = diagnose_model(model)
    empty = [i for i in diag.issues if i.code == "empty_target"]
    assert empty and empty[0].items == ("tongueOut",)
    assert diag.diagnostics["rank"] == 51  # tongueOut is empty: rank-deficient
    # facecap's local units are int16-range; the delta matrix is in those units
    assert model.scale > 1e4


def _cube_with_keys(n_keys=4):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8)
    ob = bpy.context.active_object
    ob.shape_key_add(name="Basis")
    rng = np.random.default_rng(5)
    base = np.empty(len(ob.data.vertices) * 3, np.float32)
    ob.data.vertices.foreach_get("co", base)
    for k in range(n_keys):
        kb = ob.shape_key_add(name=f"K{k}")
        kb.data.foreach_set("co", (base + rng.normal(0, 0.1, base.size)).astype(np.float32))
    return ob


def test_masks_mute_ranges_and_nonbasis_relatives_match_blender():
    ob = _cube_with_keys(4)
    blocks = ob.data.shape_keys.key_blocks
    group = ob.vertex_groups.new(name="mask")
    for i in range(0, len(ob.data.vertices), 3):
        group.add([i], (i % 7) / 7.0, "REPLACE")
    blocks["K0"].vertex_group = "mask"
    blocks["K1"].mute = True
    blocks["K2"].slider_min, blocks["K2"].slider_max = -1.0, 2.0
    blocks["K3"].relative_key = blocks["K2"]
    model = shapekeys.read_blendshape_model(ob)
    assert model.relative_to[3] == "K2"
    assert "K0" in model.masks
    codes = {i.code for i in diagnose_model(model).issues}
    assert "relative_to_non_basis" in codes
    rng = np.random.default_rng(3)
    for _ in range(5):
        w = rng.uniform(-1.5, 2.5, 4)
        shapekeys.write_slider_values(ob, model.names, w)
        assert rel_error(model.evaluate(w), evaluated(ob)) < TOL


def test_write_then_read_slider_values_roundtrip():
    ob = _cube_with_keys(3)
    names = ["K0", "K1", "K2"]
    shapekeys.write_slider_values(ob, names, [0.25, 0.5, 1.5])
    got = shapekeys.read_slider_values(ob, names)
    np.testing.assert_allclose(got, [0.25, 0.5, 1.0], atol=1e-7)  # Blender clamps to slider_max
