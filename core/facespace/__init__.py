"""Face space: a rig's representations, diagnostics, the face prior, in-betweens and curve inpainting.

J.P. Lewis, *Learning from the Artist*, 2016:

- :mod:`.forms` — whole-face / delta / convex forms of a rig (3.7.3);
- :mod:`.pca` — PCA bases, the affine maps to and from blendshape weights, compression (3.4.6, 3.7.5, 3.7.8);
- :mod:`.diagnostics` — empty targets, coherence and near-duplicates, sparsity (3.7.1, 3.7.6, Figs 3.12–3.15);
- :mod:`.prior` — the face-space Gaussian and its plausibility meter (3.7.9, ch. 6);
- :mod:`.shell` — linear and shell in-betweens (6.5);
- :mod:`.inpainting` — covariance inpainting and superresolution of curves (9.3);
- :mod:`.job` — the pure middle step of each face-space verb of :mod:`bridge.facespace` (arrays in, report out);
- :mod:`.report` — the reports those verbs return (:class:`core.result.Report`).
"""
from .diagnostics import (
                          coherence_image,
                          coherence_matrix,
                          empty_targets,
                          mutual_coherence,
                          similar_pairs,
                          sparsity_comparison,
)
from .forms import (
                          convex_slider_values,
                          delta_weights,
                          from_whole_face,
                          neutral_key_count,
                          project_convex,
                          to_whole_face,
                          whole_face_weights,
)
from .inpainting import context_channels, cubic_fill, fill_gap, gap_mask, inpaint_curve, linear_fill
from .pca import (
                          PCABasis,
                          PCASliders,
                          animation_pca,
                          blendshape_to_pca_maps,
                          compressed_animation_pca,
                          compression_report,
                          fit_pca,
                          pca_from_model,
                          pca_sliders,
                          pca_to_blendshape_maps,
)
from .prior import FaceGaussian, face_gaussian_from_arrays, fit_face_gaussian
from .shell import INTERPOLATIONS, fill_range, inbetween_times, interpolate, linear_interpolate, shell_interpolate

__all__ = [
    # forms (3.7.3)
    "to_whole_face", "from_whole_face", "whole_face_weights", "delta_weights", "project_convex",
    "convex_slider_values", "neutral_key_count",
    # PCA (3.4.6, 3.7.5, 3.7.8)
    "PCABasis", "PCASliders", "fit_pca", "pca_from_model", "animation_pca", "blendshape_to_pca_maps",
    "pca_to_blendshape_maps", "compression_report", "compressed_animation_pca", "pca_sliders",
    # diagnostics (3.7.1, 3.7.6)
    "empty_targets", "coherence_matrix", "mutual_coherence", "similar_pairs", "coherence_image",
    "sparsity_comparison",
    # prior (3.7.9, ch. 6)
    "FaceGaussian", "fit_face_gaussian", "face_gaussian_from_arrays",
    # in-betweens (6.5)
    "INTERPOLATIONS", "linear_interpolate", "shell_interpolate", "interpolate", "inbetween_times", "fill_range",
    # inpainting (9.3)
    "inpaint_curve", "context_channels", "linear_fill", "cubic_fill", "gap_mask", "fill_gap",
]
