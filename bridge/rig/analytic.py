"""Analytic Jacobian columns of shape-key slider channels (issue #25, first use of a rig).

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
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core.rig import ChannelKind
from ...core.skinning import MIN_CONTRIB, SkinWeights, bone_change_matrices
from ..meshes import world_matrix
from ..skin import armature_modifiers, check_skinning, pose_matrices, read_skinning

__all__ = ["ShapeKeyColumns", "analytic_refusal", "key_coords", "key_delta", "shape_key_columns"]


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

    def __init__(self, mesh_obj, columns, deltas, indices):
        self.mesh_obj = mesh_obj
        self.columns = list(columns)
        self.deltas = deltas
        mods = armature_modifiers(mesh_obj)
        self.armatures = [m.object for m in mods]
        self.skin = read_skinning(mesh_obj).deformers if mods else []
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
            w = d.weights.effective()
            idx = np.where(d.weights.bone_index >= 0, d.weights.bone_index, 0)
            contrib = w.sum(axis=1)
            scale = np.where(contrib > MIN_CONTRIB, 1.0 / np.where(contrib > MIN_CONTRIB, contrib, 1.0), 0.0)
            if d.vertex_mask is not None:
                scale = scale * d.vertex_mask
            step = np.eye(3) + np.einsum("pk,pkij->pij", w * scale[:, None], L[idx] - np.eye(3))
            A = step @ A
        return A

    def __call__(self) -> np.ndarray:
        """The columns (3p, k) at the current evaluation, in world space."""
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


def shape_key_columns(mesh_obj, controls, ids, indices):
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
    return ShapeKeyColumns(mesh_obj, keep, np.stack(deltas), indices), reason
