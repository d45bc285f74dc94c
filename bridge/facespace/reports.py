"""Reports and diagnostics of a face rig (thesis 3.7): the compression report and the rig analysis (coherence
image, near-duplicate and empty targets, sparsity), both stored on the rig for the panel."""
from __future__ import annotations

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.facespace.job import coherence_step, compression_step
from ...core.facespace.report import CoherenceReport, CompressionReport
from ...core.paths import check_output_file
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


def _is_png(path: str) -> bool:
    """Whether the existing file ``path`` is a PNG image (its 8-byte signature): the only file a coherence image
    may replace."""
    try:
        with open(path, "rb") as fh:
            return fh.read(8) == b"\x89PNG\r\n\x1a\n"
    except OSError:
        return False


def _png_target(path: str) -> str:
    """The absolute path to write the coherence PNG to, refused when that would overwrite something else
    (:func:`core.paths.check_output_file`: a .blend file, a folder, a missing folder, a non-regular file, the open
    .blend or an existing file that is not a PNG)."""
    return check_output_file(path, what="a PNG image", inputs=(bpy.data.filepath,), replaceable=_is_png)


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
