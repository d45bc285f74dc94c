"""Pose-space correctives in Blender (thesis ch. 7–9): the verbs operators, the live preview and tools use.

Modules by level: a module imports only modules of lower levels of this package, and each module's level is one
more than the highest level it imports (``tests/core/test_imports.py`` checks both against this list).

- level 0: :mod:`.pose` — the pose space: settings, armature, readers, the current pose;
- level 1: :mod:`.stored` — the examples' stored JSON (versioned schemas), the names ShapeSpace creates and
  settings pinned since their default changed;
- level 2: :mod:`.correctives` — the correctives' shape keys and the checks every verb makes first;
  :mod:`.targets` — driven targets (7.3.3);
- level 3: :mod:`.inversion` — invert a posed sculpt through the deformation to rest space (7.2.1);
  :mod:`.training` — train the deformer from the examples; flag bad examples (ch. 8);
  :mod:`.mirror` — Mirror Example;
- level 4: :mod:`.finalshape` — final shapes: keep each sculpt, find stale correctives, re-invert them;
  :mod:`.masked` — push a sculpt split by vertex-group masks;
  :mod:`.preview` — set the correctives and driven targets for the current pose;
  :mod:`.bake` — bake to shape-key animation or a PC2 point cache;
  :mod:`.confidence` — Gaussian-process confidence and its heat map (9.1–9.2);
- level 5: :mod:`.sculpt` — Apply Sculpt: invert the sculpt, store the corrective and the final shape;
- level 6: :mod:`.postdeform` — post-deformation correctives (frame offsets applied after skinning);
- level 7: :mod:`.examples` — add, move and remove examples.
"""
from .bake import MESH_CACHE_NAME, bake_point_cache, bake_weights, cache_path, default_cache_name, stored_cache_path
from .confidence import CONFIDENCE_ATTRIBUTE, confidence, confidence_model, show_variance
from .correctives import check_not_editing, check_topology, example_correctives, example_keys, pre_armature_positions
from .examples import add_example, move_example, posed_copy, problem, remove_example, remove_sculpt_copy
from .inversion import TEMP_KEY, modelled_exactly
from .mirror import mirror_example
from .pose import add_default_readers, armature_of, default_readers, read_pose, readers, settings
from .preview import (
                   cached_model,
                   clear_preview_message,
                   forget_models,
                   model_method,
                   preview,
                   stop_live_preview,
                   write_wpsd_preview,
)
from .sculpt import apply_example
from .stored import (
                   POSE_SCHEMA,
                   PSEUDO_POSE_SCHEMA,
                   SCULPT_SUFFIX,
                   TARGET_VALUES_SCHEMA,
                   WPSD_KEY,
                   check_examples,
                   example_pose,
                   find_example,
                   interpolation_pose,
                   pseudo_pose,
                   target_values,
                   wpsd_distance,
)
from .targets import add_target, read_targets, record_targets, target_driver, write_targets
from .training import flag_examples, trained_deformer

__all__ = [
    "settings", "armature_of", "readers", "read_pose", "default_readers", "add_default_readers",
    "SCULPT_SUFFIX", "WPSD_KEY", "POSE_SCHEMA", "PSEUDO_POSE_SCHEMA", "TARGET_VALUES_SCHEMA", "find_example",
    "example_pose", "pseudo_pose", "interpolation_pose", "target_values", "wpsd_distance",
    "add_example", "posed_copy", "remove_example", "remove_sculpt_copy", "move_example", "check_topology",
    "check_examples", "check_not_editing", "problem",
    "pre_armature_positions", "example_keys", "example_correctives",
    "TEMP_KEY", "apply_example", "modelled_exactly",
    "trained_deformer", "flag_examples",
    "preview", "cached_model", "forget_models", "model_method", "write_wpsd_preview", "stop_live_preview",
    "clear_preview_message",
    "add_target", "read_targets", "write_targets", "record_targets", "target_driver",
    "mirror_example",
    "MESH_CACHE_NAME", "bake_weights", "bake_point_cache", "cache_path", "default_cache_name",
    "stored_cache_path",
    "CONFIDENCE_ATTRIBUTE", "confidence", "confidence_model", "show_variance",
]
