"""Export for engines: bake into a temporary copy, call Blender's own exporter, leave the user's file as it was.

What each exporter needs (read from Blender's io_scene_fbx / io_scene_gltf2 and proved by re-import in
tests/bridge/test_export_roundtrip.py):

- **FBX.**  With its defaults (*All Actions* and *NLA Strips* on) the exporter writes one animation stack per
  action of each *object* that has animation data of its own, and samples shape keys only inside those
  stacks — so a face animated only through its shape keys gets no animation at all.  The *global* stack
  (both options off) samples every shape key over the scene range: the export switches both off, sets the
  range to the baked actions' and keeps every sample (simplify 0).  Blender's FBX importer adds one frame
  (``anim_offset``) on the way back in; the round trip imports with 0.
- **glTF.**  Drivers are not exported (in-betweens and combinations would arrive static), so every key's
  effective weight is keyed.  The *Scene* animation mode (not split by object) samples the scene as Blender
  evaluates it into one clip — skeleton (NLA, constraints included) and morph weights together; the default
  (*Actions*) writes the correctives as a clip separate from the skeleton's, and *Active actions merged*
  also picks up muted NLA strips on Blender 4.2.  Morph target weights an importer clamps to [0, 1] are
  split/rescaled first.
- **Alembic.**  Writes the evaluated mesh per frame: shape keys, drivers and skinning arrive exact; weighted
  PSD comes from a point cache in the copy's stack.
"""
from __future__ import annotations

import os
import shutil
import tempfile
import time

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.export.formats import check_format, check_output_path
from ...core.export.frames import export_range
from ...core.export.report import BakedObject, ExportReport
from ...core.result import ShapeSpaceError, Status
from .. import actions
from .collect import animating_actions, resolve_objects, with_dependencies
from .copy import ExportScene
from .sample import check_pose_space, paused_live_preview, sample_meshes


def export(fmt: str, path: str, names=None, frame_range=None, scene=None, whole_scene: bool = False) -> ExportReport:
    """Bake what only ShapeSpace or drivers know into plain data and write ``path`` with Blender's exporter.

    Parameters
    ----------
    fmt : str
        ``gltf``, ``fbx`` or ``abc``.
    path : str
        Output file (``.glb``/``.gltf``, ``.fbx``, ``.abc``).  Written only when everything succeeded (an
        existing file is replaced then, never before).
    names : list of str, optional
        Objects to export; default: the selection (``whole_scene``: every mesh and armature of the scene when
        nothing is selected).  Armatures and parents of exported objects are added.
    frame_range : (int, int), optional
        Default: the full range of the actions that animate the exported objects.
    scene : bpy.types.Scene, optional
        Default: the context scene.

    Every check runs before anything is baked; the user's file is left exactly as it was (the bake runs
    on copies in a temporary scene that is removed afterwards).
    """
    t0 = time.perf_counter()
    scene = scene or bpy.context.scene
    export_format = check_format(fmt)
    path = check_output_path(path, export_format, inputs=(bpy.data.filepath,))
    chosen, notes = resolve_objects(names, scene_if_none_selected=whole_scene)
    objects = with_dependencies(chosen)
    meshes = [ob for ob in objects if ob.type == "MESH"]
    check_pose_space(meshes)
    acts = animating_actions(objects)
    animated = bool(acts) or frame_range is not None
    if animated:
        start, end = export_range([actions.frame_range(a) for a in acts], (scene.frame_start, scene.frame_end),
                                  frame_range)
    else:
        start = end = scene.frame_current
        notes.append(f"nothing is animated: exported as a still at frame {start}")
    frames = np.arange(start, end + 1)
    report = ExportReport(format=export_format.name, path=path, objects=[ob.name for ob in objects],
                          frame_start=int(start), frame_end=int(end), animated=animated, notes=notes)
    with paused_live_preview(meshes):
        samples = sample_meshes(meshes, scene, frames)
        with ExportScene(scene, objects, start, end) as tmp:
            for name, smp in samples.items():
                report.notes += smp.notes
                report.baked.append(_bake_mesh(tmp, name, smp, frames, animated, export_format))
            _write(export_format.name, tmp, path, start, end, animated)
    report.seconds = time.perf_counter() - t0
    report.status = Status.WARNING if report.notes else Status.OK      # a note: something was left out or changed
    return report


