"""Analytic Jacobian columns of shape-key slider and bone channels (issue #25, first use of a rig).

A relative shape key moves each vertex by ``value × (key − relative key) × key vertex-group weight`` before any
modifier.  When every modifier after the shape keys is a linear-blend Armature modifier (vertex groups, no
envelopes, no Preserve Volume, no Multi Modifier, no B-Bone segments on a deforming bone) and nothing reads the
sliders back (no driver anywhere in the rig takes a shape-key value as input), the deformation after the
shape keys is, per vertex, the affine map ``x ↦ A_v x + t_v`` of the posed bones (:mod:`core.skinning`:
``A_v = I + m_v Σ_i w_i (L_i − I) / Σ_i w_i`` with ``L_i`` the linear part of bone ``i``'s change matrix in the
mesh's object space, ``m_v`` the modifier's vertex-group mask, ``I`` where the total weight is at most 1e-4;
stacked modifiers multiply).  A slider's column is then exactly ``W · A_v · δ_v`` (``W`` the linear part of the
mesh's world matrix, ``δ_v`` the key's object-space delta): no depsgraph evaluation per slider.

:func:`shape_key_columns` returns the columns' computer for an evaluator, or ``None`` with the reason when the
conditions do not hold (then every column is a finite difference); a muted slider, or one whose value a driver
sets, keeps a finite-difference column (what is written there does not act).

Bone channels (pose-bone rotation per axis in the bone's rotation mode, location, scale) get analytic columns
too, :func:`bone_columns`, when one linear-blend Armature modifier is the mesh's only modifier, no bone of the
armature has a constraint other than Limit Rotation / Location / Scale in local space, every child bone
inherits its parent's rotation and scale, the mesh is not parented to the armature and no driver reads or
drives the armature: a channel of bone ``k`` then moves its subtree's bones rigidly (``∂C_b/∂c = G C_b``,
:meth:`BoneColumns.__call__`), read off the evaluated pose matrices and the vertex-group weights — one
evaluation of the rig for the whole Jacobian instead of one per bone channel (Rigify's generated face, all
constraints and drivers, keeps finite differences).
"""
from __future__ import annotations

import dataclasses

import bpy
import numpy as np

from ...core.rig import ChannelKind, rotation_vector_from_quaternion
from ...core.skinning import SkinWeights, bone_change_matrices, normalised_weights
from ..meshes import world_matrix
from ..skin import armature_modifiers, check_skinning, pose_matrices, read_skinning

__all__ = ["BoneColumns", "ShapeKeyColumns", "analytic_refusal", "basis_velocity", "bone_columns", "key_coords",
           "key_delta", "shape_key_columns", "skin_refusal"]


def _skinning(mesh_obj, skinning):
    """``skinning`` (a :class:`core.skinning.SkinningRig` of ``mesh_obj`` read once and shared by the column
    computers, each of which copies its deformers before narrowing them to its vertices) or a fresh read."""
    return read_skinning(mesh_obj) if skinning is None else skinning


def _reads_shape_keys(ids, key) -> bool:
    """Whether a driver of any of ``ids`` takes an input from the shape-key datablock ``key``."""
    for idb in ids:
        ad = getattr(idb, "animation_data", None)
        for fc in (ad.drivers if ad is not None else ()):
            for var in fc.driver.variables:
                for t in var.targets:
                    if t.id is not None and (t.id == key or "shape_keys" in (t.data_path or "")):
                        return True
    return False


def analytic_refusal(mesh_obj, ids) -> str:
    """Why slider columns of ``mesh_obj`` cannot be analytic ('' when they can; module doc)."""
    key = mesh_obj.data.shape_keys
    if key is None or not key.use_relative:
        return "no relative shape keys"
    if mesh_obj.show_only_shape_key:
        return "the object shows only its active shape key"
    others = [m.name for m in mesh_obj.modifiers if m.show_viewport and m.type != "ARMATURE"]
    if others:
        return f"modifier {others[0]!r} deforms after the shape keys"
    mods = armature_modifiers(mesh_obj)
    if len(mods) != len([m for m in mesh_obj.modifiers if m.show_viewport]):
        return "an Armature modifier has no armature"
    if mods:
        bad = [i for i in check_skinning(mesh_obj) if i.severity == "error" or i.code == "bbones"]
        if bad:
            return bad[0].message
        if any(m.use_deform_preserve_volume for m in mods):
            return "an Armature modifier preserves volume (dual quaternions)"
    if _reads_shape_keys(ids, key):
        return "a driver reads a shape-key value"
    return ""




