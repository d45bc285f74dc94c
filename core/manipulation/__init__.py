"""Pin-and-drag direct manipulation (thesis ch. 4)."""
from .solve import (NORMALISED_DIAGONAL, Pin, WeightPrior, DragResult, pin_matrix, pin_rest_positions, pin_positions, train_prior, solve_drag, solve_drag_reference, drag_objective)

__all__ = ['NORMALISED_DIAGONAL', 'Pin', 'WeightPrior', 'DragResult', 'pin_matrix', 'pin_rest_positions', 'pin_positions', 'train_prior', 'solve_drag', 'solve_drag_reference', 'drag_objective']
