"""Bake Point Cache paths that travel (#12 part 2): `//`-relative to the saved .blend by Blender's Relative
Paths preference, absolute when the file is unsaved (or the preference is off), and a moved project keeps
playing — checked through Blender's own depsgraph evaluation after reopening the moved file."""
import os
import shutil

import numpy as np
import pytest

from blender_support import bpy, evaluated, import_file
from shapespace.bridge import posespace
from shapespace.core.pointcache import read_pc2
from shapespace.ui import posespace_preview
from support import shared


def _rig():
    """RiggedSimple, last bone animated over frames 1–6, one example with a sculpted corrective."""
    posespace_preview.CACHE.clear()
    import_file(shared("rigged_simple", "RiggedSimple.glb"))
    ob = bpy.data.objects["Cylinder"]
    arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    if arm.animation_data:
        arm.animation_data.action = None
    pb = arm.pose.bones[-1]
    pb.rotation_mode = "QUATERNION"
    for f, q in ((1, (1, 0, 0, 0)), (6, (0.9, 0.3, 0.2, 0.1))):
        pb.rotation_quaternion = q
        pb.keyframe_insert("rotation_quaternion", frame=f)
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = ob
    ob.select_set(True)
    bpy.context.scene.frame_set(6)
    assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
    kb = ob.data.shape_keys.key_blocks[ob.shapespace_psd.examples[0].name]
    co = np.empty(len(kb.data) * 3, dtype=np.float32)
    kb.data.foreach_get("co", co)
    co = co.reshape(-1, 3)
    co[:, 2] += 0.05 * np.linspace(0, 1, len(co), dtype=np.float32)     # a corrective to see
    kb.data.foreach_set("co", co.ravel())
    ob.data.update()
    return ob


@pytest.fixture
def relative_pref():
    prefs = bpy.context.preferences.filepaths
    before = prefs.use_relative_paths
    yield prefs
    prefs.use_relative_paths = before


def _positions_per_frame(ob, frames):
    out = {}
    for f in frames:
        bpy.context.scene.frame_set(f)
        out[f] = evaluated(ob)
    return out


def test_a_moved_project_keeps_playing_its_cache(registered, tmp_path, relative_pref):
    relative_pref.use_relative_paths = True
    ob = _rig()
    project = tmp_path / "project"
    (project / "caches").mkdir(parents=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(project / "shot.blend"))
    ob = bpy.data.objects["Cylinder"]
    pc2 = str(project / "caches" / "cyl.pc2")
    assert bpy.ops.shapespace.psd_bake_cache(filepath=pc2, frame_start=1, frame_end=6) == {"FINISHED"}
    mod = ob.modifiers[posespace.MESH_CACHE_NAME]
    assert mod.filepath == "//caches/cyl.pc2"
    baked = read_pc2(pc2)[0]
    frames = (1, 3, 6)
    before = _positions_per_frame(ob, frames)
    bpy.ops.wm.save_as_mainfile(filepath=str(project / "shot.blend"))
    moved = tmp_path / "elsewhere" / "renamed_project"
    moved.parent.mkdir()
    shutil.move(str(project), str(moved))
    assert not os.path.exists(pc2)
    bpy.ops.wm.open_mainfile(filepath=str(moved / "shot.blend"))
    ob = bpy.data.objects["Cylinder"]
    mod = ob.modifiers[posespace.MESH_CACHE_NAME]
    assert os.path.normpath(bpy.path.abspath(mod.filepath)) == str(moved / "caches" / "cyl.pc2")
    # the modifier plays the moved file: with the Armature modifier off, the evaluated mesh *is* the cache
    after = _positions_per_frame(ob, frames)
    for f in frames:
        assert np.abs(after[f] - before[f]).max() <= 1e-6 * np.ptp(before[f], axis=0).max(), f
    arm_mods = [m for m in ob.modifiers if m.type == "ARMATURE"]
    for m in arm_mods:
        m.show_viewport = False
    for f in frames:
        bpy.context.scene.frame_set(f)
        np.testing.assert_allclose(evaluated(ob), baked[f - 1], atol=1e-6)
    # and the mesh without the cache is different (the cache is what plays)
    mod.show_viewport = False
    bpy.context.scene.frame_set(6)
    assert np.abs(evaluated(ob) - baked[5]).max() > 1e-3


def test_unsaved_file_or_preference_off_stores_an_absolute_path(registered, tmp_path, relative_pref):
    relative_pref.use_relative_paths = True
    ob = _rig()
    assert not bpy.data.filepath
    pc2 = str(tmp_path / "unsaved.pc2")
    assert bpy.ops.shapespace.psd_bake_cache(filepath=pc2, frame_start=1, frame_end=2) == {"FINISHED"}
    assert ob.modifiers[posespace.MESH_CACHE_NAME].filepath == pc2
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "saved.blend"))
    ob = bpy.data.objects["Cylinder"]
    relative_pref.use_relative_paths = False
    assert bpy.ops.shapespace.psd_bake_cache(filepath=pc2, frame_start=1, frame_end=2) == {"FINISHED"}
    assert ob.modifiers[posespace.MESH_CACHE_NAME].filepath == pc2
    relative_pref.use_relative_paths = True
    assert bpy.ops.shapespace.psd_bake_cache(filepath=pc2, frame_start=1, frame_end=3) == {"FINISHED"}
    assert ob.modifiers[posespace.MESH_CACHE_NAME].filepath == "//unsaved.pc2"
    assert read_pc2(pc2)[0].shape[0] == 3


def test_the_operator_offers_a_pc2_file_browser():
    from shapespace.operators.posespace.bake_cache import SHAPESPACE_OT_psd_bake_cache as op
    props = op.__annotations__
    assert props["filepath"].keywords["subtype"] == "FILE_PATH"
    assert props["filter_glob"].keywords["default"] == "*.pc2"
    assert op.filename_ext == ".pc2"
    assert "invoke" in op.__dict__ and "check" in op.__dict__