class ShapeKeyColumns:
    """Computes the analytic columns ``columns`` (k,) of an evaluator's control set at its current evaluation.

    Parameters
    ----------
    mesh_obj : bpy.types.Object
    columns : list of int
        Positions of the slider channels in the control set.
    deltas : ndarray (k, p, 3)
        Each slider's object-space delta at the evaluated vertices.
    indices : ndarray of int (p,)
    """

    def __init__(self, mesh_obj, columns, deltas, indices, skinning=None):
        self.mesh_obj = mesh_obj
        self.columns = list(columns)
        self.deltas = deltas
        mods = armature_modifiers(mesh_obj)
        self.armatures = [m.object for m in mods]
        self.skin = [dataclasses.replace(d) for d in _skinning(mesh_obj, skinning).deformers] if mods else []
        for d in self.skin:
            d.weights = SkinWeights(d.weights.bone_index[indices], d.weights.weight[indices])
            if d.vertex_mask is not None:
                d.vertex_mask = d.vertex_mask[indices]

    def blend(self) -> np.ndarray:
        """Per-vertex linear part ``A_v`` (p, 3, 3) of the deformation after the shape keys, at the current
        evaluation (evaluated pose)."""
        dg = bpy.context.evaluated_depsgraph_get()
        mesh_world = world_matrix(self.mesh_obj.evaluated_get(dg))
        A = np.broadcast_to(np.eye(3), (self.deltas.shape[1], 3, 3))
        for d, arm in zip(self.skin, self.armatures):
            arm_eval = arm.evaluated_get(dg)
            d.armature_world = world_matrix(arm_eval)
            L = bone_change_matrices(d, pose_matrices(arm_eval), mesh_world)[:, :3, :3]
            wn, idx = normalised_weights(d.weights, d.vertex_mask)
            step = np.eye(3) + np.einsum("pk,pkij->pij", wn, L[idx] - np.eye(3))
            A = step @ A
        return A

    def __call__(self, points=None) -> np.ndarray:
        """The columns (3p, k) at the current evaluation, in world space (``points``, the evaluated positions,
        are not needed: the same call as :class:`BoneColumns`)."""
        dg = bpy.context.evaluated_depsgraph_get()
        W = world_matrix(self.mesh_obj.evaluated_get(dg))[:3, :3]
        cols = np.einsum("ij,pjk,spk->pis", W, self.blend(), self.deltas)
        return cols.reshape(-1, len(self.columns))


#: Below this fraction of the mesh's vertices, key coordinates are read vertex by vertex (a bulk read of a key
#: block costs ~3 ms on a 27k-vertex head; 58 keys' worth dominated a first use at a few pins).
SPARSE_READ = 0.02


def key_coords(kb, indices, cache) -> np.ndarray:
    """Object-space coordinates (p, 3) of a key block at ``indices`` (cached per block)."""
    if kb.name not in cache:
        if indices.size < SPARSE_READ * len(kb.data):
            data = kb.data
            cache[kb.name] = np.array([data[int(i)].co for i in indices], dtype=np.float64)
        else:
            buf = np.empty(len(kb.data) * 3, np.float32)
            kb.data.foreach_get("co", buf)
            cache[kb.name] = buf.reshape(-1, 3)[indices].astype(np.float64)
    return cache[kb.name]


def key_delta(mesh_obj, kb, indices, cache) -> np.ndarray:
    """A slider's object-space delta (p, 3) at ``indices``: key − relative key, times the key's vertex group."""
    d = key_coords(kb, indices, cache) - key_coords(kb.relative_key, indices, cache)
    if kb.vertex_group:
        vg = mesh_obj.vertex_groups.get(kb.vertex_group)
        w = np.zeros(len(indices))
        if vg is not None:
            for n, i in enumerate(indices):
                try:
                    w[n] = vg.weight(int(i))
                except RuntimeError:                      # the vertex is not in the group
                    pass
        d = d * w[:, None]
    return d


