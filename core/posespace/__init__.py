"""Pose-space deformation: readers, PSD / Shape-by-Example / weighted PSD, rest-space inversion, confidence (thesis ch. 7–9)."""
from .readers import (PoseReader, READER_DIMS, quaternion_distance, quaternion_to_matrix, swing_twist, reader_features, pose_features, feature_groups, mirror_name, mirror_features, mirror_pose)
from .psd import (PoseSpaceDeformer, train_psd, example_issues, ScalarDriver, train_driver)
from .inversion import (InversionResult, vertex_jacobians, invert_deformation)
from .confidence import (GPConfidence, gp_variance, vertex_uncertainty)

__all__ = ['PoseReader', 'READER_DIMS', 'quaternion_distance', 'quaternion_to_matrix', 'swing_twist', 'reader_features', 'pose_features', 'feature_groups', 'mirror_name', 'mirror_features', 'mirror_pose', 'PoseSpaceDeformer', 'train_psd', 'example_issues', 'ScalarDriver', 'train_driver', 'InversionResult', 'vertex_jacobians', 'invert_deformation', 'GPConfidence', 'gp_variance', 'vertex_uncertainty']
