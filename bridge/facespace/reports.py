"""Reports and diagnostics of a face rig (thesis 3.7): the compression report and the rig analysis (coherence
image, near-duplicate and empty targets, sparsity), both stored on the rig for the panel."""
from __future__ import annotations

import os

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.facespace.job import coherence_step, compression_step
from ...core.facespace.report import CoherenceReport, CompressionReport
from ...core.result import ShapeSpaceError
from .. import actions
from .readers import animation_weights, linear_model, tick
from .stored import ANALYSIS_PROP, store, stored_analysis


def compression(obj, action, tol: float, progress=None) -> CompressionReport:
    """How many PCA components keep an animation's max vertex error within ``tol`` (3.7.8).

    The report is stored for the panel (also when no number of components reaches ``tol``, which is then
    raised as an error).  ``progress`` (optional) is called with the fraction of the work done.
    """
    model = linear_model(obj)
    data = stored_analysis(obj)
    W, _ = animation_weights(obj, model.names, action, min_frames=2)
    tick(progress, 0.2)
    report = compression_step(model, W, tol, progress)
    data["compression"] = report.payload()
    store(obj, ANALYSIS_PROP, data)
    tick(progress, 1.0)
    if report.components is None:
        raise ShapeSpaceError(report.message, ErrorCode.TOLERANCE_NOT_MET)
    return report


def compression_relative(obj, tolerance: float, progress=None) -> CompressionReport:
    """:func:`compression` of the rig's own action with ``tolerance`` a fraction of the head size."""
    return compression(obj, None, tolerance * linear_model(obj).scale, progress)


def _png_target(path: str) -> str:
    """The absolute path to write the coherence PNG to, refused when that would overwrite something else:
    a .blend file, a folder, a missing folder, a non-regular file or an existing file that is not a PNG."""
    path = os.path.normpath(os.path.abspath(path))
    blend = bpy.data.filepath and os.path.normpath(os.path.abspath(bpy.data.filepath))
    if path == blend or path.lower().endswith((".blend", ".blend1")):
        raise ShapeSpaceError(f"{path!r} is a .blend file: give a .png file path", ErrorCode.OVERWRITE)
    if os.path.isdir(path):
        raise ShapeSpaceError(f"{path!r} is a folder: give a .png file path", ErrorCode.NOT_A_FILE)
    if not os.path.isdir(os.path.dirname(path)):
        raise ShapeSpaceError(f"the folder of {path!r} does not exist", ErrorCode.UNWRITABLE)
    if os.path.lexists(path):
        if not os.path.isfile(path):
            raise ShapeSpaceError(f"{path!r} is not a regular file", ErrorCode.NOT_A_FILE)
        try:
            with open(path, "rb") as fh:
                head = fh.read(8)
        except OSError as exc:
            raise ShapeSpaceError(f"cannot read {path!r} ({exc.strerror})", ErrorCode.UNWRITABLE) from None
        if head != b"\x89PNG\r\n\x1a\n":
            raise ShapeSpaceError(f"{path!r} exists and is not a PNG image: choose another file",
                                  ErrorCode.OVERWRITE)
    return path


def _coherence_image(name: str, image: np.ndarray, png_path: str = None):
    """The image datablock ``name`` holding ``image`` (rows top-down, RGBA uint8), saved as a PNG or packed."""
    img = bpy.data.images.get(name)
    if img is not None and tuple(img.size) != (image.shape[1], image.shape[0]):
        bpy.data.images.remove(img)
        img = None
    img = img or bpy.data.images.new(name, image.shape[1], image.shape[0], alpha=True)
    img.pixels.foreach_set((image[::-1].astype(np.float32) / 255.0).ravel())   # Blender's rows go up
    if png_path:
        img.filepath_raw = png_path
        img.file_format = "PNG"
        try:
            img.save()
        except RuntimeError as exc:
            raise ShapeSpaceError(f"could not write {png_path!r}: {str(exc).strip().splitlines()[-1]}",
                                  ErrorCode.UNWRITABLE) from None
    else:
        img.pack()
    return img


def analyse(obj, action=None, png_path: str = None, threshold: float = 0.95, progress=None) -> CoherenceReport:
    """Coherence image (PNG + image datablock), near-duplicate pairs, empty targets and, with an
    animation, the sparsity of its blendshape weights vs PCA coefficients (3.7.1, 3.7.6, Figs 3.12–3.15).

    Everything is read and computed before the image is made and the report stored.  ``progress``
    (optional) is called with the fraction of the work done.
    """
    png_path = _png_target(png_path) if png_path else None
    model = linear_model(obj)
    data = stored_analysis(obj)
    tick(progress, 0.1)
    key_action = action or actions.active_action(obj.data.shape_keys)
    W = animation_weights(obj, model.names, key_action)[0] \
        if key_action is not None and actions.shape_key_curves(obj, key_action) else None
    report, image = coherence_step(model, W, threshold, png_path or "", progress)
    report.image = _coherence_image(f"ShapeSpace Coherence {obj.name}", image, png_path).name
    data["coherence"] = report.payload()
    store(obj, ANALYSIS_PROP, data)
    tick(progress, 1.0)
    return report