def shape_key_columns(mesh_obj, controls, ids, indices, skinning=None):
    """``(ShapeKeyColumns or None, reason)`` for the slider channels of ``mesh_obj`` in ``controls`` (module doc);
    ``None`` with an empty reason when the control set has no slider of this mesh."""
    prefix = "data.shape_keys.key_blocks["
    cols = [j for j, ch in enumerate(controls.channels)
            if ch.kind == ChannelKind.SHAPE_KEY and ch.owner == mesh_obj.name and ch.path.startswith(prefix)]
    if not cols:
        return None, ""
    reason = analytic_refusal(mesh_obj, ids)
    if reason:
        return None, reason
    key = mesh_obj.data.shape_keys
    driven = {fc.data_path for fc in key.animation_data.drivers} if key.animation_data is not None else set()
    cache, keep, deltas, other = {}, [], [], []
    for j in cols:
        path = controls.channels[j].path[len("data.shape_keys."):]
        kb = key.path_resolve(path.rpartition(".")[0])
        if kb.mute or path in driven:                    # what is written there does not act: finite differences
            other.append(kb.name)
            continue
        keep.append(j)
        deltas.append(key_delta(mesh_obj, kb, indices, cache))
    reason = f"muted or driven shape keys by finite differences: {', '.join(other)}" if other else ""
    if not keep:
        return None, reason
    return ShapeKeyColumns(mesh_obj, keep, np.stack(deltas), indices, skinning), reason


# ---------------------------------------------------------------------------------------------------------------
# bone channels under plain linear-blend skinning

#: Bone constraints that leave a pose bone's matrix ``B · matrix_basis`` inside the channel's bounds (owner space
#: ``LOCAL``: :mod:`bridge.rig.channels` reads them as the channel's bounds).
LIMIT_CONSTRAINTS = ("LIMIT_ROTATION", "LIMIT_LOCATION", "LIMIT_SCALE")
#: Central-difference step of a rotation matrix in its own coordinates (float64: ~1e-10 relative error).
ROT_STEP = 1e-6


