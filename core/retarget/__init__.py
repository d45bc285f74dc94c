"""Retargeting: performances from captures, actions or meshes onto a shape-key rig (thesis 3.5, ch. 5).

- :mod:`.capture` — Live Link Face CSV reading and resampling;
- :mod:`.formats` — the other capture apps' recordings (Face Cap, iFacialMocap, Audio2Face, MediaPipe);
- :mod:`.cloning` — copy with gain/offset, learned cloning matrix, key poses (3.5.3);
- :mod:`.perframe` — per-frame bounded fits;
- :mod:`.spacetime_solver` — space-time cloning with slider bounds (ch. 5);
- :mod:`.landmarks` — Procrustes, landmark checks and warps, closest points (3.5.4);
- :mod:`.transfer` — dense performances onto the target's vertices;
- :mod:`.performance` — a whole performance through one method, with its errors;
- :mod:`.metrics` — position / velocity error, clipping, slider scales;
- :mod:`.report` — the per-source report;
- :mod:`.job` — the middle step of a retarget job: from the plan read out of Blender to the curves to write.

Key reduction (F-curve maths) lives in the foundation module :mod:`core.keyreduce`.
"""
from .capture import ROTATION_CHANNELS, WeightStream, parse_timecode, read_live_link_csv, resample
from .cloning import (
                      MAX_MAPPING_VALUE,
                      LearnedCloning,
                      cloning_matrix,
                      copy_weights,
                      key_frames_in_span,
                      key_poses,
                      learned_cloning,
                      moving_channels,
                      resolve_channel_mapping,
                      split_mapping,
                      suggest_key_frames,
)
from .formats import KINDS, describe_stream, detect_kind, parse_capture, read_capture
from .landmarks import check_landmarks, closest_points, landmark_layout, landmark_warp, peak_landmarks, procrustes
from .metrics import clipped_mask, per_vertex_mm, position_error_rms, slider_scales, velocity_error_rms
from .performance import (
                      GEOMETRIC_METHODS,
                      METHODS,
                      PerformanceFit,
                      normalised_basis,
                      retarget_positions,
                      retarget_weights,
)
from .perframe import fit_frames
from .report import RetargetReport
from .spacetime_solver import GreenTables, SpacetimeResult, SpacetimeSystem, spacetime
from .transfer import moving_vertices, stabilise, transfer_motion

__all__ = [
    # capture
    "WeightStream", "parse_timecode", "read_live_link_csv", "resample", "ROTATION_CHANNELS",
    "KINDS", "detect_kind", "read_capture", "parse_capture", "describe_stream",
    # cloning (3.5.3)
    "copy_weights", "split_mapping", "cloning_matrix", "key_poses", "moving_channels", "suggest_key_frames",
    "key_frames_in_span", "LearnedCloning", "learned_cloning", "resolve_channel_mapping", "MAX_MAPPING_VALUE",
    # per-frame and space-time fits (ch. 5)
    "fit_frames", "spacetime", "SpacetimeResult", "SpacetimeSystem", "GreenTables",
    # landmarks and dense transfer (3.5.4)
    "procrustes", "landmark_layout", "check_landmarks", "landmark_warp", "peak_landmarks", "closest_points",
    "stabilise", "transfer_motion", "moving_vertices",
    # whole performances, metrics, report
    "METHODS", "GEOMETRIC_METHODS", "PerformanceFit", "normalised_basis", "retarget_weights", "retarget_positions",
    "position_error_rms", "velocity_error_rms", "per_vertex_mm", "clipped_mask", "slider_scales", "RetargetReport",
]
