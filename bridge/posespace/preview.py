"""Setting the correctives (and driven targets) for the current pose.

Only the active method's correctives are ever on: PSD and Shape-by-Example set the example keys (weighted
PSD's key and muted examples' keys go to 0); weighted PSD sets its own key (every example key goes to 0).
Switching methods in any order therefore gives the method's own result.
"""
from __future__ import annotations

import numpy as np

from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from .. import shapekeys
from ..arrays import write_float
from .examples import basis_positions, check_finite_positions, check_not_editing, example_keys, shape_keys
from .pose import read_pose, settings
from .stored import WPSD_KEY
from .targets import target_driver, write_targets
from .training import trained_deformer


def preview(obj, deformer=None, names=None, driver=None) -> np.ndarray:
    """Set the correctives (and driven targets) for the current pose.

    ``deformer``/``names`` (from :func:`trained_deformer`) and ``driver`` (from :func:`target_driver`) are
    trained here when not given.  Everything is computed before anything is written.  Returns the applied
    weights (PSD/SbE) or displacement (weighted PSD).
    """
    check_not_editing(obj)
    if deformer is None:
        deformer, names = trained_deformer(obj)
    pose = read_pose(obj)
    driver = driver if driver is not None else target_driver(obj)
    targets = list(driver(pose).values()) if driver is not None else None
    if targets is not None and not np.isfinite(targets).all():
        raise _non_finite(obj, "driven target values")
    if deformer.method == "wpsd":
        disp = deformer.evaluate_fast(pose)
        check_finite_positions(disp, f"the weighted PSD corrective of {obj.name!r}")
        result = disp
    else:
        result = deformer.weights(pose)
        if not np.isfinite(result).all():
            raise _non_finite(obj, "example weights")
    if targets is not None:
        write_targets(obj, targets)
    if deformer.method == "wpsd":
        write_wpsd_preview(obj, result)
    else:
        write_example_weights(obj, names, result)
    return result


def _non_finite(obj, what: str) -> ShapeSpaceError:
    return ShapeSpaceError(f"the pose-space {what} of {obj.name!r} are not finite", ErrorCode.NON_FINITE)


def _other_correctives(obj, names) -> list:
    """The correctives' keys that exist but are not among ``names`` (muted examples, weighted PSD's key)."""
    blocks = shape_keys(obj).key_blocks
    keep = set(names)
    return sorted(n for n in example_keys(obj) if n in blocks and n not in keep)


def write_example_weights(obj, names, weights) -> None:
    """PSD / Shape-by-Example: the example keys at ``weights``, every other corrective key at 0."""
    others = _other_correctives(obj, names)
    shapekeys.write_slider_values(obj, list(names) + others, np.concatenate([np.ravel(weights),
                                                                             np.zeros(len(others))]))


def write_wpsd_preview(obj, disp) -> None:
    """Weighted PSD is per vertex: its result lives in one key; every example key stays at 0."""
    key = shape_keys(obj)
    basis = basis_positions(obj)
    if WPSD_KEY not in key.key_blocks:
        obj.shape_key_add(name=WPSD_KEY, from_mix=False)
    key = obj.data.shape_keys
    write_float(key.key_blocks[WPSD_KEY].data, "co", basis + disp)
    key.key_blocks[WPSD_KEY].value = 1.0
    zero = sorted(n for n in example_keys(obj) if n in key.key_blocks and n != WPSD_KEY)
    shapekeys.write_slider_values(obj, zero, np.zeros(len(zero)))


def stop_live_preview(obj, message: str) -> None:
    """Turn Live Preview off for ``obj`` and keep why (the panel shows it until the preview runs again)."""
    st = settings(obj)
    st.live_preview = False
    st.preview_message = message[:1000]


def clear_preview_message(obj) -> None:
    """Forget why Live Preview last stopped (written only when there is something to forget)."""
    st = settings(obj)
    if st.preview_message:
        st.preview_message = ""
