"""The registration of a transfer and its preview: the registered source neutral shown over the target.

Three steps like a transfer: :func:`read_preview` (main thread), :func:`core.authoring.job.compute_preview` (any
thread, cancellable: a modal operator runs it in a :class:`core.jobs.BackgroundJob`), :func:`write_preview`
(main thread).  The preview is one wireframe object parented to the target, removed with its mesh by
:func:`clear_preview` and by a transfer.
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core.authoring.job import PreviewOutcome, PreviewPlan, compute_preview
from ...core.errors import ErrorCode
from ...core.jobs import BackgroundJob
from ...core.result import Result, ShapeSpaceError
from ..arrays import write_float
from .landmarks import landmarks_for
from .reading import read_source_rig, read_target, target_signature

__all__ = ["PREVIEW_PROP", "PreviewPlan", "PreviewOutcome", "register_source", "preview_object", "clear_preview",
           "read_preview", "compute_preview", "write_preview", "show_preview", "start_preview_job",
           "finish_preview_job"]

PREVIEW_PROP = "shapespace_registration_preview"


def register_source(source, target, progress=None) -> Result:
    """Register the source neutral onto the target (landmarks stored on the target); value: the correspondence
    (:func:`read_preview` and :func:`compute_preview` in one go, nothing shown)."""
    return compute_preview(read_preview(source, target), progress).result


def preview_object(target):
    """The registration preview object of ``target``, or None."""
    for ob in target.children:
        if PREVIEW_PROP in ob and ob.library is None:
            return ob
    return None


def clear_preview(target) -> bool:
    """Remove the target's registration preview object and its mesh (nothing is left behind)."""
    ob = preview_object(target)
    if ob is None:
        return False
    mesh = ob.data
    bpy.data.objects.remove(ob)
    if mesh is not None and mesh.users == 0:
        bpy.data.meshes.remove(mesh)
    return True


def _triangle_mesh(name: str, verts: np.ndarray, tris: np.ndarray):
    me = bpy.data.meshes.new(name)
    me.vertices.add(len(verts))
    write_float(me.vertices, "co", verts)
    me.loops.add(tris.size)
    me.loops.foreach_set("vertex_index", np.ascontiguousarray(tris, dtype=np.int32).ravel())
    me.polygons.add(len(tris))
    me.polygons.foreach_set("loop_start", np.arange(0, tris.size, 3, dtype=np.int32))
    me.update(calc_edges=True)
    me.validate()
    return me


def read_preview(source, target) -> PreviewPlan:
    """Step 1 of :func:`show_preview` (main thread): read the source rig, the target and its landmark pairs."""
    rig = read_source_rig(source)
    tgt = read_target(target)
    pairs = landmarks_for(source, target, rig, tgt)
    return PreviewPlan(source=source.name, target=target.name, rig=rig, tgt=tgt, pairs=pairs,
                       signature=target_signature(target))


def write_preview(outcome: PreviewOutcome) -> tuple:
    """Step 3 (main thread): replace the target's preview object by the registered source neutral.

    Refused, with nothing written, when the target is gone or changed since :func:`read_preview`.  The preview
    is one object (parented to the target, not selectable, not rendered), removed with its mesh by
    :func:`clear_preview` and by a transfer.  Returns ``(preview object, registration result)``.
    """
    plan, result = outcome.plan, outcome.result
    target = bpy.data.objects.get(plan.target)
    if target is None or target.type != "MESH" or target_signature(target) != plan.signature:
        raise ShapeSpaceError(f"{plan.target!r} changed while the registration computed: nothing was shown; "
                              "preview again", ErrorCode.RIG_CHANGED)
    clear_preview(target)
    name = f"{target.name} Registration Preview"
    me = _triangle_mesh(name, np.asarray(result.value.registered, dtype=np.float64), plan.rig.triangles)
    ob = bpy.data.objects.new(name, me)
    ob[PREVIEW_PROP] = target.name
    ob.display_type = "WIRE"
    ob.show_in_front = True
    ob.hide_render = True
    ob.hide_select = True
    collection = target.users_collection[0] if target.users_collection else bpy.context.scene.collection
    collection.objects.link(ob)
    ob.parent = target
    ob.matrix_parent_inverse.identity()
    return ob, result


def show_preview(source, target, progress=None) -> tuple:
    """Register and show the registered source neutral as a wireframe object over the target (the three steps
    :func:`read_preview`, :func:`compute_preview`, :func:`write_preview` in one go)."""
    return write_preview(compute_preview(read_preview(source, target), progress))


def start_preview_job(plan: PreviewPlan) -> BackgroundJob:
    """Start :func:`compute_preview` of ``plan`` in a worker thread (a modal operator polls it and cancels it on
    Esc); :func:`finish_preview_job` shows the result once it is done."""
    return BackgroundJob(lambda progress: compute_preview(plan, progress), name="ShapeSpace registration").start()


def finish_preview_job(job: BackgroundJob) -> tuple:
    """Show a finished job's registration (main thread); re-raises what stopped the job (``Cancelled``, its
    :class:`ShapeSpaceError`), nothing is written then."""
    return write_preview(job.result())
