"""Armature modifiers ↔ :class:`core.skinning.SkinningRig`."""
from __future__ import annotations

import numpy as np

from ..core.result import Issue, ShapeSpaceError
from ..core.skinning import ArmatureDeform, SkinningRig, SkinWeights
from .arrays import read_matrices
from .meshes import group_weight_vector, vertex_groups, world_matrix


def armature_modifiers(obj) -> list:
    """The object's enabled Armature modifiers with a target, in stack order."""
    return [m for m in obj.modifiers
            if m.type == "ARMATURE" and m.object is not None and m.object.type == "ARMATURE"
            and m.show_viewport]


def check_skinning(obj) -> list:
    """Problems that make our evaluation differ from Blender's, or that the rigger should know."""
    issues = []
    if obj is None or obj.type != "MESH":
        return [Issue("error", "not_mesh", "select a skinned mesh")]
    mods = armature_modifiers(obj)
    if not mods:
        return [Issue("error", "no_armature", f"mesh {obj.name!r} has no Armature modifier with an armature")]
    if obj.parent is not None and obj.parent_type == "ARMATURE":
        issues.append(Issue("error", "armature_parent",
                            f"mesh {obj.name!r} uses an armature-deform parent; use an Armature modifier instead"))
    bone_names = set()
    for m in mods:
        arm = m.object.data
        bone_names.update(b.name for b in arm.bones)
        if m.use_bone_envelopes:
            issues.append(Issue("error", "envelopes",
                                f"modifier {m.name!r} deforms with bone envelopes, which ShapeSpace does not model"))
        if not m.use_vertex_groups:
            issues.append(Issue("error", "no_vertex_groups",
                                f"modifier {m.name!r} does not use vertex groups"))
        if m.use_multi_modifier:
            issues.append(Issue("error", "multi_modifier",
                                f"modifier {m.name!r} uses Multi Modifier, which ShapeSpace does not model"))
        bb = [b.name for b in arm.bones if b.use_deform and b.bbone_segments > 1]
        if bb:
            issues.append(Issue("warning", "bbones",
                                f"bones {', '.join(bb[:5])} are B-Bones: their curved deformation is "
                                f"approximated by the straight bone", tuple(bb)))
    mask_groups = {m.vertex_group for m in mods if m.vertex_group}
    orphan = [g.name for g in obj.vertex_groups if g.name not in bone_names and g.name not in mask_groups]
    if orphan:
        issues.append(Issue("warning", "orphan_groups",
                            f"vertex groups name no bone and are ignored by the armature: {', '.join(orphan[:8])}"
                            + (" …" if len(orphan) > 8 else ""), tuple(orphan)))
    return issues


def read_skinning(obj) -> SkinningRig:
    """Read every Armature modifier's weights, rest matrices and settings.

    Bone weights follow Blender's rules: a vertex group deforms when a bone of
    that name exists and has ``use_deform``; other groups are ignored.
    """
    errors = [i for i in check_skinning(obj) if i.severity == "error"]
    if errors:
        raise ShapeSpaceError(errors[0].message, errors[0].code)
    groups = vertex_groups(obj)
    gi, gw, gnames = groups
    deformers = []
    for m in armature_modifiers(obj):
        arm_ob = m.object
        bones = arm_ob.data.bones
        bone_names = [b.name for b in bones]
        lookup = {b.name: i for i, b in enumerate(bones) if b.use_deform}
        group_to_bone = np.array([lookup.get(n, -1) for n in gnames] + [-1], dtype=np.int64)
        bone_index = group_to_bone[gi]  # gi == -1 picks the trailing -1
        rest = read_matrices(bones, "matrix_local")
        mask = None
        if m.vertex_group:
            mask = group_weight_vector(obj, m.vertex_group, groups)
            if mask is not None and m.invert_vertex_group:
                mask = 1.0 - mask
        deformers.append(ArmatureDeform(
            weights=SkinWeights(bone_index, gw.astype(np.float64)),
            bone_names=bone_names, rest=rest, armature_world=world_matrix(arm_ob),
            preserve_volume=bool(m.use_deform_preserve_volume), vertex_mask=mask, name=m.name))
    return SkinningRig(mesh_world=world_matrix(obj), deformers=deformers)


def bone_parents(arm_obj) -> list:
    """Parent index of every bone in ``data.bones`` order (−1 for roots)."""
    bones = arm_obj.data.bones
    index = {b.name: i for i, b in enumerate(bones)}
    return [index[b.parent.name] if b.parent is not None else -1 for b in bones]


def pose_matrices(arm_obj) -> np.ndarray:
    """``PoseBone.matrix`` (armature space) of every bone in ``data.bones`` order, (b, 4, 4)."""
    pose = arm_obj.pose.bones
    order = [b.name for b in arm_obj.data.bones]
    mats = read_matrices(pose, "matrix")
    if [pb.name for pb in pose] != order:
        index = {pb.name: i for i, pb in enumerate(pose)}
        mats = mats[[index[n] for n in order]]
    return mats


def modifier_poses(obj) -> list:
    """Pose matrices for each Armature modifier of ``obj``, in stack order."""
    return [pose_matrices(m.object) for m in armature_modifiers(obj)]


def set_pose_basis(arm_obj, rotations=None, locations=None, scales=None) -> None:
    """Set pose-bone local channels (quaternions (b, 4), locations (b, 3), scales (b, 3))."""
    bones = arm_obj.pose.bones
    for pb in bones:
        pb.rotation_mode = "QUATERNION"
    if rotations is not None:
        bones.foreach_set("rotation_quaternion", np.ascontiguousarray(rotations, np.float32).ravel())
    if locations is not None:
        bones.foreach_set("location", np.ascontiguousarray(locations, np.float32).ravel())
    if scales is not None:
        bones.foreach_set("scale", np.ascontiguousarray(scales, np.float32).ravel())
    arm_obj.pose.bones[0].id_data.update_tag()

