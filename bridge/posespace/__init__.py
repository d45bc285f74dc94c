"""Pose-space correctives in Blender (thesis ch. 7–9): the verbs operators, the live preview and tools use.

- :mod:`.pose` — the pose space: settings, armature, readers, the current pose;
- :mod:`.stored` — the examples' stored JSON (versioned schemas) and the names ShapeSpace creates;
- :mod:`.examples` — add, move and remove examples; their correctives; pre-armature positions;
- :mod:`.sculpt` — Apply Sculpt: invert a posed sculpt to rest space (7.2.1);
- :mod:`.training` — train the deformer from the examples; flag bad examples (ch. 8);
- :mod:`.preview` — set the correctives and driven targets for the current pose;
- :mod:`.targets` — driven targets (7.3.3);
- :mod:`.mirror` — Mirror Example;
- :mod:`.bake` — bake to shape-key animation or a PC2 point cache;
- :mod:`.confidence` — Gaussian-process confidence and its heat map (9.1–9.2).
"""
from .bake import (MESH_CACHE_NAME, bake_point_cache, bake_weights, cache_path, default_cache_name,
                   stored_cache_path)
from .confidence import CONFIDENCE_ATTRIBUTE, confidence, confidence_model, show_variance
from .examples import (add_example, check_not_editing, check_topology, example_correctives,
                       example_keys, move_example, posed_copy, pre_armature_positions, problem, remove_example,
                       remove_sculpt_copy)
from .mirror import mirror_example
from .pose import add_default_readers, armature_of, default_readers, read_pose, readers, settings
from .preview import (cached_model, clear_preview_message, forget_models, model_method, preview, stop_live_preview,
                      write_wpsd_preview)
from .sculpt import TEMP_KEY, apply_example, modelled_exactly
from .stored import (POSE_SCHEMA, PSEUDO_POSE_SCHEMA, SCULPT_SUFFIX, TARGET_VALUES_SCHEMA, WPSD_KEY, check_examples,
                     example_pose, find_example, interpolation_pose, pseudo_pose, target_values, wpsd_distance)
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
