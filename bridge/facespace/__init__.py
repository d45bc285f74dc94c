"""Face-space tools in Blender (thesis 3.7, ch. 6, 9.3): rig conversions, diagnostics, the face prior,
shell in-betweens and curve inpainting.

Blender I/O and orchestration only: each verb reads Blender data through the other bridge modules, hands arrays to
the pure step of :mod:`core.facespace.job`, and writes *new* keys, objects, images or actions — the user's shape
keys are only changed by the verbs that say so (making the sliders convex, filling frames, inpainting a gap).  The
verbs that report return the typed reports of :mod:`core.facespace.report`.

- :mod:`.stored` — the JSON blobs kept on the rig's Key datablock (:data:`REPRESENTATION_SCHEMA`,
  :data:`PRIOR_SCHEMA`, :data:`ANALYSIS_SCHEMA`), written and read through :mod:`bridge.storage`;
- :mod:`.readers` — shared readers: the rig as a linear model, its animation at whole frames, NaN refusals;
- :mod:`.conversions` — whole-face, delta and PCA copies, Make Convex (3.7.3, 3.4.6);
- :mod:`.reports` — the compression report and the rig analysis (3.7);
- :mod:`.prior` — the face prior, its meter, implausible frames, in-betweens (3.7.9, ch. 6);
- :mod:`.inpainting` — curve inpainting (9.3).
"""
from .conversions import (
                          FORMS,
                          NEUTRAL_KEY,
                          SLIDER_LIMIT,
                          ZERO_KEY,
                          convert_rig,
                          make_convex,
                          to_delta_object,
                          to_pca_object,
                          to_pca_object_relative,
                          to_whole_face_object,
                          whole_face_issue,
)
from .inpainting import inpaint_gap
from .prior import (
                          fill_around,
                          fill_between,
                          flag_implausible_frames,
                          has_prior,
                          implausible_frames,
                          keyed_frames,
                          learn_prior,
                          meter,
                          prior,
                          set_frame,
)
from .readers import MAX_FRAMES, animation_weights, linear_model
from .reports import analyse, compression, compression_relative
from .stored import (
                          ANALYSIS_PROP,
                          ANALYSIS_SCHEMA,
                          COHERENCE_SCHEMA,
                          COMPRESSION_SCHEMA,
                          PRIOR_PROP,
                          PRIOR_SCHEMA,
                          REPRESENTATION_PROP,
                          REPRESENTATION_SCHEMA,
                          stored,
                          stored_analysis,
)

__all__ = [
    "REPRESENTATION_PROP", "PRIOR_PROP", "ANALYSIS_PROP", "REPRESENTATION_SCHEMA", "PRIOR_SCHEMA",
    "ANALYSIS_SCHEMA", "COMPRESSION_SCHEMA", "COHERENCE_SCHEMA", "stored", "stored_analysis",
    "MAX_FRAMES", "linear_model", "animation_weights",
    "NEUTRAL_KEY", "ZERO_KEY", "FORMS", "SLIDER_LIMIT", "to_whole_face_object", "whole_face_issue",
    "to_delta_object", "to_pca_object", "to_pca_object_relative", "convert_rig", "make_convex",
    "compression", "compression_relative", "analyse",
    "learn_prior", "has_prior", "prior", "meter", "implausible_frames", "flag_implausible_frames", "fill_between",
    "keyed_frames", "fill_around", "set_frame",
    "inpaint_gap",
]