def _bake_mesh(tmp: ExportScene, name: str, smp, frames, animated: bool, export_format) -> BakedObject:
    baked = BakedObject(object=name, driven=list(smp.driven), posespace=smp.posespace)
    if smp.positions is not None and export_format.per_vertex_correctives == "exact":
        baked.point_cache = bool(tmp.bake_point_cache(name, smp.positions, frames))
        baked.split = tmp.bake_keys(name, smp, frames, animated)
    elif smp.positions is not None:
        baked.per_frame_keys = tmp.bake_per_frame(name, smp.positions, frames, animated)
    else:
        baked.split = tmp.bake_keys(name, smp, frames, animated)
    key = tmp.copies[name].data.shape_keys
    baked.shape_keys = len(key.key_blocks) - 1 if key is not None else 0
    return baked


def _write(fmt: str, tmp: ExportScene, path: str, start: int, end: int, animated: bool) -> None:
    """Run the exporter into a private folder next to ``path``, then move its files into place."""
    folder = os.path.dirname(path)
    stage = tempfile.mkdtemp(prefix=".shapespace-export-", dir=folder)
    try:
        staged = os.path.join(stage, os.path.basename(path))
        with bpy.context.temp_override(**tmp.override()):
            tmp.scene.frame_set(start)
            _EXPORTERS[fmt](staged, start, end, animated)
        if not os.path.isfile(staged):
            raise ShapeSpaceError(f"Blender's {fmt} exporter wrote nothing to {path}", ErrorCode.UNWRITABLE)
        for name in os.listdir(stage):
            os.replace(os.path.join(stage, name), os.path.join(folder, name))
    except RuntimeError as exc:
        raise ShapeSpaceError(f"Blender's {fmt} exporter failed: {_first_line(exc)}", ErrorCode.UNWRITABLE) from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _gltf(path: str, start: int, end: int, animated: bool) -> None:
    bpy.ops.export_scene.gltf(
        filepath=path, export_format="GLB" if path.lower().endswith(".glb") else "GLTF_SEPARATE",
        use_selection=False, use_active_scene=True, export_apply=False,
        export_animations=animated, export_animation_mode="SCENE", export_anim_scene_split_object=False,
        export_nla_strips_merged_animation_name=os.path.splitext(os.path.basename(path))[0], export_frame_range=True,
        export_force_sampling=True, export_frame_step=1, export_morph=True, export_morph_animation=animated,
        export_skins=True, export_def_bones=False, export_anim_slide_to_zero=False, export_current_frame=False)


def _fbx(path: str, start: int, end: int, animated: bool) -> None:
    bpy.ops.export_scene.fbx(
        filepath=path, use_selection=False, use_visible=False, use_active_collection=False,
        object_types={"MESH", "ARMATURE", "EMPTY"}, use_mesh_modifiers=True, add_leaf_bones=False,
        bake_anim=animated, bake_anim_use_all_bones=True, bake_anim_use_nla_strips=False,
        bake_anim_use_all_actions=False, bake_anim_force_startend_keying=True, bake_anim_step=1.0,
        bake_anim_simplify_factor=0.0)


def _abc(path: str, start: int, end: int, animated: bool) -> None:
    bpy.ops.wm.alembic_export(filepath=path, start=start, end=end, selected=False,
                              flatten=False, evaluation_mode="VIEWPORT", export_hair=False,
                              export_particles=False, as_background_job=False, uvs=True, normals=True)


_EXPORTERS = {"gltf": _gltf, "fbx": _fbx, "abc": _abc}


def _first_line(exc) -> str:
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return (lines[-1] if lines else type(exc).__name__).replace("Error: ", "")
