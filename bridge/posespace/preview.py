"""Setting the correctives (and driven targets) for the current pose."""
from __future__ import annotations

import numpy as np

from .. import shapekeys
from ..arrays import write_float
from .examples import basis_positions
from .pose import read_pose
from .stored import WPSD_KEY
from .targets import target_driver, write_targets
from .training import trained_deformer


def preview(obj, deformer=None, names=None, driver=None) -> np.ndarray:
    """Set the correctives (and driven targets) for the current pose.

    ``deformer``/``names`` (from :func:`trained_deformer`) and ``driver`` (from :func:`target_driver`) are
    trained here when not given.  Returns the applied weights (PSD/SbE) or displacement (weighted PSD).
    """
    if deformer is None:
        deformer, names = trained_deformer(obj)
    pose = read_pose(obj)
    driver = driver if driver is not None else target_driver(obj)
    if driver is not None:
        write_targets(obj, list(driver(pose).values()))
    if deformer.method == "wpsd":
        disp = deformer.evaluate_fast(pose)
        write_wpsd_preview(obj, disp, names)
        return disp
    w = deformer.weights(pose)
    shapekeys.write_slider_values(obj, names, w)
    return w


def write_wpsd_preview(obj, disp, names) -> None:
    """Weighted PSD is per vertex: its result lives in one key; the example keys stay at 0."""
    key = obj.data.shape_keys
    if WPSD_KEY not in key.key_blocks:
        obj.shape_key_add(name=WPSD_KEY, from_mix=False)
    key = obj.data.shape_keys
    write_float(key.key_blocks[WPSD_KEY].data, "co", basis_positions(obj) + disp)
    key.key_blocks[WPSD_KEY].value = 1.0
    shapekeys.write_slider_values(obj, names, np.zeros(len(names)))
