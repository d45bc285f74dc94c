"""Export for engines, proved by re-import: export → Blender's own importer → evaluated vertex positions equal
the source's within 1e-5 of the bounding-box diagonal at sampled frames (glTF, FBX, Alembic), on a retargeted
Live Link Face take (FBHead), an in-between + combination rig (Face Cap), CesiumMan with Shape-by-Example
correctives, and weighted PSD (Alembic exact; glTF/FBX through one morph target per frame)."""
import numpy as np
import pytest

import bench_export  # tools/bench_export.py
from blender_support import blend_fingerprint, bpy
from shapespace.bridge.export import export
from shapespace.bridge.export import roundtrip as rt
from shapespace.core.blendshape import bounding_box_diagonal
from shapespace.core.export import sample_frames

TOL = 1e-5
EXT = bench_export.EXT
#: glTF exports: on bpy < 5.0 the test process must end through os._exit (see tests/bridge/conftest.py).
gltf_exits = pytest.mark.gltf_export
FORMATS = [pytest.param("gltf", marks=gltf_exits), "fbx", "abc"]


def id_counts():
    return {k: len(getattr(bpy.data, k)) for k in ("objects", "meshes", "shape_keys", "armatures", "actions",
                                                    "scenes", "materials", "images", "collections")}


# The scenarios are shared with the benchmark (tools/bench_export.py).
RIGS = bench_export.RIGS
retargeted_fbhead = bench_export.retargeted_fbhead


# -- the round trip ----------------------------------------------------------------------------------------------

def roundtrip(case, fmt, tmp_path, frames=6):
    """Build ``case``, export it as ``fmt`` and re-import; returns (max error per mesh, report, source frames)."""
    names, frame_range = RIGS[case]()
    bpy.ops.object.select_all(action="DESELECT")
    for n in names:
        bpy.data.objects[n].select_set(True)
    before, counts = blend_fingerprint(), id_counts()
    scene_state = (bpy.context.scene.frame_current, bpy.context.scene.frame_start, bpy.context.scene.frame_end)
    path = str(tmp_path / f"{case}{EXT[fmt]}")
    rep = export(fmt, path, frame_range=frame_range)
    # the user's file is exactly as before: data, datablocks, scene frame and range
    assert blend_fingerprint() == before and id_counts() == counts
    assert (bpy.context.scene.frame_current, bpy.context.scene.frame_start, bpy.context.scene.frame_end) == \
        scene_state
    sampled = sample_frames(rep.frame_start, rep.frame_end, frames)
    source = rt.sample_positions(names, sampled)
    for n in names:          # the take really moves the mesh (otherwise the test proves nothing)
        motion = np.abs(source[n] - source[n][:1]).max() / bounding_box_diagonal(source[n][0])
        assert motion > 1e-3, (case, n, motion)
    render = bpy.context.scene.render
    imported = rt.reimport(fmt, path, render.fps, render.fps_base)
    got = rt.imported_positions(names, imported, sampled)
    errors = {n: float(e.max()) for n, e in rt.compare(source, got).items()}
    return errors, rep, path


@pytest.mark.parametrize("fmt", FORMATS)
def test_retargeted_live_link_take(registered, tmp_path, fmt):
    errors, rep, _ = roundtrip("retarget", fmt, tmp_path)
    # the scene range is 20–160 but the retargeted action runs 20–183: the export takes the action's range
    assert (rep.frame_start, rep.frame_end) == (20, 183)
    assert errors["FBHead"] < TOL, errors


@pytest.mark.parametrize("fmt", FORMATS)
def test_inbetween_and_combination_drivers(registered, tmp_path, fmt):
    errors, rep, _ = roundtrip("inbetween", fmt, tmp_path)
    assert sorted(rep.baked[0].driven) == ["jawOpen@0.5", "mouthSmile_L+eyeBlink_L"]
    assert errors["Mesh_2"] < TOL, errors


@pytest.mark.parametrize("fmt", FORMATS)
def test_shape_by_example_correctives_with_weights_outside_unit_range(registered, tmp_path, fmt):
    errors, rep, path = roundtrip("psd", fmt, tmp_path, frames=9)
    baked = rep.baked[0]
    assert baked.posespace == "sbe" and baked.split          # extrapolated weights left [0, 1]: split
    assert errors["Cesium_Man"] < TOL, errors
    if fmt == "gltf":
        doc, weights = rt.glb_animations(path)
        assert len(doc["animations"]) == 1                     # skeleton and correctives in one clip
        paths = {c["target"]["path"] for c in doc["animations"][0]["channels"]}
        assert "weights" in paths and paths & {"rotation", "translation"}
        assert weights.min() >= 0.0 and weights.max() <= 1.0   # nothing for an importer to clamp


@gltf_exits
def test_clamping_importer_still_gets_the_correctives(registered, tmp_path):
    """An importer that clamps morph weights to [0, 1] (Unity by default) changes nothing after the split."""
    errors, rep, _ = roundtrip("psd", "gltf", tmp_path, frames=9)
    names = ["Cesium_Man"]
    sampled = sample_frames(rep.frame_start, rep.frame_end, 9)
    before = rt.imported_positions(names, [o.name for o in bpy.data.objects if o.type == "MESH"], sampled)
    for key in bpy.data.shape_keys:
        for kb in key.key_blocks:
            kb.slider_min, kb.slider_max = 0.0, 1.0
    after = rt.imported_positions(names, [o.name for o in bpy.data.objects if o.type == "MESH"], sampled)
    assert np.abs(after["Cesium_Man"] - before["Cesium_Man"]).max() == 0.0


@pytest.mark.parametrize("fmt", ["abc", pytest.param("gltf", marks=gltf_exits)])
def test_weighted_psd(registered, tmp_path, fmt):
    errors, rep, _ = roundtrip("wpsd", fmt, tmp_path)
    baked = rep.baked[0]
    if fmt == "abc":
        assert baked.point_cache and not baked.per_frame_keys
    else:
        assert baked.per_frame_keys == rep.frames               # one morph target per baked frame
    assert errors["Cesium_Man"] < TOL, errors


def test_blenders_fbx_defaults_drop_shape_key_only_animation(registered, tmp_path):
    """Why the export sets the FBX exporter up as it does: with its defaults the retargeted face has no
    animation at all after a round trip."""
    retargeted_fbhead()
    ob = bpy.data.objects["FBHead"]
    bpy.ops.object.select_all(action="DESELECT")
    ob.select_set(True)
    path = str(tmp_path / "defaults.fbx")
    bpy.ops.export_scene.fbx(filepath=path, use_selection=True)
    rt.reimport("fbx", path, 30)
    imported = next(o for o in bpy.data.objects if o.type == "MESH")
    assert imported.data.shape_keys.animation_data is None or imported.data.shape_keys.animation_data.action is None

