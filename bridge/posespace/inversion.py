"""Inverting a posed sculpt through the deformation to rest space (thesis 7.2.1).

Shape keys act before the Armature modifier, so the sculpt is inverted through
the deformation: with ShapeSpace's own skinning model when it reproduces the
modifier stack exactly, else through Blender's evaluation itself (B-Bones,
other deforming modifiers), one temporary shape key at a time.  Used by Apply
Sculpt (:mod:`.sculpt`), re-inversion (:mod:`.finalshape`) and masked pushes
(:mod:`.masked`).
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
from .correctives import check_finite_positions, example_keys
from .stored import is_post_deform_modifier

__all__ = ["TEMP_KEY", "modelled_exactly", "sculpt_positions_of", "invert", "invert_through_blender"]

#: Temporary key used while inverting through Blender's own evaluation (removed afterwards).
TEMP_KEY = "ShapeSpace_invert"
#: Blender evaluations a typical inversion takes (a few Newton steps of 7): the progress display's scale.
_EXPECTED_EVALUATIONS = 40.0


def modelled_exactly(obj) -> bool:
    """True when ShapeSpace's skinning model reproduces the modifier stack exactly (plain Armature
    modifiers with vertex groups, no B-Bones, no other deforming modifiers)."""
    others = [m for m in obj.modifiers if m.show_viewport and m.type != "ARMATURE" and not is_post_deform_modifier(m)]
    if others:
        return False
    problems = skin.check_skinning(obj)
    return not any(i.severity == "error" or i.code == "bbones" for i in problems)


def sculpt_positions_of(obj, ex, given=None) -> np.ndarray:
    """The sculpt to invert, (p, 3) float64 in ``obj``'s object space: ``given`` when the caller passes
    positions (checked for shape and finiteness), else the example's sculpt copy's vertices."""
    p = len(obj.data.vertices)
    positions = np.asarray(_sculpt_positions(obj, ex) if given is None else given, dtype=np.float64)
    if positions.shape != (p, 3):
        raise ShapeSpaceError(f"sculpt positions must have shape ({p}, 3)", ErrorCode.SHAPE)
    check_finite_positions(positions, f"the sculpt of {ex.name!r}")
    return positions


def _sculpt_positions(obj, ex) -> np.ndarray:
    """The sculpt copy's vertices in ``obj``'s object space."""
    p = len(obj.data.vertices)
    copy = ex.sculpt
    if copy is None:
        raise ShapeSpaceError(f"example {ex.name!r} has no sculpt copy: give sculpt positions", ErrorCode.NO_SCULPT)
    if copy.type != "MESH":
        raise ShapeSpaceError(f"the sculpt copy {copy.name!r} of {ex.name!r} is a {copy.type.lower()}, not a mesh",
                              ErrorCode.NOT_MESH)
    if copy.mode == "EDIT":
        raise ShapeSpaceError(f"the sculpt copy {copy.name!r} of {ex.name!r} is in Edit Mode: leave Edit Mode "
                              "first (its mesh data is not up to date until then)", ErrorCode.MODE)
    if len(copy.data.vertices) != p:
        raise ShapeSpaceError(f"the sculpt copy of {ex.name!r} has {len(copy.data.vertices)} "
                              f"vertices, the mesh has {p}: the topology changed", ErrorCode.VERTEX_COUNT)
    world = meshes.to_world(copy, meshes.vertex_positions(copy.data))
    check_finite_positions(world, f"the sculpt copy {copy.name!r} of {ex.name!r}")
    return meshes.to_local(obj, world)


def invert(obj, rest, sculpt, progress=None) -> InversionResult:
    """The rest-space corrective that takes ``rest`` (p, 3) to ``sculpt`` (p, 3) through ``obj``'s deformation at
    the current pose: the skinning model when it is exact, else Blender's own evaluation (``progress`` called
    with an estimated fraction done); without modifiers the sculpt minus the rest."""
    if skin.armature_modifiers(obj) and modelled_exactly(obj):
        rig = skin.read_skinning(obj)
        poses = skin.modifier_poses(obj)
        return invert_deformation(lambda x: deform(x, rig, poses), rest, sculpt)
    if [m for m in obj.modifiers if m.show_viewport]:
        return invert_through_blender(obj, rest, sculpt, progress)
    return InversionResult(sculpt - rest, residual=0.0, iterations=0, status=Status.OK,
                           message="no armature: the sculpt is the corrective")


def invert_through_blender(obj, rest, sculpt, progress=None) -> InversionResult:
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
    calls = [0]

    def blender_deform(x):
        calls[0] += 1
        if progress is not None:
            progress(min(calls[0] / _EXPECTED_EVALUATIONS, 0.99))
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
