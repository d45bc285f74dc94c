"""Training a mesh's pose-space deformer from its examples, and flagging bad examples (thesis ch. 8)."""
from __future__ import annotations

import numpy as np

from ...core.errors import ErrorCode
from ...core.posespace.examples import example_issues
from ...core.posespace.pairs import bone_pairs
from ...core.posespace.psd import skin_group_inputs, train_psd
from ...core.result import Issue, ShapeSpaceError
from .. import skin
from .correctives import example_correctives
from .pose import readers, settings
from .stored import check_examples, interpolation_pose, wpsd_distance


def trained_deformer(obj) -> tuple:
    """Train the object's pose-space deformer from its examples (muted examples left out).

    Returns ``(PoseSpaceDeformer, example names)`` in the deformer's example order.
    """
    st = settings(obj)
    check_examples(obj, need_keys=False)
    key = obj.data.shape_keys
    active = [ex for ex in st.examples if not ex.mute]
    if not active:
        raise ShapeSpaceError("no (unmuted) examples to interpolate", ErrorCode.NO_EXAMPLES)
    missing = [ex.name for ex in active if key is None or ex.name not in key.key_blocks]
    if missing:
        raise ShapeSpaceError(f"the corrective keys {', '.join(missing)} of {obj.name!r} were deleted: remove "
                              "those examples (or undo the deletion)", ErrorCode.MISSING_KEY)
    rs = readers(obj)
    n_features = sum(r.dims for r in rs)
    poses = []
    for ex in active:
        pose = interpolation_pose(ex)
        if len(pose) != n_features:
            raise ShapeSpaceError(f"example {ex.name!r} was recorded with a different pose space; record it "
                                  "again", ErrorCode.STALE_EXAMPLE)
        poses.append(pose)
    D = example_correctives(obj, active)
    method = st.method.lower()
    kwargs = {}
    if method == "wpsd":
        kwargs = _wpsd_inputs(obj, rs, wpsd_distance(st))
    return train_psd(np.array(poses), D, method, **kwargs), [ex.name for ex in active]


def _wpsd_inputs(obj, rs, distance: str) -> dict:
    """Weighted PSD's skinning inputs and distance option: SKIN (as published), BLEND (per region, by
    leave-one-out: the skin-weighted distance blended with the global one, or the bone-pair distance) or
    PAIRS (the bone-pair distance everywhere)."""
    d = skin.read_skinning(obj).deformers[0]
    kwargs = skin_group_inputs(rs, d.bone_names, d.weights.bone_index, d.weights.weight)
    if distance in ("BLEND", "PAIRS"):
        arm = skin.armature_modifiers(obj)[0].object
        kwargs["pairs"] = bone_pairs(rs, d.bone_names, d.rest, skin.bone_parents(arm), kwargs["vertex_groups"],
                                     kwargs["vertex_weights"])
        if distance == "PAIRS" and kwargs["pairs"] is None:
            raise ShapeSpaceError(f"the Bone Pairs distance of {obj.name!r} has no pair to measure: no vertex is "
                                  "skinned to two bones whose rotation the pose space reads (add rotation readers "
                                  "of neighbouring bones, or use Skin Weighted)", ErrorCode.WPSD_INPUTS)
        kwargs["blend"] = "auto" if distance == "BLEND" else "pairs"
    return kwargs


def flag_examples(obj) -> list:
    """Recompute duplicate/conflict/outlier flags on the examples; returns the core issues.

    Advisory: called after an operation succeeded, it never raises — unreadable examples leave the flags
    as they are and come back as one warning.
    """
    st = settings(obj)
    exs = list(st.examples)
    if not exs or obj.data.shape_keys is None:
        return []
    try:
        poses = [interpolation_pose(ex) for ex in exs]
        if len({len(p) for p in poses}) != 1:
            return []
        D = example_correctives(obj, exs, missing_as_zero=True)
        issues = example_issues(np.array(poses), D, [ex.name for ex in exs])
    except ShapeSpaceError as exc:
        return [Issue("warning", str(exc.code), f"examples not checked for duplicates: {exc}")]
    for ex in exs:
        ex.flags = ", ".join(sorted({i.code.replace("_", " ") for i in issues if ex.name in i.items}))
    return issues
