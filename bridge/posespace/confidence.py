"""Pose-space confidence in Blender (thesis 9.1–9.2): how well the examples cover the current pose, and a
per-vertex heat map of where a new example would matter.

The maths is :mod:`core.posespace.confidence`; this module trains it from a mesh's examples, writes the
heat map as a colour attribute and the variance the panel shows.
"""
from __future__ import annotations

from ...core.posespace import confidence as gpconf
from ..arrays import write_float
from .correctives import check_not_editing
from .pose import read_pose
from .training import trained_deformer

#: The colour attribute holding the heat map.
CONFIDENCE_ATTRIBUTE = "ShapeSpace Confidence"


def confidence_model(deformer) -> gpconf.GPConfidence:
    """The Gaussian-process model of a trained pose-space deformer: its examples' poses, a Gaussian
    kernel of the deformer's width (prior variance 1)."""
    return gpconf.GPConfidence.fit(deformer.poses, "gaussian", float(deformer.epsilon))


def show_variance(obj, variance: float) -> None:
    """The variance the panel shows next to the Confidence button (``shapespace_face.confidence``)."""
    obj.shapespace_face.confidence = float(variance)


def _write_heat_map(obj, sd) -> None:
    me = obj.data
    attr = me.color_attributes.get(CONFIDENCE_ATTRIBUTE)
    if attr is None or attr.domain != "POINT" or attr.data_type != "FLOAT_COLOR":
        if attr is not None:
            me.color_attributes.remove(attr)
        attr = me.color_attributes.new(CONFIDENCE_ATTRIBUTE, "FLOAT_COLOR", "POINT")
    write_float(attr.data, "color", gpconf.heat_map_colors(sd))
    me.color_attributes.active_color = attr


def confidence(obj, heat_map: bool = False) -> dict:
    """Gaussian-process variance of the pose-space interpolant at the current pose (0 at an example,
    1 far from all), and optionally a per-vertex heat map of the predictive standard deviation
    (a colour attribute) showing where a new example would matter.

    The variance is also stored for the panel (:func:`show_variance`).  Returns ``{"variance",
    "examples"}`` plus ``{"max_sd", "attribute"}`` with the heat map.
    """
    check_not_editing(obj)
    deformer, names = trained_deformer(obj)
    conf = confidence_model(deformer)
    pose = read_pose(obj)
    out = {"variance": float(conf.variance(pose)), "examples": len(names)}
    if heat_map:
        sd = gpconf.vertex_uncertainty(conf, pose, deformer.correctives)
        _write_heat_map(obj, sd)
        out["max_sd"] = float(sd.max())
        out["attribute"] = CONFIDENCE_ATTRIBUTE
    show_variance(obj, out["variance"])
    return out
