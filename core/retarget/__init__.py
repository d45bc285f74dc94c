"""Retargeting: capture readers, expression cloning, space-time cloning, landmarks (thesis 3.5, ch. 5)."""
from .capture import (WeightStream, parse_timecode, read_live_link_csv, resample)
from .cloning import (copy_weights, cloning_matrix, key_poses, fit_frames, spacetime, SpacetimeResult, reduce_keys, reduce_keys_bezier, curve_slopes, hermite, procrustes, landmark_warp, landmark_layout, check_landmarks, peak_landmarks, closest_points)

__all__ = ['WeightStream', 'parse_timecode', 'read_live_link_csv', 'resample', 'copy_weights', 'cloning_matrix', 'key_poses', 'fit_frames', 'spacetime', 'SpacetimeResult', 'reduce_keys', 'reduce_keys_bezier', 'curve_slopes', 'hermite', 'procrustes', 'landmark_warp', 'landmark_layout', 'check_landmarks', 'peak_landmarks', 'closest_points']
