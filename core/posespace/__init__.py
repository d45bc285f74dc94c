"""Pose-space deformation (thesis ch. 7–9).

- :mod:`.readers` — the pose space: :class:`PoseReader` and the features a rig's pose maps to (7.3, 8.1);
- :mod:`.psd` — PSD, Shape-by-Example and weighted PSD: :func:`train_psd`, :class:`PoseSpaceDeformer`
  (ch. 8, Eq. 8.3–8.4);
- :mod:`.pairs` — weighted PSD's bone-pair distance: relative rotations between a vertex's bones (8.1);
- :mod:`.examples` — duplicate, conflicting and outlier examples (8.2.1, 8.2.3);
- :mod:`.drivers` — scalar targets driven from pose space (7.3.3);
- :mod:`.inversion` — rest-space inversion of posed sculpts (7.2.1);
- :mod:`.mirror` — left↔right mirroring of names, poses and correctives;
- :mod:`.confidence` — Gaussian-process confidence of the interpolation (9.1–9.2).
"""
from .confidence import GP_KERNELS, GPConfidence, gp_variance, heat_map_colors, vertex_uncertainty
from .drivers import ScalarDriver, train_driver, train_target_driver
from .examples import example_issues
from .inversion import InversionResult, invert_deformation, vertex_jacobians
from .mirror import mirror_displacements, mirror_features, mirror_name, mirror_partners, mirror_pose
from .pairs import BonePairs, bone_pairs
from .psd import (
                  AMPLIFICATION_LIMIT,
                  METHODS,
                  PoseSpaceDeformer,
                  affine_determined,
                  default_epsilon,
                  regularisation,
                  skin_group_inputs,
                  train_psd,
)
from .readers import (
                  READER_DIMS,
                  PoseReader,
                  feature_groups,
                  pose_features,
                  quaternion_distance,
                  quaternion_to_matrix,
                  reader_features,
                  swing_twist,
)

__all__ = [
    "PoseReader", "READER_DIMS", "quaternion_distance", "quaternion_to_matrix", "swing_twist", "reader_features",
    "pose_features", "feature_groups",
    "METHODS", "AMPLIFICATION_LIMIT", "PoseSpaceDeformer", "train_psd", "default_epsilon", "affine_determined",
    "regularisation", "skin_group_inputs", "BonePairs", "bone_pairs",
    "example_issues",
    "ScalarDriver", "train_driver", "train_target_driver",
    "InversionResult", "vertex_jacobians", "invert_deformation",
    "mirror_name", "mirror_features", "mirror_pose", "mirror_partners", "mirror_displacements",
    "GP_KERNELS", "GPConfidence", "gp_variance", "vertex_uncertainty", "heat_map_colors",
]
