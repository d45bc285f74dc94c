"""ShapeSpace core: pure numpy/scipy numerics, no Blender imports.

Importable on its own (``import core`` from the repository root) so the
solvers can be tested, benchmarked and reused without Blender.
"""
from .animation import frames_to_seconds, sample_keys, seconds_to_frames
from .blendshape import BlendshapeModel, bounding_box_diagonal, diagnose_model
from .names import ARKIT_52, canonical_name, match_channels
from .result import Issue, Result, ShapeSpaceError
from .skinning import (
                       ArmatureDeform,
                       SkinningRig,
                       SkinWeights,
                       deform,
                       diagnose_weights,
                       dual_quaternion_skinning,
                       linear_blend_skinning,
)

__all__ = [
    "ARKIT_52", "ArmatureDeform", "BlendshapeModel", "Issue", "Result", "ShapeSpaceError",
    "SkinWeights", "SkinningRig", "bounding_box_diagonal", "canonical_name", "deform",
    "diagnose_model", "diagnose_weights", "dual_quaternion_skinning", "frames_to_seconds",
    "linear_blend_skinning", "match_channels", "sample_keys", "seconds_to_frames",
]
