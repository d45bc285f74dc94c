"""Apply Sculpt (thesis 7.2.1): pull an example's posed sculpt back to rest space and store it in its key.

Shape keys act before the Armature modifier, so the sculpt is inverted through
the deformation: with ShapeSpace's own skinning model when it reproduces the
modifier stack exactly, else through Blender's evaluation itself (B-Bones,
other deforming modifiers), one temporary shape key at a time.
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.posespace.inversion import InversionResult, invert_deformation
from ...core.result import ShapeSpaceError, Status
from ...core.skinning import deform
from .. import meshes, skin
from ..arrays import read_float, write_float
from .examples import basis_positions, check_topology, example_keys, pre_armature_positions
from .pose import settings
from .stored import find_example

#: Temporary key used while inverting through Blender's own evaluation (removed afterwards).
TEMP_KEY = "ShapeSpace_invert"


def modelled_exactly(obj) -> bool:
    """True when ShapeSpace's skinning model reproduces the modifier stack exactly (plain Armature
    modifiers with vertex groups, no B-Bones, no other deforming modifiers)."""
    others = [m for m in obj.modifiers if m.show_viewport and m.type != "ARMATURE"]
    if others:
        return False
    problems = skin.check_skinning(obj)
    return not any(i.severity == "error" or i.code == "bbones" for i in problems)


def _sculpt_positions(obj, ex) -> np.ndarray:
    """The sculpt copy's vertices in ``obj``'s object space."""
    p = len(obj.data.vertices)
    if ex.sculpt is None:
        raise ShapeSpaceError(f"example {ex.name!r} has no sculpt copy: give sculpt positions", ErrorCode.NO_SCULPT)
    if len(ex.sculpt.data.vertices) != p:
        raise ShapeSpaceError(f"the sculpt copy of {ex.name!r} has {len(ex.sculpt.data.vertices)} "
                              f"vertices, the mesh has {p}: the topology changed", ErrorCode.VERTEX_COUNT)
    world = meshes.to_world(ex.sculpt, meshes.vertex_positions(ex.sculpt.data))
    return meshes.to_local(obj, world)


def _invert(obj, rest, sculpt) -> InversionResult:
    if skin.armature_modifiers(obj) and modelled_exactly(obj):
        rig = skin.read_skinning(obj)
        poses = skin.modifier_poses(obj)
        return invert_deformation(lambda x: deform(x, rig, poses), rest, sculpt)
    if [m for m in obj.modifiers if m.show_viewport]:
        return _invert_through_blender(obj, rest, sculpt)
    return InversionResult(sculpt - rest, residual=0.0, iterations=0, status=Status.OK,
                           message="no armature: the sculpt is the corrective")


def apply_example(obj, example_name: str, sculpt_positions=None) -> InversionResult:
    """Invert the example's sculpt to rest space and store it in the example's shape key.

    ``sculpt_positions`` (p, 3) in ``obj``'s object space; default: the sculpt copy's vertices.
    Returns the core ``InversionResult`` (``corrective``, ``residual``, status).
    """
    check_topology(obj)
    st = settings(obj)
    ex = find_example(obj, example_name)
    p = len(obj.data.vertices)
    if sculpt_positions is None:
        sculpt_positions = _sculpt_positions(obj, ex)
    sculpt_positions = np.asarray(sculpt_positions, dtype=np.float64)
    if sculpt_positions.shape != (p, 3):
        raise ShapeSpaceError(f"sculpt positions must have shape ({p}, 3)", ErrorCode.SHAPE)
    result = _invert(obj, pre_armature_positions(obj), sculpt_positions)
    key = obj.data.shape_keys
    write_float(key.key_blocks[example_name].data, "co", basis_positions(obj) + result.corrective)
    obj.data.update()
    st.revision += 1
    return result


def _invert_through_blender(obj, rest, sculpt) -> InversionResult:
    """Newton inversion with Blender's own evaluation as the deformer (B-Bones, other modifiers).

    Each evaluation writes the candidate pre-modifier positions into a temporary shape key and reads
    Blender's evaluated mesh; Jacobians come from central differences of that evaluation.
    """
    key = obj.data.shape_keys
    blocks = key.key_blocks
    examples = [n for n in example_keys(obj) if n in blocks]
    saved = {n: blocks[n].value for n in examples}
    for n in examples:
        blocks[n].value = 0.0
    tmp = obj.shape_key_add(name=TEMP_KEY, from_mix=False)
    tmp.slider_min, tmp.slider_max = -10.0, 10.0
    tmp.value = 1.0
    name = tmp.name
    basis = read_float(key.reference_key.data, "co", 3).astype(np.float64)
    depsgraph = bpy.context.evaluated_depsgraph_get()

    def blender_deform(x):
        write_float(obj.data.shape_keys.key_blocks[name].data, "co", basis + (x - rest))
        obj.data.update()
        return meshes.evaluated_positions(obj, depsgraph).astype(np.float64)

    try:
        # float32 evaluation: ask for what single precision can give
        size = float(np.linalg.norm(np.ptp(rest, axis=0))) or 1.0
        return invert_deformation(blender_deform, rest, sculpt, tol=2e-7 * size)
    finally:
        obj.shape_key_remove(obj.data.shape_keys.key_blocks[name])
        for n, v in saved.items():
            obj.data.shape_keys.key_blocks[n].value = v
        obj.data.update()
