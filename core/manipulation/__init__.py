"""Pin-and-drag direct manipulation of blendshape sliders (thesis ch. 4).

- :mod:`.pins` — :class:`Pin` (a surface point), the pins' rows of the delta matrix and their positions;
- :mod:`.rig` — :func:`check_model` (refuse a non-finite rig, naming key and vertex) and :func:`inert_keys`
  (keys that move no vertex: every solve leaves their sliders where they are), both once per model object
  (:func:`rig_facts`);
- :mod:`.prior` — the learned prior of thesis 4.3 (:class:`WeightPrior`, :func:`train_prior`, Eq. 4.8/4.9 terms);
- :mod:`.solve` — :func:`solve_drag` (Eq. 4.5, 4.8, 4.9; Gauss–Newton for in-betweens and combinations),
  :func:`drag_objective` and the independent :func:`solve_drag_reference`;
- :mod:`.session` — :class:`DragSession`, the warm start one interactive drag carries between mouse moves.

``NORMALISED_DIAGONAL`` (the size every solve measures positions at) is re-exported from
:mod:`core.blendshape`.
"""
from ..blendshape import NORMALISED_DIAGONAL
from .pins import Pin, PinRows, pin_matrix, pin_positions, pin_rest_positions
from .prior import WeightPrior, train_prior
from .rig import RigFacts, check_model, inert_keys, rig_facts
from .session import DragSession
from .solve import DragResult, drag_objective, solve_drag, solve_drag_reference

__all__ = ["NORMALISED_DIAGONAL", "Pin", "PinRows", "WeightPrior", "DragResult", "DragSession", "pin_matrix",
           "pin_rest_positions", "pin_positions", "train_prior", "solve_drag", "solve_drag_reference",
           "drag_objective", "check_model", "inert_keys", "rig_facts", "RigFacts"]
