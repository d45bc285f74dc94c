"""The live target: per-frame solvers built from the rigs once at Start, and the per-frame Blender writes.

Everything that reads a rig happens here, before the receiver opens: the
target's sliders and ranges, the channel mapping (stored overrides first, then
names — :func:`bridge.retarget.channel_mapping`), for the learned method the
cloning matrix from the artist's key poses, for the geometric solve-through
the template's shapes carried onto the target by the landmark correspondence
(:func:`core.retarget.transfer_motion`, the offline dense path's own map), and
the chosen bones' rest orientations.  Per frame, :meth:`Pipeline.solve` is pure
numpy and :meth:`Pipeline.write` sets the sliders (one bulk write) and the bones.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.headpose import BoneSpec, bone_values
from ...core.live import (
    FACECAP_52,
    LLF_BLENDSHAPES,
    CalibratedInput,
    CopySolver,
    GeometricSolver,
    LearnedSolver,
    Neutral,
    OneEuroFilter,
)
from ...core.names import match_channels
from ...core.result import ShapeSpaceError
from ...core.retarget import (
    key_frames_in_span,
    learned_cloning,
    moving_channels,
    normalised_basis,
    split_mapping,
    transfer_motion,
)
from .. import actions, retarget, shapekeys
from ..manipulation.cache import RIGS

__all__ = ["SOURCE_NAMES", "METHODS", "BoneTarget", "Pipeline", "build_pipeline"]

#: Channel names (in the solvers' input order) per source type.
SOURCE_NAMES = {"LLF": LLF_BLENDSHAPES, "FACECAP": FACECAP_52, "IFACIALMOCAP": FACECAP_52}
METHODS = ("COPY", "LEARNED", "SOLVE")


#: A pose bone the head or an eye drives (the shared core definition: live and recorded takes alike).
BoneTarget = BoneSpec


@dataclass
class Pipeline(CalibratedInput):
    """What one frame goes through: calibrate → filter → solve → write.

    Attributes
    ----------
    target : str
        The target mesh's name (looked up every frame: undo-safe).
    slider_names : list of str
    solver : CopySolver, LearnedSolver or GeometricSolver
    n_source : int
        Blendshape channels of the source.
    method : str
    armature : str
        The armature whose bones the head and eyes drive ('' for none).
    bones : list of BoneTarget
    mirror : bool
    smoothing : OneEuroFilter or None
    neutral : Neutral or None
        The calibrated rest frame.
    """

    target: str
    slider_names: list
    solver: object
    n_source: int
    method: str
    armature: str = ""
    bones: list = field(default_factory=list)
    mirror: bool = False
    smoothing: OneEuroFilter | None = None
    neutral: Neutral | None = None

    def solve(self, vector: np.ndarray) -> tuple:
        """Sliders (n_target,) and ``{bone: values in its rotation mode}`` for a processed vector."""
        n = self.n_source
        return self.solver.solve(vector[:n]), bone_values(vector[n:n + 9], self.bones, self.mirror)

    def write(self, sliders: np.ndarray, bones: dict) -> str:
        """Set the target's sliders and the bones; returns '' or why nothing could be written.

        On a rig the drag's cache holds, the writes are evaluated at once as ShapeSpace's own
        (:meth:`bridge.manipulation.RigCache.own_update`), so they are not taken for outside edits.
        """
        obj = bpy.data.objects.get(self.target)
        if obj is None or obj.type != "MESH" or obj.data.shape_keys is None:
            return f"the target {self.target!r} was deleted (or lost its shape keys)"
        with RIGS.own_update(obj):          # ShapeSpace's own writes: no checksum at the next drag on this rig
            shapekeys.write_slider_values(obj, self.slider_names, sliders)
            if bones:
                return retarget.write_pose_bones(self.armature, self.bones, bones)
        return ""


# ------------------------------------------------------------------ building
def _mesh_rig(obj, what: str):
    if obj is None:
        raise ShapeSpaceError(f"choose the {what} (a mesh with shape keys)", ErrorCode.NO_OBJECT)
    if obj.type != "MESH":
        raise ShapeSpaceError(f"the {what} {obj.name!r} is a {obj.type.lower()}, not a mesh", ErrorCode.NOT_MESH)
    return shapekeys.read_blendshape_model(obj)


def _copy_solver(obj, model, names) -> CopySolver:
    pairs, gain, offset = split_mapping(retarget.channel_mapping(obj, list(names), model.names), model.n_targets)
    return CopySolver(pairs, gain, offset, model.slider_min, model.slider_max, len(names))


def _learned_solver(obj, model, names, settings, scene) -> LearnedSolver:
    source = bpy.path.abspath(settings.learn_csv) if settings.learn_csv else settings.learn_action
    if not source:
        raise ShapeSpaceError("the learned method needs the take the key poses were made on: a CSV file or an "
                              "action", ErrorCode.NO_KEY_POSES)
    action = settings.key_pose_action
    curves = actions.shape_key_curves(obj, action) if action is not None else {}
    if not curves:
        raise ShapeSpaceError(f"choose a key-pose action keying {obj.name!r}'s shape keys at the key poses",
                              ErrorCode.NO_KEY_POSES)
    src_names, frames, src, _ = retarget.read_source(source, scene)
    keyed = key_frames_in_span(np.concatenate([actions.read_curve(fc)[0] for fc in curves.values()]), frames)
    learned = learned_cloning(frames, src, keyed, actions.sample_shape_keys(obj, model.names, keyed, action))
    moving = [src_names[i] for i in np.flatnonzero(moving_channels(src))]
    found, missing, _ = match_channels(moving, list(names))
    if missing:
        raise ShapeSpaceError(f"the learned take's channels {', '.join(missing[:4])} have no live counterpart",
                              ErrorCode.MISSING_CHANNEL)
    return LearnedSolver([list(names).index(found[m]) for m in moving], learned.matrix, model.slider_min,
                         model.slider_max)


def _geometric_solver(obj, model, names, template) -> GeometricSolver:
    model_s = _mesh_rig(template, "template rig")
    if not model.is_linear or not model_s.is_linear:
        which = obj.name if not model.is_linear else template.name
        raise ShapeSpaceError(f"{which!r} has in-between or combination shapes: the geometric solve-through "
                              "needs rigs linear in their sliders (use copy or learned)", ErrorCode.NONLINEAR)
    found, _, _ = match_channels(list(names), model_s.names)
    pairs = [(i, model_s.names.index(found[n])) for i, n in enumerate(names) if n in found]
    to_template = CopySolver(pairs, np.ones(model_s.n_targets), np.zeros(model_s.n_targets), model_s.slider_min,
                             model_s.slider_max, len(names))
    src_lm, dst_lm = retarget.landmark_pairs(template, obj)
    same = model_s.neutral.shape[0] == model.neutral.shape[0] and not src_lm.size
    if not same and src_lm.size < 3:
        raise ShapeSpaceError(f"the template {template.name!r} and the target {obj.name!r} need at least 3 landmark "
                              f"pairs (vertex groups 'lm_…' on both; Landmarks from Shapes makes them); found "
                              f"{src_lm.size}", ErrorCode.TOO_FEW_LANDMARKS)
    shapes = model_s.neutral[None] + model_s.deltas                  # the template posed by each slider alone
    carried = transfer_motion(shapes, model_s.neutral, model.neutral, model.deltas, model.scale, src_lm, dst_lm)
    B, b0, unit = normalised_basis(model)
    T = (carried / unit - b0).T                                      # (3p, n_T): motion per template slider
    return GeometricSolver(to_template, B, T, model.slider_min, model.slider_max)


def _bones(settings) -> tuple:
    arm = settings.armature
    if arm is None:
        return "", []
    return arm.name, retarget.bone_specs(arm, settings.head_bone, settings.neck_bone, settings.eye_left_bone,
                                         settings.eye_right_bone, settings.neck_share)


def build_pipeline(scene, settings, target) -> Pipeline:
    """Validate the live settings and precompute everything one frame needs.

    Parameters
    ----------
    scene : bpy.types.Scene
    settings : the scene's ``shapespace_live`` settings
    target : bpy.types.Object
        The mesh the capture drives.

    Raises
    ------
    ShapeSpaceError
        With a one-line message naming what is missing (target, template, landmarks, key poses, bone, …).
    """
    model = _mesh_rig(target, "target")
    names = SOURCE_NAMES[settings.source]
    if settings.method == "COPY":
        solver = _copy_solver(target, model, names)
    elif settings.method == "LEARNED":
        solver = _learned_solver(target, model, names, settings, scene)
    else:
        solver = _geometric_solver(target, model, names, settings.template)
    armature, bones = _bones(settings)
    smoothing = OneEuroFilter(settings.min_cutoff, settings.beta) if settings.smoothing else None
    return Pipeline(target.name, list(model.names), solver, len(names), settings.method, armature, bones,
                    bool(settings.mirror), smoothing)
