"""The rigs in the open file as a :class:`core.inventory.FileInventory` (for ``shapespace info``)."""
from __future__ import annotations

import bpy

from ..core.blendshape import diagnose_model
from ..core.inventory import (
    ActionInfo,
    ArmatureInfo,
    ArmatureModifierInfo,
    FileInventory,
    IssueInfo,
    SceneInfo,
    ShapeKeyMeshInfo,
    SkinnedMeshInfo,
)
from ..core.names import ARKIT_52, canonical_name
from ..core.skinning import diagnose_weights
from ..core.version import version
from . import actions, shapekeys, skin, storage, symmetry
from .rig import stored as rig_stored


def bone_shape_objects() -> set:
    """Names of objects used only as custom bone shapes (e.g. the glTF importer's Icosphere)."""
    shapes = set()
    for ob in bpy.data.objects:
        if ob.type == "ARMATURE" and ob.pose:
            shapes.update(pb.custom_shape.name for pb in ob.pose.bones if pb.custom_shape)
    return shapes


def _issues(issues) -> list:
    return [IssueInfo.of(i) for i in issues]


def describe_shape_keys(obj) -> ShapeKeyMeshInfo:
    problems = shapekeys.check_shape_keys(obj)
    info = ShapeKeyMeshInfo(object=obj.name, vertices=len(obj.data.vertices))
    if any(i.severity == "error" for i in problems):
        info.issues = _issues(problems)
        return info
    model = shapekeys.read_blendshape_model(obj, finite=False)
    diag = diagnose_model(model)
    canon = {canonical_name(n) for n in model.names}
    action = actions.active_action(obj.data.shape_keys)
    info.shape_keys = model.n_targets
    info.reference_key = model.reference_name
    info.names = model.names
    info.rank = diag.diagnostics.get("rank")
    info.arkit_channels = len(canon & set(ARKIT_52))
    info.bbox_diagonal_local = model.scale
    info.animated_by = action.name if action else None
    info.issues = _issues(problems + diag.issues)
    return info


def describe_skin(obj) -> SkinnedMeshInfo:
    problems = skin.check_skinning(obj)
    mods = [ArmatureModifierInfo(m.name, m.object.name, bool(m.use_deform_preserve_volume))
            for m in skin.armature_modifiers(obj)]
    if not any(i.severity == "error" for i in problems):
        rig = skin.read_skinning(obj)
        for d in rig.deformers:
            problems += diagnose_weights(d.weights).issues
    return SkinnedMeshInfo(obj.name, len(obj.data.vertices), mods, _issues(problems))


def describe_action(action) -> ActionInfo:
    first, last = actions.frame_range(action)
    curves = actions.action_fcurves(action)
    paths = [fc.data_path for fc in curves]
    return ActionInfo(
        name=action.name, frame_range=[first, last], fcurves=len(curves),
        shape_key_curves=sum(p.startswith("key_blocks[") for p in paths),
        bone_curves=sum(p.startswith("pose.bones[") for p in paths),
        slots=actions.action_users(action),
        fractional_keys=any(any(abs(k.co[0] - round(k.co[0])) > 1e-4 for k in fc.keyframe_points) for fc in curves))


def _describe_armature(ob) -> ArmatureInfo:
    action = actions.active_action(ob)
    return ArmatureInfo(ob.name, len(ob.data.bones), sum(b.use_deform for b in ob.data.bones),
                        action.name if action else None)


def describe_file() -> FileInventory:
    """Rigs, armatures and actions in ``bpy.data`` plus scene timing."""
    scene = bpy.context.scene
    shapes = bone_shape_objects()
    meshes = [ob for ob in bpy.data.objects if ob.type == "MESH" and ob.name not in shapes]
    return FileInventory(
        file=bpy.data.filepath or None,
        blender=bpy.app.version_string,
        shapespace=version(),
        scene=SceneInfo(scene.name, scene.render.fps / scene.render.fps_base, scene.frame_start, scene.frame_end),
        shape_key_meshes=[describe_shape_keys(ob) for ob in meshes if ob.data.shape_keys],
        skinned_meshes=[describe_skin(ob) for ob in meshes if skin.armature_modifiers(ob)],
        armatures=[_describe_armature(ob) for ob in bpy.data.objects if ob.type == "ARMATURE"],
        actions=[describe_action(a) for a in bpy.data.actions],
    )


def check_object(obj) -> list:
    """All findings for one object: shape-key model and skin, most severe first.

    Returns an empty list for a healthy rig.  Never changes the object.
    """
    if obj is None:
        return shapekeys.check_shape_keys(None)
    if obj.type != "MESH":
        return shapekeys.check_shape_keys(obj)
    found = []
    has_keys = obj.data.shape_keys is not None
    has_skin = bool(skin.armature_modifiers(obj))
    found += storage.damaged_blobs(obj)
    found += symmetry.table_damage(obj)
    found += rig_stored.damage(obj)
    if has_keys or not has_skin:
        structural = shapekeys.check_shape_keys(obj)
        found += structural
        if not any(i.severity == "error" for i in structural):
            found += diagnose_model(shapekeys.read_blendshape_model(obj, finite=False)).issues
    if has_skin:
        problems = skin.check_skinning(obj)
        found += problems
        if not any(i.severity == "error" for i in problems):
            for d in skin.read_skinning(obj).deformers:
                found += diagnose_weights(d.weights).issues
    order = {"error": 0, "warning": 1, "info": 2}
    return sorted(found, key=lambda i: order.get(i.severity, 3))
