"""Rig authoring (issue #13): give any head a blendshape rig by model transfer (thesis 3.4.1).

- :mod:`.landmarks` — landmark pairs (hand-placed, from shared shapes), validated;
- :mod:`.registration` — similarity + RBF warp + non-rigid ICP of the source neutral onto the target, and
  the dense source-triangle ↔ target-point map (:class:`Correspondence`);
- :mod:`.transfer` — deformation transfer of every source shape onto the target (Sumner & Popović 2004),
  factorised once, and name-convention conversion;
- :mod:`.proposal` — automatic landmark pairs for a target head without shapes;
- :mod:`.parts` — the target's facial parts (eyes, teeth, tongue, lashes, brows, cavity) and how each moves;
- :mod:`.contacts` — eye and mouth openings: the source's lid/lip closure carried onto the target's gap;
- :mod:`.quality` — the per-key checks of a transfer (gap left, crossings, symmetry, size, parts);
- :mod:`.examples` — example-guided refinement of transferred keys (Li, Weise & Pauly 2010);
- :mod:`.mesh` — triangle-mesh helpers.

Imports only foundation modules (``core.rbf``, ``core.names``, ``core.result``, ``core.validate``).
"""
from .landmarks import (
    MIN_LANDMARKS,
    LandmarkPairs,
    check_landmarks,
    landmarks_from_indices,
    landmarks_from_points,
    landmarks_from_shared_shapes,
)
from .mesh import bbox_diagonal, mm_per_unit, symmetry_plane, triangle_parts, triangulate
from .proposal import propose_landmark_pairs
from .registration import Correspondence, register, similarity, warp_points
from .transfer import NAMINGS, Transfer, TransferredShapes, convert_name, transfer_shapes

__all__ = [
    "MIN_LANDMARKS", "LandmarkPairs", "check_landmarks", "landmarks_from_indices", "landmarks_from_points",
    "landmarks_from_shared_shapes", "bbox_diagonal", "mm_per_unit", "symmetry_plane", "triangle_parts",
    "triangulate", "Correspondence", "register", "similarity", "warp_points", "NAMINGS", "Transfer",
    "TransferredShapes", "convert_name", "transfer_shapes", "propose_landmark_pairs",
]