def _axis_rotation(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _rodrigues(v) -> np.ndarray:
    """Rotation matrix (3, 3) of a rotation vector (axis × angle)."""
    v = np.asarray(v, dtype=np.float64)
    angle = float(np.linalg.norm(v))
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    if angle < 1e-12:
        return np.eye(3) + K
    K /= angle
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def _rotation(mode: str, value) -> np.ndarray:
    """The rotation matrix of a pose bone: Euler angles (3,) in ``mode`` (``'XYZ'``: X applied first), or the
    rotation vector (3,) of a ``QUATERNION`` / ``AXIS_ANGLE`` bone."""
    if mode in ("QUATERNION", "AXIS_ANGLE"):
        return _rodrigues(value)
    R = np.eye(3)
    for axis in mode:
        a = "XYZ".index(axis)
        R = _axis_rotation(a, value[a]) @ R
    return R


def _rotation_value(pb) -> tuple:
    """(mode, values (3,)) of a pose bone's rotation: Euler angles or the rotation vector."""
    mode = pb.rotation_mode
    if mode == "QUATERNION":
        q = np.array(pb.rotation_quaternion, dtype=np.float64)
        q = q / np.linalg.norm(q) if np.linalg.norm(q) > 0 else np.array([1.0, 0.0, 0.0, 0.0])
        return mode, rotation_vector_from_quaternion(q)
    if mode == "AXIS_ANGLE":
        aa = np.array(pb.rotation_axis_angle, dtype=np.float64)
        n = np.linalg.norm(aa[1:])
        return mode, (np.zeros(3) if n == 0 else aa[0] * aa[1:] / n)
    return mode, np.array(pb.rotation_euler, dtype=np.float64)


def basis_velocity(pb, kind: ChannelKind, axis: int) -> np.ndarray:
    """``matrix_basis⁻¹ · ∂matrix_basis/∂c`` (4, 4) of one channel of pose bone ``pb`` at its current values
    (``matrix_basis = T(location) · R(rotation) · S(scale)``; a rotation channel of a ``QUATERNION`` /
    ``AXIS_ANGLE`` bone is a component of its rotation vector, :mod:`core.rig.controls`)."""
    loc = np.array(pb.location, dtype=np.float64)
    scale = np.array(pb.scale, dtype=np.float64)
    mode, rot = _rotation_value(pb)
    R = _rotation(mode, rot)
    Mb = np.eye(4)
    Mb[:3, :3], Mb[:3, 3] = R * scale, loc
    dMb = np.zeros((4, 4))
    if kind == ChannelKind.LOCATION:
        dMb[axis, 3] = 1.0
    elif kind == ChannelKind.SCALE:
        dMb[:3, axis] = R[:, axis]
    else:
        up, down = rot.copy(), rot.copy()
        up[axis] += ROT_STEP
        down[axis] -= ROT_STEP
        dMb[:3, :3] = (_rotation(mode, up) - _rotation(mode, down)) / (2.0 * ROT_STEP) * scale
    return np.linalg.solve(Mb, dMb)


def _bone_name(path: str) -> str:
    return path.split('"')[1] if path.startswith('pose.bones["') else ""


def _reads_armature(ids, arm) -> bool:
    """Whether a driver of any of ``ids`` takes an input from the armature object or its data, or drives it."""
    for idb in ids:
        ad = getattr(idb, "animation_data", None)
        for fc in (ad.drivers if ad is not None else ()):
            if idb == arm or idb == arm.data:
                return True
            for var in fc.driver.variables:
                if any(t.id is not None and (t.id == arm or t.id == arm.data) for t in var.targets):
                    return True
    return False


def skin_refusal(mesh_obj, ids, arm) -> str:
    """Why bone columns of armature ``arm`` on ``mesh_obj`` cannot be analytic ('' when they can; module doc)."""
    others = [m.name for m in mesh_obj.modifiers if m.show_viewport and m.type != "ARMATURE"]
    if others:
        return f"modifier {others[0]!r} deforms after the shape keys"
    mods = armature_modifiers(mesh_obj)
    if len(mods) != 1 or len([m for m in mesh_obj.modifiers if m.show_viewport]) != 1 or mods[0].object != arm:
        return f"the mesh is not deformed by exactly one Armature modifier on {arm.name!r}"
    bad = [i for i in check_skinning(mesh_obj) if i.severity == "error" or i.code == "bbones"]
    if bad:
        return bad[0].message
    if mods[0].use_deform_preserve_volume:
        return "the Armature modifier preserves volume (dual quaternions)"
    parent = mesh_obj.parent
    while parent is not None:
        if parent == arm:
            return f"the mesh is parented to {arm.name!r}"
        parent = parent.parent
    for pb in arm.pose.bones:
        for con in pb.constraints:
            if con.enabled and con.influence > 0 and (con.type not in LIMIT_CONSTRAINTS or con.owner_space != "LOCAL"):
                return f"bone {pb.name!r} has a {con.type} constraint"
        if pb.parent is not None and (not pb.bone.use_inherit_rotation or pb.bone.inherit_scale != "FULL"):
            return f"bone {pb.name!r} does not inherit its parent's rotation and scale"
    if _reads_armature(ids, arm):
        return f"a driver reads or drives {arm.name!r}"
    return ""


class BoneColumns:
    """Computes the analytic columns ``columns`` (k,) of bone channels on the mesh's single linear-blend Armature
    modifier, at the evaluator's current evaluation (module doc of this section: :func:`bone_columns`).

    Parameters
    ----------
    mesh_obj : bpy.types.Object
    arm : bpy.types.Object
    columns : list of int
        Positions of the bone channels in the control set.
    channels : list of (bone name, ChannelKind, axis)
    indices : ndarray of int (p,)
    """

    def __init__(self, mesh_obj, arm, columns, channels, indices, skinning=None):
        self.mesh_obj, self.arm = mesh_obj, arm
        self.columns, self.channels = list(columns), list(channels)
        d = dataclasses.replace(_skinning(mesh_obj, skinning).deformers[0])
        d.weights = SkinWeights(d.weights.bone_index[indices], d.weights.weight[indices])
        if d.vertex_mask is not None:
            d.vertex_mask = d.vertex_mask[indices]
        self.skin = d
        bones = arm.data.bones
        position = {n: i for i, n in enumerate(d.bone_names)}
        self.subtree, self.bone_index = [], []
        for name, _, _ in self.channels:
            member = np.zeros(len(d.bone_names), bool)
            member[[position[b.name] for b in [bones[name], *bones[name].children_recursive]]] = True
            self.subtree.append(member)
            self.bone_index.append(position[name])

    def __call__(self, points) -> np.ndarray:
        """The columns (3p, k) in world space, given the evaluated world positions ``points`` (p, 3) of the
        evaluator's vertices at the current evaluation.

        With ``ŵ`` the normalised (and masked) weights and ``C_b`` the bones' change matrices in the mesh's object
        space, the skinned point is ``y = x + Σ_b ŵ_b (C_b x − x)``; the pre-skinning point ``x`` is recovered from
        ``y`` (a 3 × 3 solve per vertex).  A channel of bone ``k`` moves every bone of its subtree ``S`` rigidly:
        ``∂C_b/∂c = G C_b`` with ``G = Q⁻¹ P_k (M_b⁻¹ ∂M_b/∂c) P_k⁻¹ Q`` (``P_k`` the bone's pose matrix,
        ``M_b`` its ``matrix_basis``, ``Q = arm_world⁻¹ · mesh_world``), so its column is
        ``W (G_lin Σ_{b∈S} ŵ_b C_b x + G_t Σ_{b∈S} ŵ_b)``.
        """
        dg = bpy.context.evaluated_depsgraph_get()
        mesh_world = world_matrix(self.mesh_obj.evaluated_get(dg))
        arm_eval = self.arm.evaluated_get(dg)
        d = self.skin
        d.armature_world = world_matrix(arm_eval)
        pose = pose_matrices(arm_eval)
        C = bone_change_matrices(d, pose, mesh_world)
        wn, idx = normalised_weights(d.weights, d.vertex_mask)
        Cv = C[idx]                                                        # (p, k, 4, 4)
        A = np.eye(3) + np.einsum("pk,pkij->pij", wn, Cv[:, :, :3, :3] - np.eye(3))
        t = np.einsum("pk,pki->pi", wn, Cv[:, :, :3, 3])
        y = (np.asarray(points, np.float64) - mesh_world[:3, 3]) @ np.linalg.inv(mesh_world[:3, :3]).T
        x = np.linalg.solve(A, (y - t)[:, :, None])[:, :, 0]
        z = np.einsum("pkij,pj->pki", Cv[:, :, :3, :3], x) + Cv[:, :, :3, 3]   # each bone's image of x
        Q = np.linalg.inv(d.armature_world) @ mesh_world
        Qi = np.linalg.inv(Q)
        out = np.zeros((len(points), 3, len(self.columns)))
        for j, ((name, kind, axis), member, k) in enumerate(zip(self.channels, self.subtree, self.bone_index)):
            P = pose[k]
            G = Qi @ P @ basis_velocity(self.arm.pose.bones[name], kind, axis) @ np.linalg.inv(P) @ Q
            wk = wn * member[idx]
            col = np.einsum("pk,pki->pi", wk, z) @ G[:3, :3].T + wk.sum(axis=1)[:, None] * G[:3, 3]
            out[:, :, j] = col @ mesh_world[:3, :3].T
        return out.reshape(-1, len(self.columns))


def bone_columns(mesh_obj, controls, ids, indices, skinning=None):
    """``(BoneColumns or None, reason)`` for the bone rotation / location / scale channels of the armature that
    deforms ``mesh_obj`` (:func:`skin_refusal`); ``None`` with an empty reason when there are none."""
    mods = armature_modifiers(mesh_obj)
    if not mods:
        return None, ""
    arm = mods[0].object
    kinds = (ChannelKind.ROTATION, ChannelKind.LOCATION, ChannelKind.SCALE)
    cols = [j for j, ch in enumerate(controls.channels)
            if ch.kind in kinds and ch.owner == arm.name and _bone_name(ch.path) in arm.pose.bones]
    if not cols:
        return None, ""
    reason = skin_refusal(mesh_obj, ids, arm)
    if reason:
        return None, reason
    chans = [(_bone_name(controls.channels[j].path), controls.channels[j].kind, max(controls.channels[j].index, 0))
             for j in cols]
    return BoneColumns(mesh_obj, arm, cols, chans, indices, skinning), ""
