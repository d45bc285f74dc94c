"""Retargeting onto a shape-key rig in Blender: sources read, results written back (thesis 3.5, ch. 5).

Blender I/O and orchestration only — the middle step of a retarget job (fit, key reduction, checks) is
:mod:`core.retarget.job`, the numerics (cloning, per-frame and space-time fits, dense transfer, errors) the rest of
:mod:`core.retarget`.  Sources are capture recordings, actions and animated meshes; every result is a new action
on the target's Key, with its :class:`~core.retarget.RetargetReport` kept on the Key (for the panel and *Discard
Result*) next to the channel-mapping overrides.

- :mod:`.sources` — capture recordings and actions read, the head / eye bones, key poses;
- :mod:`.run` — a retarget: read the plan, compute (worker thread or not), write the result in one step;
- :mod:`.last_result` — the last result's report on the Key, and *Discard Result*;
- :mod:`.mapping` — the channel mapping: stored overrides, then name matching;
- :mod:`.dense` — mesh performances read frame by frame, landmark pairs;
- :mod:`.landmarks` — landmark vertex groups placed by hand or found from shared shapes.
"""
from ...core.retarget import METHODS
from ...core.retarget.job import KEY_SHAPES, RetargetOutcome, RetargetPlan, compute_retarget
from .dense import LANDMARK_PREFIX, STABLE_GROUP, dense_source_positions, landmark_pairs, mesh_sequence
from .landmarks import add_landmark, landmarks_from_shapes, selected_vertex
from .last_result import LAST_PROP, LAST_SCHEMA, REPORT_KEYS, discard_last, has_result, last_report
from .mapping import (
                      MAPPING_PROP,
                      MAPPING_SCHEMA,
                      MAX_MAPPING_VALUE,
                      channel_mapping,
                      remove_mapping,
                      resolve_mapping,
                      set_mapping,
                      stored_mapping,
)
from .run import (
                      NONLINEAR_MESSAGE,
                      finish_retarget_job,
                      read_retarget,
                      read_retarget_dense,
                      reduce_action_keys,
                      retarget,
                      retarget_dense,
                      start_retarget_job,
                      write_retarget,
)
from .sources import (
                      CAPTURE_EXTENSIONS,
                      KEY_POSE_MARKER,
                      HeadEyeBones,
                      bone_specs,
                      is_capture_file,
                      read_capture_source,
                      read_source,
                      suggest_key_poses,
                      write_pose_bones,
)

__all__ = ["METHODS", "KEY_SHAPES", "read_source", "read_capture_source", "is_capture_file",
           "channel_mapping", "resolve_mapping", "suggest_key_poses",
           "retarget", "retarget_dense", "RetargetPlan", "RetargetOutcome", "read_retarget", "read_retarget_dense",
           "compute_retarget", "write_retarget", "start_retarget_job", "finish_retarget_job",
           "reduce_action_keys", "last_report", "has_result", "discard_last",
           "stored_mapping", "set_mapping", "remove_mapping", "landmark_pairs", "mesh_sequence",
           "dense_source_positions", "add_landmark", "landmarks_from_shapes", "selected_vertex",
           # names other modules and the tests use
           "CAPTURE_EXTENSIONS", "KEY_POSE_MARKER", "HeadEyeBones", "bone_specs",
           "write_pose_bones", "NONLINEAR_MESSAGE",
           "MAPPING_PROP", "MAPPING_SCHEMA", "MAX_MAPPING_VALUE", "LAST_PROP", "LAST_SCHEMA", "REPORT_KEYS",
           "LANDMARK_PREFIX", "STABLE_GROUP"]
