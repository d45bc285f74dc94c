"""The face prior (thesis 3.7.9, ch. 6): learn the Gaussian of a rig's expressions, the probability meter, the
implausible frames of an animation, and in-betweens around the prior's shell (6.5)."""
from __future__ import annotations

import numpy as np

from ...core import facespace as fs
from ...core import validate
from ...core.errors import ErrorCode
from ...core.facespace.job import meter_step, prior_step
from ...core.facespace.report import FillReport, MeterReport, PriorReport
from ...core.result import ShapeSpaceError
from .. import actions, shapekeys
from .readers import (
    animation_weights,
    linear_model,
    refuse_non_finite_frames,
    refuse_non_finite_keys,
    refuse_non_finite_samples,
    tick,
)
from .stored import PRIOR_PROP, damaged, store, stored


def learn_prior(obj, action=None, progress=None) -> PriorReport:
    """Fit the face-space Gaussian to an animation and store it on the rig (names, mean, eigenbasis)."""
    model = linear_model(obj)
    W, _ = animation_weights(obj, model.names, action, min_frames=2)
    tick(progress, 0.5)
    _, blob, report = prior_step(model.names, W)
    store(obj, PRIOR_PROP, blob)
    tick(progress, 1.0)
    return report


def has_prior(obj) -> bool:
    """Whether ``obj``'s shape keys carry a learnt face prior."""
    key = obj.data.shape_keys if obj is not None and obj.type == "MESH" else None
    return key is not None and PRIOR_PROP in key


def prior(obj):
    """The stored face Gaussian and its slider names, or ``(None, None)``.

    The arrays are checked against each other (``mean`` (n,), ``eigvecs`` (n, n), ``eigvals`` (n,) for the
    ``n`` names, :func:`core.facespace.face_gaussian_from_arrays`): a blob that does not fit is refused as
    damaged, naming the Key and the property.
    """
    data = stored(obj, PRIOR_PROP)
    if "mean" not in data:
        return None, None
    try:
        g = fs.face_gaussian_from_arrays(data["names"], data["mean"], data["eigvecs"], data["eigvals"],
                                         data["dimension"], data["ridge"], data["regularised"], data["message"])
    except ShapeSpaceError as exc:
        raise damaged(obj.data.shape_keys, PRIOR_PROP, str(exc)) from None
    return g, list(data["names"])


def _prior_or_error(obj):
    g, names = prior(obj)
    if g is None:
        raise ShapeSpaceError(f"{obj.name!r} has no face prior yet: learn one from an animation first",
                              ErrorCode.NO_PRIOR)
    missing = [n for n in names if n not in obj.data.shape_keys.key_blocks]
    if missing:
        raise ShapeSpaceError(f"the face prior was learnt with shape keys that are gone: {', '.join(missing)}",
                              ErrorCode.STALE_PRIOR)
    return g, names


def meter(obj) -> MeterReport:
    """Where the current expression lies: face norm, the high-probability shell and the χ² percentile."""
    g, names = _prior_or_error(obj)
    return meter_step(g, names, shapekeys.read_slider_values(obj, names), repr(obj.name))


def implausible_frames(obj, action=None, alpha: float = 0.01, progress=None) -> list:
    """``[(frame, reason)]`` of an animation's frames outside the prior's typical shell."""
    g, names = _prior_or_error(obj)
    W, frames = animation_weights(obj, names, action)
    tick(progress, 0.6)
    idx, reasons = g.implausible_frames(W, alpha)
    tick(progress, 1.0)
    return [(int(frames[i]), r) for i, r in zip(idx, reasons)]


def flag_implausible_frames(obj, action=None, alpha: float = 0.01, progress=None) -> list:
    """:func:`implausible_frames`, also listed in ``obj.shapespace_face.implausible`` for the panel."""
    found = implausible_frames(obj, action, alpha, progress)
    items = obj.shapespace_face.implausible
    items.clear()
    for frame, reason in found:
        item = items.add()
        item.frame, item.reason = frame, reason
    return found


def _finite_ends(obj, action, names, curves, frames, ends, inner_range) -> None:
    """Refuse end expressions (2, n) of a fill that are not finite, naming the curve and the key (keys on
    ``inner_range`` are about to be replaced, so they do not matter)."""
    for j, name in enumerate(names):
        if np.isfinite(ends[:, j]).all():
            continue
        fc = curves.get(name)
        if fc is not None:
            refuse_non_finite_keys(action, [fc], skip=inner_range)
        refuse_non_finite_samples(action, fc, np.asarray(frames, float), ends[:, j],
                                   f"shape key {name!r} of {obj.name!r}")


def fill_between(obj, frame_a: int, frame_b: int, mode: str = "SHELL") -> int:
    """Key every frame strictly between ``frame_a`` and ``frame_b`` with expressions interpolated
    around the prior's hyperellipsoid (``SHELL``, norm-preserving, 6.5) or linearly (``LINEAR``)."""
    validate.choice(mode, "mode", fs.INTERPOLATIONS, ErrorCode.MODE)
    inner, t = fs.inbetween_times(frame_a, frame_b)
    g, names = _prior_or_error(obj)
    key = obj.data.shape_keys
    action = actions.active_action(key)
    if action is None:
        raise ShapeSpaceError(f"{obj.name!r} has no shape-key animation to fill", ErrorCode.NO_ACTION)
    ends = actions.sample_shape_keys(obj, names, [frame_a, frame_b], action)
    _finite_ends(obj, action, names, actions.shape_key_curves(obj, action), [frame_a, frame_b], ends,
                 (frame_a + 1, frame_b - 1))
    W = fs.interpolate(g, ends[0], ends[1], t, mode)
    for j, name in enumerate(names):
        fc = actions.ensure_fcurve(key, actions.shape_key_path(name))
        actions.replace_keys_between(fc, frame_a + 1, frame_b - 1, inner, W[:, j])
    return int(inner.size)


def keyed_frames(obj) -> np.ndarray:
    """Every keyed frame (k,) of the rig's shape-key curves (repeats included); a key on a NaN or infinite
    frame is refused, naming its curve."""
    curves = actions.shape_key_curves(obj)
    if not curves:
        return np.zeros(0)
    action = actions.active_action(obj.data.shape_keys)
    out = []
    for fc in curves.values():
        kx = actions.read_curve(fc)[0]
        refuse_non_finite_frames(action, fc, kx)
        out.append(kx)
    return np.concatenate(out)


def fill_around(obj, frame: float, frame_start: int = -1, frame_end: int = -1, mode: str = "SHELL") -> FillReport:
    """:func:`fill_between` from ``frame_start`` to ``frame_end``; a negative one means the key just
    before / after ``frame``.  Returns the frames filled and the two frames used."""
    keyed = keyed_frames(obj) if frame_start < 0 or frame_end < 0 else np.zeros(0)
    a, b = fs.fill_range(keyed, frame, frame_start, frame_end)
    return FillReport(frames=fill_between(obj, a, b, mode), start=a, end=b)


def set_frame(scene, frame: int) -> None:
    """Make ``frame`` the scene's current frame."""
    scene.frame_set(frame)
